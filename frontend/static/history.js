// The history page: past setups of a machine, their results, confirmations and exports.
// Moved out of frontend/history.html (no inline scripts: issue 15); uses common.js.
function resultCell(s) {
  if (s.status === "queued" || s.status === "running") return el("span", { text: "still running…" });
  if (s.status === "failed") return el("span", { class: "fail", text: "Failed: " + (s.reason || "no reason recorded") });
  const off = s.result && s.result.offset;
  if (!off) return el("span", { text: "Located (no workpiece offset)" });
  return el("span", {},
    el("span", { class: off.ok === false ? "fail" : "pass", text: off.ok === false ? "FAIL " : "PASS " }),
    el("span", { class: "num", text: `X ${fmt(off.x_mm)}  Y ${fmt(off.y_mm)}  Z ${fmt(off.z_mm)}  C ${fmt(off.c_deg, 3)}°` }),
    el("div", { class: "muted", text: off.object || "" }));
}
function confirmedCell(s) {
  if (s.confirmed_revision === null || s.confirmed_revision === undefined) return el("span", { class: "muted", text: "not confirmed" });
  const stale = s.confirmed_revision !== s.result_revision ? " (changed afterwards)" : "";
  return el("span", { text: `${s.confirmed_by || "?"}, ${when(s.confirmed_at)}, revision ${s.confirmed_revision}${stale}` });
}
/** The export attempts of a confirmed setup: written and read back, or failed and why. */
/** The export attempts of a setup: written and read back, failed and why, or refused by a gate before
 *  anything was written (not confirmed, implausible, ...) and why; oldest first. */
function exportCell(s) {
  const cell = el("td", { "data-testid": "history-export" });
  cell.append(el("span", { class: "muted", text: "…" }));
  Promise.all([api(`/api/v1/setups/${s.id}/exports`), api(`/api/v1/setups/${s.id}/export-refusals`)]).then(([rows, refused]) => {
    const items = [
      ...rows.map((x) => ({ at: x.created_at, node: el("div", { class: x.status === "written" ? "pass" : "fail",
        text: x.status === "written" ? `${x.slot}: written, read back (${x.actor}, ${when(x.created_at)})`
                                     : `${x.slot}: ${x.status}. ${x.reason}` }) })),
      ...refused.map((r) => ({ at: r.at, node: el("div", { class: "fail", "data-testid": "history-export-refused",
        text: `${r.slot || "?"}: refused, nothing written (${r.actor}, ${when(r.at)}). ${r.reason}` }) })),
    ].sort((a, b) => String(a.at).localeCompare(String(b.at)));
    cell.replaceChildren(...(items.length ? items.map((i) => i.node) : [el("div", { class: "muted", text: "not exported" })]));
  }).catch((e) => cell.replaceChildren(el("span", { class: "fail", text: e.message })));
  return cell;
}
async function load() {
  const m = document.getElementById("machine").value;
  const rows = document.getElementById("rows");
  rows.innerHTML = "";
  if (!m) return;
  history.replaceState(null, "", `/history?machine=${m}`);
  try {
    const list = await api(`/api/v1/setups?machine_id=${m}&limit=100`);
    if (!list.length) say("#msg", "No setups on this machine yet.", "info"); else say("#msg", "");
    for (const s of list) {
      rows.append(el("tr", { "data-testid": "history-row" },
        el("td", {}, el("img", { class: "thumb", loading: "lazy", src: s.overlay_url || s.image_url, alt: `picture of setup ${s.id}` })),
        el("td", {}, el("div", { class: "big", text: `#${s.id}` }), el("div", { class: "muted", text: when(s.created_at) })),
        el("td", {}, resultCell(s)),
        el("td", {}, confirmedCell(s)),
        exportCell(s),
        el("td", {}, el("a", { class: "button", href: `/setup?machine=${m}&setup=${s.id}`, text: "Open" }))));
    }
  } catch (e) { say("#msg", e.message, "bad"); }
}
(async () => {
  const sel = document.getElementById("machine");
  try { await fillMachines(sel, qs("machine") || localStorage.getItem("setupcam.machine")); }
  catch (e) { return say("#msg", e.message, "bad"); }
  sel.addEventListener("change", load);
  load();
})();
