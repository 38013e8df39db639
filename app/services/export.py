"""Export a confirmed work offset to the machine's controller: gate, write, read back, audit, events.

Order (DESIGN safety rules): confirmed revision -> plausibility (offset computable, tilt, uncertainty,
travel limits) -> current offset read -> change limit (or acknowledgement) -> write -> read back ->
compare within the controller's rounding. Every attempt is in the append-only audit log; a retried
export of the same revision to the same slot is answered from the first one, never written twice.
"""

from __future__ import annotations

import logging

from sqlalchemy.exc import IntegrityError
from sqlmodel import Session, select

from app.machine import ControllerError, WorkOffset, make_controller, slot_number
from app.services.errors import Conflict, Invalid, Unavailable
from app.services.machines import get_machine
from app.services.setups import get_setup
from app.store.models import AuditEntry, Export, utcnow

log = logging.getLogger(__name__)


def audit(session: Session, actor: str, action: str, *, setup_id: int | None = None,
          machine_id: int | None = None, **detail) -> None:
    session.add(AuditEntry(actor=actor, action=action, setup_id=setup_id, machine_id=machine_id, detail=detail))
    session.flush()


def require_confirmed(setup, use: str = "exported") -> None:
    """Conflict (with a reason code) unless the setup is located and its current revision confirmed."""
    if setup.status != "located":
        raise Conflict(f"setup {setup.id} is {setup.status}; only a located and confirmed setup can be {use}",
                       code="not_located")
    if setup.confirmed_revision is None:
        raise Conflict(f"setup {setup.id} is not confirmed; an operator must confirm result revision "
                       f"{setup.result_revision} before it can be {use}", code="not_confirmed")
    if setup.confirmed_revision != setup.result_revision:
        raise Conflict(f"setup {setup.id} was changed after confirmation (confirmed revision "
                       f"{setup.confirmed_revision}, current {setup.result_revision}); confirm again",
                       code="changed_after_confirmation")


def plausibility_reasons(setup, machine) -> list[tuple[str, str]]:
    """Every (reason code, sentence) why the setup's offset must not be used; empty when it may.
    Codes: no_workpiece, tilt (the offset is not usable, e.g. tilted beyond the tolerance),
    uncertainty_fail, outside_travel."""
    result = setup.result or {}
    off = result.get("offset")
    if not off:
        return [("no_workpiece", f"setup {setup.id} has no workpiece offset (no workpiece located)")]
    reasons = []
    if not off.get("ok", False):
        reasons.append(("tilt", off.get("reason") or "offset not usable"))
    wp = next((o for o in result.get("objects", []) if o.get("name") == off.get("object")), None)
    if wp is not None and not wp.get("uncertainty_pass", False):
        reasons.append(("uncertainty_fail", f"uncertainty too large ({wp.get('uncertainty_reason') or 'unknown'}); "
                        "take another image with more of the part visible, or probe it"))
    for axis in ("x", "y", "z"):
        v = off[f"{axis}_mm"]
        lo, hi = machine.travel_mm[axis]
        if not lo <= v <= hi:
            reasons.append(("outside_travel", f"{axis.upper()} {v:.3f} mm is outside the machine's travel [{lo}, {hi}] mm"))
    return reasons


def plausibility(setup, machine, settings, use: str = "export") -> tuple[WorkOffset, dict]:
    """The offset to write, or Invalid with every reason it must not be used (code: the first reason's)."""
    reasons = plausibility_reasons(setup, machine)
    if reasons:
        raise Invalid(f"{use} refused: " + "; ".join(r for _, r in reasons), code=reasons[0][0])
    off = setup.result["offset"]
    return WorkOffset(off["x_mm"], off["y_mm"], off["z_mm"], off["c_deg"]), off


