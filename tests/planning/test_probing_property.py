"""Property test (issue 18, item 5): random scenes through the probing planner and the independent
checker (app.planning.program_check: the program parsed back, every move sampled, exact distances
from ball, stylus and body to the true primitives): 0 violations, every touch hits the part.

The default run takes 150 scenes (~15 s); the ``slow`` run 200 more with another seed (~40 s on a 2-core
CI machine; the issue asks for 200; it was 1000, then 300, suite time for no check the 200 do not make)."""

from __future__ import annotations

import collections

import numpy as np
import pytest

from app.geometry.transforms import inv
from app.planning.probing_safety import ProbingRefused, assumed_unlocated, plan_probing_program
from app.planning.program_check import Box, ProbeShape, TrueObstacle, check_program, parse_moves
from tests.support.probing_scenes import TABLE_XY_MM, T_MACHINE_TABLE, TRAVEL_MM, random_probing_scene

CLEARANCE = 5.0


def support_top(sc) -> float:
    return max([0.0, *(float((m.vertices[:, 2] + p[2, 3]).max()) for m, p in zip(sc.meshes, sc.poses))])


def check(sc, prog):
    """The independent check of a program against the scene's truth."""
    return check_program(prog.gcode, sc.truth, T_table_prog=inv(sc.T_prog_table()), clearance_mm=CLEARANCE,
                         nominal_contacts=[t.contact_tip for t in prog.touches])


def scenes_with_unlocated_clamps(seed: int, n: int):
    """Of n random scenes whose clamps are all left unlocated, those that have clamps."""
    rng = np.random.default_rng(seed)
    for _ in range(n):
        sc = random_probing_scene(rng, p_located=0.0)
        if sc.unlocated:
            yield sc


def plan(sc, assume_unlocated: bool = True, dry_run: bool = False, assumed=None):
    if assumed is None:
        assumed = (assumed_unlocated(sc.unlocated, TABLE_XY_MM, support_top(sc))
                   if sc.unlocated and assume_unlocated else [])
    return plan_probing_program(sc.meshes, sc.poses, sc.names, sc.workpiece_index, sc.T_obj_datum, sigma_mm=sc.sigma_mm,
                                assumed=assumed, T_machine_table=T_MACHINE_TABLE, travel_mm=TRAVEL_MM,
                                T_prog_table=sc.T_prog_table(), slot="G54", clearance_mm=CLEARANCE, dry_run=dry_run,
                                frame_text="G54 = datum")


def run_scenes(n: int, seed: int) -> dict:
    rng = np.random.default_rng(seed)
    codes: collections.Counter = collections.Counter()
    bad, touches, errors, min_clear = [], 0, [], np.inf
    for k in range(n):
        sc = random_probing_scene(rng)
        try:
            prog = plan(sc)
        except ProbingRefused as exc:
            codes[exc.code] += 1
            if sc.unlocated:
                assert exc.code == "obstacle_not_located", (k, exc)
            continue
        assert not sc.unlocated, f"scene {k}: a program was issued with {sc.unlocated} not located"
        codes["planned"] += 1
        codes[f"planned in a {sc.mount}"] += 1
        rep = check(sc, prog)
        if not rep.ok or len(rep.touches) != len(prog.touches):
            bad.append((k, rep.violations[:3], [(t.hit, t.obstacle) for t in rep.touches]))
        touches += len(rep.touches)
        errors += [t.error_mm for t in rep.touches]
        min_clear = min(min_clear, rep.min_travel_clearance_mm)
    return {"codes": codes, "bad": bad, "touches": touches, "errors": errors, "min_clearance": min_clear}


def _assert_property(n: int, seed: int) -> None:
    out = run_scenes(n, seed)
    assert out["bad"] == [], out["bad"][:5]
    assert out["codes"]["planned"] >= 0.3 * n, out["codes"]  # not vacuous: most scenes give a program
    assert out["codes"]["obstacle_not_located"] >= 0.05 * n, out["codes"]
    assert out["codes"]["planned in a vise"] >= 0.02 * n, out["codes"]  # touches on faces the jaws hold
    assert out["min_clearance"] >= CLEARANCE - 0.05
    # every touch hits the true part within the location error (0.3 mm) of its nominal contact
    assert max(out["errors"]) <= 0.3 + 0.05 and out["touches"] >= 4 * out["codes"]["planned"]


