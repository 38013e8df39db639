// The probing page: the planned touches, the obstacles with their source and the frame of a confirmed
// setup's probing program; download it only when the service offers it (else its refusal, with the
// code); send the probed points back and see the residual per touch and the pose before and after.
"use strict";

const SVG = "http://www.w3.org/2000/svg";
const state = { setup: null, options: null, plan: null, lastPlan: null, corner: null, sent: null };

function svgEl(tag, attrs = {}, text = null) {
  const e = document.createElementNS(SVG, tag);
  for (const [k, v] of Object.entries(attrs)) e.setAttribute(k, v);
  if (text !== null) e.textContent = text;
  return e;
}

function status(text, kind = "info") { say($("status"), text, kind); }

/** The workpiece's entry in a setup result (the object the offset is of). */
function workpiece(s) {
  const objs = (s.result && s.result.objects) || [];
  const name = s.result && s.result.offset && s.result.offset.object;
  return objs.find((o) => o.name === name) || objs.find((o) => o.kind === "workpiece") || null;
}

// ------------------------------------------------------------------------------------------- load
async function loadSetup(id) {
  state.setup = await api(`/api/v1/setups/${id}`);
  state.options = await api(`/api/v1/setups/${id}/probing-options`);
  const u = new URL(location.href);
  u.searchParams.set("setup", id);
  history.replaceState(null, "", u);
  $("setup-input").value = id;
  $("back-to-setup").href = `/setup?machine=${state.setup.machine_id}&setup=${id}`;
  const o = state.options;
  const slot = qs("wcs") || o.exported_slot || $("slot").value || o.slots[0];
  $("slot").replaceChildren(...o.slots.map((s) => el("option", { value: s, text: s, selected: s === slot })));
  fillDialects();
  const c = $("clearance");
  c.min = o.clearance_mm.min;
  c.max = o.clearance_mm.max;
  showResults(state.setup);
  await plan();
}

/** The dialects on offer for the chosen travel (the subroutine is written for more controllers). */
function fillDialects() {
  const o = state.options;
  if (!o) return;
  const sub = $("detour").value === "subroutine";
  const list = sub ? (o.subroutine_dialects || o.dialects) : o.dialects;
  const was = $("dialect").value || qs("dialect");
  $("dialect").replaceChildren(...list.map((d) => el("option", { value: d, text: d, selected: d === was })));
}

function planParams() {
  const p = new URLSearchParams({ wcs: $("slot").value, dialect: $("dialect").value, clearance_mm: $("clearance").value });
  if ($("detour").value !== "straight") p.set("detour", $("detour").value);
  const zones = $("no-go").value.trim();
  if (zones) p.set("no_go", zones);
  return p;
}

async function plan() {
  const s = state.setup;
  if (!s) return;
  status("Planning the probing program and checking its frame on the controller…", "info");
  setOffer(null);
  try {
    state.plan = await api(`/api/v1/setups/${s.id}/probing-plan?${planParams()}`);
    state.lastPlan = state.plan;
    const p = state.plan;
    setOffer(p);
    const how = p.detour === "subroutine" ? ", travel by the detour subroutine" : "";
    status(`Ready: ${p.touches.length} touches, ${p.program_lines} lines${how}, runs in ${p.slot}.`, "ok");
  } catch (e) {
    state.plan = null;
    refuse(e);
  }
  drawPlan();
}

/** A program on offer (or none: null): the frame, the obstacles, the header, the download button. */
function setOffer(p) {
  $("download").disabled = !p;
  $("refusal").classList.add("hidden");
  $("frame").textContent = p ? p.frame : "—";
  $("frame").className = "frame-text " + (p ? (/read back now/.test(p.frame) ? "pass" : "warn-text") : "muted");
  $("header").textContent = p ? p.header.join("\n") : "";
  const rows = p ? p.obstacles.map((o) => [o.name, o.source, o.top_mm, o.note]) : locatedRows();
  $("obstacles-title").textContent = p ? "Obstacles planned around" : "Objects of this setup";
  $("obstacles").tBodies[0].replaceChildren(...rows.map(([n, src, top, note]) =>
    el("tr", { "data-testid": "obstacle-row", title: note || "" }, el("td", { text: n }),
       el("td", {}, el("span", { class: `src src-${src}`, text: src })), el("td", { class: "num", text: fmt(top, 1) }))));
}

