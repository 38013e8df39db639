"""LinuxCNC over the network through ``linuxcncrsh`` (text protocol on TCP, default port 5007).

Write: ``set mdi G10 L2 P<n> X Y Z R`` in MDI mode. Read: LinuxCNC keeps slot ``n`` in the numbered
parameters ``5201 + 20 n`` + (X 0, Y 1, Z 2, R 9), e.g. G54 = #5221 #5222 #5223 #5230; the adapter
prints them with an MDI ``(DEBUG, ...)`` message and fetches it with ``get operator_display``
(linuxcncrsh has no getter for parameters or the G5x rotation). Position: the current position
#5420-#5422 through the G92 and G5x offsets (see read_position). LinuxCNC's R rotates the G5x system
counter-clockwise seen from +Z about its origin: ``p_machine = Rz(R) p_program + (X, Y, Z)``, so R is
our C unchanged (checked against a real sim in tests/machine/test_linuxcnc.py).

Safety: the adapter never resets an e-stop, powers, homes or moves the machine. It refuses to write
while a program runs or is paused, when the controller is not in mm, and reports LinuxCNC's own
error text ("Can't issue MDI command when not homed"). One TCP session per call.
"""

from __future__ import annotations

import math
import secrets
import socket

from app.machine.base import ControllerError, MachinePosition, WorkOffset, slot_number

#: decimals written into G10 (what LinuxCNC keeps in its parameter file across restarts)
WRITE_DECIMALS = 6


def _param_numbers(p: int) -> tuple[int, int, int, int]:
    base = 5201 + 20 * p
    return base, base + 1, base + 2, base + 9


