"""Benchmark: reference safe-height method vs the profile planner on random scenes.

    .venv/bin/python benchmarks/planning.py [--scenes 1000] [--seed 0]

Each scene (app/synth/planning_scenes.py): a 400 x 300 mm table with 2-6 random blocks, cylinders and
L-shaped parts (some stacked), located with up to 0.5 mm error, and 4-8 measuring points on their
surfaces. Scenes alternate between an optical sensor (working distance 30, clearance 5, radius 12)
and a touch probe (working distance 0, clearance 3, radius 4, points 3 mm above the surface).

Methods, both given the LOCATED meshes inflated by the uncertainty and the sensor radius:
* reference            - app/planning/reference.py, obstacles (d) from the meshes (one region per
                          mesh: convex footprint, top height), the four patterns
* reference+variants   - the same with both shortening variants
* profile              - app/planning/profile.py: taut path over the straight xy line, obstacles =
                          the lower of a 1 mm height grid and the convex-hull regions of the meshes
* profile+detours      - the same, plus a time-weighted visibility-graph detour around whatever
                          forces a climb, kept when faster with the axis speeds

Every path is checked with the independent swept-body check (app/planning/collision.py) against the
TRUE meshes, as executed: reference paths as non-coordinated rapids (dog-legs), profile paths as
coordinated moves. Time: axes X 10000, Y 10000, Z 5000 mm/min, ``max_i |d_i| / v_i`` per segment.
"""

from __future__ import annotations

import argparse
import platform
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from app.planning.collision import ProbeBody, check_path  # noqa: E402
from app.planning.obstacles import LowestOf, height_grid_from_meshes, regions_from_meshes  # noqa: E402
from app.planning.path import AxisSpeeds, path_length_mm, path_time_s  # noqa: E402
from app.planning.profile import ProfileOptions, plan_path_profile  # noqa: E402
from app.planning.reference import ReferenceOptions, plan_path_reference  # noqa: E402
from app.synth.planning_scenes import OPTICAL, TABLE_XY_MM, TOUCH, random_scene  # noqa: E402

SPEEDS = AxisSpeeds(10000.0, 10000.0, 5000.0)
METHODS = ("reference", "reference+variants", "profile", "profile+detours")


def run_scene(scene) -> dict[str, dict]:
    """Plan with every method, check each path against the true meshes; per method: length, time,
    collision flag, planning ms."""
    probe = scene.probe
    parts, located = scene.meshes[1:], scene.located_poses[1:]
    truth = scene.truth
    body = ProbeBody.from_probe(probe)
    out = {}
    t0 = time.perf_counter()
    regions = regions_from_meshes(parts, located, inflate_mm=probe.radius_mm, uncertainty_mm=scene.uncertainty_mm)
    t_regions = time.perf_counter() - t0
    t0 = time.perf_counter()
    grid = height_grid_from_meshes(parts, located, bounds_xy_mm=(0, 0, *TABLE_XY_MM), cell_mm=1.0,
                                   uncertainty_mm=scene.uncertainty_mm)
    t_grid = time.perf_counter() - t0
    t0 = time.perf_counter()
    hull_regions = regions_from_meshes(parts, located, uncertainty_mm=scene.uncertainty_mm)
    both = LowestOf((grid, hull_regions))
    t_grid += time.perf_counter() - t0
    for name in METHODS:
        t0 = time.perf_counter()
        if name.startswith("profile"):
            opts = ProfileOptions(speeds=SPEEDS) if name.endswith("detours") else ProfileOptions()
            path = plan_path_profile(scene.points, both, probe, opts)
            t_plan = time.perf_counter() - t0 + t_grid
        else:
            opts = ReferenceOptions(diagonal_down=True, up_diagonal=True) if name.endswith("variants") else ReferenceOptions()
            path = plan_path_reference(scene.points, regions, probe, opts)
            t_plan = time.perf_counter() - t0 + t_regions
        report = check_path(path, truth, body, SPEEDS)
        out[name] = {
            "length_mm": path_length_mm(path),
            "time_s": path_time_s(path, SPEEDS),
            "collides": not report.ok,
            "plan_ms": 1000 * t_plan,
            "segments": len(path.waypoints) - 1,
            "reason": report.reason(),
        }
    return out


def run(n_scenes: int, seed: int) -> tuple[dict[str, dict[str, float]], dict]:
    rng = np.random.default_rng(seed)
    rows = {m: {"length_mm": [], "time_s": [], "collides": [], "plan_ms": [], "segments": []} for m in METHODS}
    failures = []
    t0 = time.perf_counter()
    n_moves = 0
    for k in range(n_scenes):
        scene = random_scene(rng, probe=OPTICAL if k % 2 == 0 else TOUCH)
        n_moves += len(scene.points) - 1
        res = run_scene(scene)
        for m in METHODS:
            for key in rows[m]:
                rows[m][key].append(res[m][key])
            if res[m]["collides"]:
                failures.append((k, m, res[m]["reason"]))
    info = {"scenes": n_scenes, "moves": n_moves, "seconds": time.perf_counter() - t0, "failures": failures}
    return {m: {k: np.asarray(v, dtype=float) for k, v in r.items()} for m, r in rows.items()}, info


def table(rows, info) -> str:
    ref_len = rows["reference"]["length_mm"]
    ref_t = rows["reference"]["time_s"]
    lines = [
        f"{info['scenes']} scenes, {info['moves']} moves, run time {info['seconds']:.0f} s",
        "",
        "| method | collisions (paths) | total length m | total time s | length vs reference | time vs reference "
        "| median time ratio per scene | segments / move | planning ms / path |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for m in METHODS:
        r = rows[m]
        lines.append(
            f"| {m} | {int(r['collides'].sum())} | {r['length_mm'].sum() / 1000:.1f} | {r['time_s'].sum():.1f} "
            f"| {r['length_mm'].sum() / ref_len.sum():.3f} | {r['time_s'].sum() / ref_t.sum():.3f} "
            f"| {np.median(r['time_s'] / ref_t):.3f} | {r['segments'].sum() / info['moves']:.2f} "
            f"| {np.median(r['plan_ms']):.1f} |"
        )
    lines.append("")
    for m in METHODS[2:]:
        prof = rows[m]
        worse = int(np.sum(prof["time_s"] > ref_t + 1e-6))
        lines.append(f"{m}: slower than reference in {worse} of {info['scenes']} scenes, "
                     f"longer in {int(np.sum(prof['length_mm'] > ref_len + 1e-6))}")
    return "\n".join(lines)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", type=int, default=1000)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    rows, info = run(args.scenes, args.seed)
    print(f"python {platform.python_version()}, seed {args.seed}")
    print(table(rows, info))
    for k, m, reason in info["failures"][:10]:
        print(f"scene {k} {m}: {reason}")
    return 1 if info["failures"] else 0


if __name__ == "__main__":
    sys.exit(main())
