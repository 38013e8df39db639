"""Every failure answers a machine-readable reason ``code`` beside its sentence (issue 15, item 6): the
pages choose their advice by the code. Each refusal layer is driven once over real HTTP: the request
guard (sign-in, role, origin, size, JSON depth), FastAPI (unknown path, wrong method, validation), the
routes' own refusals (sign-in) and the services' failures (not found, conflict, invalid)."""

from __future__ import annotations

import re

import pytest

from tests.support.factories import located_setup, make_machine
from app.geometry.transforms import pose_from_xyz_euler

CODE = re.compile(r"^[a-z][a-z0-9_]*$")


@pytest.fixture(scope="module")
def machine(server):
    with server.client("admin") as c:
        return make_machine(c, None)


def _coded(r, status: int, code: str | None = None) -> str:
    assert r.status_code == status, r.text
    body = r.json()
    assert isinstance(body.get("detail"), str) and body["detail"], body
    assert CODE.match(body.get("code") or ""), f"no reason code in {body}"
    if code is not None:
        assert body["code"] == code, body
    return body["code"]


def test_refusals_of_the_request_guard_carry_a_code(server):
    with server.client(None) as c:
        _coded(c.get("/api/v1/setups"), 401, "sign_in_required")
    with server.client(None, headers={"Authorization": "Bearer nonsense"}) as c:
        _coded(c.get("/api/v1/setups"), 401, "session_expired")
    with server.client("operator") as c:
        _coded(c.post("/api/v1/cameras", json={"name": "x"}), 403, "admin_required")
        _coded(c.post("/api/v1/setups/1/export", content=b"{" * 5000,
                      headers={"Content-Type": "application/json"}), 422, "json_too_deep")
        _coded(c.post("/api/v1/setups/1/export", content=b"x" * 10_000_000,
                      headers={"Content-Type": "application/json"}), 413)
    with server.client("mes") as c:
        _coded(c.post("/api/v1/setups/1/confirm", json={"result_revision": 1}), 403, "operator_required")


def test_refusals_of_the_framework_and_the_routes_carry_a_code(server):
    with server.client("operator") as c:
        _coded(c.get("/api/v1/no-such-thing"), 404, "not_found")
        _coded(c.delete("/api/v1/auth/me"), 405, "method_not_allowed")
        _coded(c.post("/api/v1/setups/1/export", json={"slot": 54}), 422, "invalid_parameter")
        _coded(c.get("/api/v1/setups/99999999999999999999"), 404)
    with server.client(None) as c:
        _coded(c.post("/api/v1/auth/login", json={"name": "test-operator", "password": "wrong"}), 401,
               "wrong_password")


def test_failures_of_the_services_carry_a_code(server, machine):
    with server.client("operator") as c:
        _coded(c.get("/api/v1/setups/987654"), 404, "not_found")
        sid = located_setup(server, machine["id"], pose_from_xyz_euler(100, 50, 0))
        _coded(c.post(f"/api/v1/setups/{sid}/export", json={"slot": "G54"}), 409, "not_confirmed")
        _coded(c.post(f"/api/v1/setups/{sid}/confirm", json={"result_revision": 7}), 409)
        assert c.post(f"/api/v1/setups/{sid}/confirm", json={"result_revision": 1}).status_code == 200
        _coded(c.post(f"/api/v1/setups/{sid}/export", json={"slot": "G99"}), 422, "bad_slot")
        _coded(c.post(f"/api/v1/setups/{sid}/export", json={"slot": "G54"}), 422, "no_controller")


def test_the_openapi_says_every_problem_has_a_code(server):
    with server.client(None) as c:
        problem = c.get("/openapi.json").json()["components"]["schemas"]["HTTPValidationError"]
    assert problem["required"] == ["detail", "code"]
