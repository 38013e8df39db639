"""Export a confirmed work offset to the machine's controller: gate, write, read back, audit, events.

Order (DESIGN safety rules): confirmed revision -> plausibility (offset computable, tilt, uncertainty,
travel limits) -> current offset read -> change limit (or acknowledgement) -> write -> read back ->
compare within the controller's rounding. Every attempt is in the append-only audit log; a retried
export of the same revision to the same slot is answered from the first one, never written twice.
"""

from __future__ import annotations

import logging
import threading
from datetime import datetime, timezone

from sqlalchemy.exc import IntegrityError
from sqlmodel import Session, col, select

from app.geometry.work_offset import tilt_reason
from app.machine import ControllerError, NoOffsetYet, WorkOffset, make_controller
from app.services.audit import audit, audit_apart
from app.services.controller_write import (Verdict, check_slot, guarded_write, open_controller, travel_reasons,
                                           verify)
from app.services.errors import Conflict, Invalid, NotFound, Unavailable
from app.services.machines import Limit, get_machine, machine_limit
from app.services.setups import get_setup, setup_result
from app.store.db import session_scope
from app.store.models import Export, Setup, utcnow

log = logging.getLogger(__name__)


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


def plausibility_reasons(setup, machine, settings) -> list[tuple[str, str]]:
    """Every (reason code, sentence) why the setup's offset must not be used; empty when it may.
    Codes: no_workpiece, tilt (the offset is not usable, e.g. tilted beyond the tolerance),
    uncertainty_fail, rotary_axis_changed (a rotary table's axis or export angle changed since the offset
    was computed), outside_travel. The tilt is checked against the limit in force now (the machine's
    own or the global one), not the one of when the setup was located: an admin's change applies at once."""
    result = setup_result(setup)
    off = result.offset
    if not off:
        return [("no_workpiece", f"setup {setup.id} has no workpiece offset (no workpiece located)")]
    reasons = []
    if off.get("tilt_deg") is None:  # no tilt on record: the review's verdict is all there is
        if not off.get("ok", False):
            reasons.append(("tilt", off.get("reason") or "offset not usable"))
    else:
        limit = machine_limit(machine, settings, "max_tilt_deg")
        if off["tilt_deg"] > limit.value:
            reasons.append(("tilt", tilt_reason(off["tilt_deg"], off.get("a_deg", 0.0), off.get("b_deg", 0.0),
                                                limit.value, limit.source)))
    wp = result.workpiece()  # the offset is this workpiece's datum (proposed_offset)
    if wp is not None and not wp.uncertainty_pass:
        reasons.append(("uncertainty_fail", f"uncertainty too large ({wp.uncertainty_reason or 'unknown'}); "
                        "take another image with more of the part visible, or probe it"))
    axis = getattr(machine, "rotary_axis", None)
    if axis and (off.get("axis"), off.get("at_axis_deg")) != (axis["name"], float(axis["export_at_deg"])):
        was = f"{off['axis']} = {off['at_axis_deg']:g}°" if off.get("axis") else "a table that did not turn"
        why = (f"the offset was computed for {was}, but machine '{machine.name}' now expects offsets for "
               f"{axis['name']} = {axis['export_at_deg']:g}°; take the picture again")
        reasons.append(("rotary_axis_changed", why))
    at = WorkOffset(off["x_mm"], off["y_mm"], off["z_mm"], off["c_deg"])
    reasons += [("outside_travel", why) for why in travel_reasons(machine, at)]
    return reasons


def plausibility(setup, machine, settings, use: str = "export") -> tuple[WorkOffset, dict]:
    """The offset to write, or Invalid with every reason it must not be used (code: the first reason's)."""
    reasons = plausibility_reasons(setup, machine, settings)
    if reasons:
        raise Invalid(f"{use} refused: " + "; ".join(r for _, r in reasons), code=reasons[0][0])
    off = setup.result["offset"]
    return WorkOffset(off["x_mm"], off["y_mm"], off["z_mm"], off["c_deg"]), off