/** Without a plan: what the setup says it located and what it did not find. */
function locatedRows() {
  const r = (state.setup && state.setup.result) || {};
  const tops = Object.fromEntries(((state.options && state.options.located) || []).map((o) => [o.name, o.top_mm]));
  return [...(r.objects || []).map((o) => [o.name, "located", tops[o.name], ""]),
          ...(r.not_found || []).filter((n) => n.name).map((n) => [n.name, "not located", null, n.reason || ""])];
}

const WHAT_TO_DO = {
  frame_not_exported: "Export this revision's offset to that slot on the setup page (it is read back), then plan again.",
  frame_mismatch: "The controller's slot no longer holds the exported offset: export again on the setup page.",
  not_confirmed: "Confirm the result on the setup page first.",
  changed_after_confirmation: "The result changed after it was confirmed (for example by probe results): confirm it again on the setup page.",
  obstacle_not_located: "Locate the missing objects (another picture), or draw where they stand as no-go zones below.",
  uncertainty_fail: "Take another picture, refine or adjust on the setup page.",
  outside_travel: "Check the part's position and the machine's travel.",
  touch_blocked: "Move the clamps or the part, or use a smaller clearance if the shop allows it.",
  no_go_invalid: "Correct the no-go zones.",
  wcs_not_a_slot: "Choose one of the controller's slots.",
};

function refuse(e) {
  const box = $("refusal");
  box.replaceChildren(el("div", { text: `No program: ${sentence(e.message)}` }),
    el("div", { class: "code" }, "Reason code ", el("code", { "data-testid": "refusal-code", text: e.code || `HTTP ${e.status || "?"}` })),
    ...(WHAT_TO_DO[e.code] ? [el("div", { class: "todo", text: WHAT_TO_DO[e.code] })] : []));
  box.classList.remove("hidden");
  $("download").disabled = true;
  status("The service refuses this probing program; the reason is on the right.", "bad");
  if (e.code === "obstacle_not_located") $("no-go-box").open = true;
}

function sentence(t) { t = (t || "").trim(); return t && !/[.!?]$/.test(t) ? t + "." : t; }

async function download() {
  const p = state.plan;
  if (!p) return;
  // fetched again on press: the service checks the frame on the controller once more
  try {
    const resp = await api(p.program_url);
    const blob = await resp.blob();
    const a = el("a", { href: URL.createObjectURL(blob), download: `setup${p.setup_id}-probe${p.file_suffix || ".ngc"}` });
    document.body.append(a);
    a.click();
    a.remove();
    status(`Downloaded: run it in ${p.slot} with the probe tool active, then send its log below.`, "ok");
  } catch (e) {
    refuse(e);
  }
}

// ------------------------------------------------------------------------------------------- the plan picture
/** The view: the whole table while no-go zones are drawn, else the program's surroundings. */
function bounds(p) {
  const pts = [];
  if (p && $("no-go-box").open) {
    const [x0, y0, x1, y1] = p.table_xy_mm;
    return [x0 - 10, y0 - 10, x1 + 10, y1 + 10];
  }
  if (p) {
    for (const path of p.travel_mm) for (const q of path) pts.push(q);
    for (const t of p.touches) pts.push(t.approach_tip_mm, t.contact_mm);
    const [tx0, ty0, tx1, ty1] = p.table_xy_mm;
    for (const o of p.obstacles) {
      const fp = o.footprint_xy_mm;
      const whole = fp.length && fp.every(([x, y]) => x <= tx0 + 1 || x >= tx1 - 1 || y <= ty0 + 1 || y >= ty1 - 1);
      if (!whole) for (const q of fp) pts.push(q);
    }
  }
  if (!pts.length) return p ? [...p.table_xy_mm] : null;
  const xs = pts.map((q) => q[0]), ys = pts.map((q) => q[1]);
  return [Math.min(...xs) - 30, Math.min(...ys) - 30, Math.max(...xs) + 30, Math.max(...ys) + 30];
}

/** What to draw: the program on offer; else the table and the located objects (to draw no-go zones
 *  on), with the touches of the last program this page offered (its results are coloured on them). */
