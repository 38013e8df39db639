"""Sign-in and sessions as a security review expects (issue 17, item 6), over real HTTP: throttling per
user and per address, no timing difference for unknown users, failed sign-ins logged and audited,
Origin checked on cookie-authenticated writes, Secure cookie option, security headers, /health 503
naming the failing part, POST /users never echoes a password, private data folder, CLI accounts."""

from __future__ import annotations

import os
import re
import stat
import statistics
import subprocess
import sys
import time

import httpx
import pytest

from app.services.throttle import LoginThrottle
from tests.support.live_server import live_server


@pytest.fixture()
def own_server(tmp_path):
    """A service of its own: throttling state and settings must not leak into the shared one."""
    with live_server(tmp_path, load_example_library=False) as srv:
        yield srv


def _login(srv, name: str, password: str) -> httpx.Response:
    return httpx.post(f"{srv.url}/api/v1/auth/login", json={"name": name, "password": password}, timeout=30)


def test_throttle_waits_grow_after_the_free_failures():
    now = [1000.0]
    t = LoginThrottle(free=5, window_s=60, max_delay_s=900, clock=lambda: now[0])
    for _ in range(5):
        assert t.wait_s("user:a") == 0
        t.failed("user:a")
    assert t.wait_s("user:a") == pytest.approx(60)
    now[0] += 61
    assert t.wait_s("user:a") == 0
    t.failed("user:a")
    assert t.wait_s("user:a") == pytest.approx(120)   # doubles with every further failure
    for _ in range(10):
        t.failed("user:a")
    assert t.wait_s("user:a") == pytest.approx(900)   # capped
    assert t.wait_s("user:b") == 0                     # another name is not affected
    t.succeeded("user:a")
    assert t.wait_s("user:a") == 0


def test_sign_in_is_throttled_per_user_and_per_address_and_audited(own_server):
    for _ in range(5):
        assert _login(own_server, "test-operator", "wrong-password").status_code == 401
    r = _login(own_server, "test-operator", "test-operator-pw")
    assert r.status_code == 429, "even the right password waits now"
    assert "try again in" in r.json()["detail"] and int(r.headers["retry-after"]) >= 59
    r = _login(own_server, "test-admin", "test-admin-pw")
    assert r.status_code == 429, "the same address is held too"
    with own_server.client("admin-key") as c:
        entries = c.get("/api/v1/audit", params={"limit": 50}).json()
    failed = [e for e in entries if e["action"] == "auth.login_failed"]
    assert len(failed) == 5 and all(e["actor"] == "test-operator" and e["detail"]["address"] == "127.0.0.1"
                                    for e in failed)
    assert sum(e["action"] == "auth.login_throttled" for e in entries) == 2
    assert any(e["action"] == "auth.login" and e["actor"] == "test-operator" for e in entries), \
        "successful sign-ins are audited as well"


def test_failed_sign_in_is_logged(own_server, caplog):
    with caplog.at_level("WARNING"):
        assert _login(own_server, "nobody-here", "whatever-pw").status_code == 401
    assert any(r.getMessage() == "sign-in failed" and getattr(r, "user", None) == "nobody-here" for r in caplog.records)


def test_unknown_user_answers_as_slowly_as_a_wrong_password(tmp_path):
    with live_server(tmp_path, load_example_library=False, login_free_failures=1000) as srv:
        _login(srv, "warm-up", "x" * 8)
        times: dict[str, list[float]] = {"no-such-user": [], "test-operator": []}
        for _ in range(9):  # the two names taken in turn, so a change of load (other tests) hits both alike
            for name, samples in times.items():
                t0 = time.perf_counter()
                r = _login(srv, name, "not-the-password")
                samples.append(time.perf_counter() - t0)
                assert r.status_code == 401 and r.json()["detail"] == "wrong name or password"
        unknown, wrong = (statistics.median(times[n]) for n in ("no-such-user", "test-operator"))
    assert 0.5 < unknown / wrong < 2.0, f"unknown {unknown * 1000:.0f} ms vs wrong password {wrong * 1000:.0f} ms"


