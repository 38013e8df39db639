"""/api/v1/planning/paths and the probing program of a setup, over real HTTP."""

from __future__ import annotations

import numpy as np
import pytest

from app.synth.scene import place_on_table
from tests.support.factories import located_setup, make_machine
from tests.support.scenes import library_entry, library_mesh


def test_reference_worked_example_over_rest(client):
    pts = [[0, 0, 0], [20, 10, -6], [40, 20, -23], [60, 30, -33], [80, 40, -23], [100, 50, -6], [120, 60, 0]]
    r = client.post("/api/v1/planning/paths", json={"points": pts, "probe": {"working_distance_mm": 30, "clearance_mm": 5},
                                                    "obstacles": {"part_top_mm": 6}})
    assert r.status_code == 200, r.text
    moves = r.json()["moves"]
    assert [m["pattern"] for m in moves] == ["straight", "over_then_down", "up_over_down", "up_over_down",
                                             "up_then_over", "straight"]
    assert moves[2]["waypoints_mm"] == [[40, 20, -23], [40, 20, -19], [60, 30, -19], [60, 30, -33]]


@pytest.mark.parametrize("body, detail", [
    ({"points": [[0, 0, 0], [1, 1, 1]], "probe": {"clearance_mm": 5}, "obstacles": {"part_top_mm": 6}},
     "working_distance_mm is required"),
    ({"points": [[0, 0, 0], [1, 1, 1]], "probe": {"working_distance_mm": 1, "clearance_mm": 5},
      "obstacles": {"meshes": [{"path": "/etc/passwd", "T_table_obj": np.eye(4).tolist()}]}}, "for the CLI"),
    ({"points": [[0, 0, 0], [1, 1, 1]], "probe": {"working_distance_mm": 1, "clearance_mm": 5},
      "obstacles": {"part_top_mm": 6}, "method": "teleport"}, "unknown"),
])
def test_bad_plan_requests(client, body, detail):
    r = client.post("/api/v1/planning/paths", json=body)
    assert r.status_code == 422 and detail in r.json()["detail"], r.text


@pytest.fixture(scope="module")
def bracket_setup(server):
    with server.client() as c:
        m = make_machine(c, None)
        wp = next(x for x in c.get("/api/v1/models", params={"kind": "workpiece"}).json()["data"]
                  if x["key"] == "bracket_140")
    mesh = library_mesh("bracket_140")
    T = place_on_table(mesh, 300.0, 150.0, 10.0)
    sid = located_setup(server, m["id"], T, T_obj_datum=np.asarray(library_entry("bracket_140").T_obj_datum),
                        model=(wp["id"], wp["current_revision"]))
    return sid, T, mesh


def test_path_around_a_located_setup_is_collision_free(client, bracket_setup):
    sid, T, mesh = bracket_setup
    top = float(mesh.bounds[1][2])
    pts = [[150, 150, 5], [450, 150, 5]]  # across the part, below its top
    for method in ("reference", "profile"):
        r = client.post("/api/v1/planning/paths", json={"points": pts, "method": method,
                                                        "probe": {"working_distance_mm": 0, "clearance_mm": 5, "radius_mm": 5},
                                                        "obstacles": {"setup_id": sid}})
        assert r.status_code == 200, r.text
        body = r.json()
        assert body["collision"]["ok"] and not body["collision"]["hits"], body["collision"]
        assert max(w[2] for m in body["moves"] for w in m["waypoints_mm"]) >= top + 5 - 1e-6


