// The camera calibration page: pictures of the board, calibrate, check, use.
// Moved out of frontend/camera.html (no inline scripts: issue 15); uses common.js.
const shots = [];   // {name, blob}
let lastRun = null;

function board() {
  const kind = $("board-kind").value, a = Number($("nx").value), b = Number($("ny").value);
  const out = { kind, square_mm: Number($("square").value) };
  if (kind === "chessboard") out.inner_corners = [a, b];
  else Object.assign(out, { squares: [a, b], marker_mm: Number($("marker").value), dictionary: $("dictionary").value });
  return out;
}
// The print link follows the board fields, so what is printed is what the calibration looks for.
function updateBoardLink() {
  $("board-pdf").href = "/api/v1/cameras/board.pdf?board=" + encodeURIComponent(JSON.stringify(board()));
}
for (const id of ["board-kind", "nx", "ny", "square", "marker", "dictionary"]) $(id).addEventListener("change", updateBoardLink);
updateBoardLink();
$("board-kind").addEventListener("change", () => {
  const ch = $("board-kind").value === "charuco";
  for (const e of document.querySelectorAll(".charuco")) e.classList.toggle("hidden", !ch);
  $("count-label").textContent = ch ? "squares" : "inner corners";
});
function drawShots() {
  $("shots").replaceChildren(...shots.map((s, i) => el("button", { class: "chip", title: `${s.name}: tap to remove`,
    onclick: () => { shots.splice(i, 1); drawShots(); } }, `${s.name.slice(0, 16)} ✕`)));
  say("#msg", shots.length ? `${shots.length} picture(s) ready.` : "", "info");
}
$("files").addEventListener("change", (ev) => { for (const f of ev.target.files) shots.push({ name: f.name, blob: f }); ev.target.value = ""; drawShots(); });
$("clear").addEventListener("click", () => { shots.length = 0; drawShots(); });
$("grab").addEventListener("click", async () => {
  say("#msg", "Taking a picture…", "info");
  try {
    const r = await api(`/api/v1/cameras/${$("camera").value}/snapshot`, { method: "POST" });
    shots.push({ name: `grab-${shots.length + 1}.jpg`, blob: await r.blob() });
    drawShots();
  } catch (e) { say("#msg", `${e.message}. Upload pictures instead if this camera cannot be triggered from here.`, "bad"); }
});
// how well the calibration fixed the focal length and the image centre (1 sigma); every part located
// through this camera carries it in its own sigma
function sigmaText(sigma) {
  if (!sigma) return "";
  return ` Focal length known to ±${fmt(100 * sigma.f_rel, 2)} %, image centre to ±${fmt(sigma.c_px, 1)} px.`;
}
function showRun(run) {
  lastRun = run;
  const r = run.result || {};
  $("summary").textContent = run.ok
    ? `Calibration #${run.id}: reprojection error ${fmt(run.rms_px, 3)} px from ${r.n_views_used} pictures.` +
      sigmaText((r.intrinsics || {}).sigma) + (run.accepted ? " In use." : "")
    : `Calibration #${run.id} failed: ${run.reason}`;
  $("summary").className = run.ok ? "pass" : "fail";
  const cov = (r.coverage && r.coverage.cells_reached) || [];
  $("coverage").replaceChildren(...[0, 1, 2].flatMap((i) => [0, 1, 2].map((j) => el("div", { class: cov[i] && cov[i][j] ? "on" : "" }))));
  $("warnings").replaceChildren(...(r.warnings || []).map((w) => el("li", { text: w })));
  $("views").replaceChildren(...(r.views || []).map((v) => el("tr", {},
    el("td", { text: v.name }), el("td", { text: v.found ? "yes" : "no", class: v.found ? "pass" : "fail" }),
    el("td", { text: v.used ? "yes" : "no" }), el("td", { class: "num", text: fmt(v.rms_px, 3) }), el("td", { text: v.reason || "" }))));
  $("accept").classList.toggle("hidden", !run.ok || run.accepted);
}
$("calibrate").addEventListener("click", async () => {
  if (shots.length < 3) return say("#msg", "Add at least 3 pictures of the board (10 to 20 is better).", "bad");
  const form = new FormData();
  for (const s of shots) form.append("images", s.blob, s.name);
  form.append("board", JSON.stringify(board()));
  say("#msg", "Calibrating: finding the board in every picture…", "info");
  $("calibrate").disabled = true;
  try {
    const accepted = await api(`/api/v1/cameras/${$("camera").value}/calibrations`, { method: "POST", body: form });
    const { job, resource } = await jobResult(accepted);
    if (resource) showRun(resource);
    if (job.status !== "done") throw new Error(job.reason);
    say("#msg", "Done. Check the errors and the coverage, then press “Use this calibration”.", "ok");
  } catch (e) {
    say("#msg", e.code === "admin_required" ? "Only an admin may calibrate cameras. Ask your supervisor." : e.message, "bad");
  } finally { $("calibrate").disabled = false; }
});
$("accept").addEventListener("click", async () => {
  try {
    await api(`/api/v1/cameras/${$("camera").value}/calibrations/${lastRun.id}/accept`, { method: "POST" });
    lastRun.accepted = true; showRun(lastRun); loadCamera();
    say("#msg", "The camera now uses this calibration.", "ok");
  } catch (e) { say("#msg", e.message, "bad"); }
});
async function loadCamera() {
  const id = $("camera").value;
  if (!id) return;
  try {
    const c = await api(`/api/v1/cameras/${id}`);
    const i = c.intrinsics;
    say("#cam-state", i ? `${c.name}: calibrated for ${i.width} × ${i.height} px (focal length ${fmt(i.K[0][0], 0)} px).`
                        : `${c.name}: not calibrated yet. Setups need a calibrated camera.`, i ? "ok" : "warn");
    const runs = await api(`/api/v1/cameras/${id}/calibrations`);
    if (runs.length) showRun(runs[runs.length - 1]);
  } catch (e) { say("#cam-state", e.message, "bad"); }
}
(async () => {
  try {
    const cams = await api("/api/v1/cameras");
    const sel = $("camera");
    if (!cams.length) say("#cam-state", "No camera yet: an admin adds cameras on the Cameras page (/cameras).", "warn");
    for (const c of cams) sel.append(el("option", { value: c.id, text: c.name, selected: String(c.id) === qs("camera") }));
    sel.addEventListener("change", loadCamera);
    loadCamera();
  } catch (e) { say("#cam-state", e.message, "bad"); }
})();
