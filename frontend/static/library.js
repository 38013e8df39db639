// The library page: the models (workpieces, clamps, supports, tables), upload and 3D preview.
// Moved out of frontend/library.html (no inline scripts: issue 15); uses common.js.
const models = document.getElementById("models");
async function load() {
  const q = document.getElementById("q").value, kind = document.getElementById("kind").value;
  const p = new URLSearchParams({ limit: 200 });
  if (q) p.set("name", q);
  if (kind) p.set("kind", kind);
  try {
    const page = await api(`/api/v1/models?${p}`);
    models.innerHTML = "";
    if (!page.data.length) say("#msg", "No model matches.", "info"); else say("#msg", "");
    for (const m of page.data) {
      const s = m.revision.summary || {};
      const size = s.extents_mm ? s.extents_mm.map((v) => Math.round(v)).join(" × ") + " mm" : "";
      models.append(el("div", { class: "card", "data-testid": "model-card" },
        el("img", { src: m.thumbnail_url, alt: m.name, loading: "lazy" }),
        el("strong", { text: m.name }),
        el("div", { class: "muted", text: `${m.kind} · revision ${m.revision.revision} ${size ? "· " + size : ""}` }),
        ...(m.revision.support_surfaces && m.revision.support_surfaces.length
          ? [el("div", { class: "muted", text: "carries parts on: " + m.revision.support_surfaces.map((f) => `${f.name} (z ${f.z_mm} mm)`).join(", ") })]
          : []),
        el("button", { text: "3D view", onclick: () => preview(m) })));
    }
  } catch (e) { say("#msg", e.message, "bad"); }
}
function preview(m) {
  document.getElementById("preview-box").classList.remove("hidden");
  document.getElementById("preview").src = `/viewer/model/${m.id}/`;
  document.getElementById("preview-label").textContent = `${m.name}: drag to turn, pinch or scroll to zoom`;
  window.scrollTo({ top: 0, behavior: "smooth" });
}
document.querySelector("input[name=file]").addEventListener("change", (ev) => {
  const f = ev.target.files[0];
  document.getElementById("file-name").textContent = f ? f.name : "";
  const name = document.querySelector("input[name=name]");
  if (f && !name.value) name.value = f.name.replace(/\.[^.]+$/, "");
});
document.getElementById("upload").addEventListener("submit", async (ev) => {
  ev.preventDefault();
  say("#upmsg", "Uploading and checking the model…", "info");
  try {
    const m = await api("/api/v1/models", { method: "POST", body: new FormData(ev.target) });
    say("#upmsg", `Added “${m.name}”.`, "ok");
    ev.target.reset();
    document.getElementById("file-name").textContent = "";
    load();
  } catch (e) {
    say("#upmsg", e.code === "admin_required" ? "Only an admin may add models. Ask your supervisor." : e.message, "bad");
  }
});
let timer = null;
document.getElementById("q").addEventListener("input", () => { clearTimeout(timer); timer = setTimeout(load, 250); });
document.getElementById("kind").addEventListener("change", load);
load();