@pytest.mark.linuxcnc
def test_probing_program_needs_confirmation_then_runs_on_linuxcnc(server, bracket_setup):
    sid, T, _ = bracket_setup
    with server.client("operator") as c:
        r = c.get(f"/api/v1/setups/{sid}/probing-program")
        assert r.status_code == 409 and "not confirmed" in r.json()["detail"]
        c.post(f"/api/v1/setups/{sid}/confirm", json={"result_revision": 1})
        real = c.get(f"/api/v1/setups/{sid}/probing-program").text
        dry = c.get(f"/api/v1/setups/{sid}/probing-program", params={"dry_run": True}).text
    assert "G38.2" in real and "G38.2" not in dry and "G21" in dry
    from tests.machine.linuxcnc_sim import shared_sim, skip_reason

    if skip_reason():
        pytest.skip(skip_reason())
    sim = shared_sim()
    with server.client("operator") as c:
        setup = c.get(f"/api/v1/setups/{sid}").json()
        off = setup["result"]["offset"]
        T_machine_table = np.asarray(c.get(f"/api/v1/machines/{setup['machine_id']}").json()["T_machine_table"])
    # what a verified export writes into G54: the program runs in the datum frame
    sim.mdi(f"G10 L2 P1 X{off['x_mm']:.6f} Y{off['y_mm']:.6f} Z{off['z_mm']:.6f} R{off['c_deg']:.6f}")
    sim.mdi("G54")
    sim.mdi("G53 G0 X-100 Y-100 Z0")
    sim.run_program(dry, name="probe_dry.ngc")
    st = sim.wait_idle(180.0)
    # It ends above its start (the part's origin) at the retract height: an error would have stopped it earlier.
    from app.machine import WorkOffset
    from app.planning.probing import gcode_positions

    end_prog = gcode_positions(dry)[-1][1]
    end_machine = WorkOffset(off["x_mm"], off["y_mm"], off["z_mm"], off["c_deg"]).to_pose() @ [*end_prog, 1.0]
    assert st["position"][:3] == pytest.approx(end_machine[:3], abs=1e-3), st
    assert (T_machine_table @ [T[0, 3], T[1, 3], 0, 1])[:2] == pytest.approx(end_machine[:2], abs=1e-3)


def _program_frame(c, sid) -> np.ndarray:
    """T_prog_table: the program runs in the datum slot the export writes (X, Y, Z, C of the offset)."""
    from app.geometry.transforms import inv
    from app.machine import WorkOffset

    setup = c.get(f"/api/v1/setups/{sid}").json()
    off = setup["result"]["offset"]
    machine = c.get(f"/api/v1/machines/{setup['machine_id']}").json()
    T_machine_prog = WorkOffset(off["x_mm"], off["y_mm"], off["z_mm"], off["c_deg"]).to_pose()
    return inv(T_machine_prog) @ np.asarray(machine["T_machine_table"])


def _simulated_probe_log(touches, T_true_table_datum, T_nominal_table_datum, ball_r: float,
                         T_prog_table=None) -> str:
    """Tip positions (program frame) where the ball touches the TRUE faces, moving along each nominal
    approach direction."""
    from app.geometry.transforms import transform_points

    T_prog_table = np.eye(4) if T_prog_table is None else T_prog_table
    rows = []
    for t in touches:
        n_d = np.asarray(t.face_normal_datum)
        n_true = T_true_table_datum[:3, :3] @ n_d
        a = np.asarray(t.approach_tip) + [0, 0, ball_r]          # ball centre at the approach point
        d = -np.asarray(t.normal)                                # moving towards the nominal face
        # n_true . (c - t_true) = o + r along c = a + s d
        s = (t.face_offset_mm + ball_r - n_true @ (a - T_true_table_datum[:3, 3])) / (n_true @ d)
        tip = transform_points(T_prog_table, a + s * d - [0, 0, ball_r])[0]
        rows.append(" ".join(f"{v:.6f}" for v in tip) + " 0 0 0 0 0 0")
    return "\n".join(rows)


