"""The fine edge fit (app.vision.object_pose.refine): a few samples caught on a foreign edge close to
the part's own must not pull the pose."""

from __future__ import annotations

import dataclasses

import cv2
import numpy as np
import pytest
import trimesh

from app.geometry.model_edges import prepare_model, project_points_px, visible_edge_samples
from app.geometry.transforms import pose_from_xyz_euler, transform_points
from app.synth.scene import look_at_pose
from app.vision.object_pose.edge_image import prepare_image
from app.vision.object_pose.pose_params import FREE_6DOF
from app.vision.object_pose.refine import edges_along_normals, near_clipped, refine_pose
from app.vision.object_pose.uncertainty import cauchy_weights

W, H, SS = 640, 480, 8               # image size (px) and supersampling of the rendering
K = np.array([[900.0, 0.0, 320.0], [0.0, 900.0, 240.0], [0.0, 0.0, 1.0]])
BOX = trimesh.creation.box(bounds=[[-40.0, -25.0, 0.0], [40.0, 25.0, 30.0]])
T_CAM_TABLE = look_at_pose(np.array([150.0, -450.0, 380.0]), np.array([0.0, 0.0, 10.0]))
T_TRUE = pose_from_xyz_euler(0.0, 0.0, 0.0, 0.0, 0.0, 12.0)


def _render(stripe: bool, top_shade: float | None = None) -> np.ndarray:
    """8-bit image (gamma 2.2) of the box on a dark table, its faces shaded by their normals,
    antialiased by 8x supersampling; with ``stripe``, a bright 1 px line runs 1.2 px outside the
    box's left silhouette along all of it (a clamp's edge, a shadow's); ``top_shade``: the top face's
    linear brightness (over 1: beyond the sensor's top, a polished face catching the lamp), the image
    then blurred 0.7 px (the lens) before the sensor clips it."""
    Ks = K.copy()
    Ks[:2] *= SS
    Ks[:2, 2] += (SS - 1) / 2.0            # pixel centres: u_hi = 8 u + 3.5
    lin = np.full((H * SS, W * SS), 0.05, np.float32)
    T_cam_obj = T_CAM_TABLE @ T_TRUE
    light = np.array([0.3, -0.5, 0.8]) / np.linalg.norm([0.3, -0.5, 0.8])
    for f, n in zip(BOX.faces, BOX.face_normals):
        P = transform_points(T_cam_obj, BOX.vertices[f])
        if np.dot(T_cam_obj[:3, :3] @ n, P.mean(axis=0)) >= 0:      # faces away from the camera
            continue
        uv = project_points_px(P, Ks)
        shade = 0.15 + 0.6 * max(0.0, float(np.dot(T_TRUE[:3, :3] @ n, light)))
        if top_shade is not None and n[2] > 0.9:
            shade = top_shade
        cv2.fillConvexPoly(lin, np.round(uv * 16).astype(np.int32), float(shade), lineType=cv2.LINE_8, shift=4)
    if stripe:
        # the silhouette edge on the image's left: the box's x = -40, y = -25 vertical edge
        a = transform_points(T_cam_obj, np.array([[-40.0, -25.0, 0.0], [-40.0, -25.0, 30.0]]))
        uv = project_points_px(a, Ks)
        d = uv[1] - uv[0]
        out = np.array([-d[1], d[0]]) / np.linalg.norm(d)
        if out[0] > 0:
            out = -out
        p0, p1 = uv[0] + 1.2 * SS * out, uv[1] + 1.2 * SS * out
        cv2.line(lin, tuple(np.round(p0 * 16).astype(int)), tuple(np.round(p1 * 16).astype(int)), 0.9,
                 thickness=SS, lineType=cv2.LINE_8, shift=4)
    small = cv2.resize(lin, (W, H), interpolation=cv2.INTER_AREA)
    if top_shade is not None:
        small = cv2.GaussianBlur(small, (0, 0), 0.7)
    return np.clip(255.0 * np.minimum(small, 1.0) ** (1 / 2.2), 0, 255).astype(np.uint8)


def _fit(image: np.ndarray, reweight: int, drop_clipped: bool = False, clip_known: bool = True) -> np.ndarray:
    model = prepare_model(BOX, "box", detect_symmetry=False)
    eimg = prepare_image(image)
    if not clip_known:
        eimg = dataclasses.replace(eimg, clipped=None)
    start = pose_from_xyz_euler(0.4, -0.3, 0.2, 0.1, -0.1, 12.3)
    on_table = (T_TRUE, 0.15, np.radians(0.3), np.asarray(BOX.vertices))      # the contact prior
    T, info = refine_pose(eimg, model, start, T_CAM_TABLE, K, np.zeros(5), (), np.arange(len(model.samples_obj)),
                          free=FREE_6DOF, radii=(3.0, 2.0, 2.0), min_contrast=0.02, prior=on_table,
                          reweight=reweight, drop_clipped=drop_clipped)
    assert "sol" in info, info
    return transform_points(T, BOX.vertices) - transform_points(T_TRUE, BOX.vertices)


