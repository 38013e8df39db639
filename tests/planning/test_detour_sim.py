"""The detour subroutine on the simulated LinuxCNC (issue 16, part 3): a probing sequence over a scene
with obstacles runs through ``o<setupcam_detour>``; LinuxCNC's own position, sampled during the run,
follows the Python planner's path: every corner reached within 0.001 mm, no sample off the planned
polyline, and the travel never inside an obstacle box grown by the clearance.

Run under ``flock /tmp/lcnc.lock`` (one LinuxCNC per computer)."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from app.geometry.transforms import make_pose
from app.planning.detour_program import detour_probing_program
from app.planning.path import ProbeParams
from app.planning.probing import ProbingParams, choose_touch_points
from app.planning.probing_safety import KnownObstacle
from app.planning.reference import ReferenceOptions

pytestmark = [pytest.mark.integration, pytest.mark.linuxcnc]


@pytest.fixture(scope="module")
def sim():
    """The process's LinuxCNC sim (tests/machine/sim.py); skips with the reason when absent."""
    from tests.machine.linuxcnc_sim import SimError, shared_sim, skip_reason

    if why := skip_reason():
        pytest.skip(why)
    try:
        return shared_sim()
    except SimError as exc:
        pytest.fail(f"LinuxCNC sim did not start: {exc}")

CLEARANCE = 5.0
# probe feed 100 mm/min (the product's default): the simulated probe is a userspace component polled
# every 0.5 ms, and on a loaded machine it trips late; at 1200 mm/min one touch in a suite run under
# xdist came 0.08 mm long, and at 300 mm/min one did again (16 ms late: 0.0825 mm, 2026-11-29); at
# 100 mm/min such a delay costs 0.03 mm
PARAMS = ProbingParams(ball_radius_mm=1.5, stylus_length_mm=30.0, probe_feed_mm_min=100.0, approach_mm=5.0)
TRAVEL = ProbeParams(working_distance_mm=0.0, clearance_mm=CLEARANCE, radius_mm=15.0, length_mm=80.0)
START = (100.0, 200.0, 95.0)


def _rect(name, x0, y0, x1, y1, top):
    return KnownObstacle(name, "located", ((x0, y0), (x1, y0), (x1, y1), (x0, y1)), top)


def scene():
    """A 100 x 60 x 30 block at (150..250, 100..160), a tall clamp behind-left, a low one front-right."""
    part = trimesh.creation.box(extents=(100, 60, 30))
    part.apply_translation((50, 30, 15))
    T = make_pose(t=(150, 100, 0))
    touches = choose_touch_points(part, T, make_pose(t=(0, 0, 30)), PARAMS)
    obstacles = [_rect("block", 150, 100, 250, 160, 30.0), _rect("clamp A", 120, 170, 140, 190, 45.0),
                 _rect("clamp B", 260, 60, 280, 80, 20.0)]
    return touches, obstacles


def expected_corners(program, touches):
    pts = []
    for k, path in enumerate(program.travel):
        pts += [tuple(p) for p in path.waypoints]
        if k < len(touches):
            pts += [touches[k].contact_tip, touches[k].approach_tip]
    out = []
    for p in pts:
        if not out or np.linalg.norm(np.subtract(out[-1], p)) > 1e-9:
            out.append(tuple(float(v) for v in p))
    return np.asarray(out)


def _seg_dist(P, a, b):
    d = b - a
    L2 = float(d @ d)
    t = np.clip(((P - a) @ d) / L2, 0.0, 1.0) if L2 > 0 else np.zeros(len(P))
    return np.linalg.norm(P - (a + t[:, None] * d), axis=1)


def _directions(samples: np.ndarray) -> np.ndarray:
    """Per sample the direction it moves next (to the next sample that differs; 0 at the very end)."""
    D = np.zeros_like(samples)
    nxt = np.zeros(3)
    for i in range(len(samples) - 2, -1, -1):
        d = samples[i + 1] - samples[i]
        if np.linalg.norm(d) > 1e-7:
            nxt = d
        D[i] = nxt
    return D


