"""The contact prior and the sigma moved to the datum (app.vision.object_pose.uncertainty)."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from app.geometry.transforms import inv, pose_from_xyz_euler
from app.vision.object_pose.uncertainty import CAUCHY_MIN_PX, PRIOR_PX, prior_noise_px, prior_offsets


def test_the_prior_is_weighed_against_the_edge_noise_the_fit_shows():
    """The contact prior's residuals are in pixels of edge noise: the noise of this fit's own edges
    (weighted RMS, times the covariance's scale), so that the fit and its covariance give the prior
    the same weight; never more than the assumed PRIOR_PX, never less than numerical noise."""
    rng = np.random.default_rng(3)
    r = rng.normal(0.0, 0.1, 4000)
    assert prior_noise_px(r, np.ones_like(r), 1.8) == pytest.approx(0.18, rel=0.05)
    # a sample caught on another edge, down-weighted by the Cauchy weights, does not count
    caught = np.append(r, 25.0)
    assert prior_noise_px(caught, np.append(np.ones_like(r), 0.0), 1.8) == pytest.approx(0.18, rel=0.05)
    assert prior_noise_px(rng.normal(0.0, 2.0, 4000), np.ones(4000), 1.8) == PRIOR_PX
    assert prior_noise_px(np.zeros(50), np.ones(50), 1.8) == CAUCHY_MIN_PX
    assert prior_noise_px(np.zeros(0), np.zeros(0), 1.8) == PRIOR_PX


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


def _edge_fit_info(prior=None, noise_px: float = 0.05):
    """A converged edge fit as :func:`refine_pose` leaves it: 40 mm box edges seen from a camera
    600 mm away, exact targets plus a little noise, all six parameters free."""
    from types import SimpleNamespace

    from app.geometry.model_edges import project_points_px
    from app.geometry.transforms import transform_points
    from app.synth.scene import look_at_pose

    rng = np.random.default_rng(3)
    t = np.linspace(-20.0, 20.0, 9)
    X = np.concatenate([np.column_stack([t, np.full_like(t, s), np.full_like(t, h)]) for s in (-20.0, 20.0)
                        for h in (0.0, 30.0)] + [np.column_stack([np.full_like(t, s), t, np.full_like(t, h)])
                                                 for s in (-20.0, 20.0) for h in (0.0, 30.0)]
                       + [np.column_stack([np.full_like(t, sx), np.full_like(t, sy), 15.0 + 0.7 * t])
                          for sx in (-20.0, 20.0) for sy in (-20.0, 20.0)])
    edge = np.repeat(np.arange(12), len(t))
    ang = rng.uniform(0, np.pi, 12)[edge]
    n = np.column_stack([np.cos(ang), np.sin(ang)])
    T0 = pose_from_xyz_euler(500.0, 150.0, 0.0, 0.0, 0.0, 20.0)
    T_cam_table = look_at_pose(np.array([300.0, -300.0, 500.0]), np.array([450.0, 150.0, 0.0]))
    K = np.array([[1400.0, 0.0, 960.0], [0.0, 1400.0, 600.0], [0.0, 0.0, 1.0]])
    target = project_points_px(transform_points(T_cam_table @ T0, X), K, None)
    target += noise_px * rng.standard_normal((len(X), 1)) * n
    c_table = T0[:3, 3] + np.array([0.0, 0.0, 15.0])
    info = {"sol": SimpleNamespace(x=np.zeros(6)), "free": np.arange(6), "pin": None, "prior": prior, "X": X,
            "n": n, "target": target, "T0": T0, "c_table": c_table, "edge": edge}
    return info, K, T_cam_table


def test_atable_error_moves_a_freely_fitted_part_as_the_frame_moves():
    """Seen exactly and fitted in all six axes, a part in a table frame that is off by E is found at
    inv(E) @ T: the table term's linear map B must give that pose (the sigma then is B S B^T)."""
    from scipy.spatial.transform import Rotation

    from app.vision.object_pose.pose_params import perturb
    from app.vision.object_pose.uncertainty import table_error, table_covariance

    info, K, T_cam_table = _edge_fit_info()
    centroid = np.array([100.0, 100.0, 0.0])                 # the markers' centroid, 400 mm away
    e = np.array([2e-4, -1e-4, 3e-4, 0.05, -0.03, 0.02])     # rad about the table axes, mm
    S = np.outer(e, e)                                       # a covariance whose only direction is e
    C = table_covariance(info, K, None, T_cam_table, S, centroid)
    # C = (B e)(B e)^T: compare the pose B e gives with inv(E) @ T
    expected = inv(table_error(e, centroid)) @ info["T0"]
    D, c = expected @ inv(info["T0"]), info["c_table"]          # expected = perturb(T0, c, want)
    want = np.concatenate([D[:3, 3] - c + D[:3, :3] @ c, Rotation.from_matrix(D[:3, :3]).as_rotvec()])
    np.testing.assert_allclose(perturb(info["T0"], info["c_table"], want), expected, atol=1e-9)
    np.testing.assert_allclose(C, np.outer(want, want), rtol=0.02, atol=1e-7)


def test_a_part_held_on_the_table_follows_its_frame_in_height_and_tilt():
    """The contact prior holds the part on the surface as the frame says: a frame that is off in
    height carries the part with it (no height error in that frame), and no table covariance, or
    none known, gives no term."""
    from app.vision.object_pose.uncertainty import table_covariance

    free_info, K, T_cam_table = _edge_fit_info()
    box = np.array([[sx, sy, h] for sx in (-20.0, 20.0) for sy in (-20.0, 20.0) for h in (0.0, 30.0)])
    held_info, _, _ = _edge_fit_info(prior=(free_info["T0"], 0.01, np.radians(0.01), box))
    S = np.diag([0.0, 0.0, 0.0, 0.0, 0.0, 0.1 ** 2])            # the frame known to 0.1 mm in height only
    C_free = table_covariance(free_info, K, None, T_cam_table, S, np.zeros(3))
    C_held = table_covariance(held_info, K, None, T_cam_table, S, np.zeros(3))
    assert np.sqrt(C_free[2, 2]) == pytest.approx(0.1, rel=0.02)
    assert np.sqrt(C_held[2, 2]) < 0.01
    assert np.all(table_covariance(held_info, K, None, T_cam_table, np.zeros((6, 6)), np.zeros(3)) == 0)
    assert np.all(np.isinf(table_covariance(held_info, K, None, T_cam_table, np.full((6, 6), np.nan), np.zeros(3))))


def test_intrinsics_off_move_the_part_as_the_refit_says():
    """A part fitted with a focal length 0.4 % off (and the table pose moved as its jacobian says)
    lands where the intrinsics term's linear map puts it: refitted in all six axes under the moved
    intrinsics, the pose change ``d`` gives the term ``d d^T`` for a sigma along that one direction;
    no sigma, no term."""
    from scipy.optimize import least_squares

    from app.vision.intrinsics import moved_intrinsics
    from app.vision.object_pose.uncertainty import _raw, table_error, table_covariance

    info, K, T_cam_table = _edge_fit_info(noise_px=0.0)
    centroid = np.array([100.0, 100.0, 0.0])
    k_jac = np.array([[1e-3, 0, 0], [-2e-3, 0, 0], [5e-4, 0, 0], [40.0, 0, 0], [-25.0, 0, 0], [60.0, 0, 0]])
    df = 0.004
    T_told = T_cam_table @ table_error(k_jac[:, 0] * df, centroid)
    K_told = moved_intrinsics(K, 0, df)
    d = least_squares(lambda p: _raw(info, p, K_told, None, T_told), np.zeros(6), x_scale=[0.1] * 3 + [1e-3] * 3,
                      xtol=1e-14, ftol=1e-14).x
    assert np.linalg.norm(d[:3]) > 0.05                     # the move is real, not numerical noise
    S0 = np.zeros((6, 6))
    C = table_covariance(info, K, None, T_cam_table, S0, centroid, k_jac, (df, 0.0, 0.0))
    np.testing.assert_allclose(C, np.outer(d, d), rtol=0.05, atol=1e-6)
    assert np.all(table_covariance(info, K, None, T_cam_table, S0, centroid, k_jac, None) == 0)
