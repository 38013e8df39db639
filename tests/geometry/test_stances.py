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