function drawing() {
  if (state.plan) {
    $("plan-note").textContent = "The program on offer: obstacles, travel (over them) and the touches.";
    return state.plan;
  }
  const o = state.options;
  if (!o) return null;
  const last = state.lastPlan && state.lastPlan.setup_id === o.setup_id ? state.lastPlan : null;
  $("plan-note").textContent = "No program on offer: the table and the located objects" +
    (o.not_located.length ? `; not located: ${o.not_located.join(", ")}` : "") +
    (last ? "; the touches of the last program offered." : ".");
  return { table_xy_mm: o.table_xy_mm, travel_mm: [], touches: last ? last.touches : [],
           obstacles: o.located.map((x) => ({ ...x, source: "located" })) };
}

/** Draw the table, obstacles (by source), travel and touches from above; y up as on the table. */
function drawPlan() {
  const svg = $("plan");
  svg.replaceChildren();
  const p = drawing();
  const b = bounds(p);
  if (!b) {
    svg.setAttribute("viewBox", "0 0 100 40");
    svg.append(svgEl("text", { x: 50, y: 22, "text-anchor": "middle", "font-size": 4, fill: "#6b7280" },
      state.setup ? "No plan to draw." : "Choose a setup."));
    return;
  }
  const [x0, y0, x1, y1] = b;
  svg.setAttribute("viewBox", `${x0} ${-y1} ${x1 - x0} ${y1 - y0}`);
  const k = Math.max(x1 - x0, y1 - y0) / 100;  // one hundredth of the view, for strokes and text
  const Y = (y) => -y;
  const [tx0, ty0, tx1, ty1] = p.table_xy_mm;
  svg.append(svgEl("rect", { x: tx0, y: Y(ty1), width: tx1 - tx0, height: ty1 - ty0, class: "table" }));
  const wp = workpiece(state.setup);
  for (const o of p.obstacles) {
    if (!o.footprint_xy_mm.length) continue;
    const pts = o.footprint_xy_mm.map(([x, y]) => `${x},${Y(y)}`).join(" ");
    svg.append(svgEl("polygon", { points: pts, class: `ob src-${o.source}${wp && o.name === wp.name ? " wp" : ""}`,
                                  "stroke-width": 0.4 * k }, null));
    const cx = o.footprint_xy_mm.reduce((a, q) => a + q[0], 0) / o.footprint_xy_mm.length;
    const cy = o.footprint_xy_mm.reduce((a, q) => a + q[1], 0) / o.footprint_xy_mm.length;
    if (cx > x0 && cx < x1 && cy > y0 && cy < y1)
      svg.append(svgEl("text", { x: cx, y: Y(cy), "font-size": 2.6 * k, "text-anchor": "middle", class: "ob-label" }, o.name));
  }
  for (const path of p.travel_mm) {
    svg.append(svgEl("polyline", { points: path.map((q) => `${q[0]},${Y(q[1])}`).join(" "), class: "travel",
                                   "stroke-width": 0.35 * k }));
  }
  const verdicts = touchVerdicts(state.setup);
  for (const t of p.touches) {
    const [ax, ay] = t.approach_tip_mm, [cx, cy] = t.contact_mm;
    const bad = verdicts[t.name] === false;
    svg.append(svgEl("line", { x1: ax, y1: Y(ay), x2: cx, y2: Y(cy), class: "touch-move", "stroke-width": 0.6 * k }));
    svg.append(svgEl("circle", { cx, cy: Y(cy), r: 1.3 * k, class: `touch${bad ? " fail" : ""}`,
                                 "data-touch": t.name, "stroke-width": 0.3 * k }));
    const lx = ax + (ax - cx) * 0.6, ly = ay + (ay - cy) * 0.6;
    svg.append(svgEl("text", { x: lx, y: Y(ly) + k, "font-size": 3 * k, "text-anchor": "middle",
                               class: `touch-label${bad ? " fail" : ""}` }, t.name));
  }
  for (const z of zones()) {
    svg.append(svgEl("rect", { x: Math.min(z[0], z[2]), y: Y(Math.max(z[1], z[3])), width: Math.abs(z[2] - z[0]),
                               height: Math.abs(z[3] - z[1]), class: "ob src-drawn pending", "stroke-width": 0.4 * k }));
  }
  if (state.corner) svg.append(svgEl("circle", { cx: state.corner[0], cy: Y(state.corner[1]), r: k, class: "corner" }));
}

// ------------------------------------------------------------------------------------------- no-go zones
function zones() {
  return $("no-go").value.split(";").map((z) => z.split(",").map(Number)).filter((z) => z.length === 5 && z.every(Number.isFinite));
}