# Export states: pending (on record, controller untouched) -> writing (committed before the write) ->
# written (read back equal) | failed (not written: refused, unreachable, or read back different) |
# unknown (the write or its read-back broke off: only reading the controller can tell). pending,
# writing and unknown are settled by reading the slot back (reconcile), at start-up, before any retry,
# and when a "writing" export is older than WRITING_TIMEOUT_S.
OPEN_STATES = ("pending", "writing", "unknown")
WRITING_TIMEOUT_S = 60.0


def _age_s(row: Export) -> float:
    at = row.updated_at if row.updated_at.tzinfo else row.updated_at.replace(tzinfo=timezone.utc)
    return (datetime.now(timezone.utc) - at).total_seconds()


def _settle(session: Session, row: Export, status: str, reason: str, actor: str, machine_id: int | None,
            read_back: WorkOffset | None = None) -> Export:
    row.status, row.reason, row.updated_at = status, reason, utcnow()
    if read_back is not None:
        row.read_back = read_back.as_dict()
    session.add(row)
    audit(session, actor, f"export.{status}", setup_id=row.setup_id, machine_id=machine_id, slot=row.slot,
          export_id=row.id, written=row.written, read_back=row.read_back, reason=reason)
    session.commit()
    return row


def _settle_verdict(session: Session, row: Export, verdict: Verdict, actor: str, machine_id: int | None) -> Export:
    return _settle(session, row, verdict.status, verdict.reason, actor, machine_id, verdict.read_back)


def reconcile(session: Session, row: Export, controller, machine_id: int | None, actor: str = "reconcile") -> Export:
    """Settle an open export by reading the controller's slot: ``written`` when it holds what was to be
    written (within the controller's rounding), ``failed`` when it does not (or nothing was written yet),
    ``unknown`` while the controller cannot be read."""
    wanted = None
    if row.written:
        wanted = WorkOffset(row.written["x_mm"], row.written["y_mm"], row.written["z_mm"], row.written["c_deg"])
    return _settle_verdict(session, row, verify(controller, row.slot, wanted), actor, machine_id)


def reconcile_open_exports(ctx, stale_s: float = 0.0, actor: str = "reconcile at start-up") -> list[int]:
    """Settle every export left pending, writing or unknown for at least ``stale_s`` seconds: at
    start-up (0: all a previous run left) and by :class:`ExportWatch` (the timeout)."""
    settled = []
    with session_scope(ctx.engine) as session:
        rows = session.exec(select(Export).where(col(Export.status).in_(OPEN_STATES))).all()
        for row in rows:
            if _age_s(row) < stale_s:
                continue  # under way right now
            setup = session.get(Setup, row.setup_id)
            machine = get_machine(session, setup.machine_id) if setup else None
            if machine is None or not machine.controller:
                _settle(session, row, "failed", "not written: the machine or its controller is gone", "reconcile",
                        None)
                continue
            controller = make_controller(machine.controller)
            try:
                reconcile(session, row, controller, machine.id, actor)
            finally:
                controller.close()
            log.info("export reconciled", extra={"export_id": row.id, "status": row.status})
            settled.append(row.id)
    return settled


class ExportWatch:
    """A thread in the service: every ``interval_s`` it settles exports open for longer than
    WRITING_TIMEOUT_S (a request that hung, an unknown outcome) by reading the controllers back."""

    def __init__(self, ctx, interval_s: float = 30.0):
        self.ctx, self.interval_s = ctx, interval_s
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="export-watch", daemon=True)

    def start(self) -> "ExportWatch":
        self._thread.start()
        return self

    def _run(self) -> None:
        while not self._stop.wait(self.interval_s):
            try:
                reconcile_open_exports(self.ctx, stale_s=WRITING_TIMEOUT_S, actor="reconcile after timeout")
            except Exception:  # noqa: BLE001 - keep watching; the next round tries again
                log.exception("export watch: reconciliation failed")

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(timeout=5)


