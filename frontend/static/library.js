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
        el("div", { class: "muted", text: `${m.kind}${m.source === "photo" ? " · taught from pictures" : ""} · revision ${m.revision.revision} ${size ? "· " + size : ""}` }),
        ...(m.revision.support_surfaces && m.revision.support_surfaces.length
          ? [el("div", { class: "muted", text: "carries parts on: " + m.revision.support_surfaces.map((f) => `${f.name} (z ${f.z_mm} mm)`).join(", ") })]
          : []),
        ...(m.revision.guide
          ? [el("div", { class: "muted", text: `rides on ${m.revision.guide.carrier}, travel ${m.revision.guide.travel_mm[0]} to ${m.revision.guide.travel_mm[1]} mm` })]
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
// Teach from camera (issue 16): pictures of the object on the table -> a photo model; then a tap on the
// teach picture (the top face seen from above, mm) sets the datum as a new revision.
const teach = document.getElementById("teach");
async function loadMachines() {
  const sel = teach.querySelector("select[name=machine_id]");
  try {
    const list = await api("/api/v1/machines");
    sel.innerHTML = "";
    for (const m of list.data || list) sel.append(el("option", { value: m.id, text: m.name }));
  } catch (e) { say("#teachmsg", e.message, "bad"); }
}
teach.querySelector("input[name=pictures]").addEventListener("change", (ev) => {
  document.getElementById("teach-files").textContent = `${ev.target.files.length} picture(s)`;
});
teach.addEventListener("submit", async (ev) => {
  ev.preventDefault();
  const form = new FormData(teach);
  if (!form.get("height_mm")) form.delete("height_mm");
  if (!form.get("grab")) form.delete("grab");
  if (form.get("grab")) form.delete("pictures");
  say("#teachmsg", "Locating the table and teaching the object…", "info");
  try {
    const m = await api("/api/v1/models/photo", { method: "POST", body: form });
    const p = m.revision.photo;
    say("#teachmsg", `Taught “${m.name}”: ${Math.round(p.edge_length_mm)} mm of edges, ${p.holes} hole(s), ` +
        `height ${p.height_mm.toFixed(1)} mm (${p.height_source}), from ${p.n_views} picture(s).`, "ok");
    showDatum(m);
    load();
  } catch (e) {
    say("#teachmsg", e.code === "admin_required" ? "Only an admin may teach models. Ask your supervisor." : e.message, "bad");
  }
});
function showDatum(m) {
  const p = m.revision.photo, img = document.getElementById("teach-picture");
  document.getElementById("datum-box").classList.remove("hidden");
  img.src = p.teach_picture_url;
  img.onclick = async (ev) => {
    // the picture is shown flipped (table y up): the tap's place from the picture's own box
    const r = img.getBoundingClientRect(), g = p.teach_grid, T = p.T_table_obj_teach;
    const u = (ev.clientX - r.left) / r.width * img.naturalWidth;
    const v = (1 - (ev.clientY - r.top) / r.height) * img.naturalHeight;
    const x = g.x0_mm + u * g.mm_per_px - T[0][3], y = g.y0_mm + v * g.mm_per_px - T[1][3];
    const datum = [[1, 0, 0, x], [0, 1, 0, y], [0, 0, 1, p.height_mm], [0, 0, 0, 1]];
    const body = new FormData();
    body.set("T_obj_datum", JSON.stringify(datum));
    body.set("note", "datum tapped on the teach picture");
    try {
      const n = await api(`/api/v1/models/${m.id}/revisions`, { method: "POST", body });
      say("#datummsg", `Datum set at x ${x.toFixed(1)}, y ${y.toFixed(1)} mm from the object's centre ` +
          `(revision ${n.revision.revision}).`, "ok");
    } catch (e) { say("#datummsg", e.message, "bad"); }
  };
}
loadMachines();
let timer = null;
document.getElementById("q").addEventListener("input", () => { clearTimeout(timer); timer = setTimeout(load, 250); });
document.getElementById("kind").addEventListener("change", load);
load();
