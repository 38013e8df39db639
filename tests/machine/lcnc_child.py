"""Independent LinuxCNC access through Debian's ``linuxcnc`` Python module, run in a child process.

Run with a CPython 3.11 that can import ``linuxcnc`` (Debian's /usr/bin/python3). The tests never
import the module in their own process: a process that polls status before the controller is up
stays broken (see /work/shared/notes/linuxcnc-opcua.md), and the adapter under test must be checked
by something that does not share its code path (linuxcncrsh over TCP).

Usage: python3 lcnc_child.py ready | prepare | status | read-slot P | mdi CODE | run FILE | trace FILE [S]
Prints one JSON object on stdout (except ``ready``, which answers by exit code).
"""

import json
import sys
import time

sys.path.append("/usr/lib/python3/dist-packages")
import linuxcnc  # noqa: E402


def _wait(s, pred, what, timeout=30.0):  # generous: CI machines are small and busy
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        s.poll()
        if pred():
            return
        time.sleep(0.02)
    raise SystemExit(f"timed out waiting for {what() if callable(what) else what}")


def _status(s):
    s.poll()
    return {
        "task_state": s.task_state, "task_mode": s.task_mode, "interp_state": s.interp_state,
        "exec_state": s.exec_state, "paused": bool(s.paused), "g5x_index": s.g5x_index,
        "g5x_offset": list(s.g5x_offset[:3]), "rotation_xy": s.rotation_xy,
        "position": list(s.position[:3]), "actual_position": list(s.actual_position[:3]),
        "rotary_position": list(s.actual_position[3:6]), "probed_position": list(s.probed_position[:3]),
        "probe_tripped": bool(s.probe_tripped),
        "tool_offset": list(s.tool_offset[:3]), "g92_offset": list(s.g92_offset[:3]), "homed": list(s.homed[:3]), "current_vel": s.current_vel,
        "interp_idle": s.interp_state == linuxcnc.INTERP_IDLE,
        "interp_paused": s.interp_state == linuxcnc.INTERP_PAUSED,
        "mode_auto": s.task_mode == linuxcnc.MODE_AUTO,
    }


def main(argv):
    cmd = argv[1]
    s = linuxcnc.stat()
    if cmd == "ready":
        try:
            s.poll()
        except linuxcnc.error:
            return 1
        return 0 if s.task_state >= linuxcnc.STATE_ESTOP else 1
    c = linuxcnc.command()
    if cmd == "prepare":  # what the operator does at the machine: reset e-stop, power on, home
        c.state(linuxcnc.STATE_ESTOP_RESET); c.wait_complete()
        c.state(linuxcnc.STATE_ON); c.wait_complete()
        _wait(s, lambda: s.task_state == linuxcnc.STATE_ON, "machine on")
        c.mode(linuxcnc.MODE_MANUAL); c.wait_complete()
        c.teleop_enable(False); c.wait_complete()
        c.home(-1); c.wait_complete()
        _wait(s, lambda: all(s.homed[:3]), "homed")
    elif cmd == "read-slot":  # activate G5x of slot P, read LinuxCNC's own status, restore the old slot
        p = int(argv[2])
        names = ["G54", "G55", "G56", "G57", "G58", "G59", "G59.1", "G59.2", "G59.3"]
        s.poll()
        # a freshly started LinuxCNC reports g5x_index 0 until the interpreter first changes the
        # slot, and an MDI of the slot already active does not refresh it: step through another slot
        before = s.g5x_index or 1
        c.mode(linuxcnc.MODE_MDI); c.wait_complete()
        if s.g5x_index != p:
            c.mdi(names[p % len(names)]); c.wait_complete()
            _wait(s, lambda: s.interp_state == linuxcnc.INTERP_IDLE, "interpreter idle")
        c.mdi(names[p - 1]); c.wait_complete()
        _wait(s, lambda: s.interp_state == linuxcnc.INTERP_IDLE and s.g5x_index == p, f"{names[p - 1]} active")
        out = _status(s)
        if before != p:
            c.mdi(names[before - 1]); c.wait_complete()
            _wait(s, lambda: s.interp_state == linuxcnc.INTERP_IDLE, "interpreter idle")
        print(json.dumps(out))
        return 0
    elif cmd == "mdi":  # run one MDI line to the end (e.g. a move that shows where G5x puts a point)
        c.mode(linuxcnc.MODE_MDI); c.wait_complete()
        c.mdi(argv[2]); c.wait_complete()
        _wait(s, lambda: s.interp_state == linuxcnc.INTERP_IDLE and s.inpos, "MDI done", timeout=30)
        err = linuxcnc.error_channel().poll()
        if err:
            raise SystemExit(f"controller error: {err}")
    elif cmd == "run":  # start a program file in auto mode and wait until it moves
        errors = linuxcnc.error_channel()
        c.mode(linuxcnc.MODE_AUTO); c.wait_complete()
        _wait(s, lambda: s.task_mode == linuxcnc.MODE_AUTO, lambda: f"auto mode (controller says: {errors.poll()}; status {_status(s)})")
        c.program_open(argv[2]); c.wait_complete()
        c.auto(linuxcnc.AUTO_RUN, 0)
        _wait(s, lambda: s.interp_state != linuxcnc.INTERP_IDLE, lambda: f"program started (controller says: {errors.poll()})")
        try:  # on a starved machine the first move may take a moment; running is what counts
            _wait(s, lambda: s.current_vel > 0 or s.interp_state == linuxcnc.INTERP_IDLE, "program moving", timeout=15.0)
        except SystemExit:
            pass
    elif cmd == "trace":  # run a program to its end, sampling the position as fast as status allows
        errors = linuxcnc.error_channel()
        c.mode(linuxcnc.MODE_AUTO); c.wait_complete()
        _wait(s, lambda: s.task_mode == linuxcnc.MODE_AUTO, "auto mode")
        c.program_open(argv[2]); c.wait_complete()
        c.auto(linuxcnc.AUTO_RUN, 0)
        _wait(s, lambda: s.interp_state != linuxcnc.INTERP_IDLE, lambda: f"program started ({errors.poll()})")
        samples, end = [], time.monotonic() + float(argv[3] if len(argv) > 3 else 300)
        while time.monotonic() < end:
            s.poll()
            samples.append(list(s.actual_position[:3]))
            if s.interp_state == linuxcnc.INTERP_IDLE and s.inpos:
                break
            time.sleep(0.0002)
        err = errors.poll()
        s.poll()
        print(json.dumps({"samples": samples, "error": list(err) if err else None, "done": s.interp_state ==
                          linuxcnc.INTERP_IDLE, "g5x_offset": list(s.g5x_offset[:3]), "rotation_xy": s.rotation_xy}))
        return 0
    elif cmd != "status":
        raise SystemExit(f"unknown command {cmd!r}")
    print(json.dumps(_status(s)))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