def test_probe_results_refine_the_pose(server, bracket_setup):
    from app.geometry.transforms import pose_from_xyz_euler
    from app.planning.probing import ProbingParams, choose_touch_points

    sid, T, mesh = bracket_setup
    datum = np.asarray(library_entry("bracket_140").T_obj_datum)
    with server.client("operator") as c:
        setup = c.get(f"/api/v1/setups/{sid}").json()
        c.post(f"/api/v1/setups/{sid}/confirm", json={"result_revision": setup["result_revision"]})
        T_nom = np.asarray(c.get(f"/api/v1/setups/{sid}").json()["result"]["objects"][0]["T_table_obj"])
        touches = choose_touch_points(mesh, T_nom, datum, ProbingParams())
        shift = pose_from_xyz_euler(0.30, -0.20, 0.05, 0, 0, 0.08)
        T_true_datum = shift @ T_nom @ datum
        log = _simulated_probe_log(touches, T_true_datum, T_nom @ datum, ProbingParams().ball_radius_mm,
                                   T_prog_table=_program_frame(c, sid))
        r = c.post(f"/api/v1/setups/{sid}/probe-results", content=log, headers={"Content-Type": "text/plain"})
        assert r.status_code == 200, r.text
        body = r.json()
        got = np.asarray(body["result"]["objects"][0]["T_table_obj"]) @ datum
        assert np.allclose(got[:3, 3], T_true_datum[:3, 3], atol=1e-3)
        assert body["result_revision"] == setup["result_revision"] + 1 and body["confirmed_revision"] != body["result_revision"]
        r = c.post(f"/api/v1/setups/{sid}/probe-results", content="1 2\n", headers={"Content-Type": "text/plain"})
        assert r.status_code == 409  # the new revision is not confirmed yet
        rev = c.get(f"/api/v1/setups/{sid}").json()["result_revision"]
        c.post(f"/api/v1/setups/{sid}/confirm", json={"result_revision": rev})
        r = c.post(f"/api/v1/setups/{sid}/probe-results", content="1 2\n", headers={"Content-Type": "text/plain"})
        assert r.status_code == 422 and "expected 3 or 9 numbers" in r.json()["detail"], r.text


def _bracket_setup(server, x_mm: float, y_mm: float, z_mm: float, sigma_mm: float) -> tuple[int, object, np.ndarray, np.ndarray]:
    """(setup id, mesh, T_obj_datum) of a located setup (factory) with the library's bracket_140 at x, y, z."""
    mesh = library_mesh("bracket_140")
    datum = np.asarray(library_entry("bracket_140").T_obj_datum)
    with server.client() as c:
        m = make_machine(c, None)
        wp = next(x for x in c.get("/api/v1/models", params={"kind": "workpiece"}).json()["data"]
                  if x["key"] == "bracket_140")
    T = place_on_table(mesh, x_mm, y_mm, z_mm)
    sid = located_setup(server, m["id"], T, T_obj_datum=datum, model=(wp["id"], wp["current_revision"]),
                        sigma_mm=sigma_mm)
    return sid, mesh, datum, T