def follow(samples: np.ndarray, W: np.ndarray, tol: float):
    """Assign each sample, in order, to a segment of the polyline W (the current one or one of the next
    few) that it lies on (within ``tol``) and moves along: the segment index per sample;
    AssertionError at the first sample off the path."""
    D = _directions(samples)
    j, seg = 0, []
    for i, p in enumerate(samples):
        for k in range(j, min(j + 4, len(W) - 1)):
            along = D[i] @ (W[k + 1] - W[k])
            if _seg_dist(p[None], W[k], W[k + 1])[0] <= tol and (along > 0 or not D[i].any()):
                j = k
                break
        else:
            off = min(_seg_dist(p[None], W[k], W[k + 1])[0] for k in range(len(W) - 1))
            raise AssertionError(f"sample {i} at {p.tolist()} is {off:.4f} mm off the planned path or moves "
                                 f"against it (segment {j})")
        seg.append(j)
    return np.asarray(seg)


def _fit_line(P: np.ndarray):
    """Centroid and unit direction of the points (principal axis), or None when they do not span 0.05 mm."""
    if len(P) < 2 or np.ptp(P, axis=0).max() < 0.05:
        return None
    c = P.mean(axis=0)
    return c, np.linalg.svd(P - c)[2][0]


def corner_errors(samples, seg, W):
    """Per interior corner W[j]: where the sim turned, as the meeting point of the lines fitted to the
    samples on the segments into and out of it (robust to gaps in the sampling), and as the nearest
    sample; a reversal (a touch: out and back on one line) by its furthest sample. Returns (error,
    nearest-sample error, kind) per corner, mm; kind 0 a turn, 1 a reversal, 2 straight on (error NaN)."""
    out = []
    for j in range(1, len(W) - 1):
        a_in, a_out = samples[seg == j - 1], samples[seg == j]
        near = float(np.min(np.linalg.norm(np.vstack([a_in, a_out]) - W[j], axis=1)))
        u, v = W[j] - W[j - 1], W[j + 1] - W[j]
        cos = float(u @ v) / (np.linalg.norm(u) * np.linalg.norm(v))
        if cos < -0.999:  # a reversal: its far end
            far = a_in[np.argmax((a_in - W[j - 1]) @ u)] if len(a_in) else W[j - 1]
            out.append((float(np.linalg.norm(far - W[j])), near, 1))
            continue
        if cos > 0.999:  # straight on (e.g. up from a touch and on up): no corner to see in the path
            out.append((np.nan, near, 2))
            continue
        f_in, f_out = _fit_line(a_in), _fit_line(a_out)
        if f_in is None or f_out is None:
            out.append((near, near, 0))
            continue
        (p, d), (q, e) = f_in, f_out
        A = np.column_stack([d, -e])  # p + s d = q + t e, least squares
        st = np.linalg.lstsq(A, q - p, rcond=None)[0]
        meet = (p + st[0] * d + q + st[1] * e) / 2.0
        out.append((float(np.linalg.norm(meet - W[j])), near, 0))
    return np.asarray(out)


def inside_grown_boxes(P, program_boxes, c, tol=1e-3):
    """Samples more than ``tol`` inside an obstacle box grown by ``c`` (sideways and on top)."""
    bad = np.zeros(len(P), dtype=bool)
    for b in program_boxes:
        bad |= ((P[:, 0] > b.x0 - c + tol) & (P[:, 0] < b.x1 + c - tol) & (P[:, 1] > b.y0 - c + tol)
                & (P[:, 1] < b.y1 + c - tol) & (P[:, 2] < b.top_mm + c - tol))
    return bad


@pytest.mark.parametrize("options", [None, ReferenceOptions(box_margin_mm=15.0, diagonal_down=True, up_diagonal=True)],
                         ids=["plain", "diagonals"])