/** Two taps on the plan give a rectangle (table frame) with the chosen top. */
function tapPlan(ev) {
  if (!$("no-go-box").open || !state.options) return;
  const svg = $("plan");
  const pt = svg.createSVGPoint();
  pt.x = ev.clientX;
  pt.y = ev.clientY;
  const q = pt.matrixTransform(svg.getScreenCTM().inverse());
  const [tx0, ty0, tx1, ty1] = state.options.table_xy_mm;
  const x = Math.min(tx1, Math.max(tx0, q.x)), y = Math.min(ty1, Math.max(ty0, -q.y));
  if (!state.corner) {
    state.corner = [x, y];
    status("First corner set: tap the opposite corner.", "info");
  } else {
    const [a, b] = state.corner;
    state.corner = null;
    const z = [a, b, x, y].map((v) => v.toFixed(1)).join(",") + "," + Number($("no-go-top").value || 0).toFixed(1);
    $("no-go").value = [$("no-go").value.trim(), z].filter(Boolean).join(";");
    plan();
    return;
  }
  drawPlan();
}

// ------------------------------------------------------------------------------------------- results
function cOf(T) { return Math.atan2(T[1][0], T[0][0]) * 180 / Math.PI; }

/** The touch names of the last probe results, in the program's order (the plan's touches). */
function touchNames(wp) {
  const plan = state.lastPlan;
  return (wp.probe_deviation_mm || []).map((_, i) => (plan && plan.touches[i] ? plan.touches[i].name : `#${i + 1}`));
}

/** Per touch name: true when the probe found its face within the allowed error of the camera's pose
 *  (probe_expected_mm: 3 sigma + the probe's tolerance), false beyond, from the last probe results. */
function touchVerdicts(s) {
  const wp = s && workpiece(s);
  const out = {};
  if (!wp || !wp.probed) return out;
  const names = touchNames(wp);
  (wp.probe_deviation_mm || []).forEach((d, i) => { out[names[i]] = Math.abs(d) <= wp.probe_expected_mm; });
  return out;
}

/** The probed points (program frame) as sent from this page: the first three numbers of each row. */
function sentPoints() {
  const t = (state.sent || "").trim();
  if (!t) return [];
  try {
    if (t.startsWith("[")) return JSON.parse(t);
  } catch (e) { return []; }
  return t.split(/\r?\n/).filter((l) => l.trim()).map((l) => l.trim().split(/\s+/).slice(0, 3).map(Number));
}

function showResults(s) {
  const wp = workpiece(s);
  const view = $("results-view");
  if (!wp || !wp.probed || !wp.probe_before) {
    view.classList.add("hidden");
    say($("verdict"), "", "info");
    return;
  }
  view.classList.remove("hidden");
  const names = touchNames(wp);
  const dev = wp.probe_deviation_mm || [], res = wp.probe_residuals_mm || [], meas = sentPoints();
  const ok = touchVerdicts(s);
  $("residuals").tBodies[0].replaceChildren(...dev.map((d, i) => {
    const n = names[i], m = meas[i] || [];
    return el("tr", { "data-testid": "residual-row", class: ok[n] ? "" : "fail-row" },
      el("th", { text: n }), el("td", { class: "num", text: fmt(m[0], 3) }), el("td", { class: "num", text: fmt(m[1], 3) }),
      el("td", { class: "num", text: fmt(m[2], 3) }), el("td", { class: "num", text: fmt(d, 3) }),
      el("td", { class: "num", text: `± ${fmt(wp.probe_expected_mm, 3)}` }), el("td", { class: "num", text: fmt(res[i], 3) }),
      el("td", { class: ok[n] ? "pass" : "fail", text: ok[n] ? "PASS" : "FAIL" }));
  }));
  const before = wp.probe_before.T_table_obj, after = wp.T_table_obj, fit = wp.probe_fit_T_table_obj;
  const row = (label, T, tid) => el("tr", { "data-testid": tid }, el("th", { text: label }),
    ...[0, 1, 2].map((i) => el("td", { class: "num", text: fmt(T[i][3], 3) })), el("td", { class: "num", text: fmt(cOf(T), 3) }));
  const shown = fit || after;
  const diff = [0, 1, 2].map((i) => shown[i][3] - before[i][3]);
  $("pose").tBodies[0].replaceChildren(row("Before (camera)", before, "pose-before"),
    row(fit ? "Probe fit (not taken)" : "After (probe)", shown, "pose-after"),
    el("tr", { "data-testid": "pose-change" }, el("th", { text: "Change" }), ...diff.map((v) => el("td", { class: "num", text: fmt(v, 3) })),
       el("td", { class: "num", text: fmt(cOf(shown) - cOf(before), 4) })));
  const fail = wp.probe_fail;
  say($("verdict"), fail ? `FAIL: ${sentence(fail)}` :
      `PASS: every touch within ± ${fmt(wp.probe_expected_mm, 3)} mm of the camera's pose; the pose is refined (revision ${s.result_revision}). Confirm it again on the setup page before exporting.`,
      fail ? "bad" : "ok");
  drawChart(names, dev, wp.probe_expected_mm, ok);
}

