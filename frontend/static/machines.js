// Machines: every signed-in user picks the machine here; admins add, change and delete machines
// (operators see the same form read-only). Test connection reads the controller's offset in a slot.
"use strict";
const state = { machines: [], tables: [], cameras: [], editing: null, admin: false, defaults: {} };
const AXES = ["x", "y", "z"];
const LIMITS = { max_tilt_deg: ["tilt", "°"], max_offset_change_mm: ["X, Y, Z change", " mm"],
                 max_offset_change_deg: ["C change", "°"] };
const limitField = (name) => document.querySelector(`[data-limit="${name}"]`);

/** The limit fields as the API takes them: a number, or null (empty: the global setting). */
function limitsFromFields() {
  const out = {};
  for (const [name, [what]] of Object.entries(LIMITS)) {
    const f = limitField(name);
    if (f.validity.badInput) throw new Error(`The ${what} limit is not a number.`);
    out[name] = f.value.trim() === "" ? null : Number(f.value);
  }
  return out;
}

/** Which limits are in force, and from where: this machine's fields or the global settings. */
function showLimitsInForce() {
  const parts = Object.entries(LIMITS).map(([name, [what, unit]]) => {
    const own = limitField(name).value.trim(), d = state.defaults[name];
    return own !== "" ? `${what} ${own}${unit} (this machine)` : d ? `${what} ${d.value}${unit} (${d.setting})` : "";
  });
  $("limits-note").textContent = "In force: " + parts.filter(Boolean).join(" · ");
}

/** T_machine_table from the X, Y, Z, C fields: a turn C about z, then the corner's position (mm). */
function poseFromFields() {
  const c = Number($("t-c").value) * Math.PI / 180, co = Math.cos(c), si = Math.sin(c);
  return [[co, -si, 0, Number($("t-x").value)], [si, co, 0, Number($("t-y").value)],
          [0, 0, 1, Number($("t-z").value)], [0, 0, 0, 1]];
}

/** A jogged point from its X, Y, Z fields (Z optional unless `needZ`), or null when X and Y are empty. */
function pointFromFields(prefix, needZ = false) {
  const v = (a) => $(`${prefix}-${a}`).value.trim();
  if (!v("x") && !v("y") && !v("z")) return null;
  const p = { x_mm: Number(v("x")), y_mm: Number(v("y")) };
  if (v("z") || needZ) p.z_mm = Number(v("z"));
  return p;
}

/** Ask the service for the table's pose from the points (and C as typed when no edge point is given),
 *  show its picture and notes; with `fill`, put the pose into the X, Y, Z, C fields. */
async function workOutPose(fill) {
  const table = Number($("m-table").value);
  if (!table) return;
  const body = { table_model_id: table, corner: pointFromFields("t", true), x_edge: pointFromFields("p2"),
                 y_edge: pointFromFields("p3"), c_deg: Number($("t-c").value) };
  const r = await postJSON("/api/v1/machines/table-frame", body);
  if (fill) $("t-c").value = +r.c_deg.toFixed(4);
  $("frame-notes").replaceChildren(...r.notes.map((n) => el("li", { text: n })));
  $("table-figure").src = "data:image/svg+xml;charset=utf-8," + encodeURIComponent(r.svg);
  $("table-figure").classList.remove("hidden");
  return r;
}

/** Read where the tool tip is from the saved controller into point `n`'s fields. */
async function readPoint(n) {
  const m = state.editing, prefix = n === "1" ? "t" : `p${n}`;
  say("#read-msg", `Reading the position for point ${n}…`, "info");
  try {
    const p = await api(`/api/v1/machines/${m.id}/position`);
    $(`${prefix}-x`).value = +p.x_mm.toFixed(4); $(`${prefix}-y`).value = +p.y_mm.toFixed(4);
    $(`${prefix}-z`).value = +p.z_mm.toFixed(4);
    const tool = p.tool_offset_mm.some((v) => Math.abs(v) > 1e-6)
      ? ` (tool length offset ${p.tool_offset_mm.map((v) => fmt(v, 3)).join(" / ")} mm taken off)` : "";
    say("#read-msg", `Point ${n}: X ${fmt(p.x_mm, 3)} Y ${fmt(p.y_mm, 3)} Z ${fmt(p.z_mm, 3)} mm${tool}.`, "ok");
  } catch (e) {
    say("#read-msg", e.status === 409 ? e.message : `Could not read the position: ${e.message}`, e.status === 409 ? "warn" : "bad");
  }
}

