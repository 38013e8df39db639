"""Probing program: touch points on the datum faces, G-code, simulated probing, least-squares offset."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from app.geometry.transforms import inv, make_pose, transform_points
from app.geometry.work_offset import work_offset_from_poses
from app.planning.collision import BodyCylinder, ProbeBody, Scene
from app.planning.obstacles import height_grid_from_meshes
from app.planning.path import ProbeParams
from app.planning.probing import (
    ProbingParams,
    check_probing_program,
    choose_touch_points,
    gcode_positions,
    parse_probe_results,
    probing_gcode,
    refine_offset,
    refined_work_offset,
)

PARAMS = ProbingParams(ball_radius_mm=1.5, stylus_length_mm=30.0, approach_mm=5.0, overtravel_mm=3.0, depth_mm=5.0)
TRAVEL = ProbeParams(working_distance_mm=0.0, clearance_mm=5.0, radius_mm=15.0, length_mm=80.0)
BODY = ProbeBody((BodyCylinder(1.5, 0.0, 30.0), BodyCylinder(15.0, 30.0, 110.0)))


def _rz_pose(c_deg, t):
    c = np.radians(c_deg)
    return make_pose([[np.cos(c), -np.sin(c), 0], [np.sin(c), np.cos(c), 0], [0, 0, 1]], t)


def _part():
    m = trimesh.creation.box(extents=(100, 60, 30))
    m.apply_translation((50, 30, 15))  # obj frame: corner at the origin, z up
    return m


T_TABLE_OBJ = _rz_pose(3.0, (150, 100, 0))
T_OBJ_DATUM = make_pose(t=(0, 0, 30))  # datum at the front-left top corner


def test_touch_points_on_the_datum_faces():
    touches = choose_touch_points(_part(), T_TABLE_OBJ, T_OBJ_DATUM, PARAMS)
    assert [t.name for t in touches] == ["x", "y1", "y2", "z"]
    T_datum_table = inv(T_TABLE_OBJ @ T_OBJ_DATUM)
    c_d = transform_points(T_datum_table, [t.contact for t in touches])
    assert c_d[0, 0] == pytest.approx(0, abs=1e-9) and c_d[1, 1] == pytest.approx(0, abs=1e-9)
    assert c_d[2, 1] == pytest.approx(0, abs=1e-9) and c_d[3, 2] == pytest.approx(0, abs=1e-9)
    assert c_d[0, 2] == pytest.approx(-5.0) and c_d[1, 2] == pytest.approx(-5.0)  # depth below the top edge
    assert c_d[2, 0] - c_d[1, 0] == pytest.approx(0.7 * (100 - 2 * 3.5))  # 15 % .. 85 % of the usable edge
    assert touches[0].face_normal_datum == (-1.0, 0.0, 0.0) and touches[3].face_normal_datum == (0.0, 0.0, 1.0)
    # rotated 3 degrees on the table
    assert touches[1].normal[0] == pytest.approx(np.sin(np.radians(3.0)))
    for t in touches:  # the tip sits approach + ball radius outside the face, ball centre r above the tip
        centre = np.asarray(t.approach_tip) + [0, 0, 1.5]
        assert np.dot(centre - t.contact, t.normal) == pytest.approx(6.5)


def test_missing_face_is_a_reason():
    disc = trimesh.creation.cylinder(radius=30, height=10)
    with pytest.raises(ValueError, match="no planar face perpendicular to datum x"):
        choose_touch_points(disc, np.eye(4), np.eye(4), PARAMS)


def _program(dry_run):
    part = _part()
    clamp = trimesh.creation.box(extents=(20, 40, 45))
    T_clamp = make_pose(t=(300, 140, 22.5))
    grid = height_grid_from_meshes([part, clamp], [T_TABLE_OBJ, T_clamp], bounds_xy_mm=(0, 0, 400, 300), uncertainty_mm=0.5)
    touches = choose_touch_points(part, T_TABLE_OBJ, T_OBJ_DATUM, PARAMS)
    prog = probing_gcode(touches, grid, TRAVEL, (20, 20, 80), params=PARAMS, dry_run=dry_run)
    return prog, Scene([part, clamp], [T_TABLE_OBJ, T_clamp], ["part", "clamp"])


def test_gcode_is_plain_linuxcnc():
    prog, _ = _program(dry_run=False)
    lines = prog.gcode.splitlines()
    assert lines[0] == "%" and lines[-1] == "%"
    assert "G21 G90 G17 G94 G40 G54" in lines and "M2" in lines
    assert lines.count("(PROBEOPEN setupcam_probe.txt)") == 1 and "(PROBECLOSE)" in lines
    probes = [ln for ln in lines if ln.startswith("G38.2")]
    assert len(probes) == 4 and all(" F100" in ln for ln in probes)
    code = [ln.split("(")[0] for ln in lines]
    assert not any(w.startswith(("T", "M6", "G10", "G43")) for ln in code for w in ln.split())
    assert all(" F" in ln for ln in code if ln.startswith("G1 "))
    dry, _ = _program(dry_run=True)
    assert "G38" not in dry.gcode and "PROBEOPEN" not in dry.gcode
    visited = [p for g, p in gcode_positions(dry.gcode)]
    for t in prog.touches:
        assert any(np.allclose(v, t.contact_tip, atol=1e-4) for v in visited)


def test_every_dry_run_position_is_collision_free():
    prog, scene = _program(dry_run=True)
    pos = gcode_positions(prog.gcode)
    contact_tips = [np.asarray(t.contact_tip) for t in prog.touches]
    touching = ProbeBody((BodyCylinder(1.4, 0.1, 30.0), BodyCylinder(15.0, 30.0, 110.0)))
    n_checked = 0
    for (_, a), (_, b) in zip(pos[:-1], pos[1:]):
        if np.isnan(a).any() or np.isnan(b).any():
            continue
        at_contact = any(np.allclose(b, c, atol=1e-4) or np.allclose(a, c, atol=1e-4) for c in contact_tips)
        body = touching if at_contact else BODY
        assert scene.check_polyline([a, b], body).ok, (a, b)
        n_checked += 1
    assert n_checked > 12
    # the library function agrees, for the dry run and for the real program (G38 up to the contact)
    assert check_probing_program(prog, scene, BODY, touching).ok
    real, _ = _program(dry_run=False)
    report = check_probing_program(real, scene, BODY, touching)
    assert report.ok and report.n_segments >= n_checked
    # a clamp right where the probe travels is found
    clamp2 = trimesh.creation.box(extents=(10, 10, 100))
    blocked = Scene([_part(), clamp2], [T_TABLE_OBJ, make_pose(t=np.asarray(prog.touches[1].approach_tip) + [0, 0, 0])],
                    ["part", "post"])
    bad = check_probing_program(prog, blocked, BODY, touching)
    assert not bad.ok and bad.hits[0].obstacle == "post"
    # the full-size body at the contact does touch (the check is not vacuous)
    assert not scene.check_polyline([contact_tips[0]], BODY).ok


def _simulate_probing(gcode, touches, T_true_table_datum, r):
    """Tip positions where each G38.2 stops on the true (displaced) part: the ball centre reaches
    distance r from the true face plane."""
    out = []
    pos = gcode_positions(gcode)
    k = 0
    for (_, a), (g, b) in zip(pos[:-1], pos[1:]):
        if g != "G38.2":
            continue
        t = touches[k]
        n_d, o = np.asarray(t.face_normal_datum), t.face_offset_mm
        n_true = T_true_table_datum[:3, :3] @ n_d
        c0 = T_true_table_datum[:3, 3] + T_true_table_datum[:3, :3] @ (o * n_d)  # a point of the true plane
        ca, cb = a + [0, 0, r], b + [0, 0, r]  # ball centres
        da, db = (ca - c0) @ n_true - r, (cb - c0) @ n_true - r
        assert da > 0 > db
        s = da / (da - db)
        out.append(a + s * (b - a))
        k += 1
    return np.asarray(out)


@pytest.mark.parametrize("delta", [(0.7, -0.4, 0.2, 0.3), (-1.2, 0.9, -0.3, -0.8), (0.0, 0.0, 0.0, 0.0)])
def test_probe_results_refine_the_offset(delta):
    dx, dy, dz, dc = delta
    prog, _ = _program(dry_run=False)
    T_located = T_TABLE_OBJ @ T_OBJ_DATUM
    T_true = _rz_pose(dc, (dx, dy, dz)) @ make_pose(T_located[:3, :3]) @ np.eye(4)
    T_true[:3, 3] = T_located[:3, 3] + (dx, dy, dz)
    tips = _simulate_probing(prog.gcode, prog.touches, T_true, PARAMS.ball_radius_mm)
    log = "\n".join(" ".join(f"{v:.6f}" for v in list(p) + [0.0] * 6) for p in tips) + "\n"
    measured = parse_probe_results(log)
    assert measured.shape == (4, 3)
    ref = refine_offset(prog.touches, measured, T_located, ball_radius_mm=PARAMS.ball_radius_mm)
    assert ref.ok, ref.reason
    assert [ref.dx_mm, ref.dy_mm, ref.dz_mm, ref.dc_deg] == pytest.approx([dx, dy, dz, dc], abs=1e-4)
    assert np.allclose(ref.T_table_datum, T_true, atol=1e-5)
    assert max(abs(v) for v in ref.residuals_mm) < 1e-5
    T_machine_table = make_pose(t=(-400, -300, -250))
    located = work_offset_from_poses(T_machine_table, T_TABLE_OBJ, T_OBJ_DATUM, max_tilt_deg=0.1)
    off = refined_work_offset(ref, T_machine_table, T_OBJ_DATUM, max_tilt_deg=0.1)
    assert off.ok and off.c_deg == pytest.approx(located.c_deg + dc, abs=1e-4)
    assert [off.x_mm - located.x_mm, off.y_mm - located.y_mm, off.z_mm - located.z_mm] == pytest.approx([dx, dy, dz], abs=1e-4)


def test_results_parser_and_refusals():
    assert parse_probe_results("[[1, 2, 3], [4, 5, 6]]").tolist() == [[1, 2, 3], [4, 5, 6]]
    assert parse_probe_results("1.0 2.0 3.0\n\n4 5 6\n").shape == (2, 3)
    with pytest.raises(ValueError, match="expected 3 or 9 numbers"):
        parse_probe_results("1 2 3 4\n")
    prog, _ = _program(dry_run=False)
    with pytest.raises(ValueError, match="3 probe results for 4 touches"):
        refine_offset(prog.touches, np.zeros((3, 3)), np.eye(4), ball_radius_mm=1.5)
    few = refine_offset(prog.touches[:3], np.zeros((3, 3)), np.eye(4), ball_radius_mm=1.5)
    assert not few.ok and "cannot fix X, Y, Z and C" in few.reason
    # a burr: one touch 0.3 mm off the plane -> refused with the residual
    T_located = T_TABLE_OBJ @ T_OBJ_DATUM
    tips = np.asarray([t.contact_tip for t in prog.touches])
    tips[0] += 0.3 * np.asarray(prog.touches[0].normal)
    bad = refine_offset(list(prog.touches) + [prog.touches[3]], np.vstack([tips, tips[3]]) + [0, 0, 0], T_located,
                        ball_radius_mm=1.5)
    assert bad.ok  # 5 touches, 4 unknowns: a burr on the single x touch is absorbed by dx
    tips2 = np.vstack([tips, tips[1] + [0, 0, 0]])
    tips2[1] += 0.3 * np.asarray(prog.touches[1].normal)
    bad2 = refine_offset(list(prog.touches) + [prog.touches[1]], tips2, T_located, ball_radius_mm=1.5)
    assert not bad2.ok and "largest probe residual" in bad2.reason
