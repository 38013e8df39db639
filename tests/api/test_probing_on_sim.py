"""Proven on the controller (issue 18, item 5): a located, confirmed and exported setup with a clamp;
its real probing program (G38.2) runs on the LinuxCNC sim with a simulated probe that trips where the
ball meets the TRUE part (tests/machine/simprobe.py, a HAL component on motion.probe-input). Every
touch lands within 0.1 mm of where the true part is met, the program passes the independent check
against the true scene, and the probe log sent back refines the pose to the truth (item 6)."""

from __future__ import annotations

import json

import numpy as np
import pytest
import trimesh

from app.geometry.transforms import inv, pose_from_xyz_euler, transform_points
from app.machine import WorkOffset
from app.planning.probing import parse_probe_results
from app.planning.program_check import Box, TrueObstacle, check_program
from app.store.db import session_scope
from app.store.models import Setup
from tests.support.factories import located_setup, make_machine
from tests.support.scenes import library_mesh

pytestmark = [pytest.mark.integration, pytest.mark.linuxcnc]

SIZE = (120.0, 70.0, 35.0)
DATUM = pose_from_xyz_euler(-SIZE[0] / 2, -SIZE[1] / 2, SIZE[2] / 2)  # front-left top corner


def _box_model(c) -> dict:
    stl = trimesh.creation.box(extents=SIZE).export(file_type="stl")
    r = c.post("/api/v1/models", files={"file": ("probe_block.stl", stl)},
               data={"kind": "workpiece", "name": "probe block", "T_obj_datum": json.dumps(DATUM.tolist())})
    assert r.status_code == 201, r.text
    return r.json()


def _true_tip(t, T_true_table_datum, ball_r) -> np.ndarray:
    """Where the tip is when the ball, moving from the approach point along -normal, meets the TRUE face."""
    n_true = T_true_table_datum[:3, :3] @ np.asarray(t.face_normal_datum)
    a = np.asarray(t.approach_tip) + [0, 0, ball_r]
    d = -np.asarray(t.normal)
    s = (t.face_offset_mm + ball_r - n_true @ (a - T_true_table_datum[:3, 3])) / (n_true @ d)
    return a + s * d - [0, 0, ball_r]


def _obb(mesh, T, name, role) -> TrueObstacle:
    """A z-turned box around a posed mesh (conservative for the check)."""
    lo, hi = mesh.bounds
    c = transform_points(T, [(lo + hi) / 2])[0]
    yaw = float(np.degrees(np.arctan2(T[1, 0], T[0, 0])))
    return TrueObstacle(name, role, (Box((c[0], c[1]), tuple((hi - lo)[:2] / 2), float(T[2, 3] + lo[2]),
                                         float(T[2, 3] + hi[2]), yaw),))