/** Bars: how far each touch found its face from the camera's pose, against the allowed error. */
function drawChart(names, dev, limit, ok) {
  const svg = $("residual-chart");
  svg.replaceChildren();
  const W = 300, H = 160, top = Math.max(limit * 1.6, ...dev.map(Math.abs)) || 1;
  svg.setAttribute("viewBox", `0 0 ${W} ${H}`);
  const y = (v) => H - 24 - (H - 40) * Math.min(v, top) / top;
  const bw = (W - 40) / Math.max(dev.length, 1);
  dev.forEach((d, i) => {
    const n = names[i];
    const x = 30 + i * bw + bw * 0.2;
    svg.append(svgEl("rect", { x, y: y(Math.abs(d)), width: bw * 0.6, height: H - 24 - y(Math.abs(d)),
                               class: ok[n] ? "bar" : "bar fail" }));
    svg.append(svgEl("text", { x: x + bw * 0.3, y: H - 8, "text-anchor": "middle", "font-size": 12 }, n));
    svg.append(svgEl("text", { x: x + bw * 0.3, y: y(Math.abs(d)) - 3, "text-anchor": "middle", "font-size": 10 }, fmt(Math.abs(d), 2)));
  });
  svg.append(svgEl("line", { x1: 26, x2: W - 4, y1: y(limit), y2: y(limit), class: "limit" }));
  svg.append(svgEl("text", { x: W - 4, y: y(limit) - 4, "text-anchor": "end", "font-size": 10, class: "limit-label" },
    `allowed ${fmt(limit, 3)} mm`));
}

async function sendResults() {
  const s = state.setup;
  const text = $("results").value.trim();
  if (!s) return status("Choose a setup first.", "bad");
  if (!text) return status("Paste the probe log, or upload its file, first.", "bad");
  $("results-button").disabled = true;
  status("Fitting the pose to the probed points…", "info");
  try {
    state.sent = text;
    state.setup = await api(`/api/v1/setups/${s.id}/probe-results`,
      { method: "POST", headers: { "Content-Type": "text/plain" }, body: text });
    showResults(state.setup);
    await plan();  // the new revision is not confirmed: the page says so
  } catch (e) {
    status(`Results not used: ${sentence(e.message)}`, "bad");
  } finally {
    $("results-button").disabled = false;
  }
}

// ------------------------------------------------------------------------------------------- start
document.addEventListener("DOMContentLoaded", async () => {
  $("plan-button").addEventListener("click", plan);
  for (const id of ["slot", "dialect", "clearance"]) $(id).addEventListener("change", plan);
  $("detour").addEventListener("change", () => { fillDialects(); plan(); });
  $("no-go").addEventListener("change", plan);
  $("no-go-clear").addEventListener("click", () => { $("no-go").value = ""; state.corner = null; plan(); });
  $("plan").addEventListener("click", tapPlan);
  $("no-go-box").addEventListener("toggle", () => { state.corner = null; drawPlan(); });
  $("download").addEventListener("click", download);
  $("results-button").addEventListener("click", sendResults);
  $("results-file").addEventListener("change", async (ev) => {
    const f = ev.target.files[0];
    if (f) $("results").value = await f.text();
    ev.target.value = "";
  });
  $("setup-input").addEventListener("change", () => {
    const id = $("setup-input").value;
    if (id) loadSetup(id).catch((e) => status(sentence(e.message), "bad"));
  });
  const id = qs("setup");
  if (!id) {
    status("Open a setup: type its number, or come here from the setup page.", "info");
    drawPlan();
    return;
  }
  try {
    await loadSetup(id);
  } catch (e) {
    status(sentence(e.message), "bad");
  }
});
