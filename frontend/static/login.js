// The sign-in page.
// Moved out of frontend/login.html (no inline scripts: issue 15); uses common.js.
document.getElementById("login").addEventListener("submit", async (ev) => {
  ev.preventDefault();
  const f = new FormData(ev.target);
  try {
    await postJSON("/api/v1/auth/login", { name: f.get("name"), password: f.get("password") });
    const next = qs("next");
    location.href = next && next.startsWith("/") && !next.startsWith("//") ? next : "/";
  } catch (e) {
    say("#msg", e.code === "wrong_password" ? "Wrong name or password. Try again, or ask your supervisor." : e.message, "bad");
  }
});