def test_real_program_on_the_sim_with_a_simulated_probe(server, lcnc):
    from app.planning.probing import ProbingParams, choose_touch_points

    with server.client() as c:
        m = make_machine(c, lcnc.settings)
        model = _box_model(c)
        clamp = next(x for x in c.get("/api/v1/models", params={"kind": "clamp"}).json()["data"]
                     if x["key"] == "strap_clamp_125")
    T_true = pose_from_xyz_euler(300.0, 150.0, SIZE[2] / 2, 0, 0, 12.0)
    # located with a small error: shifted and turned 0.1 deg about its own origin
    T_loc = pose_from_xyz_euler(0.25, -0.15, 0.05) @ T_true @ pose_from_xyz_euler(0, 0, 0, 0, 0, 0.1)
    # stated 1-sigma 0.15 mm: 3 sigma covers the 0.42 mm error at the far corner
    sid = located_setup(server, m["id"], T_loc, T_obj_datum=DATUM, model=(model["id"], model["current_revision"]),
                        sigma_mm=0.15)
    T_clamp = pose_from_xyz_euler(300.0, 260.0, 0.0)
    with session_scope(server.app.state.engine) as session:  # the clamp was located too
        s = session.get(Setup, sid)
        objs = [*s.result["objects"], {"name": "strap clamp", "kind": "clamp", "model_id": clamp["id"],
                                       "revision": clamp["current_revision"], "T_table_obj": T_clamp.tolist(),
                                       "sigma": {"x_mm": 0.05, "y_mm": 0.05, "z_mm": 0.05}, "uncertainty_pass": True}]
        s.result = {**s.result, "objects": objs}
        session.add(s)
    with server.client("operator") as c:
        assert c.post(f"/api/v1/setups/{sid}/confirm", json={"result_revision": 1}).status_code == 200
        e = c.post(f"/api/v1/setups/{sid}/export", json={"slot": "G54", "acknowledge_change": True})
        assert e.status_code == 200 and e.json()["status"] == "written", e.text
        r = c.get(f"/api/v1/setups/{sid}/probing-program", params={"dialect": "linuxcnc", "wcs": "G54"})
        assert r.status_code == 200, r.text
        program = r.text
        off = c.get(f"/api/v1/setups/{sid}").json()["result"]["offset"]
    lines = program.splitlines()
    assert lines[1].startswith("(frame: G54 = datum of block") and "read back now" in lines[1]
    assert "(obstacle located: strap clamp" in program

    T_machine_table = np.asarray(m["T_machine_table"])
    T_machine_prog = WorkOffset(off["x_mm"], off["y_mm"], off["z_mm"], off["c_deg"]).to_pose()  # what G54 holds
    T_prog_table = inv(T_machine_prog) @ T_machine_table
    # the independent check against the true scene first: the sim only shows that the controller agrees
    block = trimesh.creation.box(extents=SIZE)
    truth = [TrueObstacle("table", "support", (Box((0.0, 0.0), (1000.0, 1000.0), -60.0, 0.0),)),
             _obb(block, T_true, "block", "workpiece"), _obb(library_mesh("strap_clamp_125"), T_clamp, "clamp", "fixture")]
    params = ProbingParams()
    touches = choose_touch_points(block, T_loc, DATUM, params)  # nominal (default placement: nothing in the way)
    rep = check_program(program, truth, T_table_prog=inv(T_prog_table), clearance_mm=5.0)
    assert not rep.violations and len(rep.touches) == 4 and all(t.hit for t in rep.touches), rep.violations[:3]

    # the true part for the simulated probe, in machine coordinates
    T_mt = T_machine_table @ T_true
    lcnc.set_probe_part([{"centre_xy": [T_mt[0, 3], T_mt[1, 3]], "half_xy": [SIZE[0] / 2, SIZE[1] / 2],
                          "yaw_deg": 12.0, "z0": T_mt[2, 3] - SIZE[2] / 2, "z1": T_mt[2, 3] + SIZE[2] / 2}],
                        params.ball_radius_mm)
    log_file = lcnc.workdir / "setupcam_probe.txt"
    log_file.unlink(missing_ok=True)
    try:
        lcnc.mdi("G53 G0 Z0")
        lcnc.mdi("G53 G0 X-100 Y-100")
        lcnc.run_program(program, name="probe_real.ngc")
        lcnc.wait_idle(300.0)
    finally:
        lcnc.set_probe_part([])
    assert log_file.exists(), "PROBEOPEN wrote no log"
    tips = parse_probe_results(log_file.read_text())
    assert len(tips) == 4, log_file.read_text()  # a G38.2 without contact would have stopped the program
    # the program's touches are where the service put them: read them back from the G38.2 lines' order
    T_true_datum = T_true @ DATUM
    expected = [transform_points(T_prog_table, [_true_tip(t, T_true_datum, params.ball_radius_mm)])[0]
                for t in _service_touches(program, touches, T_prog_table)]
    err = np.linalg.norm(tips - np.asarray(expected), axis=1)
    print(f"sim probe: touch errors {np.round(err, 4).tolist()} mm")
    assert np.all(err <= 0.1), err  # every touch within 0.1 mm of where the true part is met

    with server.client("operator") as c:  # results back in: the pose moves to the truth
        r = c.post(f"/api/v1/setups/{sid}/probe-results", content=log_file.read_text(),
                   headers={"Content-Type": "text/plain"})
        assert r.status_code == 200, r.text
        got = np.asarray(r.json()["result"]["objects"][0]["T_table_obj"])
    print(f"refined position error {np.round(got[:3, 3] - T_true[:3, 3], 4).tolist()} mm")
    assert np.allclose(got[:3, 3], T_true[:3, 3], atol=0.02), (got[:3, 3], T_true[:3, 3])
    yaw = np.degrees(np.arctan2(got[1, 0], got[0, 0]))
    assert yaw == pytest.approx(12.0, abs=0.01)


def _service_touches(program: str, default, T_prog_table):
    """The default touches (the test places nothing in their way, so the service keeps them), checked
    against the program's G38.2 lines: each runs from the touch's approach point to its probe end."""
    from app.planning.probing import gcode_positions

    pos = gcode_positions(program)
    g38 = [p for w, p in pos if w == "G38.2"]
    assert len(g38) == len(default)
    for t, p in zip(default, g38):
        assert np.allclose(transform_points(T_prog_table, [t.probe_end_tip])[0], p, atol=0.6), (t.name, p)
    return default
