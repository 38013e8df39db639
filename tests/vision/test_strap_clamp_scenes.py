"""A plate under two strap clamp sets in a scene of our generator (app.synth.fixtures, scene 47: a shop
scene, low lamp, spindle in view), located as the service locates a setup's named models."""

from __future__ import annotations

import re

import numpy as np
import pytest

from app.synth.fixtures import synth_entry, synth_scene
from app.vision.localize import Candidate, localize
from app.vision.pose_errors import pose_error_6dof

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def scene():
    sc, image = synth_scene(synth_entry(47))
    wp = Candidate(sc.workpiece["name"], sc.workpiece["mesh_obj"], kind="workpiece")
    clamps = [Candidate(o["name"], o["mesh_obj"], kind="clamp") for o in sc.gt["objects"]]
    return sc, image, wp, clamps


def _workpiece(res, name):
    return next((o for o in res.objects if o["name"] == name), None)


def test_without_its_clamps_the_plate_is_not_taken_for_a_plate_on_its_side(scene):
    """The clamps hide half the plate and put their own edges inside its outline: its true pose fits
    50 % of 1850 px of edges, while the plate on its side 301 mm away fits 61 % of 1420 px, leaving
    more of the image unexplained. That reading was returned with a 0.04-0.08 mm sigma in x and y
    (refused only by its 0.28 mm in z); now the part is refused as ambiguous."""
    sc, image, wp, _ = scene
    res = localize(image, sc.K, sc.dist, sc.layout, [wp] + sc.fixture_candidates, table_model=sc.table_candidate,
                   chain=True)
    assert _workpiece(res, wp.name) is None
    (why,) = [n for n in res.not_found if n["name"] == wp.name]
    assert why["kind"] == "ambiguous" and "explains" in why["reason"], why


def test_with_its_clamps_in_the_library_the_plate_and_the_clamps_are_located(scene):
    sc, image, wp, clamps = scene
    res = localize(image, sc.K, sc.dist, sc.layout, [wp] + sc.fixture_candidates + clamps,
                   table_model=sc.table_candidate, chain=True)
    obj = _workpiece(res, wp.name)
    assert obj is not None, [n["reason"] for n in res.not_found]
    err = pose_error_6dof(np.asarray(obj["T_table_obj"]), np.asarray(sc.workpiece["T_table_object"]), wp.prepare())
    assert np.linalg.norm(err[:3]) < 0.1 and np.nanmax(np.abs(err[3:])) < 0.1, err
    truth = {o["name"]: o for o in sc.gt["objects"]}
    located = [c for c in clamps if _workpiece(res, c.name) is not None]
    assert located, [n["reason"] for n in res.not_found]
    for c in located:
        e = pose_error_6dof(np.asarray(_workpiece(res, c.name)["T_table_obj"]),
                            np.asarray(truth[c.name]["T_table_object"]), c.prepare())
        assert np.linalg.norm(e[:3]) < 0.3 and np.nanmax(np.abs(e[3:])) < 0.1, (c.name, e)


def _part_refused(k: int) -> dict:
    """The part of our generator's scene ``k`` located with the scene's vise and parallels only (its
    clamps are not in the library): it must not be returned; its not-found entry."""
    sc, image = synth_scene(synth_entry(k))
    wp = Candidate(sc.workpiece["name"], sc.workpiece["mesh_obj"], kind="workpiece")
    res = localize(image, sc.K, sc.dist, sc.layout, [wp] + sc.fixture_candidates, table_model=sc.table_candidate,
                   chain=True)
    assert _workpiece(res, wp.name) is None
    (why,) = [n for n in res.not_found if n["name"] == wp.name]
    return why


def test_a_bracket_hidden_by_clamps_not_in_the_library_is_not_read_on_clutter():
    """Scene 42: a bracket under two strap clamp sets that are not in the library (its true pose fits
    38 % of its edges). Its best fit lay 420 mm away on clutter with a 4-9 mm sigma, 33-213 sigma off,
    leaving 86 % of the image's edges inside its outline unexplained: a part there would hide them."""
    why = _part_refused(42)
    assert why["kind"] == "not_found" and "unexplained" in why["reason"], why


def test_a_pin_block_whose_place_the_image_does_not_fix_is_not_located():
    """Scene 40: a 32 mm pin block under clamps that are not in the library. Its best fit stood 300 mm
    away on a clamp's heel block with a 31 mm sigma in x (0.3 deg in rotation, 68 deg off): not a
    place, and it was returned as one. Which refusal catches it depends on the render's last digits: on
    the libraries of 2026-11-29 (a fresh install) two poses fit it within 1 % and it is refused as
    ambiguous before its sigma is taken; on those of 2026-12-05 (a fresh install; the engine of the
    day before gives the same) its best fit supports 38 % of its edges and it is not found. The sigma
    rule itself is tested in test_place_not_fixed."""
    why = _part_refused(40)
    assert (why["kind"] == "not_found" and "does not fix its place" in why["reason"]) or \
        (why["kind"] == "ambiguous" and "two different poses fit almost equally well" in why["reason"]) or \
        (why["kind"] == "not_found" and re.search(r"supports only \d+% of its visible edges", why["reason"])), why