function fieldsFromPose(T) {
  $("t-x").value = +T[0][3].toFixed(4); $("t-y").value = +T[1][3].toFixed(4); $("t-z").value = +T[2][3].toFixed(4);
  $("t-c").value = +(Math.atan2(T[1][0], T[0][0]) * 180 / Math.PI).toFixed(4);
  const tilted = Math.abs(T[2][2] - 1) > 1e-9;
  $("tilt-note").classList.toggle("hidden", !tilted);
  $("tilt-note").textContent = tilted ? "This table is tilted against the machine's Z; saving here sets it level." : "";
}

const IDENTITY = [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]];
const matrixText = (T) => "[" + T.map((row) => JSON.stringify(row.map((v) => +v.toFixed(6)))).join(",\n ") + "]";

/** The rotary fields shown when the table sits on an axis; the table pose fields are then derived. */
function showRotaryFields() {
  const on = $("r-on").checked;
  for (const e of document.querySelectorAll(".rotary")) e.classList.toggle("hidden", !on);
  for (const id of ["t-x", "t-y", "t-z", "t-c", "from-points"]) $(id).disabled = on;
  for (const b of document.querySelectorAll(".read-pos")) b.classList.toggle("hidden", on);
}

function fillRotary(axis) {
  $("r-on").checked = !!axis;
  $("r-name").value = axis ? axis.name : "C";
  $("r-from").value = axis ? axis.angle_from : "controller";
  $("r-export").value = axis ? axis.export_at_deg : 0;
  $("r-axis").value = matrixText(axis ? axis.T_machine_axis : IDENTITY);
  $("r-table").value = matrixText(axis ? axis.T_axis_table : IDENTITY);
  showRotaryFields();
}

/** The rotary axis as the API takes it (null: the table does not turn); the service checks the poses. */
function rotaryFromFields() {
  if (!$("r-on").checked) return null;
  if ($("r-export").validity.badInput) throw new Error("The export angle is not a number.");
  return { name: $("r-name").value, angle_from: $("r-from").value, export_at_deg: Number($("r-export").value),
           T_machine_axis: parseJSONField($("r-axis").value, "T_machine_axis"),
           T_axis_table: parseJSONField($("r-table").value, "T_axis_table") };
}

function showControllerFields() {
  const kind = $("c-kind").value;
  for (const e of document.querySelectorAll(".ctl")) e.classList.toggle("hidden", !e.classList.contains(kind));
}

function controllerFromFields() {
  const kind = $("c-kind").value;
  if (!kind) return null;
  const old = state.editing && state.editing.controller && state.editing.controller.kind === kind ? state.editing.controller : {};
  if (kind === "opcua") return parseJSONField($("c-json").value, "The OPC UA settings");
  if (kind === "linuxcnc") return { ...old, kind, host: $("c-host").value.trim(), port: Number($("c-port").value) };
  return { ...old, kind, dialect: $("c-dialect").value, folder: $("c-folder").value.trim() };
}