def test_the_fit_finds_the_rendered_box():
    err = np.linalg.norm(_fit(_render(stripe=False), reweight=3), axis=1)
    assert err.max() < 0.1


def test_samples_caught_on_a_foreign_edge_do_not_pull_the_reweighted_fit():
    """A stripe 1.2 px beside one silhouette edge catches its samples: a soft-L1 fit is pulled by
    them (0.56 mm at the worst corner), the Cauchy-reweighted one lets them go (0.07 mm, as without
    the stripe)."""
    image = _render(stripe=True)
    plain = np.linalg.norm(_fit(image, reweight=0), axis=1).max()
    robust = np.linalg.norm(_fit(image, reweight=3), axis=1).max()
    assert plain > 0.3                 # the stripe does pull a fit that keeps listening to it
    assert robust < 0.1


def test_cauchy_weights_scale_with_the_residuals_own_spread():
    rng = np.random.default_rng(0)
    r = rng.normal(0.0, 0.1, 2000)
    w = cauchy_weights(np.concatenate([r, [1.5]]))
    assert np.median(w[:-1]) > 0.85                     # the inliers keep nearly full weight
    assert w[-1] < 0.06                                 # 15 sigma out: nearly gone
    assert cauchy_weights(np.concatenate([10 * r, [1.5]]))[-1] > 0.5   # ten times the noise: 1.5 sigma
    assert cauchy_weights(np.zeros(5)) == pytest.approx(np.ones(5))     # the floor: no division by zero


def _step(dark_grey: int, bright_grey: int, noise_grey: float = 0.0) -> np.ndarray:
    """8-bit image (gamma 2.2) of a vertical step, blurred 1 px in linear light, with read noise."""
    lin = np.full((60, 80), (dark_grey / 255.0) ** 2.2, np.float32)
    lin[:, 40:] = (bright_grey / 255.0) ** 2.2
    img = 255.0 * cv2.GaussianBlur(lin, (0, 0), 1.0) ** (1 / 2.2)
    img += np.random.default_rng(1).normal(0.0, noise_grey, img.shape)
    return np.clip(np.rint(img), 0, 255).astype(np.uint8)


def _contrast(img, gamma):
    eimg = prepare_image(img)
    uv = np.stack([np.full(20, 39.5), np.arange(20, 40.0)], axis=1)
    off, contrast = edges_along_normals(eimg.linear, uv, np.tile([1.0, 0.0], (20, 1)), 3.0, gamma=gamma)
    assert np.all(np.abs(off) <= 1.5) and np.median(np.abs(off)) < 0.5, off     # found where it is
    return float(np.median(contrast))


def test_a_dark_edge_is_judged_against_its_own_noise():
    """30 grey levels between two dark plateaus (30 -> 60) with 4 grey levels of noise: 7.5 times the
    noise, as far above it as an edge 30 levels wide at mid-grey. In linear light it is only 0.03,
    under the floor of 6 times the noise taken at mid-grey (0.09); scaled to mid-grey it passes."""
    noise_lin = 4.0 / 255.0 * 2.2 * 0.5 ** 1.2
    floor = 6.0 * noise_lin
    dark = _step(30, 60, noise_grey=4.0)
    assert _contrast(dark, None) < floor < _contrast(dark, 2.2)
    # the same 30 levels at mid-grey pass either way, and a bright edge keeps its linear contrast
    assert _contrast(_step(113, 143), 2.2) > floor
    bright = _step(150, 180)
    assert _contrast(bright, 2.2) == pytest.approx(_contrast(bright, None))


def test_edges_beside_a_clipped_face_are_left_out_of_the_fit():
    """A top face three times over the sensor's top: its edges' 50 % crossings sit toward the dark
    side (the bright plateau is cut off), and a fit that takes them makes the box look bigger, so
    nearer. Left out (``drop_clipped``: the final fit's), the side faces' edges place it as if
    nothing were clipped."""
    image = _render(stripe=False, top_shade=3.0)
    assert (image == 255).mean() > 0.01                       # the top face is clipped (2 % of the image)
    eimg = prepare_image(image)
    model = prepare_model(BOX, "box", detect_symmetry=False)
    es = visible_edge_samples(model, T_CAM_TABLE @ T_TRUE, K, np.zeros(5), W, H)
    off, _ = edges_along_normals(eimg.linear, es.uv_px, es.normal_uv, 2.0, gamma=eimg.gamma)
    near = near_clipped(eimg.clipped, es.uv_px, es.normal_uv, off)
    top = transform_points(np.eye(4), es.points_obj)[:, 2] > 29.9
    assert near[top].mean() > 0.9 and near[~top].mean() < 0.5
    taken = np.linalg.norm(_fit(image, reweight=3), axis=1).max()
    left_out = np.linalg.norm(_fit(image, reweight=3, drop_clipped=True), axis=1).max()
    not_known = np.linalg.norm(_fit(image, reweight=3, drop_clipped=True, clip_known=False), axis=1).max()
    assert taken > 0.3 and not_known == taken          # nothing marked clipped: nothing left out
    assert left_out < 0.1
