"""The detour subroutine (issue 16, part 3): its logic is the reference planner's, and each dialect's
text, parsed back and run by tests/planning/detour_interp.py (and LinuxCNC's own rs274), reaches the
planner's corners within the dialect's resolution for many start and target points, every variant."""

from __future__ import annotations

import itertools
import os
import re
import shutil
import subprocess

import numpy as np
import pytest

from app.planning.detour_emit import (
    DECIMALS,
    DETOUR_DIALECTS,
    assemble,
    emit_call,
    emit_rapid,
    emit_subroutine,
    quantise_inputs,
    quantise_point,
)
from app.planning.detour_subroutine import (
    BoxObstacles,
    ObstacleBox,
    build_detour,
    evaluate,
)
from app.planning.obstacles import Region, RegionMap
from app.planning.path import ProbeParams
from app.planning.reference import ReferenceOptions, plan_path_reference
from tests.planning.detour_interp import corners, run

VARIANTS = {
    "plain": ReferenceOptions(box_margin_mm=4.0),
    "diagonal_down": ReferenceOptions(box_margin_mm=4.0, diagonal_down=True),
    "up_diagonal": ReferenceOptions(box_margin_mm=2.5, up_diagonal=True),
    "both_diagonals": ReferenceOptions(diagonal_down=True, up_diagonal=True),
    "orthogonal": ReferenceOptions(box_margin_mm=1.0, orthogonal=True),
}


def random_scene(rng, n_boxes=5):
    boxes = []
    for k in range(n_boxes):
        x0, y0 = rng.uniform(-80, 60, 2)
        w, h = rng.uniform(5, 40, 2)
        boxes.append(ObstacleBox(float(x0), float(y0), float(x0 + w), float(y0 + h), float(rng.uniform(2, 45)),
                                 f"b{k}"))
    return BoxObstacles(tuple(boxes), 0.0)


def random_points(rng, n):
    return np.column_stack([rng.uniform(-100, 100, n), rng.uniform(-100, 100, n), rng.uniform(-10, 70, n)])


def test_box_source_is_the_region_map_of_the_same_rectangles():
    rng = np.random.default_rng(3)
    for _ in range(20):
        scene = random_scene(rng)
        rm = RegionMap(tuple(Region.rectangle(b.x0, b.y0, b.x1, b.y1, b.top_mm) for b in scene.boxes), "highest", 0.0)
        for a, b in zip(random_points(rng, 30), random_points(rng, 30)):
            for m in (0.0, 3.0):
                assert scene.box_max_mm(0, a, b, m) == pytest.approx(rm.box_max_mm(0, a, b, m), abs=1e-9)


@pytest.mark.parametrize("variant", VARIANTS)
def test_the_subroutine_logic_is_the_reference_planner(variant):
    opt = VARIANTS[variant]
    rng = np.random.default_rng(11)
    patterns = set()
    for _ in range(40):
        scene = random_scene(rng)
        probe = ProbeParams(working_distance_mm=float(rng.choice([0.0, 30.0])), clearance_mm=float(rng.uniform(1, 8)))
        sub = build_detour(scene, probe, opt)
        for a, b in zip(random_points(rng, 10), random_points(rng, 10)):
            path = plan_path_reference([a, b], scene, probe, opt)
            patterns.add(path.moves[0].pattern)
            got, want = np.asarray(evaluate(sub, a, b)), np.asarray(path.waypoints)
            assert got.shape == want.shape and np.abs(got - want).max() <= 1e-8, (got, want)
    assert len(patterns) == 4  # every pattern (or its variant) was met


def _program(dialect, sub, points):
    main = [emit_rapid(dialect, points[0])]
    for p in points[1:]:
        main += emit_call(dialect, p)
    return assemble(dialect, "detour test", main, emit_subroutine(dialect, sub))


@pytest.mark.parametrize("variant", VARIANTS)
@pytest.mark.parametrize("dialect", DETOUR_DIALECTS)
def test_each_dialect_parsed_back_reaches_the_planners_corners(dialect, variant):
    rng = np.random.default_rng(7)
    res = 10.0 ** -DECIMALS[dialect]
    for _ in range(6):
        boxes, probe, opt = quantise_inputs(dialect, random_scene(rng, 6), ProbeParams(0.0, 5.0),
                                            VARIANTS[variant])
        sub = build_detour(boxes, probe, opt)
        pts = [quantise_point(dialect, p) for p in random_points(rng, 12)]
        want = plan_path_reference(pts, boxes, probe, opt).waypoints
        got = corners(run(dialect, _program(dialect, sub, pts), (0.0, 0.0, 0.0)))
        assert len(got) == len(want)
        assert np.abs(np.asarray(got) - np.asarray(want)).max() <= res / 2