def test_random_scenes_have_no_violation():
    _assert_property(150, seed=18)


@pytest.mark.slow
def test_200_more_random_scenes_have_no_violation():
    _assert_property(200, seed=1018)


def test_the_checker_finds_the_issues_clamp():
    """Planning around the located objects only (the issue's bug) drives the probe into clamps that
    were not located: the checker sees it."""
    found = 0
    for sc in scenes_with_unlocated_clamps(seed=7, n=80):
        try:
            prog = plan(sc, assume_unlocated=False)
        except ProbingRefused:
            continue
        rep = check(sc, prog)
        found += any(o.startswith("strap_clamp") for _, _, o, _ in rep.violations) or not all(t.hit for t in rep.touches)
    assert found >= 3


def test_checker_on_hand_made_moves():
    block = TrueObstacle("block", "workpiece", (Box((50.0, 0.0), (10.0, 10.0), 0.0, 20.0),))
    table = TrueObstacle("table", "support", (Box((0.0, 0.0), (200.0, 200.0), -10.0, 0.0),))
    probe = ProbeShape()
    # travel through the block
    rep = check_program("G0 X0 Y0 Z10\nG1 X100 Y0 Z10 F1000\n", [block, table], probe=probe)
    assert any(o == "block" for _, _, o, _ in rep.violations)
    # travel 5.5 mm above it: clear; 4 mm: not
    assert check_program("G0 X0 Y0 Z25.5\nG1 X100 F1000\n", [block, table], probe=probe).ok
    assert not check_program("G0 X0 Y0 Z24\nG1 X100 F1000\n", [block, table], probe=probe).ok
    # a touch from the -x side at z 10: the ball trips where its surface meets the face x = 40
    rep = check_program("G0 X20 Y0 Z40\nG1 Z10 F1000\nG38.2 X45 F100\nG1 X20 F500\nG0 Z40\n", [block, table], probe=probe,
                        nominal_contacts=[(38.5, 0.0, 10.0)])
    assert rep.ok, rep.violations
    (t,) = rep.touches
    assert t.hit and t.tip == pytest.approx([38.5, 0.0, 10.0], abs=1e-6) and t.error_mm < 1e-6
    # a G38.2 that meets nothing is a miss
    assert not check_program("G0 X20 Y0 Z40\nG38.2 X0 F100\n", [block, table], probe=probe).ok
    # the body (r 15 from 30 mm above the tip) passing 3 mm beside and 3 mm above the block (4.2 mm)
    assert not check_program("G0 X22 Y0 Z-7\nG1 Y50 F1000\n", [block], probe=probe).ok
    with pytest.raises(ValueError, match="G53"):
        parse_moves("G53 G0 Z0\n")


