"""The real and the dry-run probing program pass LinuxCNC's own interpreter (rs274).

The dry run on the simulated LinuxCNC (real interpreter, real motion, soft limits) is driven the way a
user gets it, over REST, in tests/api/test_planning.py: it runs early in the suite. Run here, after the
controller tests' pause-and-abort, the Debian 12 LinuxCNC (2.9.0~pre1) sim intermittently stopped
taking MDI and mode commands (task echo serial stuck), even after a restart of the sim."""

from __future__ import annotations

import os
import shutil
import subprocess

import numpy as np
import pytest
import trimesh

from app.geometry.transforms import make_pose
from app.planning.obstacles import height_grid_from_meshes
from app.planning.path import AxisSpeeds, ProbeParams
from app.planning.probing import ProbingParams, choose_touch_points, probing_gcode

pytestmark = pytest.mark.integration

# the sim's machine: X/Y +-500, Z +-300 mm, 100 mm/s on every axis
SPEEDS = AxisSpeeds(6000, 6000, 6000)
PARAMS = ProbingParams(ball_radius_mm=1.5, stylus_length_mm=30.0, probe_feed_mm_min=1200.0)
TRAVEL = ProbeParams(working_distance_mm=0.0, clearance_mm=5.0, radius_mm=15.0, length_mm=80.0)


def _programs():
    part = trimesh.creation.box(extents=(100, 60, 30))
    part.apply_translation((50, 30, 15))
    c = np.radians(2.0)
    T_table_obj = make_pose([[np.cos(c), -np.sin(c), 0], [np.sin(c), np.cos(c), 0], [0, 0, 1]], (150, 100, 0))
    touches = choose_touch_points(part, T_table_obj, make_pose(t=(0, 0, 30)), PARAMS)
    grid = height_grid_from_meshes([part], [T_table_obj], uncertainty_mm=0.5)
    start = (20.0, 20.0, 80.0)
    return {dry: probing_gcode(touches, grid, TRAVEL, start, params=PARAMS, speeds=SPEEDS, dry_run=dry) for dry in (True, False)}


@pytest.mark.skipif(shutil.which("rs274") is None, reason="LinuxCNC's rs274 interpreter is not installed (linuxcnc-uspace)")
def test_linuxcnc_interpreter_reads_both_variants(tmp_path):
    for dry, prog in _programs().items():
        f = tmp_path / f"probe_{int(dry)}.ngc"
        f.write_text(prog.gcode)
        # rs274 attaches to LinuxCNC's SysV IPC; in its own IPC namespace it cannot touch the shared sim
        isolate = ["unshare", "--ipc"] if os.geteuid() == 0 else ["unshare", "--map-root-user", "--ipc"]
        r = subprocess.run([*isolate, "rs274", "-g", str(f)], capture_output=True, text=True, timeout=60, cwd=tmp_path)
        out = r.stdout + r.stderr
        assert r.returncode == 0 and "error" not in out.lower(), out[-2000:]
        assert "PROGRAM_END()" in out
        assert out.count("STRAIGHT_PROBE(") == (0 if dry else 4)


@pytest.mark.skipif(shutil.which("rs274") is None, reason="LinuxCNC's rs274 interpreter is not installed (linuxcnc-uspace)")
def test_the_rotary_guard_aborts_unless_the_axis_stands_at_the_planned_angle(tmp_path):
    """rs274 alone starts with every axis at 0: a program planned for C = 0 runs, one for C = 37 aborts
    before its first move (the sim proves both on a turned table: tests/e2e/test_rotary_table_sim.py)."""
    from app.planning.probing import rotary_guard_lines

    for angle, runs in ((0.0, True), (37.0, False)):
        f = tmp_path / f"guard_{angle:g}.ngc"
        f.write_text("\n".join(["%", "G21 G90 G54", *rotary_guard_lines("C", angle, "G54"), "G0 Z10", "M2", "%"]) + "\n")
        isolate = ["unshare", "--ipc"] if os.geteuid() == 0 else ["unshare", "--map-root-user", "--ipc"]
        r = subprocess.run([*isolate, "rs274", "-g", str(f)], capture_output=True, text=True, timeout=60, cwd=tmp_path,
                           check=False)
        out = r.stdout + r.stderr
        moved = "STRAIGHT_TRAVERSE(" in out
        assert moved == runs, out[-2000:]
        if not runs:
            assert "not at 37.000 deg" in out, out[-2000:]
