// The setup page: choose the part, capture or upload, follow the stages, review in 2D and 3D,
// adjust, refine, confirm, export.
"use strict";

const state = { setup: null, events: null, poll: null, expectedStages: 2, viewerFor: null,
                machines: [], current: null };  // current: {key, values | null, why} of the controller's slot

// What to do, chosen by the service's reason code (a refused start: app/api/problems.py) or by the
// stage that failed (a localisation that ran and failed), never by the words of the reason.
const CAMERA_ADVICE = "Check that the camera is switched on and connected, or upload a photo instead.";
const CODE_ADVICE = {
  camera_not_calibrated: "Calibrate this camera on the Cameras page first.",
  camera_unavailable: CAMERA_ADVICE,
  camera_upload_only: CAMERA_ADVICE,
  no_camera: "An admin adds a camera to this machine on the Machines page.",
  image_size_mismatch: "Use a picture from this machine's camera at its full resolution.",
  table_angle_required: "Type the rotary table's angle as the controller shows it, then take the picture again.",
  position_unavailable: "An admin sets this machine's rotary axis to take the angle from the operator.",
  unavailable: "Check that the controller is on and connected.",
};
const MARKER_ADVICE = "Move the camera so that more table markers are in the picture, clean the markers, or add light; then take the picture again.";
const PART_ADVICE = "Check that the right part is chosen and that it is well lit and not hidden, then take the picture again.";
const DEFAULT_ADVICE = "Look at the picture, then take a new one. If it keeps failing, call the person who set up the camera.";

function sentence(text) {
  text = (text || "").trim();
  return text && !/[.!?]$/.test(text) ? text + "." : text;
}

/** The reason, and what to do: ``advice`` (from a code or a stage) or the general advice. */
function explain(reason, advice) {
  return `${sentence(reason || "No result.")} ${advice || DEFAULT_ADVICE}`;
}

/** The advice for a localisation that failed, by its first failed stage (see app/vision/localize.py). */
function stageAdvice(stages) {
  const bad = (stages || []).find((st) => !st.ok);
  if (!bad) return DEFAULT_ADVICE;
  return bad.name === "table markers" ? MARKER_ADVICE : PART_ADVICE;
}

function fail(text) { say($("status"), text, "bad"); }

// ------------------------------------------------------------------------------------------- choose
async function loadParts() {
  const [wp, cl, su] = await Promise.all([api("/api/v1/models?kind=workpiece&limit=500"),
    api("/api/v1/models?kind=clamp&limit=500"), api("/api/v1/models?kind=support&limit=500")]);
  const part = $("part");
  for (const m of wp.data) part.append(el("option", { value: m.id, text: m.name }));
  const clamps = $("clamps");
  // fixtures (vises, clamps, parallels): located first, the part is then searched on what they carry
  for (const m of [...cl.data, ...su.data]) {
    clamps.append(el("label", { class: "button" }, el("input", { type: "checkbox", value: m.id, class: "clamp" }), " " + m.name));
  }
  $("part-search").addEventListener("input", () => {
    const q = $("part-search").value.toLowerCase();
    let first = null;
    for (const o of part.options) {
      const show = !o.value || o.text.toLowerCase().includes(q);
      o.hidden = !show;
      if (show && o.value && !first) first = o;
    }
    if (q && first) part.value = first.value;
  });
}

function chosenModels() {
  const ids = [];
  if ($("part").value) ids.push($("part").value);
  for (const c of document.querySelectorAll("input.clamp:checked")) ids.push(c.value);
  return ids;
}

/** The chosen machine's rotary axis (null when its table does not turn). */
function rotaryAxis() {
  const m = state.machines.find((x) => String(x.id) === $("machine").value);
  return (m && m.rotary_axis) || null;
}