function fillForm(m) {
  state.editing = m;
  $("form-title").textContent = m ? m.name : "New machine";
  $("m-name").value = m ? m.name : "";
  $("m-table").replaceChildren(...state.tables.map((t) => el("option", { value: t.id, text: t.name, selected: m && m.table_model_id === t.id })));
  $("m-cameras").replaceChildren(...state.cameras.map((c) => el("label", {},
    el("input", { type: "checkbox", value: c.id, checked: m ? m.camera_ids.includes(c.id) : state.cameras.length === 1 }), c.name)));
  if (!state.cameras.length) $("m-cameras").append(el("a", { href: "/cameras", text: "add a camera first" }));
  fieldsFromPose(m ? m.T_machine_table : [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]);
  for (const id of ["p2-x", "p2-y", "p2-z", "p3-x", "p3-y", "p3-z"]) $(id).value = "";
  for (const b of document.querySelectorAll(".read-pos")) {
    b.disabled = !(m && m.controller);
    b.title = m && m.controller ? "Read where the tool tip is now from the saved controller"
                                : "Save the machine with a controller first (or type the position)";
  }
  say("#read-msg", ""); $("frame-notes").replaceChildren(); $("table-figure").classList.add("hidden");
  fillRotary(m ? m.rotary_axis : null);
  for (const a of AXES) {
    if (m) { $(`tr-${a}0`).value = m.travel_mm[a][0]; $(`tr-${a}1`).value = m.travel_mm[a][1]; }
  }
  for (const name of Object.keys(LIMITS)) {
    const f = limitField(name), d = state.defaults[name];
    f.value = m && m[name] !== null && m[name] !== undefined ? m[name] : "";
    f.placeholder = d ? String(d.value) : "";
    f.title = d ? `Empty: the global setting ${d.setting} (${d.value})` : "";
  }
  showLimitsInForce();
  const ctl = (m && m.controller) || {};
  $("c-kind").value = ctl.kind || "";
  $("c-host").value = ctl.host || ""; $("c-port").value = ctl.port || 5007;
  $("c-dialect").value = ctl.dialect || "linuxcnc"; $("c-folder").value = ctl.folder || "";
  $("c-json").value = ctl.kind === "opcua" ? JSON.stringify(ctl, null, 2)
    : JSON.stringify({ kind: "opcua", endpoint: "opc.tcp://host:4840", nodes: { x: "ns=2;s={slot}.X", y: "ns=2;s={slot}.Y", z: "ns=2;s={slot}.Z" } }, null, 2);
  showControllerFields();
  $("delete").classList.toggle("hidden", !m || !state.admin);
  $("test").disabled = !(m && m.controller);
  $("test").title = m && m.controller ? "Read the controller's current offset in this slot with the saved settings"
                                      : "Save the machine with a controller first";
  say("#form-msg", "");
  $("machine-form").classList.remove("hidden");
  $("machine-form").scrollIntoView({ block: "nearest" });
  workOutPose(false).catch(() => {});  // the saved pose's picture; a bad field shows its reason on Work out
}

function drawCards() {
  const box = $("machines");
  box.replaceChildren();
  if (!state.machines.length) {
    say("#msg", state.admin ? "No machine yet: press “Add a machine”. You need a camera (Cameras page) and a table model (Library)."
                            : "No machine is set up yet. Ask an admin to add one.", "warn");
  }
  for (const m of state.machines) {
    const cams = m.camera_ids.length ? `${m.camera_ids.length} camera(s)` : "no camera yet";
    const ctl = m.controller ? m.controller.kind : "no controller";
    const own = Object.entries(LIMITS).filter(([n]) => m[n] !== null).map(([n, [what, unit]]) => `${what} ${m[n]}${unit}`);
    const r = m.rotary_axis;
    const rotary = r ? ` · rotary ${r.name} (angle ${r.angle_from === "operator" ? "typed" : "read"}, offsets for ${r.name} = ${r.export_at_deg}°)` : "";
    box.append(el("div", { class: "card", "data-testid": "machine-card" },
      el("h2", { text: m.name }),
      el("p", { class: "muted", text: `Travel X ${m.travel_mm.x[0]}…${m.travel_mm.x[1]} mm · ${cams} · ${ctl}`
                                      + rotary + (own.length ? ` · own limits: ${own.join(", ")}` : "") }),
      el("div", { class: "row" },
        el("a", { class: "button primary", href: `/setup?machine=${m.id}`, text: "Set up here" }),
        el("a", { class: "button", href: `/history?machine=${m.id}`, text: "History" }),
        el("button", { type: "button", "data-testid": "machine-edit", text: state.admin ? "Edit" : "Details",
                       onclick: () => fillForm(m) }))));
  }
}