def test_quantising_never_makes_the_scene_smaller():
    rng = np.random.default_rng(5)
    scene = random_scene(rng)
    for d in DETOUR_DIALECTS:
        q, probe, opt = quantise_inputs(d, scene, ProbeParams(0.3333, 4.44444), ReferenceOptions(box_margin_mm=1.23456))
        for a, b in zip(scene.boxes, q.boxes):
            assert b.x0 <= a.x0 and b.y0 <= a.y0 and b.x1 >= a.x1 and b.y1 >= a.y1 and b.top_mm >= a.top_mm
        assert probe.clearance_mm >= 4.44444 and probe.working_distance_mm <= 0.3333 and opt.box_margin_mm >= 1.23456


def test_the_travel_never_enters_an_obstacle_grown_by_the_clearance():
    """With a box margin of at least the clearance, every point of every planned (= subroutine) move
    whose ends are outside the grown boxes stays outside them."""
    rng = np.random.default_rng(21)
    c = 5.0
    checked = 0
    for _ in range(30):
        scene = random_scene(rng)
        sub = build_detour(scene, ProbeParams(0.0, c), ReferenceOptions(box_margin_mm=c))

        def inside(P, scene=scene):
            return np.any([(P[:, 0] > b.x0 - c + 1e-9) & (P[:, 0] < b.x1 + c - 1e-9) & (P[:, 1] > b.y0 - c + 1e-9)
                           & (P[:, 1] < b.y1 + c - 1e-9) & (P[:, 2] < b.top_mm + c - 1e-9) for b in scene.boxes], axis=0)

        pts = random_points(rng, 40)
        pts = pts[~inside(pts)]
        for a, b in itertools.pairwise(pts):
            W = np.asarray(evaluate(sub, a, b))
            S = np.vstack([p + np.linspace(0, 1, 50)[:, None] * (q - p) for p, q in itertools.pairwise(W)])
            assert not inside(S).any()
            checked += 1
    assert checked > 500


def test_bad_scenes_are_refused():
    with pytest.raises(ValueError, match="x1 >= x0"):
        ObstacleBox(5, 0, 1, 1, 3)
    with pytest.raises(ValueError, match="finite"):
        ObstacleBox(0, 0, 1, 1, float("nan"))
    with pytest.raises(ValueError, match="margin"):
        build_detour(BoxObstacles(()), ProbeParams(0, 5), margin_mm=-1)
    with pytest.raises(ValueError, match="heidenhain"):
        emit_call("mazak", (0, 0, 0))


@pytest.mark.skipif(shutil.which("rs274") is None, reason="LinuxCNC's rs274 interpreter is not installed (linuxcnc-uspace)")
def test_linuxcncs_own_interpreter_reaches_the_same_corners(tmp_path):
    rng = np.random.default_rng(8)
    for variant in ("plain", "both_diagonals", "orthogonal"):
        boxes, probe, opt = quantise_inputs("linuxcnc", random_scene(rng), ProbeParams(0.0, 5.0), VARIANTS[variant])
        pts = [quantise_point("linuxcnc", p) for p in random_points(rng, 15)]
        f = tmp_path / f"detour_{variant}.ngc"
        f.write_text(_program("linuxcnc", build_detour(boxes, probe, opt), pts))
        isolate = ["unshare", "--ipc"] if os.geteuid() == 0 else ["unshare", "--map-root-user", "--ipc"]
        r = subprocess.run([*isolate, "rs274", "-g", str(f)], capture_output=True, text=True, timeout=60,
                           cwd=tmp_path, check=False)
        out = r.stdout + r.stderr
        assert r.returncode == 0 and "error" not in out.lower(), out[-2000:]
        got = [tuple(float(v) for v in m.split(",")[:3]) for m in re.findall(r"STRAIGHT_TRAVERSE\(([^)]*)\)", out)]
        want = plan_path_reference(pts, boxes, probe, opt).waypoints
        assert np.abs(np.asarray(corners([("", p) for p in got])) - np.asarray(want)).max() <= 1e-4