/** A machine with a rotary table: the operator types the angle, or it is read from the controller (shown now). */
async function showAngleBox() {
  const axis = rotaryAxis();
  $("angle-box").classList.toggle("hidden", !axis);
  if (!axis) return;
  for (const e of document.querySelectorAll(".angle-axis")) e.textContent = axis.name;
  const typed = axis.angle_from === "operator";
  $("angle-typed").classList.toggle("hidden", !typed);
  const export_ = `offsets are for ${axis.name} = ${fmt(axis.export_at_deg, 3)}°`;
  $("angle-note").textContent = typed ? `(${export_})` : `${axis.name} is read from the controller with the picture; ${export_}.`;
  try {
    const now = await api(`/api/v1/machines/${$("machine").value}/rotary-axis`);
    $("angle-note").textContent += ` The controller shows ${axis.name} ${fmt(now.angle_deg, 3)}° now.`;
  } catch (e) {
    if (!typed) $("angle-note").textContent += ` It cannot be read now: ${e.message}`;
  }
}

async function start(grab, file) {
  const machine = $("machine").value;
  if (!machine) return fail("Choose the machine first.");
  const axis = rotaryAxis();
  const typed = axis && axis.angle_from === "operator";
  if (typed && ($("table-angle").value.trim() === "" || $("table-angle").validity.badInput))
    return fail(`Type the table angle ${axis.name} (degrees, as the controller shows it) before the picture.`);
  const ids = chosenModels();
  const form = new FormData();
  form.append("machine_id", machine);
  if (typed) form.append("table_angle_deg", $("table-angle").value.trim());
  if (ids.length) form.append("model_ids", ids.join(","));
  if (grab) form.append("grab", "true");
  if (file) form.append("image", file);
  resetProgress(stagesFor(ids.length));
  $("step").textContent = grab ? "Taking the picture…" : "Sending the photo…";
  say($("status"), "Working: the picture is being checked.", "info");
  setBusy(true);
  try {
    const acc = await api("/api/v1/setups", { method: "POST", body: form });
    showSetupId(acc.id);
    follow(acc.id, acc.events_url);
  } catch (e) {
    setBusy(false);
    $("step").textContent = "Nothing was started.";
    $("setup-id").textContent = "";
    setProgress(100, "failed");
    fail(explain(e.message, CODE_ADVICE[e.code]));
  }
}

function setBusy(busy) {
  for (const b of [$("capture"), $("upload")]) b.disabled = busy;
}

function showSetupId(id) {
  $("setup-id").textContent = `Setup ${id}`;
  $("probing-link").href = `/probing?setup=${id}`;
  const u = new URL(location.href);
  u.searchParams.set("machine", $("machine").value);
  u.searchParams.set("setup", id);
  history.replaceState(null, "", u);
}

// ------------------------------------------------------------------------------------------- progress
// Stages a setup will have: the table markers, then one per model named; with none named (recognition)
// one per fixture of the library (each is looked for first), then the recognition itself.
function stagesFor(named) {
  return named ? 1 + named : 2 + document.querySelectorAll("#clamps input.clamp").length;
}

function resetProgress(expected) {
  $("probing-link").classList.add("hidden");
  state.expectedStages = Math.max(1, expected);
  $("stages").innerHTML = "";
  $("result").classList.add("hidden");
  setProgress(3, "");
}

function setProgress(pct, cls) {
  const p = $("progress");
  p.className = "progress " + (cls || "");
  p.firstElementChild.style.width = `${Math.min(100, pct)}%`;
  p.setAttribute("aria-valuenow", Math.round(pct));
}

function addStage(st) {
  $("stages").append(el("li", { class: st.ok ? "ok" : "bad", title: st.message || "" },
    `${st.ok ? "✓" : "✗"} ${st.name} (${(st.ms / 1000).toFixed(1)} s)`));
  const n = $("stages").children.length;
  setProgress(100 * n / (state.expectedStages + 0.5), "");
  $("step").textContent = st.ok ? `Done: ${st.name}. Working on the next step…` : `Problem in step “${st.name}”.`;
}

// A long stage under way (recognition over the library: 30-60 s): the bar moves within it and the
// step says how far it is, so that a still bar never means "stuck".
function showProgress(p) {
  if (!p || !p.total) return;
  const n = $("stages").children.length;
  const within = Math.min(1, p.done / p.total);
  setProgress(100 * (n + within) / (state.expectedStages + 0.5), "");
  $("step").textContent = `${capitalised(p.stage)}: ${capitalised(p.message)}…`;
}

function capitalised(text) {
  return text.charAt(0).toUpperCase() + text.slice(1);
}