def test_linuxcnc_runs_the_detour_subroutine_on_the_planned_path(sim, options):
    from app.planning.detour_program import program_boxes

    touches, obstacles = scene()
    prog = detour_probing_program("linuxcnc", touches, obstacles, TRAVEL, START, params=PARAMS, dry_run=True,
                                  retract_z_mm=START[2], options=options, title="detour sim")
    W = expected_corners(prog, touches)
    assert {m.pattern for p in prog.travel for m in p.moves} >= {"up_over_down"}
    sim.mdi("G10 L2 P1 X0 Y0 Z0 R0")
    sim.mdi("G54")
    sim.mdi(f"G0 X{START[0]} Y{START[1]} Z{START[2]}")
    out = sim.trace_program(prog.gcode, name="detour_dry.ngc")
    assert out["error"] is None and out["done"], out.get("error")
    S = np.asarray(out["samples"], dtype=float)
    assert len(S) > 1000
    assert np.linalg.norm(S[-1] - W[-1]) < 1e-3  # it ends where the plan ends
    seg = follow(S, W, tol=1e-3)
    assert seg[-1] == len(W) - 2, "the run stopped before the end of the planned path"
    errs = corner_errors(S, seg, W)
    turn, rev = errs[:, 2] == 0, errs[:, 2] == 1
    print(f"\n{len(W)} corners ({int(turn.sum())} turns, {int(rev.sum())} touch reversals), {len(S)} samples; "
          f"turn corners from fitted lines: max {errs[turn, 0].max() * 1000:.3f} um; touch ends sampled within "
          f"{errs[rev, 0].max() * 1000:.1f} um; nearest sample: median "
          f"{np.median(errs[:, 1]) * 1000:.3f} um, max {errs[:, 1].max() * 1000:.1f} um; "
          f"patterns {[m.pattern for p in prog.travel for m in p.moves]}")
    assert errs[turn, 0].max() <= 1e-3, errs  # every corner of the detour where the planner puts it
    # the touches' far ends (out and back on one line) are only seen as far as the sampling caught them;
    # ``follow`` has shown that no sample went beyond them
    # the travel (not the touches themselves) never inside an obstacle box grown by the clearance
    touch_legs = np.zeros(len(S), dtype=bool)
    for k in range(len(W) - 1):
        a, b = W[k], W[k + 1]
        if any(np.allclose(a, t.contact_tip) or np.allclose(b, t.contact_tip) for t in touches):
            touch_legs |= seg == k
    boxes = program_boxes(obstacles, np.eye(4)).boxes
    bad = inside_grown_boxes(S[~touch_legs], boxes, CLEARANCE)
    assert not bad.any(), (S[~touch_legs][bad][:5], np.unique(seg[~touch_legs][bad]), W)


def test_real_touches_through_the_subroutine_trip_on_the_true_part(sim):
    """The real program (G38.2, PROBEOPEN log) on the sim with a simulated probe: the block stands
    0.4 mm further in +x and 0.3 mm in -y than located. No rapid of the detours trips the probe (LinuxCNC
    would stop the program), and each touch logs where the ball meets the true face."""
    from app.planning.probing import parse_probe_results

    touches, obstacles = scene()
    prog = detour_probing_program("linuxcnc", touches, obstacles, TRAVEL, START, params=PARAMS, dry_run=False,
                                  retract_z_mm=START[2], title="detour sim real")
    shift = np.array([0.4, -0.3, 0.0])
    sim.mdi("G10 L2 P1 X0 Y0 Z0 R0")
    sim.mdi("G54")
    sim.mdi(f"G0 X{START[0]} Y{START[1]} Z{START[2]}")
    sim.set_probe_part([{"centre_xy": [200.0 + shift[0], 130.0 + shift[1]], "half_xy": [50.0, 30.0], "yaw_deg": 0.0,
                         "z0": 0.0, "z1": 30.0}], PARAMS.ball_radius_mm)
    log = sim.workdir / "setupcam_probe.txt"
    log.unlink(missing_ok=True)
    trips = sim.workdir / "simprobe_trips.txt"
    trips.unlink(missing_ok=True)
    try:
        out = sim.trace_program(prog.gcode, name="detour_real.ngc")
    finally:
        sim.set_probe_part([])
    assert out["error"] is None and out["done"], out.get("error")
    tips = parse_probe_results(log.read_text())
    assert len(tips) == 4, log.read_text()
    want = [np.asarray(t.contact_tip) + float(shift @ np.asarray(t.normal)) * np.asarray(t.normal) for t in touches]
    err = np.linalg.norm(tips - np.asarray(want), axis=1)
    # the simulated probe trips late on a loaded machine (polled from user space: 32 ms at 100 mm/min
    # cost 0.054 mm in one suite run) and says how deep the ball was when it tripped and just after;
    # the controller latched between the two: what is left is the program's, each touch where the true
    # face is, to 0.01 mm
    late = np.loadtxt(trips, ndmin=2)[:, 3:5]
    print(f"\nreal touches through the subroutine: errors {np.round(err * 1000, 1).tolist()} um, "
          f"the probe's own lateness {np.round(late * 1000, 1).tolist()} um")
    assert len(late) == len(tips), trips.read_text()        # one trip per touch: no rapid met the part
    assert np.all((err >= late[:, 0] - 0.01) & (err <= late[:, 1] + 0.01)), (err, late)
    assert np.all(late <= 0.25), late        # a sim this late measures nothing: look at the machine's load
    assert np.linalg.norm(np.asarray(out["samples"][-1]) - np.asarray(START)) < 1e-3  # back at the start
