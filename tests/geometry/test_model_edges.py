"""Edge models: creases, silhouettes, hidden lines, resting states, symmetry."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
import trimesh

from app.geometry import parts
from app.geometry.model_edges import (prepare_model, project_points_px, render_depth, resting_pose,
                                      visible_edge_samples)
from app.geometry.transforms import inv, make_pose, pose_from_xyz_euler, transform_points

K = np.array([[1000.0, 0, 480], [0, 1000.0, 300], [0, 0, 1]])
W, H = 960, 600


def _box(x, y, z):
    return trimesh.creation.box(bounds=[[0, 0, 0], [x, y, z]])


@pytest.fixture(scope="module")
def block():
    return prepare_model(_box(120, 80, 40), "block")


def _look_down(distance_mm=800.0, tilt_deg=0.0):
    """T_cam_table for a camera above the table origin, looking down (image x ~ table x)."""
    return pose_from_xyz_euler(0, 0, distance_mm, 180.0 + tilt_deg, 0, 0)


def test_project_points_matches_opencv():
    rng = np.random.default_rng(0)
    P = rng.uniform([-300, -200, 500], [300, 200, 1500], (50, 3))
    dist = np.array([-0.12, 0.08, 4e-4, -3e-4, -0.02])
    ref, _ = cv2.projectPoints(P, np.zeros(3), np.zeros(3), K, dist)
    np.testing.assert_allclose(project_points_px(P, K, dist), ref.reshape(-1, 2), atol=1e-9)


def test_render_depth_of_a_plane_is_exact():
    # a square at z = 1000 mm facing the camera: depth 1000 inside, inf outside
    V = np.array([[-100, -100, 1000], [100, -100, 1000], [100, 100, 1000], [-100, 100, 1000.0]])
    F = np.array([[0, 2, 1], [0, 3, 2]])
    depth, fid = render_depth([(V, F)], K, W, H, cull_back_faces=False)
    assert np.allclose(depth[300, 480], 1000.0)
    assert np.isinf(depth[50, 50]) and fid[50, 50] == -1
    inside = np.isfinite(depth)
    assert abs(inside.sum() - 201 * 201) <= 2 * 201  # 200 mm = 200 px at f / z = 1


def test_block_edges_resting_states_and_symmetry(block):
    assert len(block.edge_vertices) == 12 and block.edge_feature.all()
    # on its big face first; opposite faces are the same state up to the 180 deg flip
    assert block.resting_states[0].height_mm == pytest.approx(40.0)
    assert block.resting_states[1].same_as == 0
    exact = sorted(round(s.angle_deg) for s in block.symmetries if s.exact)
    assert exact == [180, 180, 180]          # about z, x and y; no 90 deg for a 120 x 80 block
    assert block.continuous_axis_obj is None
    T = resting_pose(block, 0, 300.0, 200.0, 30.0)
    V = transform_points(T, block.mesh.vertices)
    assert V[:, 2].min() == pytest.approx(0.0, abs=1e-9)
    c = transform_points(T, block.center_obj[None])[0]
    np.testing.assert_allclose(c[:2], [300.0, 200.0], atol=1e-9)


def test_square_plate_is_fourfold_and_round_part_is_continuous():
    sq = prepare_model(_box(80, 80, 20), "square")
    about_z = sorted(round(s.angle_deg) for s in sq.symmetries if s.exact and abs(s.axis_obj[2]) > 0.99)
    assert about_z == [90, 180, 270]
    cyl = prepare_model(trimesh.creation.cylinder(radius=30, height=20, sections=64), "round")
    assert cyl.continuous_axis_obj is not None and abs(cyl.continuous_axis_obj[2]) > 0.999


def test_pin_hole_makes_the_flange_only_near_symmetric():
    fl = prepare_model(parts.flange_plate_80(), "flange")
    about_z = [s for s in fl.symmetries if abs(s.axis_obj[2]) > 0.99]
    assert sorted(round(s.angle_deg) for s in about_z) == [90, 180, 270]
    assert not any(s.exact for s in about_z)       # the 4 mm pin hole breaks them
    assert all(s.matched_fraction > 0.9 for s in about_z)


def test_visible_edges_hide_the_back_and_the_occluded(block):
    T_cam_table = _look_down()
    T_cam_obj = T_cam_table @ resting_pose(block, 0, 0.0, 0.0, 0.0)
    es = visible_edge_samples(block, T_cam_obj, K, None, W, H)
    P_table = transform_points(inv(T_cam_table), es.points_cam)
    # seen from straight above only the top face's 4 edges show (its outline is the silhouette)
    assert np.all(P_table[:, 2] > 39.9)
    assert es.silhouette.all()
    np.testing.assert_allclose(np.linalg.norm(es.normal_uv, axis=1), 1.0)
    # the image normal is perpendicular to the projected edge
    a = transform_points(T_cam_obj, block.samples_obj[es.index] + 0.5 * block.sample_dir_obj[es.index])
    t = project_points_px(a, K, None) - es.uv_px
    assert np.max(np.abs(np.einsum("ij,ij->i", t, es.normal_uv))) < 1e-6
    # a plate held above the left half hides the edges below it
    plate = _box(80, 200, 5)
    T_cam_plate = T_cam_table @ make_pose(None, [-80, -100, 100])
    es2 = visible_edge_samples(block, T_cam_obj, K, None, W, H, occluders=((plate, T_cam_plate),))
    P2 = transform_points(inv(T_cam_table), es2.points_cam)
    assert 0.3 < len(es2.index) / len(es.index) < 0.8
    assert np.all(P2[:, 0] > -2.0)         # the visibility test is lenient by ~1 buffer pixel at borders


def test_hidden_lines_of_a_concave_part():
    # an L-shaped angle seen from in front of its web (x = -600, below the web's top, looking along
    # +x): the web hides the whole foot behind it
    angle = trimesh.boolean.union([_box(160, 70, 15), _box(15, 70, 90)], engine="manifold")
    m = prepare_model(angle, "angle")
    cam_pos = np.array([-600.0, 35.0, 60.0])
    z = np.array([1.0, 0, 0])
    x = np.array([0, -1.0, 0])
    y = np.cross(z, x)
    T_cam_table = inv(make_pose(np.column_stack([x, y, z]), cam_pos))
    T_cam_obj = T_cam_table
    with_z = visible_edge_samples(m, T_cam_obj, K, None, W, H, occlusion_test=True)
    without = visible_edge_samples(m, T_cam_obj, K, None, W, H, occlusion_test=False)
    P = transform_points(inv(T_cam_table), with_z.points_cam)
    P0 = transform_points(inv(T_cam_table), without.points_cam)
    assert np.any(P0[:, 0] > 16)            # back-face culling alone keeps some foot edges
    assert len(with_z.index) > 20
    assert not np.any(P[:, 0] > 16)         # the z-buffer hides them all


def test_project_points_with_every_coefficient_count_matches_opencv():
    """The rational and thin-prism terms are left out where their coefficients are 0: with them set
    (8 and 12 coefficients) and without (the same model padded with zeros) the pixels are OpenCV's."""
    rng = np.random.default_rng(1)
    P = rng.uniform([-300, -200, 500], [300, 200, 1500], (50, 3))
    for dist in ([-0.12, 0.08, 4e-4, -3e-4, -0.02, 0.01, -0.003, 0.002],
                 [-0.12, 0.08, 4e-4, -3e-4, -0.02, 0.0, 0.0, 0.0, 1e-3, -2e-4, 5e-4, 1e-4],
                 [-0.12, 0.08, 4e-4, -3e-4, -0.02, 0.0, 0.0, 0.0]):
        d = np.array(dist)
        ref, _ = cv2.projectPoints(P, np.zeros(3), np.zeros(3), K, d)
        np.testing.assert_allclose(project_points_px(P, K, d), ref.reshape(-1, 2), atol=1e-9)