function follow(id, eventsUrl) {
  if (state.events) state.events.close();
  const es = new EventSource(eventsUrl);
  state.events = es;
  es.addEventListener("stage", (ev) => addStage(JSON.parse(ev.data)));
  es.addEventListener("progress", (ev) => showProgress(JSON.parse(ev.data)));
  es.addEventListener("status", async (ev) => {
    const s = JSON.parse(ev.data);
    if (s.status === "running" && !$("stages").children.length) $("step").textContent = "Finding the table markers and the parts…";
    if (s.status === "located" || s.status === "failed") {
      es.close();
      state.events = null;
      await loadSetup(id);
    }
  });
  es.onerror = async () => {  // the stream ended or broke: read the state instead
    es.close();
    state.events = null;
    await loadSetup(id);
  };
}

// ------------------------------------------------------------------------------------------- result
async function loadSetup(id) {
  try {
    const s = await api(`/api/v1/setups/${id}`);
    if ((s.status === "queued" || s.status === "running") && !state.events) {
      resetProgress(stagesFor(s.models.length));
      for (const st of s.stages) addStage(st);
      showProgress(s.progress);
      follow(id, `/api/v1/setups/${id}/events`);
      return;
    }
    render(s);
  } catch (e) {
    fail(e.message);
  }
}

function workpieceIndex(result) {
  const objs = (result && result.objects) || [];
  const i = objs.findIndex((o) => o.kind === "workpiece");
  return i >= 0 ? i : (objs.length ? 0 : -1);
}

function render(s) {
  state.setup = s;
  setBusy(false);
  showSetupId(s.id);
  if (!$("stages").children.length) for (const st of s.stages) addStage(st);
  const located = s.status === "located";
  $("probing-link").classList.toggle("hidden", !located);
  setProgress(100, located ? "done" : "failed");
  $("result").classList.remove("hidden");
  $("result").classList.toggle("failed", !located);
  const pic = s.overlay_url || s.image_url;
  $("overlay").src = `${pic}?rev=${s.result_revision}`;
  $("overlay-link").href = $("overlay").src;
  $("machine").value = String(s.machine_id);
  if (!located) {
    $("step").textContent = "The setup could not be located.";
    fail(explain(s.reason, stageAdvice(s.stages)));
    showViewer(null);
    fillOffset(null, null);
    $("uncertainty").textContent = "";
    $("uncertainty").className = "message";
    setActions(false);
    return;
  }
  $("step").textContent = `Located. Check the picture and the 3D view, then confirm. (Result revision ${s.result_revision})`;
  const r = s.result || {};
  const wi = workpieceIndex(r);
  const wp = wi >= 0 ? r.objects[wi] : null;
  // what each object rests on (the support chain), e.g. "bracket (on vise seat on table)"
  const named = r.objects.map((o) => (o.chain && o.chain.length ? `${o.name} (on ${o.chain.join(" on ")})` : o.name));
  const msg = r.reason ? `Located with a remark: ${r.reason}` : `Located: ${named.join(", ")}.`;
  say($("status"), msg, r.reason ? "warn" : "ok");
  showViewer(s.id);
  fillOffset(r.offset, wp);
  readController(s, r.offset, wp);
  setActions(wp !== null);
  showConfirmation(s);
}

// viser switches to its phone layout below 576 px; render the frame at >= 600 px and scale it to fit.
const VIEWER_MIN_PX = 600;
function fitViewer() {
  const box = $("viewer-view"), frame = $("viewer");
  const s = Math.min(1, box.clientWidth / VIEWER_MIN_PX) || 1;
  frame.style.width = `${box.clientWidth / s}px`;
  frame.style.height = `${box.clientHeight / s}px`;
  frame.style.transform = `scale(${s})`;
  frame.style.transformOrigin = "0 0";
}
window.addEventListener("resize", fitViewer);

function showViewer(id) {
  const frame = $("viewer");
  if (id === null) {
    frame.classList.add("hidden");
    state.viewerFor = null;
    return;
  }
  frame.classList.remove("hidden");
  fitViewer();
  if (state.viewerFor !== id) {
    frame.src = `/viewer/setup/${id}/`;
    state.viewerFor = id;
  }
}