def test_cookie_writes_need_this_service_as_origin(own_server):
    with httpx.Client(base_url=own_server.url, timeout=30) as c:
        assert c.post("/api/v1/auth/login", json={"name": "test-admin", "password": "test-admin-pw"}).status_code == 200
        evil = {"Origin": "http://evil.example"}
        r = c.post("/api/v1/users", json={"name": "mallory", "role": "admin"}, headers=evil)
        assert r.status_code == 403 and "cross-origin" in r.json()["detail"]
        r = c.post("/api/v1/users", json={"name": "mallory", "role": "admin"},
                   headers={"Referer": "http://evil.example/page"})
        assert r.status_code == 403
        r = c.post("/api/v1/users", json={"name": "mallory", "role": "admin"})  # no Origin, no Referer
        assert r.status_code == 403
        r = c.post("/api/v1/auth/logout", headers=evil)
        assert r.status_code == 403, "a foreign page cannot sign the operator out either"
        r = c.post("/api/v1/users", json={"name": "berta", "role": "operator"}, headers={"Origin": own_server.url})
        assert r.status_code == 201, r.text
        assert c.get("/api/v1/auth/me").status_code == 200, "reading needs no Origin"
    with own_server.client("admin") as c:  # a bearer token is not sent by browsers on their own: no Origin needed
        assert c.post("/api/v1/users", json={"name": "carla", "role": "operator"}).status_code == 201


def test_post_users_never_echoes_the_password(own_server):
    with own_server.client("admin") as c:
        r = c.post("/api/v1/users", json={"name": "dora", "role": "operator", "password": "dora-secret-1"})
        assert r.status_code == 201
        assert "dora-secret-1" not in r.text and r.json()["initial_password"] is None
        r = c.post("/api/v1/users", json={"name": "emil", "role": "operator"})
        assert len(r.json()["initial_password"]) >= 12, "a made-up password is shown once"
        entries = c.get("/api/v1/audit").json()
    assert {"user.create"} <= {e["action"] for e in entries}
    assert all("dora-secret-1" not in str(e) for e in entries)


def test_session_cookie_secure_option(tmp_path):
    with live_server(tmp_path, load_example_library=False, cookie_secure=True) as srv:
        r = _login(srv, "test-operator", "test-operator-pw")
    cookie = r.headers["set-cookie"]
    assert "Secure" in cookie and "HttpOnly" in cookie and "SameSite=strict" in cookie


def test_security_headers_on_pages_api_and_viewer(server):
    with server.client(None) as c:
        page = c.get("/setup")
        api = c.get("/api/v1/health")
        refused = c.get("/api/v1/setups")
        viewer = c.get("/viewer/setup/1/")
    for r in (page, api, refused, viewer):
        assert r.headers["x-content-type-options"] == "nosniff"
        assert r.headers["x-frame-options"] == "SAMEORIGIN"
        assert "frame-ancestors 'self'" in r.headers["content-security-policy"]
    csp = page.headers["content-security-policy"]
    nonce = re.search(r"'nonce-([^']+)'", csp).group(1)
    scripts = re.findall(r"<script[^>]*>", page.text)
    assert scripts and all(f'nonce="{nonce}"' in s for s in scripts)
    assert "unsafe-inline" not in csp.split("script-src", 1)[1].split(";", 1)[0], "no inline script without nonce"
    assert api.headers["content-security-policy"].startswith("default-src 'none'")
    assert "connect-src 'self' ws://127.0.0.1:" in viewer.headers["content-security-policy"]


