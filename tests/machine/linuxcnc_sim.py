"""A headless simulated LinuxCNC mill for tests (Debian ``linuxcnc-uspace``), reachable over
``linuxcncrsh`` on 127.0.0.1 and checked independently through the ``linuxcnc`` Python module in
child processes (lcnc_child.py).

Recipe and pitfalls: /work/shared/notes/linuxcnc-opcua.md. In short: as root ``RTAPI_UID`` must be
a non-zero uid and ``RTAPI_FIFO_PATH`` a folder that uid can write; ``DISPLAY`` unset; no
hal_manualtoolchange; home-in-place joints; a fresh config folder per run (offsets persist in the
parameter file); one instance per computer (fixed lock, shared memory keys), so a cross-process
file lock serialises test sessions that want the sim.

Use from any test package (always under this one module name, so that one pytest run shares one
instance)::

    from tests.machine.linuxcnc_sim import shared_sim, skip_reason

    @pytest.fixture(scope="session")
    def linuxcnc_sim():
        if why := skip_reason():
            pytest.skip(why)
        return shared_sim()   # started once per process, stopped at exit

    sim.settings              # {"kind": "linuxcnc", "host": "127.0.0.1", "port": ...}
    sim.read_slot("G54")      # LinuxCNC's own status: {"g5x_offset": [x, y, z], "rotation_xy": c, ...}

tests/machine/conftest.py defines exactly that fixture, ``linuxcnc_sim``.
"""

from __future__ import annotations

import atexit
import fcntl
import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
CHILD = HERE / "lcnc_child.py"
SYSTEM_PYTHON = "/usr/bin/python3"
SESSION_LOCK = Path("/tmp/setupcam-linuxcnc-sim.lock")
LINUXCNC_LOCK = Path("/tmp/linuxcnc.lock")

_INI = """\
[EMC]
VERSION = 1.1
MACHINE = setupcam-test-sim
DEBUG = 0

[DISPLAY]
# linuxcncrsh is the display: the adapter under test talks to it over TCP
DISPLAY = linuxcncrsh --port {port}
CYCLE_TIME = 0.100

[TASK]
TASK = milltask
CYCLE_TIME = 0.001

[RS274NGC]
PARAMETER_FILE = sim_mm.var

[EMCMOT]
EMCMOT = motmod
COMM_TIMEOUT = 1.0
BASE_PERIOD = 0
SERVO_PERIOD = 1000000

[EMCIO]
EMCIO = io
CYCLE_TIME = 0.100
TOOL_TABLE = sim_mm.tbl

[HAL]
HALFILE = LIB:basic_sim.tcl -no_use_hal_manualtoolchange
# a simulated touch probe (tests/machine/simprobe.py): trips where the ball meets the part in simprobe_part.json
HALFILE = simprobe.hal

[TRAJ]
COORDINATES = {coordinates}
LINEAR_UNITS = mm
ANGULAR_UNITS = degree
DEFAULT_LINEAR_VELOCITY = 100
MAX_LINEAR_VELOCITY = 100
DEFAULT_LINEAR_ACCELERATION = 1000
MAX_LINEAR_ACCELERATION = 1000

[KINS]
KINEMATICS = trivkins coordinates={kins}
JOINTS = {joints}
"""

_AXIS = """
[AXIS_{axis}]
MAX_VELOCITY = 100
MAX_ACCELERATION = 1000
MIN_LIMIT = {lo}
MAX_LIMIT = {hi}

[JOINT_{joint}]
TYPE = {type}
HOME = 0.0
MAX_VELOCITY = 100
MAX_ACCELERATION = 1000
MIN_LIMIT = {lo}
MAX_LIMIT = {hi}
FERROR = 1.27
MIN_FERROR = .254
# home in place: home(-1) completes at once
HOME_SEARCH_VEL = 0
HOME_LATCH_VEL = 0
HOME_SEQUENCE = 0
"""

TRAVEL_MM = {"X": (-500.0, 500.0), "Y": (-500.0, 500.0), "Z": (-300.0, 300.0)}
#: a rotary axis the XYZC sim adds (degrees; LinuxCNC's usual "unlimited" rotary limits)
ROTARY_TRAVEL_DEG = (-9999.0, 9999.0)


def _linuxcnc_module_python() -> str | None:
    """A python that can import Debian's ``linuxcnc`` module, or None."""
    if not Path(SYSTEM_PYTHON).exists():
        return None
    r = subprocess.run([SYSTEM_PYTHON, "-c", "import sys; sys.path.append('/usr/lib/python3/dist-packages'); import linuxcnc"],
                       capture_output=True)
    return SYSTEM_PYTHON if r.returncode == 0 else None


