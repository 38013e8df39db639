"""Access over real HTTP: sign-in, API keys, and every refusal (401/403) with its reason."""

from __future__ import annotations

import subprocess
import sys

import pytest
import trimesh


def test_login_me_logout(server):
    with server.client(None) as c:
        r = c.post("/api/v1/auth/login", json={"name": "test-operator", "password": "wrong-password"})
        assert r.status_code == 401 and r.json()["detail"] == "wrong name or password"
        r = c.post("/api/v1/auth/login", json={"name": "test-operator", "password": "test-operator-pw"})
        assert r.status_code == 200 and r.json()["role"] == "operator"
        assert c.get("/api/v1/auth/me").json() == {"name": "test-operator", "kind": "user", "role": "operator"}
        assert c.post("/api/v1/auth/logout").status_code == 204
        assert c.get("/api/v1/auth/me").status_code == 401


def test_anonymous_is_401_except_health(server):
    with server.client(None) as c:
        assert c.get("/api/v1/health").status_code == 200
        for path in ("/api/v1/models", "/api/v1/cameras", "/api/v1/machines", "/api/v1/setups"):
            r = c.get(path)
            assert r.status_code == 401 and "sign in" in r.json()["detail"], path
        r = c.get("/api/v1/models", headers={"Authorization": "Bearer sck_not-a-key"})
        assert r.status_code == 401 and "unknown, revoked or expired" in r.json()["detail"]


@pytest.mark.parametrize("who", ["operator", "mes"])
def test_only_admins_change_library_cameras_machines(server, who):
    stl = trimesh.creation.box().export(file_type="stl")
    with server.client(who) as c:
        assert c.get("/api/v1/models").status_code == 200, "everyone signed in may read"
        r = c.post("/api/v1/models", files={"file": ("b.stl", stl)}, data={"kind": "workpiece", "name": "x"})
        assert r.status_code == 403 and "an admin must do this" in r.json()["detail"]
        assert c.post("/api/v1/cameras", json={"name": "c"}).status_code == 403
        assert c.post("/api/v1/machines", json={}).status_code == 403
        assert c.delete("/api/v1/models/1").status_code == 403
        assert c.post("/api/v1/users", json={"name": "z", "role": "admin"}).status_code == 403
        assert c.post("/api/v1/apikeys", json={"scope": "admin"}).status_code == 403


def test_mes_key_may_not_confirm_or_adjust(server):
    with server.client("mes") as c:
        for path, body in (("/api/v1/setups/1/confirm", {"result_revision": 1}),
                           ("/api/v1/setups/1/adjust", {"object_index": 0, "nudge": {"dx_mm": 1}})):
            r = c.post(path, json=body)
            assert r.status_code == 403 and "need a signed-in operator" in r.json()["detail"], path


def test_admin_makes_accounts_and_keys_over_rest(server):
    with server.client("admin") as c:
        r = c.post("/api/v1/users", json={"name": "berta", "role": "operator"})
        assert r.status_code == 201 and len(r.json()["initial_password"]) >= 12
        pw = r.json()["initial_password"]
        assert c.post("/api/v1/users", json={"name": "berta", "role": "operator"}).status_code == 409
        assert c.post("/api/v1/users", json={"name": "x", "role": "king"}).status_code == 422
        key = c.post("/api/v1/apikeys", json={"name": "mes 2", "scope": "mes"}).json()
    with server.client(None) as c:
        assert c.post("/api/v1/auth/login", json={"name": "berta", "password": pw}).status_code == 200
        assert c.get("/api/v1/setups", headers={"Authorization": f"Bearer {key['key']}"}).status_code == 200
    with server.client("admin") as c:
        assert c.delete(f"/api/v1/apikeys/{key['id']}").status_code == 204
    with server.client(None) as c:
        assert c.get("/api/v1/setups", headers={"Authorization": f"Bearer {key['key']}"}).status_code == 401


def test_cli_makes_users_and_keys(tmp_path):
    env = {"SETUPCAM_DATA_DIR": str(tmp_path), "PATH": "/usr/bin:/bin"}
    run = lambda *a: subprocess.run([sys.executable, "-m", "app.cli", *a], env=env, capture_output=True, text=True)  # noqa: E731
    r = run("user", "add", "carl", "--role", "operator")
    assert r.returncode == 0 and "password (shown once):" in r.stdout, r.stderr
    r = run("user", "add", "carl", "--role", "operator")
    assert r.returncode == 2 and "exists already" in r.stderr
    r = run("apikey", "create", "--scope", "mes", "--name", "line 1")
    assert r.returncode == 0 and "key (shown once): sck_" in r.stdout


def test_admin_lists_disables_and_resets_users_and_lists_keys(server):
    with server.client("admin") as c:
        uid = c.post("/api/v1/users", json={"name": "carla", "role": "operator", "password": "carla-pw-1"}).json()["id"]
        users = {u["name"]: u for u in c.get("/api/v1/users").json()}
        assert users["carla"] == {**users["carla"], "role": "operator", "disabled": False}
        assert "password_hash" not in users["carla"]
        with server.client(None) as anon:
            assert anon.post("/api/v1/auth/login", json={"name": "carla", "password": "carla-pw-1"}).status_code == 200
            assert anon.get("/api/v1/auth/me").status_code == 200

            r = c.patch(f"/api/v1/users/{uid}", json={"disabled": True})
            assert r.status_code == 200 and r.json()["disabled"] is True
            assert anon.get("/api/v1/auth/me").status_code == 401, "disabling ends the open session"
            assert anon.post("/api/v1/auth/login", json={"name": "carla", "password": "carla-pw-1"}).status_code == 401
            assert c.patch(f"/api/v1/users/{uid}", json={"disabled": False}).json()["disabled"] is False

            r = c.post(f"/api/v1/users/{uid}/password", json={})
            assert r.status_code == 200 and r.json()["name"] == "carla"
            new = r.json()["password"]
            assert anon.post("/api/v1/auth/login", json={"name": "carla", "password": "carla-pw-1"}).status_code == 401
            assert anon.post("/api/v1/auth/login", json={"name": "carla", "password": new}).status_code == 200

        me = users["test-admin"]["id"]
        r = c.patch(f"/api/v1/users/{me}", json={"disabled": True})
        assert r.status_code == 409 and "your own account" in r.json()["detail"]
        assert c.post("/api/v1/users/99999/password", json={}).status_code == 404

        key = c.post("/api/v1/apikeys", json={"name": "line 2", "scope": "mes"}).json()
        listed = {k["id"]: k for k in c.get("/api/v1/apikeys").json()}[key["id"]]
        assert listed["prefix"] == key["key"][:12] and listed["revoked"] is False
        assert key["key"] not in str(c.get("/api/v1/apikeys").json()), "the secret is never listed"
    with server.client("operator") as c:
        assert c.get("/api/v1/users").status_code == 403 and c.get("/api/v1/apikeys").status_code == 403