def test_probe_results_beyond_the_expected_error_mark_the_result_fail(server):
    """Touches that find the part further from the confirmed pose than its stated error allow: a new
    revision with the probed pose, the per-touch deviation, and FAIL (no export, no program) until
    an operator accepts it by adjusting."""
    from app.geometry.transforms import pose_from_xyz_euler
    from app.planning.probing import ProbingParams, choose_touch_points

    sid, mesh, datum, T = _bracket_setup(server, 320.0, 160.0, 5.0, sigma_mm=0.05)
    with server.client("operator") as c:
        c.post(f"/api/v1/setups/{sid}/confirm", json={"result_revision": 1})
        touches = choose_touch_points(mesh, T, datum, ProbingParams())
        for shift_mm, fail in ((0.1, False), (0.6, True)):  # 3 sigma + 0.05 = 0.2 mm expected
            T_true_datum = pose_from_xyz_euler(shift_mm, 0, 0) @ np.asarray(
                c.get(f"/api/v1/setups/{sid}").json()["result"]["objects"][0]["T_table_obj"]) @ datum
            log = _simulated_probe_log(touches, T_true_datum, None, ProbingParams().ball_radius_mm,
                                       T_prog_table=_program_frame(c, sid))
            r = c.post(f"/api/v1/setups/{sid}/probe-results", content=log, headers={"Content-Type": "text/plain"})
            assert r.status_code == 200, r.text
            o = r.json()["result"]["objects"][0]
            assert o["probe_before"]["T_table_obj"] and len(o["probe_deviation_mm"]) == 4
            assert max(abs(v) for v in o["probe_deviation_mm"]) == pytest.approx(shift_mm, abs=0.01)
            assert o["uncertainty_pass"] is (not fail) and (("probe_fail" in o) is fail), o.get("uncertainty_reason")
            rev = r.json()["result_revision"]
            assert c.post(f"/api/v1/setups/{sid}/confirm", json={"result_revision": rev}).status_code == 200
            touches = choose_touch_points(mesh, np.asarray(o["T_table_obj"]), datum, ProbingParams())
        assert "probing" in o["uncertainty_reason"]
        r = c.get(f"/api/v1/setups/{sid}/probing-program")
        assert r.status_code == 422 and r.json()["code"] == "uncertainty_fail", r.text
        r = c.post(f"/api/v1/setups/{sid}/adjust", json={"object_index": 0, "nudge": {"dx_mm": 0.0}})
        assert r.status_code == 200, r.text
        o = r.json()["result"]["objects"][0]
        assert o["uncertainty_pass"] and "probe_fail" not in o


def test_probe_results_redraw_the_overlay_at_the_probed_pose(server):
    """Every revision of a result is drawn anew: after probe results the overlay shows the probed pose, not
    the pose before (it used to keep the previous revision's picture), and T_cam_obj follows T_table_obj."""
    from app.geometry.transforms import pose_from_xyz_euler
    from app.planning.probing import ProbingParams, choose_touch_points

    # under the factory's camera (320 x 200 px, 900 mm above), so the part is in the picture
    sid, mesh, datum, _ = _bracket_setup(server, 400.0, -200.0, 0.0, sigma_mm=0.5)
    with server.client("operator") as c:
        r = c.post(f"/api/v1/setups/{sid}/adjust", json={"object_index": 0, "nudge": {"dx_mm": 0.0}})
        assert r.status_code == 200, r.text
        drawn = r.json()
        assert drawn["overlay_url"], "an adjusted revision is drawn"
        before_png = c.get(drawn["overlay_url"]).content
        c.post(f"/api/v1/setups/{sid}/confirm", json={"result_revision": drawn["result_revision"]})
        T_nom = np.asarray(drawn["result"]["objects"][0]["T_table_obj"])
        touches = choose_touch_points(mesh, T_nom, datum, ProbingParams())
        T_true_datum = pose_from_xyz_euler(1.0, -0.8, 0.0, 0, 0, 0.3) @ T_nom @ datum
        log = _simulated_probe_log(touches, T_true_datum, None, ProbingParams().ball_radius_mm,
                                   T_prog_table=_program_frame(c, sid))
        r = c.post(f"/api/v1/setups/{sid}/probe-results", content=log, headers={"Content-Type": "text/plain"})
        assert r.status_code == 200, r.text
        probed = r.json()
        o = probed["result"]["objects"][0]
        assert not np.allclose(o["T_table_obj"], T_nom, atol=0.1), "the probed pose differs from the nominal"
        T_cam_table = np.asarray(probed["result"]["table"]["T_cam_table"])
        assert np.allclose(o["T_cam_obj"], T_cam_table @ np.asarray(o["T_table_obj"]), atol=1e-9)
        assert probed["result"]["overlay_sha256"] != drawn["result"]["overlay_sha256"]
        after_png = c.get(probed["overlay_url"]).content
        assert after_png != before_png, "the overlay still shows the pose before probing"
    with server.client("admin") as c:
        actions = [e["action"] for e in c.get("/api/v1/audit", params={"setup_id": sid}).json()]
        assert "setup.probe_results" in actions and "setup.adjust" in actions