function fillOffset(off, wp) {
  const sig = (wp && wp.sigma) || {};
  const cur = state.current && state.current.values;  // the controller's offset, when it could be read
  const rows = [["x", "x_mm", "x_mm"], ["y", "y_mm", "y_mm"], ["z", "z_mm", "z_mm"], ["c", "c_deg", "rz_deg"]];
  for (const [k, key, sk] of rows) {
    const v = off ? off[key] : null;
    $(`offset-${k}`).textContent = fmt(v, k === "c" ? 3 : 2);
    $(`sig-${k}`).textContent = sig[sk] === undefined ? "—" : fmt(sig[sk], 3);
    $(`cur-${k}`).textContent = cur ? fmt(cur[key], k === "c" ? 3 : 2) : "—";
    $(`dif-${k}`).textContent = cur && v !== null ? fmt(v - cur[key], k === "c" ? 3 : 2) : "—";
  }
  const u = $("uncertainty");
  if (!wp) {
    say(u, off === null ? "" : "No workpiece located: no offset can be proposed.", "bad");
  } else {
    const sigOk = wp.uncertainty_pass !== false;
    const offOk = !off || off.ok !== false;
    const ok = sigOk && offOk;
    const why = [!sigOk ? `uncertainty too large (${wp.uncertainty_reason})` : "", !offOk ? off.reason : ""].filter(Boolean).join("; ");
    say(u, ok ? "PASS: uncertainty and tilt within tolerance." : `FAIL: ${why}. Adjust or refine, or take a new picture.`,
        ok ? "ok" : "bad");
  }
  fillDatumChoice(off);
  fillPartsChoice(state.setup && state.setup.status === "located" ? state.setup.result : null);
  const notes = [];
  if (off && off.object) notes.push(`Datum of ${off.object}.`);
  if (wp && wp.chain && wp.chain.length) notes.push(`Rests on ${wp.chain.join(" on ")}.`);
  if (wp && (wp.flags || []).includes("contact"))
    notes.push("It does not sit where it should rest: its height and tilt are not known from this picture (probe Z, or take another view).");
  if (off && off.datum_ambiguous && !(off.datum_choices || []).length && off.datum_note) notes.push(`Note: ${off.datum_note}.`);
  if (off && off.datum_defined === false) notes.push("This part has no datum in the library: the offset is its model origin.");
  if (off && off.tilt_deg !== undefined) notes.push(`Tilt ${fmt(off.tilt_deg, 3)}°.`);
  const s = state.setup;
  if (off && off.axis) {
    const at = s && s.table_angle_deg !== null && s.table_angle_deg !== undefined
      ? ` (picture taken at ${off.axis} = ${fmt(s.table_angle_deg, 3)}°, ${s.table_angle_from === "operator" ? "typed by the operator" : "read from the controller"})` : "";
    notes.push(`Offset for ${off.axis} = ${fmt(off.at_axis_deg, 3)}°${at}.`);
  }
  if (!cur) notes.push(state.current && state.current.why ? `Controller: ${state.current.why}` : "Controller not read yet.");
  $("offset-note").textContent = notes.join(" ");
}

/** A symmetric part: the image cannot say which of the look-alike poses is meant; the operator picks one
 *  (each button shows the offset it would give). Confirm is refused by the service until then. */
function fillDatumChoice(off) {
  const box = $("datum-choice");
  const choices = (off && off.datum_choices) || [];
  box.replaceChildren();
  box.classList.toggle("hidden", choices.length === 0);
  if (!choices.length) return;
  const head = document.createElement("div");
  head.textContent = `Datum not decided: ${choices.length} poses look the same (${off.datum_note}). Which one is meant?`;
  box.append(head);
  choices.forEach((c, i) => {
    const b = document.createElement("button");
    b.setAttribute("data-testid", "datum-option");
    b.style.margin = "4px 4px 0 0";
    b.textContent = `${i === 0 ? "As shown" : `Pose ${i + 1}`}: X ${fmt(c.x_mm, 2)} Y ${fmt(c.y_mm, 2)} Z ${fmt(c.z_mm, 2)} C ${fmt(c.c_deg, 2)}°`;
    b.addEventListener("click", () => act((s) => postJSON(`/api/v1/setups/${s.id}/datum`,
      { object_index: workpieceIndex(s.result), choice: i }), `Using pose ${i + 1} as the datum…`));
    box.append(b);
  });
}