def test_health_is_503_naming_the_failing_part(own_server):
    from app.store.db import make_engine

    with own_server.client(None) as c:
        r = c.get("/api/v1/health")
        assert r.status_code == 200 and r.json()["failing"] == []
        engine = own_server.app.state.engine
        own_server.app.state.engine = make_engine("postgresql+psycopg://nobody@127.0.0.1:1/none")  # refuses
        try:
            r = c.get("/api/v1/health")
        finally:
            own_server.app.state.engine = engine
        assert r.status_code == 503 and r.json()["failing"] == ["database"]
        assert r.json()["database"].startswith("error: ") and r.json()["status"] == "degraded"
        own_server.app.state.jobs.shutdown()
        r = c.get("/api/v1/health")
        assert r.status_code == 503 and r.json()["failing"] == ["worker"] and r.json()["worker"] == "stopped"


def test_data_folder_and_database_are_private(own_server):
    data = own_server.settings.data_dir
    assert stat.S_IMODE(os.stat(data).st_mode) == 0o700
    assert stat.S_IMODE(os.stat(data / "files").st_mode) == 0o700
    assert stat.S_IMODE(os.stat(data / "setupcam.db").st_mode) == 0o600


def test_cli_lists_disables_resets_users_and_lists_revokes_keys(tmp_path):
    env = {"SETUPCAM_DATA_DIR": str(tmp_path), "PATH": "/usr/bin:/bin", "SETUPCAM_LOAD_EXAMPLES": "false"}

    def run(*a):
        return subprocess.run([sys.executable, "-m", "app.cli", *a], env=env, capture_output=True, text=True)

    assert run("user", "add", "carl", "--role", "operator", "--password", "carl-pw-123").returncode == 0
    r = run("user", "list")
    assert r.returncode == 0 and re.search(r"carl\s+operator\s+enabled", r.stdout), r.stdout
    r = run("user", "passwd", "carl")
    assert r.returncode == 0 and "password (shown once):" in r.stdout
    new_pw = r.stdout.rsplit(": ", 1)[1].strip()
    r = run("user", "disable", "carl")
    assert r.returncode == 0 and "disabled" in r.stdout
    assert re.search(r"carl\s+operator\s+disabled", run("user", "list").stdout)
    assert run("user", "disable", "nobody").returncode == 2
    r = run("key", "create", "--scope", "mes", "--name", "line 1")
    assert r.returncode == 0 and "key (shown once): sck_" in r.stdout
    key = r.stdout.rsplit(": ", 1)[1].strip()
    r = run("key", "list")
    assert re.search(r"1\s+" + re.escape(key[:12]) + r"\s+mes\s+line 1\s+active", r.stdout), r.stdout
    assert run("key", "revoke", "1").returncode == 0
    assert "revoked" in run("key", "list").stdout
    assert run("key", "revoke", "99").returncode == 2

    from app.config import Settings
    from app.services.access import login, resolve_token
    from app.store.db import make_engine, session_scope
    from app.store.models import AuditEntry

    engine = make_engine(Settings(SETUPCAM_DATA_DIR=str(tmp_path)).database_url)
    with session_scope(engine) as session:
        assert login(session, "carl", new_pw) is None, "disabled"
        assert resolve_token(session, key) is None, "revoked"
        actions = [e.action for e in session.query(AuditEntry).order_by(AuditEntry.id)]
    assert actions == ["user.create", "user.passwd", "user.disable", "apikey.create", "apikey.revoke"]
    engine.dispose()


def test_serve_says_why_when_the_database_refuses(tmp_path):
    env = {**os.environ, "SETUPCAM_DATA_DIR": str(tmp_path),
           "DATABASE_URL": "postgresql+psycopg://setupcam:s3cret@127.0.0.1:1/setupcam"}
    r = subprocess.run([sys.executable, "-m", "app.cli", "serve", "--port", "1"], env=env, capture_output=True,
                       text=True, timeout=60)
    assert r.returncode == 1
    assert r.stderr.startswith("setupcam serve: cannot reach the database at postgresql+psycopg://setupcam:***@")
    assert "Traceback" not in r.stderr and "s3cret" not in r.stderr
