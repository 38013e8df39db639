// Users and API keys (admin only): add, disable/enable, reset a password; create and revoke keys.
// Passwords and key secrets are shown once, right after they are made.
"use strict";

function showOnce(box, text, secret) {
  box.replaceChildren(document.createTextNode(text + " "), el("span", { class: "secret", "data-testid": "secret-once", text: secret }),
    document.createTextNode(" (shown once: write it down or pass it on now)"));
  box.className = "message ok";
}

async function loadUsers() {
  const me = await whoAmI();
  const users = await api("/api/v1/users");
  $("users").replaceChildren(...users.map((u) => el("tr", { "data-testid": "user-row" },
    el("td", { text: u.name }), el("td", { text: u.role }),
    el("td", { text: u.disabled ? "disabled" : "active", class: u.disabled ? "fail" : "" }),
    el("td", {},
      el("button", { type: "button", class: "small", text: u.disabled ? "Enable" : "Disable", disabled: u.name === me.name,
        onclick: () => act($("user-msg"), async () => {
          await api(`/api/v1/users/${u.id}`, { method: "PATCH", headers: { "Content-Type": "application/json" },
                                               body: JSON.stringify({ disabled: !u.disabled }) });
          say("#user-msg", `${u.name} is ${u.disabled ? "enabled" : "disabled and signed out"}.`, "ok");
          await loadUsers();
        }) }), " ",
      el("button", { type: "button", class: "small", text: "New password", "data-testid": "user-reset",
        onclick: () => act($("user-msg"), async () => {
          if (!confirm(`Give ${u.name} a new random password? Their open sessions end.`)) return;
          const r = await postJSON(`/api/v1/users/${u.id}/password`, {});
          showOnce($("user-msg"), `New password of ${r.name}:`, r.password);
        }) })))));
}

async function loadKeys() {
  const keys = await api("/api/v1/apikeys");
  $("keys").replaceChildren(...keys.map((k) => el("tr", {},
    el("td", { text: k.name }), el("td", { text: k.scope }), el("td", { class: "num", text: `${k.prefix}…` }),
    el("td", { text: k.revoked ? "revoked" : "active", class: k.revoked ? "fail" : "" }),
    el("td", {}, k.revoked ? null : el("button", { type: "button", class: "small", text: "Revoke",
      onclick: () => act($("key-msg"), async () => {
        if (!confirm(`Revoke key “${k.name}”? Whatever uses it stops working.`)) return;
        await api(`/api/v1/apikeys/${k.id}`, { method: "DELETE" });
        say("#key-msg", `Key “${k.name}” revoked.`, "ok");
        await loadKeys();
      }) })))));
}

async function act(box, fn) {
  try { await fn(); } catch (e) { say(box, e.message, "bad"); }
}

$("user-form").addEventListener("submit", (ev) => {
  ev.preventDefault();
  act($("user-msg"), async () => {
    const password = $("u-password").value;
    const r = await postJSON("/api/v1/users", { name: $("u-name").value.trim(), role: $("u-role").value, password: password || null });
    if (password) say("#user-msg", `User ${r.name} (${r.role}) added with the password you typed.`, "ok");
    else showOnce($("user-msg"), `User ${r.name} (${r.role}) added. Password:`, r.initial_password);
    ev.target.reset();
    await loadUsers();
  });
});
$("key-form").addEventListener("submit", (ev) => {
  ev.preventDefault();
  act($("key-msg"), async () => {
    const r = await postJSON("/api/v1/apikeys", { name: $("k-name").value.trim(), scope: $("k-scope").value });
    showOnce($("key-msg"), `Key “${r.name}” (${r.scope}); send it as “Authorization: Bearer <key>”:`, r.key);
    ev.target.reset();
    await loadKeys();
  });
});

(async () => {
  const me = await whoAmI();
  if (!me || me.role !== "admin") {
    say("#msg", "Only an admin manages users and API keys. Ask your supervisor for a new password or an account.", "warn");
    return;
  }
  $("admin-area").classList.remove("hidden");
  try { await Promise.all([loadUsers(), loadKeys()]); } catch (e) { say("#msg", e.message, "bad"); }
})();