def test_a_touch_beside_a_clamp_moves_along_the_face():
    """A strap clamp right where the default touch y1 (15 % along the long face) would go: the
    planner slides that touch along the face instead of refusing, and the program is clean."""
    import trimesh

    from app.geometry.transforms import make_pose
    from app.planning.program_check import VCylinder
    from tests.support.probing_scenes import ProbingScene

    L, W, H = 200.0, 80.0, 40.0
    part = Box((300.0, 200.0), (L / 2, W / 2), 0.0, H)
    x_default = 200.0 + 3.5 + 0.15 * (L - 7.0)  # 15 % along the usable line of the front (y) face
    strap = Box((x_default, 200.0 - W / 2 + 5.0), (12.5, 50.0), H, H + 12)
    riser = Box((x_default, 200.0 - W / 2 - 40.0), (12.5, 12.5), 0.0, H)
    stud = VCylinder((x_default, 200.0 - W / 2 - 5.0), 6.0, 0.0, H + 32)
    truth = (TrueObstacle("table", "support", (Box((400.0, 200.0), (400.0, 200.0), -60.0, 0.0),)),
             TrueObstacle("workpiece", "workpiece", (part,)),
             TrueObstacle("strap_clamp", "fixture", (strap, riser, stud)))
    from tests.support.probing_scenes import _mesh

    meshes = (_mesh((part,)), _mesh((strap, riser, stud)))
    sc = ProbingScene(truth, meshes, (np.eye(4), np.eye(4)), ("workpiece", "strap_clamp"), 0,
                      make_pose(t=(200.0, 160.0, H)), 0.1, (), "table")
    assert isinstance(meshes[0], trimesh.Trimesh)
    prog = plan(sc)
    y_touches = [t for t in prog.touches if t.name.startswith("y")]
    assert len(y_touches) == 2 and min(abs(t.contact[0] - x_default) for t in y_touches) > 20.0
    rep = check(sc, prog)
    assert rep.ok and len(rep.touches) == 4, rep.violations[:3]


def test_clamps_not_located_inside_drawn_zones_are_avoided():
    """The operator draws a rectangle around each clamp that was not located (its true footprint, 2 mm
    margin, any top: the tallest candidate counts): the planner plans around the zones, and the
    program passes the independent check against the truth."""
    from app.planning.probing_safety import assumed_in_zones as assume_in_zones
    from app.planning.probing_safety import drawn_zones

    planned = 0
    for sc in scenes_with_unlocated_clamps(seed=11, n=60):
        rects = []
        for ob in sc.truth:
            if ob.name not in dict(sc.unlocated):
                continue
            pts = []
            for g in ob.parts:
                c, s = np.cos(np.radians(getattr(g, "yaw_deg", 0.0))), np.sin(np.radians(getattr(g, "yaw_deg", 0.0)))
                hx, hy = g.half_xy if isinstance(g, Box) else (g.radius, g.radius)
                for u, v in ((hx, hy), (hx, -hy), (-hx, hy), (-hx, -hy)):
                    pts.append((g.centre_xy[0] + c * u - s * v, g.centre_xy[1] + s * u + c * v))
            P = np.asarray(pts)
            lo, hi = np.clip(P.min(axis=0) - 2, 0, None), np.minimum(P.max(axis=0) + 2, [800, 400])
            rects.append(f"{lo[0]:.1f},{lo[1]:.1f},{hi[0]:.1f},{hi[1]:.1f},10")
        zones = drawn_zones(";".join(rects), TABLE_XY_MM, 300.0)
        try:
            prog = plan(sc, assumed=assume_in_zones(sc.unlocated, zones, support_top(sc)))
        except ProbingRefused as exc:
            assert exc.code in ("obstacle_not_located", "touch_blocked", "outside_travel"), exc
            continue
        planned += 1
        assert "(obstacle drawn: drawn zone 1" in prog.gcode
        rep = check(sc, prog)
        assert rep.ok, rep.violations[:3]
    assert planned >= 5


def vise_scene(above_jaws_mm: float):
    """A 120 x 60 x 40 mm part held in a vise across its 60 mm width (the datum y face against the
    front jaw), standing ``above_jaws_mm`` above the jaws; the located pose is the truth + 0.1 mm."""
    from app.geometry.transforms import make_pose
    from tests.support.probing_scenes import ProbingScene, _mesh

    L, W, H, base = 120.0, 60.0, 40.0, 30.0
    c = (300.0, 200.0)
    part = Box(c, (L / 2, W / 2), base, base + H)
    vise = Box(c, (L / 2 + 40, W / 2 + 60), 0.0, base)
    jaw_top = base + H - above_jaws_mm
    jaws = tuple(Box((c[0], c[1] + s * (W / 2 + 12.5)), (85.0, 12.5), base, jaw_top) for s in (-1, 1))
    truth = (TrueObstacle("table", "support", (Box((400.0, 200.0), (400.0, 200.0), -60.0, 0.0),)),
             TrueObstacle("vise_base", "support", (vise,)), TrueObstacle("vise_jaws", "fixture", jaws),
             TrueObstacle("workpiece", "workpiece", (part,)))
    off = make_pose(t=(0.06, -0.05, 0.05))
    return ProbingScene(truth, (_mesh((vise,)), _mesh(jaws), _mesh((part,))), (off, off, off),
                        ("vise_base", "vise_jaws", "workpiece"), 2, make_pose(t=(c[0] - L / 2, c[1] - W / 2, base + H)),
                        0.1, (), "vise")


