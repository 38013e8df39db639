"""Stances a part is searched in: the stable ones, and always its CAD z up and down."""

from __future__ import annotations

import numpy as np
import trimesh

from app.geometry.model_edges import prepare_model


def _tall_plate() -> trimesh.Trimesh:
    """A plate modelled standing on its narrow edge (CAD z up = 120 mm tall, 8 mm thick): a random
    drop almost never ends upright, but that is how it is clamped."""
    return trimesh.creation.box(bounds=[[0, 0, 0], [100, 8, 120]])


def test_cad_upright_and_upside_down_stances_are_always_there():
    m = prepare_model(_tall_plate(), "plate")
    tags = [s.cad_axis for s in m.resting_states]
    assert "+z" in tags and "-z" in tags
    up = m.resting_states[tags.index("+z")]
    # standing upright: the CAD z axis is the table normal and the lowest point is on the table
    np.testing.assert_allclose(up.T_rest_obj[:3, :3] @ [0, 0, 1.0], [0, 0, 1.0], atol=1e-9)
    V = (up.T_rest_obj[:3, :3] @ m.mesh.vertices.T).T + up.T_rest_obj[:3, 3]
    assert abs(V[:, 2].min()) < 1e-9 and abs(up.height_mm - 120.0) < 1e-6


def test_fixtures_stand_only_as_modelled():
    m = prepare_model(_tall_plate(), "parallel", upright_only=True)
    assert len(m.resting_states) == 1 and m.resting_states[0].cad_axis == "+z"


def _clamp_set(stud_depth_mm: float = 16.0, tongue: bool = False) -> trimesh.Trimesh:
    """A strap clamp set as the devset models it: heel block (32 x 46 mm) on the table, strap (120 x 40 mm)
    at 30 mm, and its stud (12 mm) reaching ``stud_depth_mm`` down into the T-slot; with ``tongue``,
    a 15 x 60 mm key under the heel instead of the stud (it rides on a rail's face, as a vise jaw's does)."""
    heel = trimesh.creation.box(bounds=[[-60, -23, 0], [-28, 23, 30]])
    strap = trimesh.creation.box(bounds=[[-60, -20, 30], [60, 20, 46]])
    below = (trimesh.creation.box(bounds=[[-52, -30, -8], [-37, 30, 0]]) if tongue else
             trimesh.creation.cylinder(radius=6.0, segment=[[0, 0, -stud_depth_mm], [0, 0, 64]], sections=24))
    return trimesh.util.concatenate([heel, strap, below])


def test_a_clamp_set_stands_on_its_heel_not_on_its_stud_in_the_slot():
    """Standing on its lowest point, the set was searched 16 mm too high (every devset strap clamp)."""
    m = prepare_model(_clamp_set(), "strap_clamp", upright_only=True)
    (up,) = m.resting_states
    assert abs(up.T_rest_obj[2, 3]) < 1e-9               # its CAD z = 0, the heel's underside, on the plane
    assert abs(up.height_mm - 64.0) < 1e-6
    # the stud's end cannot rest on anything; the heel's corners can
    assert m.support_vertices[:, 2].min() > -1e-9
    assert len(m.support_vertices) < len(m.mesh.vertices)


def test_a_key_under_a_fixture_that_rides_on_a_face_carries_it():
    m = prepare_model(_clamp_set(tongue=True), "jaw", upright_only=True)
    assert abs(m.resting_states[0].T_rest_obj[2, 3] - 8.0) < 1e-9
    assert len(m.support_vertices) == len(m.mesh.vertices)


def test_a_part_rests_on_any_of_its_vertices():
    m = prepare_model(_clamp_set(), "part")
    assert len(m.support_vertices) == len(m.mesh.vertices)
