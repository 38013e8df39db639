"""The contact prior and the sigma moved to the datum (app.vision.object_pose.uncertainty)."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from app.geometry.transforms import inv, pose_from_xyz_euler
from app.vision.object_pose.uncertainty import prior_offsets


def test_contact_prior_holds_the_lowest_point_not_the_centre():
    """A part tilted by a chip under one edge still touches its support with the other edge: the
    contact prior measures the lift of its lowest point, so the tilt is not also paid as a lift of
    its centre (which pulled tilted parts down along the line of sight)."""
    box = trimesh.creation.box((100.0, 60.0, 20.0))
    T_rest = pose_from_xyz_euler(200.0, 100.0, 10.0, 0.0, 0.0, 0.0)       # flat on z = 0
    prior = (T_rest, 0.15, np.radians(0.3), np.asarray(box.vertices))

    def about(pivot, deg):
        P = pose_from_xyz_euler(*pivot, 0.0, 0.0, 0.0)
        return P @ pose_from_xyz_euler(0.0, 0.0, 0.0, 0.0, deg, 0.0) @ inv(P) @ T_rest

    on_edge = prior_offsets(about((150.0, 100.0, 0.0), -0.5), prior)        # pivots on its left edge
    assert abs(on_edge[0]) < 1e-9                                           # lowest point stays down
    assert on_edge[2] == pytest.approx(-0.5 / 0.3, rel=1e-6)                 # the tilt is paid once
    about_centre = prior_offsets(about((200.0, 100.0, 10.0), -0.5), prior)  # one edge sinks in
    assert about_centre[0] == pytest.approx(-50.0 * np.sin(np.radians(0.5)) / 0.15, rel=1e-3)
    lifted = prior_offsets(pose_from_xyz_euler(0.0, 0.0, 0.3, 0.0, 0.0, 0.0) @ T_rest, prior)
    np.testing.assert_allclose(lifted, [0.3 / 0.15, 0.0, 0.0], atol=1e-9)


def test_an_unknown_height_leaves_x_and_y_unknown_along_the_line_of_sight():
    """Seen from (0, -600, 600) a part at (0, 0, 0) raised by dz looks the same moved towards the
    camera by dz in y: x stays known, y and z are unknown together."""
    from app.geometry.model_edges import prepare_model
    from app.vision.object_pose.uncertainty import unknown_height_covariance
    from app.synth.scene import look_at_pose

    model = prepare_model(trimesh.creation.box(bounds=[[-20, -20, 0], [20, 20, 10]]), "block")
    T = np.eye(4)
    T_cam_table = look_at_pose(np.array([0.0, -600.0, 600.0]), np.array([0.0, 0.0, 0.0]))
    C = unknown_height_covariance(T, model, T_cam_table, 15.0)
    slide_y = (0.0 + 600.0) / (5.0 - 600.0)          # centre at z 5: dy/dz along the ray
    assert C[0, 0] == pytest.approx(0.0, abs=1e-9)
    assert C[2, 2] == pytest.approx(225.0)
    assert C[1, 1] == pytest.approx(225.0 * slide_y ** 2, rel=1e-9)
    assert C[1, 2] == pytest.approx(225.0 * slide_y, rel=1e-9)
    assert np.all(C[3:, :] == 0)