def test_touches_on_a_face_the_vise_holds_move_up_into_the_free_band():
    """The part stands 10.5 mm above the jaws: at the default depth (5 mm below the edge) the ball
    would pass 1.5 mm over the jaw, so the touches on the held face move up the face until the ball
    keeps the clearance over the jaw, and the independent checker finds no violation; every touch
    hits the part. At 6 mm above the jaws there is no such band: refused, saying how much is needed."""
    sc = vise_scene(10.5)
    prog = plan(sc)
    top = 70.0
    held = [t for t in prog.touches if t.name.startswith("y")]
    assert len(held) == 2, [t.name for t in prog.touches]
    for t in held:  # moved up from 5 mm below the edge, still on the face with its margin
        assert 2.0 < top - t.contact[2] < 5.0 - 0.2, t
        assert t.approach_tip[2] >= top - 10.5 + CLEARANCE, t  # the ball's bottom keeps the clearance over the jaw
    rep = check(sc, prog)
    assert rep.ok and len(rep.touches) == 4 and all(t.hit for t in rep.touches), rep.violations[:3]
    assert max(t.error_mm for t in rep.touches) < 0.2
    x = next(t for t in prog.touches if t.name == "x")  # the free face keeps its default depth
    assert top - x.contact[2] == pytest.approx(5.0, abs=0.2)

    with pytest.raises(ProbingRefused) as exc:
        plan(vise_scene(6.0))
    assert exc.value.code == "touch_blocked"
    msg = str(exc.value)
    assert "by vise_jaws" in msg and "mm above vise_jaws at touch y1" in msg and "free band needs" in msg, msg
    room = float(msg.split("the part stands ")[1].split(" mm")[0])
    assert room == pytest.approx(6.0, abs=0.6), msg


def test_random_vise_scenes_move_touches_up_or_refuse_with_the_room():
    """120 random parts in a vise standing 0 to 16 mm above the jaws: 0 violations in what is
    issued; every part with a free band wider than what a touch needs (ball + clearance + edge
    margin + 2 x 3 sigma, 1 mm to spare for the raster) gets a program; every refusal says how far
    the part stands above the jaws."""
    from app.planning.probing import ProbingParams

    p = ProbingParams()
    need = p.ball_radius_mm + CLEARANCE + p.edge_margin_mm + 2 * 0.3
    rng = np.random.default_rng(2018)
    planned = moved = 0
    for k in range(120):
        sc = random_probing_scene(rng, mount="vise", above_jaws_mm=(0.0, 16.0))
        wp = next(o for o in sc.truth if o.name == "workpiece").parts[0]
        above = wp.z1 - next(o for o in sc.truth if o.name == "vise_jaws").parts[0].z1
        try:
            prog = plan(sc, assumed=[])
        except ProbingRefused as exc:
            assert above < need + 1.0, (k, above, str(exc))
            if exc.code == "touch_blocked" and "vise_jaws" in str(exc):
                assert "above vise_jaws at touch" in str(exc), str(exc)
            continue
        planned += 1
        moved += any(wp.z1 - t.contact[2] < 4.9 for t in prog.touches if t.name != "z")
        rep = check(sc, prog)
        assert rep.ok and len(rep.touches) == len(prog.touches), (k, rep.violations[:3])
    print(f"vise scenes: {planned} of 120 planned, {moved} with touches moved up")
    assert planned >= 40 and moved >= 5, (planned, moved)