class LinuxCncController:
    """Controller adapter for LinuxCNC reached through ``linuxcncrsh``."""

    rounding_mm = 10.0 ** -WRITE_DECIMALS
    rounding_deg = 10.0 ** -WRITE_DECIMALS

    def __init__(self, host: str = "127.0.0.1", port: int = 5007, *, connect_password: str = "EMC",
                 enable_password: str = "EMCTOO", timeout_s: float = 5.0):
        self.host, self.port = host, int(port)
        self.connect_password, self.enable_password = connect_password, enable_password
        self.timeout_s = float(timeout_s)
        self.describe = f"LinuxCNC at {host}:{self.port}"
        self._closed = False

    # -- protocol ----------------------------------------------------------------------------------
    def _fail(self, what: str) -> ControllerError:
        return ControllerError(f"{self.describe}: {what}")

    def _session(self) -> "_RshSession":
        if self._closed:
            raise self._fail("adapter already closed")
        try:
            sock = socket.create_connection((self.host, self.port), timeout=self.timeout_s)
        except ConnectionRefusedError:
            raise self._fail("connection refused (is LinuxCNC running with DISPLAY = linuxcncrsh?)") from None
        except socket.timeout:
            raise self._fail(f"no connection within {self.timeout_s:g} s") from None
        except OSError as exc:
            raise self._fail(f"cannot connect ({exc.strerror or exc})") from None
        s = _RshSession(sock, self)
        try:
            reply = s.ask(f"hello {self.connect_password} setupcam 1.0")
            if not reply.startswith("HELLO ACK"):
                raise self._fail(f"hello refused ({reply}); check the connect password")
            s.ask("set echo off")  # still echoed once
            s.set("verbose on")
            s.set(f"enable {self.enable_password}", what="enable refused (check the enable password)")
        except BaseException:
            s.close()
            raise
        return s

    def _prepare_mdi(self, s: "_RshSession", purpose: str) -> str:
        """Check the machine can take MDI without disturbing anything; returns the previous mode."""
        if s.get("estop") != "ESTOP OFF":
            raise self._fail(f"emergency stop is active; cannot {purpose}")
        if s.get("machine") != "MACHINE ON":
            raise self._fail(f"machine is off; cannot {purpose}")
        status = s.get("program_status")
        if status != "PROGRAM_STATUS IDLE":
            state = status.split()[-1].lower() if status else "busy"
            raise self._fail(f"a program is {state}; the work offset is not touched while a program runs "
                             f"(cannot {purpose})")
        units = s.get("program_linear_units")
        if units.split()[-1:] != ["MM"]:
            raise self._fail(f"program units are {units.split()[-1].lower()} (G20?), this adapter works in mm: "
                             f"switch the controller to G21 to {purpose}")
        mode = s.get("mode").split()[-1].lower()
        if mode != "mdi":
            s.set("mode mdi")
        return mode

    def _mdi(self, s: "_RshSession", code: str) -> None:
        s.set(f"mdi {code}")
        if s.ask("set wait done") != "SET WAIT ACK":
            raise self._fail(f"'{code}' was refused: {s.last_error()}")

    def _restore_mode(self, s: "_RshSession", mode: str) -> None:
        if mode in ("manual", "auto"):
            try:
                s.set(f"mode {mode}")
            except ControllerError:
                pass  # the offset work is done; a mode left in MDI is harmless

    # -- Controller interface ---------------------------------------------------------------------
    def write_offset(self, slot: str, offset: WorkOffset) -> None:
        p = slot_number(slot)
        words = " ".join(f"{k}{round(v, WRITE_DECIMALS):.{WRITE_DECIMALS}f}" for k, v in
                         zip("XYZR", (offset.x_mm, offset.y_mm, offset.z_mm, offset.c_deg)))
        code = f"G10 L2 P{p} {words}"
        s = self._session()
        try:
            mode = self._prepare_mdi(s, f"write {slot}")
            s.sent_write = code
            self._mdi(s, code)
            self._restore_mode(s, mode)
        finally:
            s.close()

    def _read_numbers(self, s: "_RshSession", params: list[str], what: str) -> list[float]:
        """Numbered parameters (e.g. ``#5221``) printed by an MDI ``(DEBUG, ...)`` message and fetched with
        ``get operator_display``: linuxcncrsh has no getter for them. The session must be in MDI."""
        token = f"setupcam-{secrets.token_hex(4)}"
        self._mdi(s, f"(DEBUG,{token} {' '.join(f'%.9f{p}' for p in params)})")
        reply = s.get("operator_display")
        fields = reply.split()
        if len(fields) != len(params) + 2 or fields[1] != token:
            raise self._fail(f"unexpected answer while reading {what}: {reply!r}")
        try:
            return [float(v) for v in fields[2:]]
        except ValueError:
            raise self._fail(f"unexpected numbers while reading {what}: {reply!r}") from None

    def read_offset(self, slot: str) -> WorkOffset:
        p = slot_number(slot)
        s = self._session()
        try:
            mode = self._prepare_mdi(s, f"read {slot}")
            x, y, z, r = self._read_numbers(s, [f"#{n}" for n in _param_numbers(p)], slot)
            self._restore_mode(s, mode)
        finally:
            s.close()
        return WorkOffset(x, y, z, r)

    def read_position(self) -> MachinePosition:
        """Where the tool tip is, in machine coordinates: LinuxCNC's current position in program
        coordinates (#5420-#5422, the tip) carried through the G92 offset, the active G5x rotation and
        origin (``p_machine = g5x + Rz(R) (p + g92)``, the interpreter's own order). ``get abs_act_pos``
        (``stat.actual_position``, the machine-mode DRO) minus that is the active tool length offset.
        Never moves the machine; needs it on, homed, idle and in mm like the offset reads."""
        s = self._session()
        try:
            mode = self._prepare_mdi(s, "read the position")
            active = int(round(self._read_numbers(s, ["#5220"], "the active coordinate system")[0]))
            if not 1 <= active <= 9:
                raise self._fail(f"unexpected active coordinate system #5220 = {active}")
            x, y, z, g92_on, gx, gy, gz, ox, oy, oz, r = self._read_numbers(
                s, ["#5420", "#5421", "#5422", "#5210", "#5211", "#5212", "#5213", *(f"#{n}" for n in _param_numbers(active))],
                "the position")
            actual = s.get("abs_act_pos")
            self._restore_mode(s, mode)
        finally:
            s.close()
        if g92_on:
            x, y, z = x + gx, y + gy, z + gz
        c, si = math.cos(math.radians(r)), math.sin(math.radians(r))
        tip = (ox + c * x - si * y, oy + si * x + c * y, oz + z)
        fields = actual.split()
        try:
            if fields[0] != "ABS_ACT_POS" or len(fields) < 4:
                raise ValueError
            spindle = [float(v) for v in fields[1:4]]  # program units = mm (checked), linuxcncrsh's default
        except (ValueError, IndexError):
            raise self._fail(f"unexpected answer while reading the position: {actual!r}") from None
        return MachinePosition(*tip, tuple(round(a - b, 6) for a, b in zip(spindle, tip)))

    def read_axis_deg(self, name: str) -> float:
        """Rotary axis ``name`` (A, B or C) in machine coordinates, degrees: ``get abs_act_pos`` answers
        the actual position of X Y Z A B C (``stat.actual_position``), with no work offset applied. Reads
        only (no MDI, no mode change), so it works while a program runs too."""
        i = {"A": 3, "B": 4, "C": 5}.get(name)
        if i is None:
            raise ValueError(f"rotary axis name must be A, B or C, got {name!r}")
        s = self._session()
        try:
            reply = s.get("abs_act_pos")
        finally:
            s.close()
        fields = reply.split()
        try:
            if fields[0] != "ABS_ACT_POS" or len(fields) < 7:
                raise ValueError
            angle = float(fields[1 + i])
        except (ValueError, IndexError):
            raise self._fail(f"unexpected answer while reading the {name} axis: {reply!r}") from None
        if not math.isfinite(angle):
            raise self._fail(f"the {name} axis reads {angle}")
        return angle

    def _one_command(self, command: str) -> None:
        s = self._session()
        try:
            s.set(command, what=f"{command} refused")
        finally:
            s.close()

    def pause(self) -> None:
        """Feed hold of the running program (``set pause``)."""
        self._one_command("pause")

    def stop(self) -> None:
        """Abort the running program or MDI (``set abort``)."""
        self._one_command("abort")

    def close(self) -> None:
        self._closed = True