def export_offset(session: Session, settings, events, setup_id: int, *, slot: str, actor: str,
                  acknowledge_change: bool = False, idempotency_key: str | None = None) -> Export:
    """Write the confirmed offset (see the states above). A refusal before any row exists (not confirmed,
    implausible, bad slot) is audited as ``export.refused`` in a transaction of its own."""
    try:
        return _export(session, settings, events, setup_id, slot=slot, actor=actor,
                       acknowledge_change=acknowledge_change, idempotency_key=idempotency_key)
    except (Invalid, Conflict) as exc:
        if not getattr(exc, "audited", False):
            audit_apart(session.get_bind(), actor, "export.refused", setup_id=setup_id, slot=slot[:20],
                        reason=exc.detail[:1000])
        raise


def _export(session: Session, settings, events, setup_id: int, *, slot: str, actor: str,
            acknowledge_change: bool, idempotency_key: str | None) -> Export:
    setup = get_setup(session, setup_id)
    slot = check_slot(slot)
    require_confirmed(setup)
    key = (idempotency_key or "").strip()[:100] or f"setup{setup_id}-r{setup.result_revision}-{slot}"
    done = session.exec(select(Export).where(Export.setup_id == setup_id, Export.slot == slot,
                                            Export.result_revision == setup.result_revision)).first()
    same_key = session.exec(select(Export).where(Export.idempotency_key == key)).first()
    if same_key is not None and (done is None or same_key.id != done.id):
        raise Conflict(f"idempotency key {key!r} belongs to export {same_key.id} (setup {same_key.setup_id}, "
                       f"{same_key.slot}, revision {same_key.result_revision}), not to this one", code="idempotency_key_taken")
    if done is not None and done.status == "written":
        return done  # a retry: answered from the first export, never written twice
    if done is not None and done.status in ("pending", "writing") and _age_s(done) < WRITING_TIMEOUT_S:
        return done  # under way right now
    machine = get_machine(session, setup.machine_id)
    if not machine.controller:
        raise Invalid(f"machine {machine.id} ({machine.name}) has no controller configured", code="no_controller")
    offset, off = plausibility(setup, machine, settings)
    controller = open_controller(machine)
    try:
        if done is not None and done.status in OPEN_STATES:
            # after a crash, a timeout or an unknown outcome: read back before writing anything again
            reconcile(session, done, controller, machine.id, actor)
            if done.status == "written":
                return done
            if done.status == "unknown":
                raise Unavailable(f"export to {slot}: {done.reason}", code="export_outcome_unknown")
        row = done or Export(setup_id=setup_id, result_revision=setup.result_revision, slot=slot, actor=actor,
                             status="pending")
        row.status, row.actor, row.reason, row.idempotency_key = "pending", actor, "", key
        row.written = row.read_back = None
        row.updated_at = utcnow()
        session.add(row)
        try:
            session.flush()
        except IntegrityError:
            session.rollback()
            raise Conflict(f"an export of setup {setup_id} to {slot} is already under way",
                               code="export_under_way") from None
        audit(session, actor, "export.attempt", setup_id=setup_id, machine_id=machine.id, slot=slot,
              export_id=row.id, idempotency_key=key)
        session.commit()  # the attempt is on record before the controller is touched
        ids = {"setup_id": setup_id, "machine_id": machine.id}

        def unreachable(exc: ControllerError) -> None:
            _settle(session, row, "failed", f"controller unreachable ({exc}); nothing was written", actor, machine.id)
            events.publish("offset.export_failed", {"setup_id": setup_id, "slot": slot, "reason": str(exc)})

        def target(before: WorkOffset | None, empty: str) -> WorkOffset:
            why = change_reason(offset, before, empty, slot, machine_limit(machine, settings, "max_offset_change_mm"),
                                machine_limit(machine, settings, "max_offset_change_deg"))
            if why and not acknowledge_change:
                row.before = before.as_dict() if before is not None else None
                _settle(session, row, "failed", f"refused, nothing written: {why}", actor, machine.id)
                refused = Conflict(why, code="change_needs_acknowledgement" if before is not None
                                   else "first_export_needs_acknowledgement")
                refused.audited = True  # the row and its export.failed entry say it already
                raise refused
            return offset

        def writing(before: WorkOffset | None, new: WorkOffset) -> None:
            row.status, row.written, row.updated_at = "writing", new.as_dict(), utcnow()
            row.before = before.as_dict() if before is not None else None
            session.add(row)

        verdict = guarded_write(session, controller, slot=slot, actor=actor, action="export", ids=ids,
                                target=target, unreachable=unreachable, writing=writing)
        _settle_verdict(session, row, verdict, actor, machine.id)
        if verdict.error is not None:  # the write broke off; the read-back said whether it arrived
            if row.status == "failed":
                row.reason = f"export to {slot} failed: {verdict.error}; {row.reason}"
                session.add(row)
                session.commit()
            events.publish("offset.export_failed", {"setup_id": setup_id, "slot": slot, "reason": row.reason})
            if row.status != "written":
                raise Unavailable(f"export to {slot} {'failed' if row.status == 'failed' else 'broke off'}: "
                                  f"{verdict.error}; status {row.status}: {row.reason}",
                                  code="export_failed" if row.status == "failed" else "export_outcome_unknown")
            return row
        if row.status == "written":
            events.publish("offset.exported", {"setup_id": setup_id, "machine_id": machine.id, "slot": slot,
                                               "written": row.written, "read_back": row.read_back})
        else:
            log.error("export not confirmed by read-back", extra={"setup_id": setup_id, "reason": row.reason})
            events.publish("offset.export_failed", {"setup_id": setup_id, "slot": slot, "reason": row.reason})
            if row.status == "unknown":
                raise Unavailable(f"export to {slot}: {row.reason}", code="export_outcome_unknown")
        return row
    finally:
        controller.close()