/** Recognition found more than one workpiece: the offset is the first one's. The operator takes out a
 *  part that is not on the table ("Not there": a new revision without it); clamps and fixtures stay. */
function fillPartsChoice(result) {
  const box = $("parts-choice");
  const objs = (result && result.objects) || [];
  const parts = objs.map((o, i) => [o, i]).filter(([o]) => o.kind === "workpiece");
  box.replaceChildren();
  box.classList.toggle("hidden", parts.length < 2);
  if (parts.length < 2) return;
  const head = document.createElement("div");
  head.textContent = `${parts.length} parts recognised; the offset is for ${parts[0][0].name}. Take out any that is not on the table:`;
  box.append(head);
  for (const [o, i] of parts) {
    const b = document.createElement("button");
    b.setAttribute("data-testid", "dismiss-part");
    b.style.margin = "4px 4px 0 0";
    b.textContent = `Not there: ${o.name}${o.score === null || o.score === undefined ? "" : ` (${Math.round(100 * o.score)} %)`}`;
    b.addEventListener("click", () => act((s) => postJSON(`/api/v1/setups/${s.id}/dismiss`, { object_index: i }),
      `Taking ${o.name} out of the result…`));
    box.append(b);
  }
}

/** Read the controller's current offset in the chosen slot (once per machine and slot), then redraw the table. */
async function readController(s, off, wp, force = false) {
  const slot = $("slot").value, key = `${s.machine_id}/${slot}`;
  if (!force && state.current && state.current.key === key) return;
  const m = state.machines.find((x) => x.id === s.machine_id);
  if (m && !m.controller) {
    state.current = { key, values: null, why: "none configured for this machine." };
  } else {
    state.current = { key, values: null, why: "reading…" };
    try {
      state.current = { key, values: await api(`/api/v1/machines/${s.machine_id}/offsets/${slot}`), why: "" };
    } catch (e) {
      state.current = { key, values: null, why: sentence(e.message) };
    }
  }
  if (state.setup === s) fillOffset(off, wp);
}

function setActions(enabled) {
  for (const b of document.querySelectorAll("[data-nudge], #refine, #confirm")) b.disabled = !enabled;
}

function showConfirmation(s) {
  const confirmed = s.confirmed_revision !== null && s.confirmed_revision !== undefined;
  const current = confirmed && s.confirmed_revision === s.result_revision;
  const status = $("export-status");
  const wrap = $("export-wrap");
  if (current) {
    status.textContent = `Confirmed by ${s.confirmed_by || "?"}, ${when(s.confirmed_at)}, revision ${s.confirmed_revision}.`;
    status.className = "pass";
    wrap.classList.remove("hidden");
    const b = $("export");
    b.disabled = false;
    b.title = "Write this offset into the controller";
  } else {
    wrap.classList.add("hidden");
    status.className = "muted";
    status.textContent = confirmed
      ? `Changed after the confirmation of revision ${s.confirmed_revision}: confirm again.`
      : "Not confirmed yet: check the picture and the numbers, then press Confirm.";
  }
}

// ------------------------------------------------------------------------------------------- actions
async function act(fn, busyText) {
  const s = state.setup;
  if (!s) return;
  setActions(false);
  say($("status"), busyText, "info");
  try {
    const out = await fn(s);
    if (out && out.events_url) {  // a job was started: follow it
      resetProgress(2);
      follow(s.id, out.events_url);
      return;
    }
    render(out && out.id ? out : await api(`/api/v1/setups/${s.id}`));
  } catch (e) {
    setActions(true);
    fail(e.message);
  }
}

function nudge(button) {
  const key = button.dataset.nudge;
  const step = Number(key === "dc_deg" ? $("step-deg").value : $("step-mm").value) * Number(button.dataset.sign);
  const index = workpieceIndex(state.setup.result);
  act((s) => postJSON(`/api/v1/setups/${s.id}/adjust`, { object_index: index, nudge: { [key]: step } }),
      `Moving the workpiece: ${button.textContent} ${Math.abs(step)}…`);
}

