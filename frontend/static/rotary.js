// The rotary axis check page: upload pictures of the printed target at commanded angles (POST
// /api/v1/rotary/runs), show the error per picture, the ISO 230-2 figures, the error plot, the CSV
// downloads and the compensation proposals; list past runs.
"use strict";

let chosen = [];   // File objects in the order they are sent

/** Natural order of file names: img2 before img10. */
function byName(a, b) { return a.name.localeCompare(b.name, undefined, { numeric: true, sensitivity: "base" }); }

function angleList() {
  return $("angles").value.split(/[,; ]+/).filter((s) => s.trim() !== "");
}

function showChosen() {
  const n = chosen.length, a = angleList().length;
  $("count").textContent = n ? `${n} picture${n === 1 ? "" : "s"} chosen` + (a && a !== n ? ` (but ${a} angles)` : "") : "no pictures chosen";
}

async function fillCameras() {
  const cams = await api("/api/v1/cameras");
  const sel = $("camera");
  sel.innerHTML = "";
  if (!cams.length) sel.append(el("option", { value: "", text: "No camera yet: add one on the Cameras page" }));
  for (const c of cams) {
    sel.append(el("option", { value: c.id, text: c.intrinsics ? c.name : `${c.name} (not calibrated yet)` }));
  }
  const firstReady = cams.find((c) => c.intrinsics);
  if (firstReady) sel.value = String(firstReady.id);
}

function figure(id, value, note) {
  $(id).textContent = fmt(value, 1);
  $(id + "-note").textContent = value === null || value === undefined ? note : "";
}

function link(name, url, text) {
  return el("a", { class: "button", href: url, download: name, text, "data-testid": `rotary-file-${name}` });
}

function showRun(run) {
  $("result-title").textContent = `Result: run #${run.id}, axis ${run.axis_name}, ${when(run.created_at)}`;
  if (!run.ok) {
    $("body").classList.add("hidden");
    say($("summary"), `The measurement did not succeed: ${run.reason}`, "bad");
    return;
  }
  const r = run.result || {}, rep = run.report || {};
  const errs = (r.error_arcsec || []).filter((e) => e !== null && e !== undefined);
  const worst = errs.length ? Math.max(...errs.map(Math.abs)) : null;
  say($("summary"), `${run.angles_deg.length} pictures measured (${r.method === "reference" ? "reference method" : "direct fit"}); largest error ${fmt(worst, 1)} arc-seconds.`, "ok");
  const rows = run.angles_deg.map((a, i) => {
    const img = (r.images || [])[i];
    const why = img && !img.ok ? img.reason : "";
    return el("tr", {}, el("td", { text: String(i + 1) }), el("td", { class: "num", text: fmt(a, 3) }),
      el("td", { class: "num", text: fmt((r.measured_deg || [])[i], 4) }),
      el("td", { class: "num", text: why || fmt((r.error_arcsec || [])[i], 1) }));
  });
  $("rows").replaceChildren(...rows);
  const updown = rep.runs_up !== undefined ? ` (runs: ${rep.runs_up} up, ${rep.runs_down} down)` : "";
  const twoRuns = "needs at least 2 runs in each direction" + updown;
  figure("fig-reversal", rep.reversal_B_arcsec, "needs the same positions approached in both directions");
  figure("fig-repeat", rep.repeatability_arcsec, twoRuns);
  figure("fig-accuracy", rep.accuracy_arcsec, twoRuns);
  const files = run.files || {};
  const plot = files["error.png"] || files["error.svg"];
  if (plot) { $("plot").src = plot; $("plot-link").href = plot; } else { $("plot").removeAttribute("src"); $("plot-link").removeAttribute("href"); }
  const downloads = [], proposals = [];
  for (const [name, url] of Object.entries(files)) {
    const lower = name.toLowerCase();
    if (lower.endsWith(".com")) proposals.push(link(name, url, `HEIDENHAIN table proposal (${name})`));
    else if (lower.includes("fanuc") || lower.includes("proposal")) proposals.push(link(name, url, `Fanuc pitch-error proposal (${name})`));
    else if (lower.endsWith(".csv")) downloads.push(link(name, url, `Download ${name}`));
    else downloads.push(link(name, url, `Plot ${name}`));
  }
  $("downloads").replaceChildren(...downloads);
  $("proposals").replaceChildren(...proposals);
  $("body").classList.remove("hidden");
}

async function fillRuns(selectId) {
  const runs = await api("/api/v1/rotary/runs");
  if (!runs.length) return;
  $("runs").replaceChildren(...runs.slice(0, 12).map((run) => el("button", {
    class: "small", "data-testid": "rotary-run",
    text: `#${run.id} ${when(run.created_at)} · ${run.axis_name} · ${run.angles_deg.length} pictures · ${run.ok ? "ok" : "failed"}`,
    onclick: () => { history.replaceState(null, "", `/rotary?run=${run.id}`); say("#msg", ""); showRun(run); },
  })));
  if (selectId) { const r = runs.find((x) => String(x.id) === String(selectId)); if (r) showRun(r); }
}

async function measure() {
  const btn = $("measure");
  if (!$("camera").value) return say("#msg", "Choose a camera first (add and calibrate one on the Cameras page).", "bad");
  if (chosen.length < 2) return say("#msg", "Choose at least 2 pictures: the first is the zero position.", "bad");
  const form = new FormData();
  form.append("camera_id", $("camera").value);
  for (const f of chosen) form.append("images", f, f.name);
  form.append("angles_deg", $("angles").value);
  form.append("method", $("method").value);
  form.append("axis_name", $("axis").value.trim() || "C");
  btn.disabled = true;
  btn.textContent = "Measuring…";
  say("#msg", `Measuring ${chosen.length} pictures, this takes a few seconds…`, "info");
  try {
    const { job, resource: run } = await jobResult(await api("/api/v1/rotary/runs", { method: "POST", body: form }));
    if (!run) throw new Error(job.reason);
    say("#msg", run.ok ? "Measured." : `Not measured: ${run.reason}`, run.ok ? "ok" : "bad");
    history.replaceState(null, "", `/rotary?run=${run.id}`);
    showRun(run);
    fillRuns().catch(() => {});
  } catch (e) {
    say("#msg", `Not measured: ${e.message}`, "bad");
  } finally {
    btn.disabled = false;
    btn.textContent = "2. Measure";
  }
}

(async () => {
  $("images").addEventListener("change", () => { chosen = Array.from($("images").files).sort(byName); showChosen(); });
  $("angles").addEventListener("input", showChosen);
  $("measure").addEventListener("click", measure);
  try {
    await fillCameras();
    await fillRuns(qs("run"));
  } catch (e) { say("#msg", e.message, "bad"); }
})();
