// Shared helpers of the operator pages (no framework, no build step). Every page loads this file
// (frontend/_layout.html) and then its own script from /static; no page has an inline script.
"use strict";

/** The element with this id. A property of the window (not a declaration), so a page script that
 *  still declares its own ``$`` keeps working. */
globalThis.$ = (id) => document.getElementById(id);

/** Call the REST API; resolve to JSON (or a Response for non-JSON), reject with an Error whose message is
 *  the service's plain sentence (never a stack trace), ``status`` the HTTP status and ``code`` the
 *  service's reason code (app/api/problems.py): pages choose their advice by the code, not the text. */
async function api(path, opts = {}) {
  let resp;
  try {
    resp = await fetch(path, opts);
  } catch (e) {
    throw new Error("The service does not answer. Check the network cable or that the service is running, then try again.");
  }
  if (resp.status === 401 && !opts.noRedirect && location.pathname !== "/login") {
    location.href = "/login?next=" + encodeURIComponent(location.pathname + location.search);
    throw new Error("Please sign in first.");
  }
  if (!resp.ok) {
    let detail = "", code = "";
    try {
      const j = await resp.json();
      detail = typeof j.detail === "string" ? j.detail : JSON.stringify(j.detail);
      code = typeof j.code === "string" ? j.code : "";
    } catch (e) { detail = ""; }
    const err = new Error(detail || `The service answered ${resp.status} ${resp.statusText}.`);
    err.status = resp.status;
    err.code = code;
    throw err;
  }
  const type = resp.headers.get("content-type") || "";
  if (resp.status === 204) return null;
  return type.includes("json") ? resp.json() : resp;
}

function postJSON(path, body) {
  return api(path, { method: "POST", headers: { "Content-Type": "application/json" }, body: JSON.stringify(body) });
}

/** Wait for a job the service accepted (202: {job_url, ...}) and read what it made.
 *  Resolves to {job, resource}: resource is null when the job made nothing (then job.reason says why). */
async function jobResult(accepted, pollMs = 300) {
  let job = await api(accepted.job_url);
  while (job.status !== "done" && job.status !== "failed") {
    await new Promise((resolve) => setTimeout(resolve, pollMs));
    job = await api(accepted.job_url);
  }
  const resource = job.result && job.result.url ? await api(job.result.url) : null;
  return { job, resource };
}

/** Show a sentence in a message box: kind = info | ok | bad | warn. */
function say(el, text, kind = "info") {
  if (typeof el === "string") el = document.querySelector(el);
  el.textContent = text || "";
  el.className = "message " + kind;
}

function qs(name) { return new URLSearchParams(location.search).get(name); }

function el(tag, attrs = {}, ...children) {
  const e = document.createElement(tag);
  for (const [k, v] of Object.entries(attrs)) {
    if (k === "class") e.className = v;
    else if (k === "text") e.textContent = v;
    else if (k.startsWith("on")) e.addEventListener(k.slice(2), v);
    else if (v !== null && v !== undefined && v !== false) e.setAttribute(k, v === true ? "" : v);
  }
  for (const c of children) if (c !== null && c !== undefined) e.append(c);
  return e;
}

function fmt(v, digits = 2) {
  return (v === null || v === undefined || Number.isNaN(v)) ? "—" : Number(v).toFixed(digits);
}

function when(iso) {
  if (!iso) return "—";
  const d = new Date(iso.endsWith("Z") || iso.includes("+") ? iso : iso + "Z");
  return d.toLocaleString([], { dateStyle: "short", timeStyle: "short" });
}

/** Fill a <select> with the machines; resolve to the list. */
async function fillMachines(select, selectedId) {
  const machines = await api("/api/v1/machines");
  select.innerHTML = "";
  if (!machines.length) select.append(el("option", { value: "", text: "No machine yet: an admin adds one on the Machines page" }));
  for (const m of machines) select.append(el("option", { value: m.id, text: m.name, selected: String(m.id) === String(selectedId) }));
  return machines;
}

async function signOut() {
  try { await api("/api/v1/auth/logout", { method: "POST", noRedirect: true }); } catch (e) { /* signed out anyway */ }
  location.href = "/login";
}

// Mark the current page in the top navigation; show who is signed in.
document.addEventListener("DOMContentLoaded", async () => {
  for (const a of document.querySelectorAll("header.top nav a")) {
    if (a.getAttribute("href") === location.pathname) a.classList.add("here");
  }
  const who = document.getElementById("who");
  if (!who || location.pathname === "/login") return;
  try {
    const me = await api("/api/v1/auth/me", { noRedirect: true });
    who.replaceChildren(el("span", { "data-testid": "signed-in-as", text: `${me.name} (${me.role})` }), " ",
      el("a", { href: "#", text: "Sign out", onclick: (ev) => { ev.preventDefault(); signOut(); } }));
  } catch (e) {
    who.replaceChildren(el("a", { href: "/login?next=" + encodeURIComponent(location.pathname + location.search), text: "Sign in" }));
  }
});

/** Who is signed in ({name, kind, role}), asked once per page; null when nobody is. */
let _me = null;
function whoAmI() {
  _me = _me || api("/api/v1/auth/me").catch(() => null);
  return _me;
}

/** Parse a JSON text field; throw an Error that names the field when it is not JSON. */
function parseJSONField(text, what) {
  try { return JSON.parse(text); } catch (e) { throw new Error(`${what} is not valid JSON (${e.message}).`); }
}

/** Admin pages (machines, cameras): the admin gets the .admin-only buttons; everyone else sees the form's
 *  #fields read-only with a note. Resolves to true for an admin. (The page shows its #add button once
 *  its lists are loaded, so a new form never opens with empty choices.) */
async function adminMode(noun) {
  const me = await whoAmI();
  const admin = !!me && me.role === "admin";
  document.getElementById("fields").disabled = !admin;
  for (const b of document.querySelectorAll(".admin-only")) b.classList.toggle("hidden", !admin);
  document.getElementById("readonly-note").textContent = admin ? "" : `Read-only: only an admin changes ${noun}.`;
  return admin;
}

/** PATCH ``base/id`` when editing, POST ``base`` when new; resolves to the answer. */
function saveJSON(base, id, body) {
  if (id === null || id === undefined) return postJSON(base, body);
  return api(`${base}/${id}`, { method: "PATCH", headers: { "Content-Type": "application/json" }, body: JSON.stringify(body) });
}
