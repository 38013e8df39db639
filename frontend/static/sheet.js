// The sheet monitor page: alignment picture, thresholds, a live chart of the four corner errors
// (server-sent events from /api/v1/sheet/monitors/{id}/events), the current decision in words, Stop.
"use strict";

const WORDS = {
  ok: ["SHEET IN PLACE", "ok"],
  redatum: ["SHEET MOVED: NEW ORIGIN SENT", "warn"],
  stop: ["SHEET MOVED TOO FAR: MACHINE STOPPED", "bad"],
  frame_missing: ["NO PICTURE FROM THE CAMERA", "bad"],
  corner_not_found: ["A CORNER IS NOT VISIBLE", "bad"],
};
const COLOURS = ["#1d4ed8", "#15803d", "#b45309", "#7c3aed"];
let points = [];   // [{frame, errors: [4]}]
let monitor = null;
let source = null;

function drawChart() {
  const c = document.getElementById("chart"), g = c.getContext("2d");
  const W = c.width, H = c.height, L = 48, B = 26, T = 10, R = 10;
  g.clearRect(0, 0, W, H);
  if (!monitor) return;
  const ymax = monitor.l2_mm * 1.5;
  const n = Math.max(10, points.length);
  const x = (i) => L + (W - L - R) * (i / (n - 1));
  const y = (v) => H - B - (H - B - T) * Math.min(v, ymax) / ymax;
  g.strokeStyle = "#9ca3af"; g.lineWidth = 1; g.font = "12px sans-serif"; g.fillStyle = "#374151";
  g.beginPath(); g.moveTo(L, T); g.lineTo(L, H - B); g.lineTo(W - R, H - B); g.stroke();
  for (const v of [0, monitor.l1_mm, monitor.l2_mm]) g.fillText(v.toFixed(1), 4, y(v) + 4);
  g.fillText("frames →", W - 70, H - 6);
  for (const [v, col, name] of [[monitor.l1_mm, "#b45309", "L1"], [monitor.l2_mm, "#b91c1c", "L2"]]) {
    g.setLineDash([6, 4]); g.strokeStyle = col; g.beginPath(); g.moveTo(L, y(v)); g.lineTo(W - R, y(v)); g.stroke();
    g.setLineDash([]); g.fillStyle = col; g.fillText(name, W - R - 20, y(v) - 4);
  }
  for (let k = 0; k < 4; k++) {
    g.strokeStyle = COLOURS[k]; g.lineWidth = 2; g.beginPath();
    let pen = false;
    points.forEach((p, i) => {
      const v = p.errors[k];
      if (v === null || v === undefined) { pen = false; return; }  // a gap where the corner was not seen
      if (pen) g.lineTo(x(i), y(v)); else g.moveTo(x(i), y(v));
      pen = true;
    });
    g.stroke();
  }
  // missing frames / lost corners as red ticks on the time axis
  g.fillStyle = "#b91c1c";
  points.forEach((p, i) => { if (p.decision === "frame_missing" || p.decision === "corner_not_found") g.fillRect(x(i) - 1, H - B - 8, 3, 8); });
}

function show(d) {
  const [words, kind] = WORDS[d.decision] || [d.decision, "info"];
  const box = document.getElementById("decision");
  box.textContent = words; box.className = "sheet-decision " + kind;
  document.getElementById("reason").textContent = `frame ${d.frame_index}: ${d.reason}` + actionText(d.action);
  if (d.picture_url) {
    document.getElementById("lastpic").src = d.picture_url;
    document.getElementById("lastpic").classList.remove("hidden");
    document.getElementById("lastnone").classList.add("hidden");
    document.getElementById("lastlink").href = d.picture_url;
  }
}

function actionText(a) {
  if (!a) return "";
  const out = [];
  if (a.redatum) out.push(`new origin ${a.redatum.status}${a.redatum.reason ? " (" + a.redatum.reason + ")" : ""}`);
  if (a.stop) out.push(`machine stop: ${a.stop}`);
  if (a.pause) out.push(`machine hold: ${a.pause}`);
  return out.length ? " — " + out.join("; ") : "";
}

function add(d) {
  points.push({ frame: d.frame_index, errors: d.errors_mm, decision: d.decision });
  if (points.length > 600) points = points.slice(-600);
  show(d); drawChart();
}

function ended(state, reason) {
  say("#msg", `Monitoring ${state === "stopped" ? "stopped the machine" : "has ended"}${reason ? ": " + reason : ""}.`,
      state === "stopped" ? "bad" : "info");
  document.getElementById("stop").disabled = true;
}

async function open(id) {
  if (source) source.close();
  points = [];
  history.replaceState(null, "", `/sheet?monitor=${id}`);
  try {
    monitor = await api(`/api/v1/sheet/monitors/${id}?recent=1`);
  } catch (e) { return say("#msg", e.message, "bad"); }
  say("#msg", "");
  document.getElementById("monitor-view").classList.remove("hidden");
  const a = monitor.alignment, off = a.result && a.result.offset;
  document.getElementById("picture").src = a.picture_url || a.image_url;
  document.getElementById("offset").textContent = off ?
    `origin X ${fmt(off.x_mm)} Y ${fmt(off.y_mm)} mm, angle ${fmt(off.c_deg, 3)}° (bed), slot ${monitor.slot}; confirmed by ${a.confirmed_by || "—"}` : "";
  document.getElementById("thresholds").textContent =
    `L1 = ${fmt(monitor.l1_mm)} mm (from here: new origin)   L2 = ${fmt(monitor.l2_mm)} mm (from here: stop the machine)`;
  document.getElementById("legend").replaceChildren(...COLOURS.map((c, k) =>
    el("span", {}, el("b", { text: "■ ", style: `color:${c}` }), `corner ${k}`)));
  document.getElementById("stop").disabled = monitor.state !== "running";
  drawChart();
  source = new EventSource(`/api/v1/sheet/monitors/${id}/events`);
  source.addEventListener("decision", (ev) => add(JSON.parse(ev.data)));
  source.addEventListener("end", (ev) => { const e = JSON.parse(ev.data); ended(e.state, e.reason); source.close(); });
}

(async () => {
  const sel = document.getElementById("monitor");
  let list = [];
  try { list = await api("/api/v1/sheet/monitors?limit=50"); } catch (e) { return say("#msg", e.message, "bad"); }
  if (!list.length) { sel.append(el("option", { value: "", text: "No monitor yet" })); return say("#msg", "No sheet is being monitored. Monitoring starts when a sheet on a cutting bed has been "
    + "aligned and confirmed (by the MES or a cell script); its corners, decisions and a Stop button then show here.", "info"); }
  const want = qs("monitor") || String(list[0].id);
  for (const m of list) sel.append(el("option", { value: m.id, selected: String(m.id) === want, text: `#${m.id} (${m.state})` }));
  sel.addEventListener("change", () => open(sel.value));
  document.getElementById("stop").addEventListener("click", async () => {
    if (!monitor) return;
    try { const m = await postJSON(`/api/v1/sheet/monitors/${monitor.id}/stop`, {}); ended(m.state, m.reason); }
    catch (e) { say("#msg", e.message, "bad"); }
  });
  open(want);
})();
