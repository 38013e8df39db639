"""The dry-run probing program runs to its end on the simulated LinuxCNC (real interpreter, real
motion, soft limits), and the real program passes LinuxCNC's own interpreter (rs274)."""

from __future__ import annotations

import os
import shutil
import subprocess
import time

import numpy as np
import pytest
import trimesh

from app.geometry.transforms import make_pose
from app.planning.obstacles import height_grid_from_meshes
from app.planning.path import AxisSpeeds, ProbeParams
from app.planning.probing import ProbingParams, choose_touch_points, probing_gcode
from tests.machine.linuxcnc_sim import SimError, shared_sim, skip_reason

pytestmark = pytest.mark.integration

# the sim: X/Y +-500, Z +-300 mm, 100 mm/s on every axis
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
        # rs274 attaches to LinuxCNC's SysV IPC: run beside the shared sim it stalled the sim's task
        # (after a pause and abort no command was taken any more). Its own IPC namespace keeps it apart.
        isolate = ["unshare", "--ipc"] if os.geteuid() == 0 else ["unshare", "--map-root-user", "--ipc"]
        r = subprocess.run([*isolate, "rs274", "-g", str(f)], capture_output=True, text=True, timeout=60, cwd=tmp_path)
        out = r.stdout + r.stderr
        assert r.returncode == 0 and "error" not in out.lower(), out[-2000:]
        assert "PROGRAM_END()" in out
        assert out.count("STRAIGHT_PROBE(") == (0 if dry else 4)


@pytest.fixture(scope="module")
def sim():
    why = skip_reason()
    if why:
        pytest.skip(why)
    try:
        return shared_sim()
    except SimError as exc:
        pytest.fail(f"LinuxCNC sim did not start: {exc}")


def test_dry_run_runs_to_the_end_on_the_sim(sim):
    prog = _programs()[True]
    sim.mdi("G10 L2 P1 X0 Y0 Z0 R0")  # G54 = machine zero, so the program frame is the table frame
    sim.mdi("G54")
    sim.mdi("G53 G0 X-100 Y-100 Z0")  # somewhere else than where the program ends
    W = np.asarray([p for path in prog.travel for p in path.waypoints])
    t_min = float(np.sum(np.max(np.abs(np.diff(W, axis=0)), axis=1))) / 100.0  # travel alone at 100 mm/s
    t0 = time.monotonic()
    sim.run_program(prog.gcode, name="setupcam_probe_dry.ngc")
    status = sim.status()
    while not status["interp_idle"] and time.monotonic() - t0 < 180:
        time.sleep(0.5)
        status = sim.status()
    elapsed = time.monotonic() - t0
    assert status["interp_idle"], "the dry run did not finish within 180 s"
    assert elapsed > 0.8 * t_min, (elapsed, t_min)  # it really drove the path
    # the program ends at the start xy with Z at the top (G53 G0 Z0); an error would stop it earlier
    assert status["position"] == pytest.approx([20.0, 20.0, 0.0], abs=1e-3), status