async function load() {
  const [machines, tables, cameras, defaults] = await Promise.all([
    api("/api/v1/machines"), api("/api/v1/models?kind=table&limit=500"), api("/api/v1/cameras"),
    api("/api/v1/machines/default-limits")]);
  state.machines = machines; state.tables = tables.data; state.cameras = cameras; state.defaults = defaults;
  drawCards();
}

$("c-kind").addEventListener("change", showControllerFields);
$("r-on").addEventListener("change", showRotaryFields);
for (const name of Object.keys(LIMITS)) limitField(name).addEventListener("input", showLimitsInForce);
$("from-points").addEventListener("click", async () => {
  try {
    const r = await workOutPose(true);
    say("#form-msg", `Table origin X ${fmt(r.x_mm, 3)} Y ${fmt(r.y_mm, 3)} Z ${fmt(r.z_mm, 3)} mm, C ${fmt(r.c_deg, 4)}°: check the picture, then Save.`, "ok");
  } catch (e) { say("#form-msg", e.message, "bad"); }
});
for (const b of document.querySelectorAll(".read-pos")) b.addEventListener("click", () => readPoint(b.dataset.point));
$("add").addEventListener("click", () => fillForm(null));
$("close").addEventListener("click", () => $("machine-form").classList.add("hidden"));
$("machine-form").addEventListener("submit", async (ev) => {
  ev.preventDefault();
  try {
    const rotary = rotaryFromFields();
    const body = {
      name: $("m-name").value.trim(), table_model_id: Number($("m-table").value),
      camera_ids: [...$("m-cameras").querySelectorAll("input:checked")].map((i) => Number(i.value)),
      travel_mm: Object.fromEntries(AXES.map((a) => [a, [Number($(`tr-${a}0`).value), Number($(`tr-${a}1`).value)]])),
      controller: controllerFromFields(),
      rotary_axis: rotary,
      ...limitsFromFields(),
    };
    if (!rotary) body.T_machine_table = poseFromFields();  // with an axis the service derives it
    const m = await saveJSON("/api/v1/machines", state.editing && state.editing.id, body);
    await load();
    fillForm(state.machines.find((x) => x.id === m.id));
    say("#form-msg", `Saved “${m.name}”.${m.controller ? " Press Test connection to check the controller." : ""}`, "ok");
    say("#msg", "");
  } catch (e) { say("#form-msg", e.message, "bad"); }
});
$("delete").addEventListener("click", async () => {
  const m = state.editing;
  if (!m || !confirm(`Delete machine “${m.name}”? Its history stays.`)) return;
  try {
    await api(`/api/v1/machines/${m.id}`, { method: "DELETE" });
    $("machine-form").classList.add("hidden");
    await load();
    say("#msg", `Deleted “${m.name}”.`, "ok");
  } catch (e) { say("#form-msg", e.message, "bad"); }
});
$("test").addEventListener("click", async () => {
  const m = state.editing, slot = $("test-slot").value;
  say("#form-msg", `Reading ${slot} from the controller…`, "info");
  try {
    const o = await api(`/api/v1/machines/${m.id}/offsets/${slot}`);
    say("#form-msg", `Connected. ${o.slot} now holds X ${fmt(o.x_mm, 3)}, Y ${fmt(o.y_mm, 3)}, Z ${fmt(o.z_mm, 3)} mm, C ${fmt(o.c_deg, 3)}°.`, "ok");
  } catch (e) {
    say("#form-msg", e.code === "slot_empty" ? `Reached, but: ${e.message}` : `No connection: ${e.message}`, e.code === "slot_empty" ? "warn" : "bad");
  }
});

(async () => {
  try {
    state.admin = await adminMode("machines");
    await load();
    $("add").classList.toggle("hidden", !state.admin);
  } catch (e) { say("#msg", e.message, "bad"); }
})();