def export_offset(session: Session, settings, events, setup_id: int, *, slot: str, actor: str,
                  acknowledge_change: bool = False) -> Export:
    setup = get_setup(session, setup_id)
    slot = slot.strip().upper()
    try:
        slot_number(slot)
    except ValueError as exc:
        raise Invalid(str(exc)) from None
    require_confirmed(setup)
    done = session.exec(select(Export).where(Export.setup_id == setup_id, Export.slot == slot,
                                            Export.result_revision == setup.result_revision)).first()
    if done is not None and done.status in ("verified", "writing"):
        return done  # a retry: answered from the first export, never written twice
    machine = get_machine(session, setup.machine_id)
    if not machine.controller:
        raise Invalid(f"machine {machine.id} ({machine.name}) has no controller configured")
    offset, off = plausibility(setup, machine, settings)
    try:
        controller = make_controller(machine.controller)
    except ValueError as exc:
        raise Invalid(f"machine {machine.id} controller settings: {exc}") from None
    try:
        try:
            before = controller.read_offset(slot)
        except ControllerError as exc:
            audit(session, actor, "export.unreachable", setup_id=setup_id, machine_id=machine.id, slot=slot,
                  reason=str(exc))
            session.commit()
            events.publish("offset.export_failed", {"setup_id": setup_id, "slot": slot, "reason": str(exc)})
            raise Unavailable(f"{exc}; nothing was written") from None
        d_mm, d_deg = offset.difference(before)
        if (d_mm > settings.max_offset_change_mm or d_deg > settings.max_offset_change_deg) and not acknowledge_change:
            raise Conflict(f"the new {slot} differs from the controller's current one by {d_mm:.3f} mm / "
                           f"{d_deg:.3f}° (limits {settings.max_offset_change_mm} mm / "
                           f"{settings.max_offset_change_deg}°); compare them and export again with "
                           "acknowledge_change=true if this is intended")
        row = done or Export(setup_id=setup_id, result_revision=setup.result_revision, slot=slot, actor=actor,
                             status="writing")
        row.status, row.written, row.before, row.actor = "writing", offset.as_dict(), before.as_dict(), actor
        session.add(row)
        try:
            session.flush()
        except IntegrityError:
            session.rollback()
            raise Conflict(f"an export of setup {setup_id} to {slot} is already under way") from None
        audit(session, actor, "export.write", setup_id=setup_id, machine_id=machine.id, slot=slot,
              before=before.as_dict(), written=offset.as_dict(), controller=controller.describe)
        session.commit()  # the attempt is on record before the controller is touched
        try:
            controller.write_offset(slot, offset)
            back = controller.read_offset(slot)
        except ControllerError as exc:
            row.status, row.reason, row.updated_at = "failed", str(exc), utcnow()
            session.add(row)
            audit(session, actor, "export.failed", setup_id=setup_id, machine_id=machine.id, slot=slot,
                  reason=str(exc))
            session.commit()
            log.error("export failed", extra={"setup_id": setup_id, "slot": slot, "reason": str(exc)})
            events.publish("offset.export_failed", {"setup_id": setup_id, "slot": slot, "reason": str(exc)})
            raise Unavailable(f"export to {slot} failed: {exc}") from None
        agree = offset.agrees_with(back, controller.rounding_mm, controller.rounding_deg)
        row.read_back, row.updated_at = back.as_dict(), utcnow()
        row.status = "verified" if agree else "mismatch"
        row.reason = "" if agree else (f"read-back {back} differs from written {offset} beyond the controller's "
                                       f"rounding ({controller.rounding_mm} mm, {controller.rounding_deg}°)")
        session.add(row)
        audit(session, actor, "export.verified" if agree else "export.mismatch", setup_id=setup_id,
              machine_id=machine.id, slot=slot, written=offset.as_dict(), read_back=back.as_dict())
        session.commit()
        if agree:
            events.publish("offset.exported", {"setup_id": setup_id, "machine_id": machine.id, "slot": slot,
                                               "written": offset.as_dict(), "read_back": back.as_dict()})
        else:
            log.error("export read-back mismatch", extra={"setup_id": setup_id, "reason": row.reason})
            events.publish("offset.export_failed", {"setup_id": setup_id, "slot": slot, "reason": row.reason})
        return row
    finally:
        controller.close()


def read_current_offset(session: Session, machine_id: int, slot: str) -> WorkOffset:
    """The controller's offset now (for the side-by-side comparison on the page)."""
    machine = get_machine(session, machine_id)
    try:
        slot_number(slot)
    except ValueError as exc:
        raise Invalid(str(exc)) from None
    if not machine.controller:
        raise Invalid(f"machine {machine.id} ({machine.name}) has no controller configured")
    controller = make_controller(machine.controller)
    try:
        return controller.read_offset(slot)
    except ControllerError as exc:
        raise Unavailable(str(exc)) from None
    finally:
        controller.close()
