"""Which pose of a near-symmetric part is meant (app.vision.object_pose.datum) and which reading of
the same place wins (app.vision.object_pose.locate._clearer_reading)."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from app.geometry import parts
from app.geometry.model_edges import prepare_model
from app.geometry.transforms import make_pose
from app.vision.object_pose.datum import choose_datum
from app.vision.object_pose.locate import Fit, _clearer_reading
from app.vision.object_pose.verify import pose_distance


@pytest.fixture(scope="module")
def flange():
    """80 x 80 x 20 mm plate, four-fold near-symmetric: only a 4 mm pin hole breaks it."""
    return prepare_model(parts.flange_plate_80())


def _rz(deg: float) -> np.ndarray:
    a = np.radians(deg)
    return np.array([[np.cos(a), -np.sin(a), 0.0], [np.sin(a), np.cos(a), 0.0], [0.0, 0.0, 1.0]])


def _upright(rz_deg: float) -> np.ndarray:
    return make_pose(_rz(rz_deg), (400.0, 200.0, 25.0))


def _upside_down(rz_deg: float) -> np.ndarray:
    """Turned over about x: its bottom face up, resting on its top face at the same height."""
    flip = np.diag([1.0, -1.0, -1.0])
    return make_pose(_rz(rz_deg) @ flip, (400.0, 200.0, 45.0))


def _listed(datum, T) -> bool:
    return any(max(pose_distance(U, T, np.zeros(3))) < 0.1 for U in datum.equivalent)


def test_an_open_flip_is_listed_with_every_undecided_turn(flange):
    near_z = [s for s in flange.symmetries if not s.exact and abs(s.axis_obj[2]) > 0.99]
    assert sorted(round(s.angle_deg) for s in near_z) == [90, 180, 270]
    T = _upside_down(15.0)
    flip = SimpleNamespace(T=_upright(15.0), score=0.80)
    d = choose_datum(flange, T, 0.92, [(s, 0.92) for s in near_z], [flip, flip], [flip, flip], 0.80, 0.1)
    assert d.ambiguous
    # the truth may be the plate right side up turned by 90 deg: it must be among the choices
    for turn in (0.0, 90.0, 180.0, 270.0):
        assert _listed(d, flip.T @ make_pose(_rz(turn), (0.0, 0.0, 0.0)))
    for turn in (90.0, 180.0, 270.0):
        assert _listed(d, T @ make_pose(_rz(turn), (0.0, 0.0, 0.0)))
    assert not _listed(d, T)                    # the located pose itself is not an alternative
    assert len(d.equivalent) == 7               # 3 turns of the located pose, 4 of the flip, none twice


def test_a_decided_flip_is_named_as_decided(flange):
    d = choose_datum(flange, _upright(0.0), 0.81, [], [SimpleNamespace(T=_upside_down(0.0), score=0.91)], [],
                     0.91, 0.1)
    assert not d.ambiguous and d.equivalent == ()
    assert "unexplained" in d.note and "the face up is decided" in d.note


def _fit(T, score, support_px, state=0) -> Fit:
    return Fit(state=state, T=T, info={"sol": object()}, score=score, es=None, sup=None, support_px=support_px)


def _ctx(model, unexplained: dict):
    return SimpleNamespace(model=model, opts=SimpleNamespace(min_score=0.5),
                           unexplained=lambda T: unexplained[np.asarray(T).tobytes()])


def test_the_reading_that_explains_more_of_the_image_wins_over_a_higher_share(flange):
    # generator synth_016: upside down 92 % of its edges, 1134 px, 33 % of the image inside its
    # outline unexplained; right side up 80 %, 1373 px, 9 % unexplained
    down, up = _fit(_upside_down(15.0), 0.92, 1134.0, 1), _fit(_upright(15.0), 0.80, 1373.0)
    far = _fit(make_pose(_rz(15.0), (600.0, 50.0, 0.0)), 0.85, 2000.0)
    u = {down.T.tobytes(): 0.33, up.T.tobytes(): 0.087, far.T.tobytes(): 0.0}
    assert _clearer_reading(_ctx(flange, u), down, [down, up, far]) is up
    # explaining less edge length, the clearer reading does not win on its share of unexplained alone
    less = _fit(_upright(15.0), 0.80, 1000.0)
    u[less.T.tobytes()] = 0.087
    assert _clearer_reading(_ctx(flange, u), down, [down, less, far]) is down
    # nor does it when it leaves about as much unexplained
    u[up.T.tobytes()] = 0.25
    assert _clearer_reading(_ctx(flange, u), down, [down, up, far]) is down