def test_a_symmetry_already_found_is_told_as_np_allclose_tells_it():
    """``_one_of`` compares a pose with every symmetry found at once; its answer is the one of
    ``any(np.allclose(S, s.S, atol))``, near the tolerance too."""
    from app.geometry.model_edges import Symmetry, _one_of

    rng = np.random.default_rng(7)
    found = [Symmetry(S=np.round(rng.standard_normal((4, 4)) * 2, 1), axis_obj=np.array([0.0, 0.0, 1.0]),
                      angle_deg=90.0, matched_fraction=1.0, exact=True) for _ in range(6)]
    atol = 1e-4
    assert not _one_of(found[0].S, [], atol)
    told = []
    for k in range(400):
        S = found[k % 6].S + rng.choice([0.0, 0.5, 0.9, 1.0, 1.1, 3.0]) * atol * rng.choice([-1, 1], (4, 4))
        told.append(_one_of(S, found, atol))
        assert told[-1] == any(np.allclose(S, s.S, atol=atol) for s in found)
    assert 50 < sum(told) < 350                  # both answers asked for


def test_share_within_is_exact_when_it_reaches_the_need_and_below_it_when_not():
    from scipy.spatial import cKDTree

    from app.geometry.model_edges import _share_within

    rng = np.random.default_rng(3)
    ref = rng.uniform(0, 100, (5000, 3))
    tree = cKDTree(ref)
    for shift in (0.0, 0.3, 1.0, 3.0):
        pts = ref[:1700] + rng.normal(0, shift, (1700, 3))
        d, _ = tree.query(pts, distance_upper_bound=2.0)
        exact = float(np.mean(d <= 0.5))
        for need in (0.0, 0.5, 0.85, 0.995):
            got = _share_within(tree, pts, 0.5, need)
            if exact >= need:
                assert got == exact
            else:
                assert exact <= got < need


def test_the_projection_jacobian_is_the_projections_derivative_for_every_coefficient_count():
    """``project_points_jacobian`` against central differences of ``project_points_px`` (px per mm),
    no distortion, 4, 5, 8, 12 and 14 (tilted sensor) coefficients."""
    from app.geometry.model_edges import project_points_jacobian

    rng = np.random.default_rng(2)
    P = rng.uniform([-300, -200, 500], [300, 200, 1500], (40, 3))
    for dist in (None, [-0.1, 0.05, 1e-3, -2e-3], [-0.12, 0.08, 4e-4, -3e-4, -0.02],
                 [-0.12, 0.08, 4e-4, -3e-4, -0.02, 0.01, -0.003, 0.002],
                 [-0.12, 0.08, 4e-4, -3e-4, -0.02, 0.0, 0.0, 0.0, 1e-3, -2e-4, 5e-4, 1e-4],
                 [-0.12, 0.08, 4e-4, -3e-4, -0.02, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.01, -0.02]):
        d = None if dist is None else np.array(dist)
        J = project_points_jacobian(P, K, d)
        h = 1e-3
        num = np.stack([(project_points_px(P + h * e, K, d) - project_points_px(P - h * e, K, d)) / (2 * h)
                        for e in np.eye(3)], axis=-1)
        assert J.shape == (40, 2, 3)
        np.testing.assert_allclose(J, num, atol=1e-6 * np.abs(num).max())
    assert project_points_jacobian(np.zeros((0, 3)), K).shape == (0, 2, 3)