def change_reason(offset: WorkOffset, before: WorkOffset | None, empty: str, slot: str, max_mm: Limit,
                  max_deg: Limit) -> str:
    """Why writing ``offset`` over ``before`` needs the operator's acknowledgement ("" when it does not):
    the slot holds nothing yet (``empty``: the controller's sentence), or the change exceeds ``max_mm``
    (X/Y/Z) or ``max_deg`` (C), each the machine's own limit or the global one (the sentence names which)."""
    if before is None:
        # nothing to show side by side: the first write to a slot is acknowledged like a large change
        return (f"{empty}, so there is no current {slot} to compare the change with; check the new values "
                "and export again with acknowledge_change=true")
    d_mm, d_deg = offset.difference(before)
    over = [f"{d:.3f}{unit} is more than the {lim.value:g}{unit} allowed by {lim.source}"
            for d, lim, unit in ((d_mm, max_mm, " mm"), (d_deg, max_deg, "°")) if d > lim.value]
    if over:
        return (f"the new {slot} differs from the controller's current one by {d_mm:.3f} mm / {d_deg:.3f}° "
                f"({'; '.join(over)}); compare them and export again with acknowledge_change=true if this "
                "is intended")
    return ""


def list_exports(session: Session, setup_id: int) -> list[Export]:
    """Every export of a setup, oldest first (NotFound for an unknown setup)."""
    get_setup(session, setup_id)
    return list(session.exec(select(Export).where(Export.setup_id == setup_id).order_by(Export.id)).all())


def read_current_offset(session: Session, machine_id: int, slot: str) -> WorkOffset:
    """The controller's offset now (for the side-by-side comparison on the page)."""
    machine = get_machine(session, machine_id)
    slot = check_slot(slot)
    controller = open_controller(machine)
    try:
        return controller.read_offset(slot)
    except NoOffsetYet as exc:
        raise NotFound(f"{exc}; the first export will write it", code="slot_empty") from None
    except ControllerError as exc:
        raise Unavailable(str(exc), code="controller_unreachable") from None
    finally:
        controller.close()