class _RshSession:
    """One linuxcncrsh connection. Replies end in "\\r\\n" (get) or "\\n\\r" (set ACK/NAK)."""

    def __init__(self, sock: socket.socket, owner: LinuxCncController):
        self.sock, self.owner = sock, owner
        self.buf = b""
        self.sent_write = ""  # the G10 sent in this session, for "may or may not be written" messages

    def _lost(self, exc: BaseException) -> ControllerError:
        what = "connection lost" if not isinstance(exc, socket.timeout) else \
            f"no answer within {self.owner.timeout_s:g} s"
        if self.sent_write:
            return self.owner._fail(f"{what} after sending '{self.sent_write}'; the offset may or may not "
                                    "have changed: read it back before trusting it")
        return self.owner._fail(what)

    def _line(self) -> str:
        while True:
            while b"\n" not in self.buf:
                try:
                    chunk = self.sock.recv(4096)
                except OSError as exc:
                    raise self._lost(exc) from None
                if not chunk:
                    raise self._lost(ConnectionResetError())
                self.buf += chunk
            raw, self.buf = self.buf.split(b"\n", 1)
            text = raw.decode("utf-8", "replace").strip("\r\n ")
            if text:
                return text

    def ask(self, text: str) -> str:
        try:
            self.sock.sendall((text + "\r\n").encode())
        except OSError as exc:
            raise self._lost(exc) from None
        return self._line()

    def get(self, what: str) -> str:
        return self.ask(f"get {what}")

    def set(self, command: str, *, what: str | None = None) -> str:
        """``set <command>`` (verbose on: answers ``SET <WORD> ACK`` or ``NAK``)."""
        reply = self.ask(f"set {command}")
        if not reply.endswith(" ACK"):
            detail = self.last_error() if reply.endswith(" NAK") else reply
            raise self.owner._fail(f"{what or f'set {command.split()[0]} refused'}: {detail}")
        return reply

    def last_error(self) -> str:
        reply = self.get("error")
        return reply[len("ERROR "):] if reply.startswith("ERROR ") else reply

    def close(self) -> None:
        try:
            self.sock.sendall(b"quit\r\n")
        except OSError:
            pass
        self.sock.close()