def skip_reason() -> str:
    """Why the sim cannot run here ('' when it can)."""
    if shutil.which("linuxcnc") is None:
        return ("LinuxCNC is not installed: run scripts/install-linuxcnc.sh (Debian 12 package "
                "linuxcnc-uspace, --no-install-recommends) to run the real-controller tests")
    if shutil.which("linuxcncrsh") is None:
        return "linuxcncrsh is missing although linuxcnc is installed; reinstall linuxcnc-uspace"
    if _linuxcnc_module_python() is None:
        return f"{SYSTEM_PYTHON} cannot import Debian's linuxcnc module (needed for the independent read-back)"
    return ""


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class SimError(RuntimeError):
    pass


class LinuxCncSim:
    """Start/stop one simulated LinuxCNC; ``settings`` is what the service stores for the machine."""

    def __init__(self, workdir: Path, port: int | None = None, lock_timeout_s: float = 180.0,
                 coordinates: str = "XYZ"):
        if coordinates not in ("XYZ", "XYZA", "XYZB", "XYZC"):
            raise ValueError(f"coordinates must be XYZ or XYZ plus one rotary axis, got {coordinates!r}")
        self.coordinates = coordinates
        self.workdir = Path(workdir)
        self.port = port or free_port()
        self.host = "127.0.0.1"
        self.lock_timeout_s = lock_timeout_s
        self.proc: subprocess.Popen | None = None
        self._lock_fd: int | None = None
        self._fifo_dir: Path | None = None
        self.startup_s = float("nan")

    @property
    def settings(self) -> dict:
        return {"kind": "linuxcnc", "host": self.host, "port": self.port}

    # -- life cycle ------------------------------------------------------------------------------
    def _acquire_session_lock(self) -> None:
        fd = os.open(SESSION_LOCK, os.O_CREAT | os.O_RDWR, 0o666)
        end = time.monotonic() + self.lock_timeout_s
        while True:
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                break
            except BlockingIOError:
                if time.monotonic() > end:
                    os.close(fd)
                    raise SimError(f"another test session held {SESSION_LOCK} for {self.lock_timeout_s:.0f} s "
                                   "(only one LinuxCNC can run per computer)")
                time.sleep(0.2)
        self._lock_fd = fd
        if LINUXCNC_LOCK.exists():
            alive = subprocess.run(["pidof", "milltask", "linuxcncsvr"], capture_output=True, text=True).stdout.split()
            if alive:
                self._release_session_lock()
                raise SimError(f"a LinuxCNC not started by these tests is running (pids {' '.join(alive)}); "
                               "starting another would kill it")
            LINUXCNC_LOCK.unlink(missing_ok=True)  # stale lock of a crashed run, no processes left

    def _release_session_lock(self) -> None:
        if self._lock_fd is not None:
            fcntl.flock(self._lock_fd, fcntl.LOCK_UN)
            os.close(self._lock_fd)
            self._lock_fd = None

    def _write_config(self) -> Path:
        self.workdir.mkdir(parents=True, exist_ok=True)
        text = _INI.format(port=self.port, coordinates=" ".join(self.coordinates), kins=self.coordinates,
                           joints=len(self.coordinates))
        travel = {**TRAVEL_MM, **{a: ROTARY_TRAVEL_DEG for a in self.coordinates[3:]}}
        for joint, axis in enumerate(self.coordinates):
            lo, hi = travel[axis]
            text += _AXIS.format(axis=axis, joint=joint, lo=lo, hi=hi, type="LINEAR" if axis in "XYZ" else "ANGULAR")
        ini = self.workdir / "sim.ini"
        ini.write_text(text)
        (self.workdir / "sim_mm.tbl").write_text("T1 P1 D0.0 Z0.0 ;\n")
        (self.workdir / "sim_mm.var").write_text("")  # fresh parameter file: no offsets from earlier runs
        (self.workdir / "simprobe.hal").write_text(
            f"loadusr -Wn simprobe {SYSTEM_PYTHON} {HERE / 'simprobe.py'} {self.workdir / 'simprobe_part.json'}\n"
            + "".join(f"net J{j}:pos-fb => simprobe.{a}\n" for j, a in enumerate("xyz"))
            + ("net J3:pos-fb => simprobe.r\n" if len(self.coordinates) > 3 else "")
            + "net simprobe-trip simprobe.probe => motion.probe-input\n")
        return ini

    def set_probe_part(self, boxes: list[dict], ball_radius_mm: float = 1.5,
                       rotary_centre_xy: tuple[float, float] | None = None) -> None:
        """What the simulated probe touches: boxes turned about Z in machine coordinates (see
        tests/machine/simprobe.py); an empty list clears it. ``rotary_centre_xy``: the boxes sit on a C
        table turning about the machine Z line through that point (XYZC sim): they are given at C = 0 and
        the probe meets them turned by the C axis' position."""
        tmp = self.workdir / "simprobe_part.json.tmp"
        part = {"ball_radius_mm": ball_radius_mm, "boxes": boxes}
        if rotary_centre_xy is not None:
            part["rotary"] = {"centre_xy": list(rotary_centre_xy)}
        tmp.write_text(json.dumps(part))
        os.replace(tmp, self.workdir / "simprobe_part.json")  # the component never reads half a file
        time.sleep(0.05)

    def start(self, timeout_s: float = 30.0) -> "LinuxCncSim":
        self._acquire_session_lock()
        try:
            ini = self._write_config()
            env = dict(os.environ)
            env.pop("DISPLAY", None)  # no X: keeps the linuxcnc script from popping Tk dialogs
            if os.geteuid() == 0:
                env["RTAPI_UID"] = "65534"  # rtapi_app refuses root without a fallback uid
            # rtapi_app (real uid = RTAPI_UID) binds its socket here: a folder that uid can reach and
            # write (pytest's tmp folders are 0700 under /tmp/pytest-of-root, so not there)
            self._fifo_dir = Path(tempfile.mkdtemp(prefix="setupcam-rtapi-"))
            os.chmod(self._fifo_dir, 0o777)
            env["RTAPI_FIFO_PATH"] = str(self._fifo_dir / "rtapi_fifo")
            t0 = time.monotonic()
            self.proc = subprocess.Popen(["linuxcnc", str(ini)], cwd=self.workdir, env=env,
                                         stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                                         stderr=subprocess.DEVNULL, start_new_session=True)
            self._wait_ready(t0 + timeout_s)
            self._child("prepare")
            self.startup_s = time.monotonic() - t0
        except BaseException:
            self.stop()
            raise
        return self

    def _wait_ready(self, deadline: float) -> None:
        port_open = task_up = False
        while time.monotonic() < deadline:
            if self.proc.poll() is not None:
                raise SimError(f"linuxcnc exited (rc={self.proc.returncode}) during start-up; "
                               f"see {Path.home() / 'linuxcnc_debug.txt'} and linuxcnc_print.txt")
            if not port_open:
                try:
                    socket.create_connection((self.host, self.port), timeout=1).close()
                    port_open = True
                except OSError:
                    pass
            if not task_up:  # probe in a throw-away child (the module poisons a process polled too early)
                task_up = subprocess.run([SYSTEM_PYTHON, str(CHILD), "ready"], capture_output=True).returncode == 0
            if port_open and task_up:
                return
            time.sleep(0.05)
        raise SimError("LinuxCNC did not come up in time")

    def _rsh_shutdown(self) -> None:
        """Ask linuxcncrsh to shut LinuxCNC down (a SIGTERM to the script would wait for the display)."""
        with socket.create_connection((self.host, self.port), timeout=5) as sock:
            sock.sendall(b"hello EMC sim-fixture 1.0\r\nset enable EMCTOO\r\nshutdown\r\n")
            sock.settimeout(5)
            try:
                while sock.recv(4096):
                    pass
            except OSError:
                pass

    def stop(self, timeout_s: float = 15.0) -> None:
        try:
            if self.proc is not None and self.proc.poll() is None:
                try:
                    self._rsh_shutdown()
                    self.proc.wait(timeout=timeout_s)
                except (OSError, subprocess.TimeoutExpired):
                    # the whole group: linuxcncrsh ends, the script's trap runs its Cleanup
                    os.killpg(self.proc.pid, signal.SIGTERM)
                    try:
                        self.proc.wait(timeout=timeout_s)
                    except subprocess.TimeoutExpired:
                        os.killpg(self.proc.pid, signal.SIGKILL)
                        self.proc.wait()
        finally:
            self.proc = None
            if self._fifo_dir is not None:
                shutil.rmtree(self._fifo_dir, ignore_errors=True)
                self._fifo_dir = None
            self._release_session_lock()

    def __enter__(self) -> "LinuxCncSim":
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()

    # -- independent access through the linuxcnc module ----------------------------------------
    def _child(self, *args: str, timeout_s: float = 90.0) -> dict | None:
        r = subprocess.run([SYSTEM_PYTHON, str(CHILD), *args], capture_output=True, text=True, timeout=timeout_s)
        if r.returncode != 0:
            raise SimError(f"lcnc_child {' '.join(args)} failed (rc={r.returncode}): {r.stderr.strip() or r.stdout.strip()}")
        out = r.stdout.strip().splitlines()
        return json.loads(out[-1]) if out else None

    def status(self) -> dict:
        """LinuxCNC's own status (active G5x, offsets, rotation, interpreter state, position)."""
        return self._child("status")

    def read_slot(self, slot: str) -> dict:
        """Activate ``slot`` by MDI, return LinuxCNC's status (``g5x_offset``, ``rotation_xy``), restore."""
        names = ["G54", "G55", "G56", "G57", "G58", "G59", "G59.1", "G59.2", "G59.3"]
        return self._child("read-slot", str(names.index(slot) + 1))

    def mdi(self, code: str) -> dict:
        """Run one MDI line through the linuxcnc module (waits until in position); returns status."""
        return self._child("mdi", code, timeout_s=40)

    def wait_idle(self, timeout_s: float = 180.0) -> dict:
        """Status once the interpreter is idle (a program ended or stopped); SimError after the timeout."""
        end = time.monotonic() + timeout_s
        while True:
            st = self.status()
            if st["interp_idle"]:
                return st
            if time.monotonic() > end:
                raise SimError(f"the program did not finish within {timeout_s:.0f} s")
            time.sleep(0.1)

    def run_program(self, text: str, name: str = "program.ngc") -> dict:
        """Write ``text`` into the config folder, start it in auto mode, return once it moves."""
        path = self.workdir / name
        path.write_text(text)
        os.chmod(path, 0o644)
        return self._child("run", str(path), timeout_s=120)

    def trace_program(self, text: str, name: str = "trace.ngc", timeout_s: float = 300.0) -> dict:
        """Run ``text`` to its end and sample LinuxCNC's own position (machine coordinates, mm) all the
        while: {"samples": [[x, y, z], ...], "error": controller error or None, "done": bool, ...}."""
        path = self.workdir / name
        path.write_text(text)
        os.chmod(path, 0o644)
        return self._child("trace", str(path), str(timeout_s), timeout_s=timeout_s + 60)


