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
function exportCell(s) {
  const cell = el("td", { "data-testid": "history-export" });
  if (s.confirmed_revision === null || s.confirmed_revision === undefined) return cell;
  cell.append(el("span", { class: "muted", text: "…" }));
  api(`/api/v1/setups/${s.id}/exports`).then((rows) => {
    cell.replaceChildren(...(rows.length ? rows : [null]).map((x) => x === null
      ? el("div", { class: "muted", text: "not exported" })
      : el("div", { class: x.status === "written" ? "pass" : "fail",
                    text: x.status === "written"
                      ? `${x.slot}: written, read back (${x.actor}, ${when(x.created_at)})`
                      : `${x.slot}: ${x.status}. ${x.reason}` })));
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