function refine() {
  const index = workpieceIndex(state.setup.result);
  act((s) => postJSON(`/api/v1/setups/${s.id}/refine`, { object_index: index }),
      "Refining the fit from the current position…");
}

function confirmResult() {  // the service records the signed-in operator as "who"
  act((s) => postJSON(`/api/v1/setups/${s.id}/confirm`, { result_revision: s.result_revision }), "Recording the confirmation…");
}

// the export's refusals that the operator may overrule after comparing the values (app/services/export.py)
const NEEDS_ACKNOWLEDGEMENT = new Set(["change_needs_acknowledgement", "first_export_needs_acknowledgement"]);

async function exportOffset(acknowledge = false) {
  const s = state.setup;
  $("export").disabled = true;
  $("export-anyway").classList.add("hidden");
  say($("status"), "Writing the offset into the controller and reading it back…", "info");
  const status = $("export-status");
  try {
    const out = await postJSON(`/api/v1/setups/${s.id}/export`, { slot: $("slot").value, acknowledge_change: acknowledge });
    const w = out.read_back || out.written || {};
    const vals = ["x_mm", "y_mm", "z_mm", "c_deg"].filter((k) => k in w).map((k) => `${k[0].toUpperCase()} ${fmt(w[k], 3)}`).join(", ");
    if (out.status === "written") {
      status.textContent = `Written to ${out.slot} and read back: ${vals}.`;
      status.className = "pass";
      say($("status"), `Done: the controller holds the new offset in ${out.slot}.`, "ok");
      readController(s, s.result.offset, s.result.objects[workpieceIndex(s.result)], true);
    } else {
      status.textContent = `${out.slot}: ${out.status}. ${out.reason}`;
      status.className = "fail";
      fail(`The controller did not confirm the values (${out.status}): ${out.reason} Check the controller before machining.`);
    }
  } catch (e) {
    status.textContent = `Not written: ${e.message}`;
    status.className = "fail";
    fail(`Not written: ${e.message}`);
    if (NEEDS_ACKNOWLEDGEMENT.has(e.code)) $("export-anyway").classList.remove("hidden");
  } finally {
    $("export").disabled = false;
  }
}


// Follow changes made elsewhere (gizmo in the 3D view, another browser) while a result is shown.
function startPolling() {
  state.poll = setInterval(async () => {
    const s = state.setup;
    if (!s || s.status !== "located" || state.events) return;
    try {
      const fresh = await api(`/api/v1/setups/${s.id}`);
      if (fresh.result_revision !== s.result_revision || fresh.confirmed_revision !== s.confirmed_revision) render(fresh);
    } catch (e) { /* keep the last state; the next poll tries again */ }
  }, 1500);
}

// ------------------------------------------------------------------------------------------- start
document.addEventListener("DOMContentLoaded", async () => {
  $("capture").addEventListener("click", () => start(true, null));
  $("upload").addEventListener("change", (ev) => {
    const f = ev.target.files[0];
    if (f) start(false, f);
    ev.target.value = "";
  });
  for (const b of document.querySelectorAll("[data-nudge]")) b.addEventListener("click", () => nudge(b));
  $("refine").addEventListener("click", refine);
  $("confirm").addEventListener("click", confirmResult);
  $("export").addEventListener("click", () => exportOffset(false));
  $("export-anyway").addEventListener("click", () => exportOffset(true));
  setActions(false);
  setBusy(true);   // no capture or upload before the machines are listed ("Choose the machine first")
  try {
    const machineId = qs("machine") || localStorage.getItem("setupcam.machine");
    [state.machines] = await Promise.all([fillMachines($("machine"), machineId), loadParts()]);
    $("slot").addEventListener("change", () => {
      const s = state.setup;
      if (s && s.status === "located") readController(s, s.result.offset, s.result.objects[workpieceIndex(s.result)], true);
    });
    $("machine").addEventListener("change", () => {
      localStorage.setItem("setupcam.machine", $("machine").value);
      showAngleBox();
    });
    showAngleBox();
    if ($("machine").value) localStorage.setItem("setupcam.machine", $("machine").value);
  } catch (e) {
    fail(e.message);
  }
  setBusy(false);
  const setupId = qs("setup");
  if (setupId) await loadSetup(setupId);
  startPolling();
});
