// Cameras: admins add and change cameras (image source, intrinsics) and grab a test picture; operators
// see the same read-only. Calibration itself is on /camera.
"use strict";
const state = { cameras: [], editing: null, admin: false, grabUrl: null };

function showSourceFields() {
  const kind = $("s-kind").value;
  for (const e of document.querySelectorAll(".src")) e.classList.toggle("hidden", !e.classList.contains(kind));
}

function sourceFromFields() {
  const kind = $("s-kind").value;
  const old = state.editing && state.editing.source.kind === kind ? state.editing.source : {};
  if (kind === "http") return { ...old, kind, url: $("s-url").value.trim() };
  if (kind === "folder") return { ...old, kind, path: $("s-path").value.trim() };
  if (kind === "opencv") {
    const d = $("s-device").value.trim();
    const { device, url, ...rest } = old;
    return /^\d+$/.test(d) ? { ...rest, kind, device: Number(d) } : { ...rest, kind, url: d };
  }
  return { kind: "upload" };
}

function describe(c) {
  const i = c.intrinsics;
  const cal = i ? `calibrated, ${i.width} × ${i.height} px` : "not calibrated";
  const src = { upload: "photos uploaded", http: "snapshot URL", folder: "folder", opencv: "USB / stream" }[c.source.kind] || c.source.kind;
  return `${cal} · ${src}`;
}

function fillForm(c) {
  state.editing = c;
  $("form-title").textContent = c ? c.name : "New camera";
  $("c-name").value = c ? c.name : "";
  const s = c ? c.source : { kind: "upload" };
  $("s-kind").value = s.kind;
  $("s-url").value = s.kind === "http" ? s.url : "";
  $("s-path").value = s.kind === "folder" ? s.path : "";
  $("s-device").value = s.kind === "opencv" ? (s.device ?? s.url ?? "") : "";
  $("c-intrinsics").value = c && c.intrinsics ? JSON.stringify(c.intrinsics) : "";
  $("calibrate-link").href = c ? `/camera?camera=${c.id}` : "/camera";
  showSourceFields();
  $("delete").classList.toggle("hidden", !c || !state.admin);
  $("grab").disabled = !c;
  $("grab-image").classList.add("hidden");
  say("#form-msg", "");
  $("camera-form").classList.remove("hidden");
  $("camera-form").scrollIntoView({ block: "nearest" });
}

function drawCards() {
  $("cameras").replaceChildren(...state.cameras.map((c) => el("div", { class: "card", "data-testid": "camera-card" },
    el("h2", { text: c.name }), el("p", { class: "muted", text: describe(c) }),
    el("div", { class: "row" },
      el("button", { type: "button", "data-testid": "camera-edit", text: state.admin ? "Edit" : "Details", onclick: () => fillForm(c) }),
      el("a", { class: "button", href: `/camera?camera=${c.id}`, text: "Calibrate" })))));
  say("#msg", state.cameras.length ? "" : (state.admin ? "No camera yet: press “Add a camera”." : "No camera yet. Ask an admin to add one."),
      "warn");
}

async function load() {
  state.cameras = await api("/api/v1/cameras");
  drawCards();
}

$("s-kind").addEventListener("change", showSourceFields);
$("add").addEventListener("click", () => fillForm(null));
$("close").addEventListener("click", () => $("camera-form").classList.add("hidden"));
$("camera-form").addEventListener("submit", async (ev) => {
  ev.preventDefault();
  try {
    const text = $("c-intrinsics").value.trim();
    const body = { name: $("c-name").value.trim(), source: sourceFromFields(),
                   intrinsics: text ? parseJSONField(text, "The intrinsics") : null };
    if (state.editing && !text) delete body.intrinsics;   // empty keeps what the camera has
    const c = await saveJSON("/api/v1/cameras", state.editing && state.editing.id, body);
    await load();
    fillForm(state.cameras.find((x) => x.id === c.id));
    say("#form-msg", `Saved “${c.name}” (${describe(c)}).`, "ok");
  } catch (e) { say("#form-msg", e.message, "bad"); }
});
$("delete").addEventListener("click", async () => {
  const c = state.editing;
  if (!c || !confirm(`Delete camera “${c.name}”?`)) return;
  try {
    await api(`/api/v1/cameras/${c.id}`, { method: "DELETE" });
    $("camera-form").classList.add("hidden");
    await load();
  } catch (e) { say("#form-msg", e.message, "bad"); }
});
$("grab").addEventListener("click", async () => {
  const c = state.editing;
  say("#form-msg", "Taking a picture…", "info");
  try {
    const r = await api(`/api/v1/cameras/${c.id}/snapshot`, { method: "POST" });
    const blob = await r.blob();
    if (state.grabUrl) URL.revokeObjectURL(state.grabUrl);
    state.grabUrl = URL.createObjectURL(blob);
    $("grab-image").src = state.grabUrl;
    $("grab-image").classList.remove("hidden");
    const w = r.headers.get("X-Image-Width"), h = r.headers.get("X-Image-Height");
    const i = c.intrinsics;
    const match = !i ? "" : (Number(w) === i.width && Number(h) === i.height ? " It matches the intrinsics."
      : ` The intrinsics are for ${i.width} × ${i.height} px: calibrate again or change the camera's resolution.`);
    say("#form-msg", `Got a picture of ${w} × ${h} px.${match}`, match.includes("again") ? "warn" : "ok");
  } catch (e) {
    $("grab-image").classList.add("hidden");
    say("#form-msg", `No picture: ${e.message}`, "bad");
  }
});

(async () => {
  try {
    state.admin = await adminMode("cameras");
    await load();
    $("add").classList.toggle("hidden", !state.admin);
  } catch (e) { say("#msg", e.message, "bad"); }
})();
