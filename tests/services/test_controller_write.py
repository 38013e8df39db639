"""The one guarded controller write, against a fake controller: order of the steps, audit before the
write, read-back decides, a broken-off write is read back, refusals write nothing."""

from __future__ import annotations

import pytest
from sqlmodel import Session, select

from app.machine import ControllerError, WorkOffset
from app.services.controller_write import check_slot, guarded_write, travel_reasons, verify
from app.services.errors import Invalid, Unavailable
from app.store.db import make_engine, migrate
from app.store.models import AuditEntry
from tests.support.fake_controller import FakeController


@pytest.fixture
def session(tmp_path):
    engine = make_engine(f"sqlite:///{tmp_path / 'w.db'}")
    migrate(engine)
    with Session(engine) as s:
        yield s


def _actions(session) -> list[str]:
    return [e.action for e in session.exec(select(AuditEntry).order_by(AuditEntry.id)).all()]


NEW = WorkOffset(10, 20, -30, 5)


def _write(session, ctl, target=lambda before, empty: NEW, writing=None):
    seen = []
    verdict = guarded_write(session, ctl, slot="G55", actor="tester", action="t", ids={"machine_id": None},
                            target=target, unreachable=lambda exc: seen.append(str(exc)), writing=writing)
    return verdict, seen


def test_write_is_audited_before_the_controller_is_touched_and_read_back(session):
    ctl = FakeController({"G55": WorkOffset(0, 0, 0, 0)})
    audited_at_write = []
    orig = ctl.write_offset
    ctl.write_offset = lambda slot, off: (audited_at_write.append(_actions(session)), orig(slot, off))
    verdict, _ = _write(session, ctl)
    assert verdict.status == "written" and verdict.read_back == NEW and verdict.reason == ""
    assert ctl.journal == ["read G55", "write G55", "read G55"] and audited_at_write == [["t.write"]]
    entry = session.exec(select(AuditEntry)).one()
    assert entry.detail["before"] == WorkOffset(0, 0, 0, 0).as_dict() and entry.detail["written"] == NEW.as_dict()


def test_read_back_that_differs_is_a_failed_write(session):
    verdict, _ = _write(session, FakeController({"G55": WorkOffset(0, 0, 0)}, drift_mm=0.01))
    assert verdict.status == "failed" and verdict.differs and "G55 holds" in verdict.reason


def test_write_that_broke_off_is_read_back(session):
    arrived, _ = _write(session, FakeController({"G55": WorkOffset(0, 0, 0)},
                                                fail={"write": ControllerError("link lost")}))
    assert arrived.status == "written" and str(arrived.error) == "link lost"
    ctl = FakeController({"G55": WorkOffset(0, 0, 0)}, fail={"write": ControllerError("link lost")})
    ctl.write_offset = lambda slot, off: (_ for _ in ()).throw(ControllerError("refused: program running"))
    lost, _ = _write(session, ctl)
    assert lost.status == "failed" and not lost.differs and lost.read_back == WorkOffset(0, 0, 0)


def test_unreachable_controller_writes_nothing_and_says_so(session):
    ctl = FakeController({"G55": WorkOffset(0, 0, 0)}, fail={"read": ControllerError("connection refused")})
    with pytest.raises(Unavailable, match="connection refused; nothing was written"):
        _write(session, ctl)
    assert "write G55" not in ctl.journal and _actions(session) == []


def test_refusing_target_writes_nothing_and_empty_slot_is_named(session):
    ctl = FakeController({})
    seen = []

    def target(before, empty):
        seen.append((before, empty))
        raise Invalid("no")

    with pytest.raises(Invalid):
        _write(session, ctl, target=target)
    assert seen == [(None, "fake controller holds no G55 yet")] and "write G55" not in ctl.journal
    assert _actions(session) == []


def test_verify_without_a_write_and_while_unreadable():
    assert verify(FakeController({"G54": NEW}), "G54", None).status == "failed"
    assert verify(FakeController({}), "G54", NEW).status == "failed"
    assert verify(FakeController(fail={"read": ControllerError("down")}), "G54", NEW).status == "unknown"


def test_slot_and_travel_checks():
    assert check_slot(" g59.1 ") == "G59.1"
    with pytest.raises(Invalid, match="use one of"):
        check_slot("G60")

    class M:
        travel_mm = {"x": [0, 100], "y": [0, 100], "z": [-50, 0]}

    assert travel_reasons(M, WorkOffset(50, 50, -10)) == []
    assert [r[:1] for r in travel_reasons(M, WorkOffset(150, 50, 10))] == ["X", "Z"]
    assert [r[:1] for r in travel_reasons(M, WorkOffset(150, 50, 10), "xy")] == ["X"]
