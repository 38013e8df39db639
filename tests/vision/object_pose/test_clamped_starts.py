"""Starts for a part held between located jaw faces (app.vision.object_pose.clamped_starts)."""

from __future__ import annotations

import numpy as np
import trimesh

from app.geometry.model_edges import prepare_model
from app.geometry.transforms import make_pose, transform_points
from app.vision.object_pose.clamped_starts import clamped_poses, jaw_openings
from app.vision.object_pose.clamping import fixture_faces
from app.vision.object_pose.search import searched_states
from app.vision.object_pose.uncertainty import hull_points


def _box(lo, hi) -> trimesh.Trimesh:
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    return trimesh.creation.box(hi - lo, transform=make_pose(None, 0.5 * (lo + hi)))


def _jaws(opening_mm: float, turn_deg: float = 0.0):
    """A fixed jaw (face at x = 0 facing +x) and a moving jaw ``opening_mm`` away facing it, 120 mm
    long and 70..110 mm high, the pair turned ``turn_deg`` about the table normal."""
    T = make_pose(trimesh.transformations.rotation_matrix(np.radians(turn_deg), [0, 0, 1])[:3, :3])
    fixed = fixture_faces(_box((-20.0, -60.0, 70.0), (0.0, 60.0, 110.0)), T, "vise_body")
    moving = fixture_faces(_box((opening_mm, -60.0, 70.0), (opening_mm + 30.0, 60.0, 110.0)), T, "vise_jaw")
    return fixed + moving


def test_only_faces_that_face_each_other_across_a_gap_are_an_opening():
    got = jaw_openings(_jaws(30.0), max_gap_mm=100.0)
    assert len(got) == 1
    a, b, gap = got[0]
    assert abs(gap - 30.0) < 1e-9
    assert float(a.n @ b.n) < -0.999
    assert jaw_openings(_jaws(30.0), max_gap_mm=20.0) == []              # wider than the part can be
    # two blocks side by side along the jaws (their faces facing each other do not overlap across)
    apart = fixture_faces(_box((-20.0, -60.0, 70.0), (0.0, 0.0, 110.0)), np.eye(4), "a") + \
        fixture_faces(_box((30.0, 10.0, 70.0), (60.0, 60.0, 110.0)), np.eye(4), "b")
    assert jaw_openings(apart, 100.0) == []


def test_a_block_between_turned_jaws_touches_both_and_turns_with_them():
    """A 30 x 50 x 20 block fits the 30 mm opening across its 30 mm side only: every pose offered
    touches both jaws, is turned as the jaws are, lies within their length and stands at a given height."""
    block = _box((0.0, 0.0, 0.0), (30.0, 50.0, 20.0))
    model = prepare_model(block, name="block")
    hull = hull_points(model)
    faces = _jaws(30.0, turn_deg=17.0)
    n = np.array([np.cos(np.radians(17.0)), np.sin(np.radians(17.0)), 0.0])
    u = np.array([-n[1], n[0], 0.0])
    poses = clamped_poses(model, hull, faces, [90.0, 200.0], searched_states(model), step_mm=5.0)
    assert poses, "no pose for a block that fits the opening"
    for st, h, T in poses:
        P = transform_points(T, hull)
        assert h == 90.0                                     # at 200 mm it would float above the jaws
        assert abs((P @ n).min() - 0.0) < 1e-6 and abs((P @ n).max() - 30.0) < 1e-6
        assert -60.0 - 1e-6 <= (P @ u).min() and (P @ u).max() <= 60.0 + 1e-6
        assert abs(P[:, 2].min() - 90.0) < 1e-6
    # too wide for the opening every way round: nothing
    wide = prepare_model(_box((0.0, 0.0, 0.0), (34.0, 50.0, 20.0)), name="wide")
    assert clamped_poses(wide, hull_points(wide), faces, [90.0], searched_states(wide), 5.0) == []


def test_the_ways_of_a_vise_are_no_opening_and_a_lone_fixed_jaw_still_holds():
    """Two 8 mm edges facing each other (the vise's ways) are a slot, not jaws. With the moving jaw
    not located, the fixed jaw alone gives the part's turn and place across it: every side of the
    block against it, and nothing from the ways or from a wall standing on the table."""
    ways = fixture_faces(_box((-60.0, -25.0, 62.0), (-40.0, 25.0, 70.0)), np.eye(4), "rail_a") + \
        fixture_faces(_box((-40.0, -60.0, 62.0), (40.0, -25.0, 70.0)), np.eye(4), "rail_b") + \
        fixture_faces(_box((-40.0, 25.0, 62.0), (40.0, 60.0, 70.0)), np.eye(4), "rail_c")
    assert jaw_openings(ways, 100.0) == []
    fixed = fixture_faces(_box((-20.0, -60.0, 70.0), (0.0, 60.0, 110.0)), np.eye(4), "vise_body")
    wall = fixture_faces(_box((-200.0, -60.0, 0.0), (-180.0, 60.0, 110.0)), np.eye(4), "wall")
    block = prepare_model(_box((0.0, 0.0, 0.0), (30.0, 50.0, 20.0)), name="block")
    hull = hull_points(block)
    poses = clamped_poses(block, hull, ways + fixed + wall, [90.0], searched_states(block), step_mm=5.0)
    widths = set()
    for _, _, T in poses:
        P = transform_points(T, hull)
        assert abs(P[:, 0].min() + 180.0) > 1e-6 and abs(P[:, 0].max() + 200.0) > 1e-6   # never against the wall
        assert abs(P[:, 2].min() - 90.0) < 1e-6
        if abs(P[:, 0].min()) < 1e-6:                    # in front of the fixed jaw's face x = 0
            widths.add(round(float(np.ptp(P[:, 0])), 3))
    assert {30.0, 50.0} <= widths                          # held across either side
