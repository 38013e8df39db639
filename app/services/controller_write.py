"""The one guarded write of a work offset to a controller (DESIGN safety rules).

Sequence, the same for a setup's export and a sheet's export or re-datum: check the slot (and, by the
caller's ``target``, the travel) -> read the slot's current offset -> the offset to write (refused by
raising) -> audit the write with before and new values, committed before the controller is touched ->
write -> read back -> compare within the controller's rounding -> the caller records the verdict (audit)
and publishes its event. A write that broke off is read back too: only the controller can tell whether
it arrived.

The callers keep their own words: the setup export settles its ``Export`` row (pending -> writing ->
written | failed | unknown) and audits ``export.*``; the sheet audits ``sheet.export.*`` /
``sheet.redatum.*`` and answers ``verified`` / ``mismatch`` / ``failed`` in its REST shapes.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Callable

from sqlmodel import Session

from app.machine import Controller, ControllerError, NoOffsetYet, WorkOffset, make_controller, slot_number
from app.services.audit import audit
from app.services.errors import Invalid, Unavailable

log = logging.getLogger(__name__)


def check_slot(slot: str) -> str:
    """The slot name normalised ("g54 " -> "G54"), or Invalid naming the slots there are."""
    slot = str(slot).strip().upper()
    try:
        slot_number(slot)
    except ValueError as exc:
        raise Invalid(str(exc), code="bad_slot") from None
    return slot


def open_controller(machine) -> Controller:
    """The machine's controller adapter, or Invalid when none is configured or its settings are wrong."""
    if not machine.controller:
        raise Invalid(f"machine {machine.id} ({machine.name}) has no controller configured", code="no_controller")
    try:
        return make_controller(machine.controller)
    except ValueError as exc:
        raise Invalid(f"machine {machine.id} controller settings: {exc}",
                      code="controller_settings_invalid") from None


def travel_reasons(machine, offset: WorkOffset, axes: str = "xyz") -> list[str]:
    """One sentence per axis of ``axes`` on which ``offset`` (machine coordinates, mm) lies outside the
    machine's travel; empty when it lies inside."""
    out = []
    for axis in axes:
        v = getattr(offset, f"{axis}_mm")
        lo, hi = machine.travel_mm[axis]
        if not lo <= v <= hi:
            out.append(f"{axis.upper()} {v:.3f} mm is outside the machine's travel [{lo}, {hi}] mm")
    return out


@dataclass(frozen=True)
class Verdict:
    """What the controller's slot holds after a write (or a write that broke off).

    ``status``: ``written`` (holds ``wanted`` within the controller's rounding), ``failed`` (holds
    something else, or nothing: not written) or ``unknown`` (it cannot be read: only a later read-back
    can tell). ``read_back`` is what it holds when it could be read; ``error`` is the write's own error
    when the write broke off.
    """

    status: str
    wanted: WorkOffset | None
    read_back: WorkOffset | None
    reason: str
    error: ControllerError | None = None

    @property
    def differs(self) -> bool:
        """Read back, and different from what was to be written (a mismatch, not a broken link)."""
        return self.status == "failed" and self.read_back is not None and self.error is None


def verify(controller: Controller, slot: str, wanted: WorkOffset | None,
           error: ControllerError | None = None) -> Verdict:
    """Read ``slot`` back and compare it with ``wanted`` (None: nothing was written yet)."""
    try:
        back = controller.read_offset(slot)
    except NoOffsetYet as exc:  # the controller answers and holds nothing there: nothing arrived
        return Verdict("failed", wanted, None, f"not written: {exc}", error)
    except ControllerError as exc:
        return Verdict("unknown", wanted, None, f"outcome unknown and the controller cannot be read ({exc}); "
                                                "it is read back again before any retry and at start-up", error)
    if wanted is None:
        return Verdict("failed", None, back, "not written: the export stopped before the write", error)
    if wanted.agrees_with(back, controller.rounding_mm, controller.rounding_deg):
        return Verdict("written", wanted, back, "", error)
    return Verdict("failed", wanted, back, f"not written: {slot} holds {back}, not {wanted}", error)


def guarded_write(session: Session, controller: Controller, *, slot: str, actor: str, action: str,
                  ids: dict, target: Callable[[WorkOffset | None, str], WorkOffset],
                  unreachable: Callable[[ControllerError], None],
                  writing: Callable[[WorkOffset | None, WorkOffset], None] | None = None) -> Verdict:
    """Read the current offset, take the one to write, audit, write, read back and compare.

    Parameters
    ----------
    slot : a checked slot name (:func:`check_slot`)
    action : audit prefix: the write is on record as ``{action}.write`` (with ``ids``, the slot, the
        offset before and the one written, the controller) and committed before the controller is touched
    target : the offset to write (machine coordinates, mm / degrees) from the current one and, when the
        controller holds none yet (None), the controller's sentence saying so; it refuses by raising
        (Invalid, Conflict: nothing written)
    unreachable : records that the current offset could not be read; Unavailable is raised after it
    writing : records the caller's own state just before the audit of the write (same transaction)

    Returns the :class:`Verdict`; the caller records it and publishes its event.
    """
    empty = ""
    try:
        before = controller.read_offset(slot)
    except NoOffsetYet as exc:
        before, empty = None, str(exc)
    except ControllerError as exc:
        unreachable(exc)
        raise Unavailable(f"{exc}; nothing was written", code="controller_unreachable") from None
    offset = target(before, empty)
    before_dict = before.as_dict() if before is not None else None
    if writing is not None:
        writing(before, offset)
    audit(session, actor, f"{action}.write", **ids, slot=slot, before=before_dict, written=offset.as_dict(),
          controller=controller.describe)
    session.commit()  # on record before the write: a crash from here on is reconciled by reading back
    try:
        controller.write_offset(slot, offset)
    except ControllerError as exc:
        log.error("offset write broke off", extra={"slot": slot, "action": action, "reason": str(exc)})
        return verify(controller, slot, offset, exc)  # did anything arrive?
    return verify(controller, slot, offset)