_SHARED: LinuxCncSim | None = None
#: whether the running test is marked ``linuxcnc`` (set per test by tests/conftest.py; True outside pytest)
CALLER_MARKED = True


def shared_sim(coordinates: str = "XYZ") -> LinuxCncSim:
    """The one sim of this test process, started on first use (fresh temp config folder) and
    stopped when the process exits. Every test package that needs LinuxCNC should use this, so two
    fixtures in one pytest run never try to start two instances (LinuxCNC allows one per computer).
    ``coordinates``: "XYZ" (the mill) or "XYZC" (a C rotary table, joint 3); asking for the other
    kind stops the running sim and starts a fresh one. Under pytest-xdist only tests marked ``linuxcnc``
    may call it (tests/conftest.py sends them all to one worker)."""
    global _SHARED
    if os.environ.get("PYTEST_XDIST_WORKER") and not CALLER_MARKED:
        # fail at once and every time, not only when the test lands on the other worker (after 180 s)
        raise SimError("this test uses the LinuxCNC sim but is not marked pytest.mark.linuxcnc: under "
                       "pytest-xdist all such tests must run in the one worker that holds the sim")
    if _SHARED is None or _SHARED.proc is None or _SHARED.proc.poll() is not None \
            or _SHARED.coordinates != coordinates:
        if _SHARED is not None:
            _SHARED.stop()
            shutil.rmtree(_SHARED.workdir, ignore_errors=True)
        sim = LinuxCncSim(Path(tempfile.mkdtemp(prefix="setupcam-lcnc-")), coordinates=coordinates)
        sim.start()
        if _SHARED is None:
            atexit.register(_stop_shared)
        _SHARED = sim
    return _SHARED


def _stop_shared() -> None:
    if _SHARED is not None:
        _SHARED.stop()
        shutil.rmtree(_SHARED.workdir, ignore_errors=True)


if __name__ == "__main__":  # manual check: python tests/machine/linuxcnc_sim.py
    why = skip_reason()
    if why:
        sys.exit(why)
    with LinuxCncSim(Path(tempfile.mkdtemp(prefix="lcnc-sim-")), coordinates=(sys.argv[1:] or ["XYZ"])[0]) as sim:
        print(f"up in {sim.startup_s:.2f} s on port {sim.port}:", sim.status())
