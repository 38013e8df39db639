"""Photo models (app/vision/photo_model.py): the plane's homography, rectification with and without lens
distortion, teaching, locating a repeat placement, the height from two views and look-alikes.

The pictures here are drawn directly through the plane homographies (a textured table at z = 0, the
object's top face at z = h), so every number has an exact truth and the tests stay fast; the rendered
scenes with the T-slot table, shadows and side walls are in benchmarks/photo_model.py and the API test.
"""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from app.geometry.transforms import make_pose
from app.synth.scene import look_at_pose
from app.vision import photo_model as pm

W, H = 1280, 800
K = np.array([[1400.0, 0, 640], [0, 1400.0, 400], [0, 0, 1]])
HEIGHT = 12.0


def plate_top(holes=((30.0, 25.0, 8.0), (110.0, 25.0, 8.0))) -> tuple[np.ndarray, list]:
    """Outline (mm, plate frame: front-left corner at 0) of a notched 140 x 90 plate and its holes."""
    outline = np.array([[0, 0], [140, 0], [140, 65], [115, 90], [0, 90]], float)
    return outline, list(holes)


def draw(T_cam_table: np.ndarray, T_table_plate: np.ndarray, holes, dist=None, seed: int = 0) -> np.ndarray:
    """A grey picture: a streaked table (z = 0) and the plate's top face (z = HEIGHT) with dark holes."""
    rng = np.random.default_rng(seed)
    dist = np.zeros(5) if dist is None else dist
    # the table: a top view at 0.5 mm/px, machining streaks along x
    gt = pm.PlaneGrid(0.0, 0.0, 0.5, 1600, 800, 0.0)
    tex = (110 + 5 * np.sin(np.arange(gt.height)[:, None] / 3.0) + rng.normal(0, 4, (gt.height, gt.width)))
    tex = cv2.GaussianBlur(tex.astype(np.float32), (0, 0), 0.8)
    # the plate's top at 0.1 mm/px in its own frame
    gp = pm.PlaneGrid(-5.0, -5.0, 0.1, 1500, 1000, HEIGHT)
    top = np.zeros((gp.height, gp.width), np.float32)
    outline, _ = plate_top()
    cv2.fillPoly(top, [np.rint(gp.to_px(outline) * 16).astype(np.int32)], 1.0, lineType=cv2.LINE_AA, shift=4)
    for x, y, r in holes:
        cv2.circle(top, tuple(np.rint(gp.to_px([[x, y]])[0] * 16).astype(int)), int(r / gp.mm_per_px * 16), 0.35,
                   -1, lineType=cv2.LINE_AA, shift=4)
    img = _warp(tex, gt, T_cam_table, dist)
    T_cam_plate = T_cam_table @ T_table_plate
    alpha = _warp(np.where(top > 0, 1.0, 0.0).astype(np.float32) * np.minimum(top * 4, 1), gp, T_cam_plate, dist)
    shade = _warp(top, gp, T_cam_plate, dist)
    out = img * (1 - alpha) + alpha * (60 + 130 * shade)
    out += rng.normal(0, 1.5, out.shape)
    return np.clip(cv2.GaussianBlur(out.astype(np.float32), (0, 0), 0.7), 0, 255).astype(np.uint8)


def _warp(src: np.ndarray, grid: pm.PlaneGrid, T_cam_plane: np.ndarray, dist) -> np.ndarray:
    """Draw a top view (on its grid, in the frame of ``T_cam_plane``) into the camera picture."""
    Hm = pm.plane_homography(K, T_cam_plane, grid)
    if not np.any(dist):
        return cv2.warpPerspective(src, Hm, (W, H), flags=cv2.INTER_LINEAR)
    # distorted: for each camera pixel, its ideal pixel, then the grid pixel through the inverse homography
    uu, vv = np.meshgrid(np.arange(W, dtype=np.float32), np.arange(H, dtype=np.float32))
    pts = cv2.undistortPoints(np.stack([uu.ravel(), vv.ravel()], 1)[:, None, :], K, dist, P=K)[:, 0, :]
    g = np.linalg.inv(Hm) @ np.vstack([pts.T, np.ones(len(pts))])
    mx = (g[0] / g[2]).reshape(H, W).astype(np.float32)
    my = (g[1] / g[2]).reshape(H, W).astype(np.float32)
    return cv2.remap(src, mx, my, cv2.INTER_LINEAR, borderValue=0)


def rot_z(deg: float) -> np.ndarray:
    c, s = np.cos(np.radians(deg)), np.sin(np.radians(deg))
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])


def placed(x: float, y: float, c_deg: float) -> np.ndarray:
    """T_table_plate with the plate's middle (70, 45) at (x, y), turned c_deg."""
    R = rot_z(c_deg)
    return make_pose(R, np.array([x, y, 0.0]) - R @ np.array([70.0, 45.0, 0.0]))


CAM_A = look_at_pose(np.array([400.0, -350.0, 600.0]), np.array([400.0, 200.0, 0.0]))
CAM_B = look_at_pose(np.array([150.0, -250.0, 650.0]), np.array([350.0, 180.0, 0.0]), roll_deg=4.0)
DIST = np.array([-0.08, 0.04, 2e-4, -1e-4, 0.0])


def test_plane_homography_is_the_projection_of_the_plane() -> None:
    grid = pm.PlaneGrid(100.0, 50.0, 0.5, 200, 100, 25.0)
    uv = np.array([[0.0, 0.0], [199.0, 0.0], [37.5, 81.25]])
    p = pm.plane_homography(K, CAM_A, grid) @ np.vstack([uv.T, np.ones(3)])
    xy = grid.to_mm(uv)
    P = (CAM_A @ np.vstack([xy.T, np.full(3, 25.0), np.ones(3)]))[:3]
    np.testing.assert_allclose((p[:2] / p[2]).T, (K @ P)[:2].T / P[2][:, None], atol=1e-9)


@pytest.mark.parametrize("dist", [None, DIST])
def test_rectify_puts_table_points_on_their_grid_pixel(dist) -> None:
    """A dot drawn where the camera sees table point (x, y, z) is found at that point's grid pixel,
    with and without lens distortion (warpPerspective and remap paths)."""
    img = np.zeros((H, W), np.uint8)
    pts = np.array([[300.0, 150.0], [420.5, 230.25], [510.0, 180.0]])
    from app.geometry.model_edges import project_points_px
    from app.geometry.transforms import transform_points
    uv = project_points_px(transform_points(CAM_A, np.column_stack([pts, np.full(3, 7.0)])), K,
                           np.zeros(5) if dist is None else dist)
    for u, v in uv:
        cv2.circle(img, (round(u * 16), round(v * 16)), 3 * 16, 255, -1, lineType=cv2.LINE_AA, shift=4)
    grid = pm.PlaneGrid.around(250, 560, 100, 280, 0.25, 7.0)
    rect, valid, _ = pm.rectify(img, K, dist, CAM_A, grid)
    assert valid.min() == 255
    for p in pts:
        c = np.rint(grid.to_px(p[None])[0]).astype(int)
        win = rect[c[1] - 20:c[1] + 21, c[0] - 20:c[0] + 21].astype(float)
        vv, uu = np.mgrid[-20:21, -20:21]
        centre = np.array([(win * uu).sum(), (win * vv).sum()]) / win.sum() * grid.mm_per_px
        assert np.hypot(*(centre + (c - grid.to_px(p[None])[0]) * grid.mm_per_px)) < 0.05


@pytest.fixture(scope="module")
def taught() -> tuple[pm.PhotoModel, np.ndarray]:
    T_teach = placed(380.0, 200.0, 10.0)
    view = pm.View(draw(CAM_A, T_teach, plate_top()[1], seed=1), K, np.zeros(5), CAM_A)
    model, _pic = pm.teach([view], HEIGHT)
    return model, T_teach


def test_teach_finds_the_top_face_in_mm(taught) -> None:
    model, T_teach = taught
    outline, holes = plate_top()
    # the obj frame's origin is the outline's centroid on the table, axes as the table's
    centre_true = (T_teach @ np.array([*_centroid(outline), 0.0, 1.0]))[:2]
    np.testing.assert_allclose(model.T_table_obj_teach[:2, 3], centre_true, atol=0.3)
    area = cv2.contourArea(model.outline_mm.astype(np.float32))
    assert abs(area - cv2.contourArea(outline.astype(np.float32))) < 0.03 * area
    assert len(model.holes_mm) == 2
    assert model.symmetry_deg == ()
    # the template's edges: outline and hole rims, about 0.5 mm apart
    perimeter = cv2.arcLength(outline.astype(np.float32), True) + sum(2 * np.pi * r for *_, r in holes)
    assert 0.8 * perimeter < model.edge_length_mm < 1.2 * perimeter
    again = pm.PhotoModel.from_dict(model.to_dict())
    np.testing.assert_allclose(again.points_mm, model.points_mm, atol=1e-4)
    assert again.teach_grid == model.teach_grid


def _centroid(poly: np.ndarray) -> np.ndarray:
    m = cv2.moments(poly.astype(np.float32))
    return np.array([m["m10"] / m["m00"], m["m01"] / m["m00"]])


def test_teach_refuses_a_picture_without_object_and_a_bad_height() -> None:
    empty = pm.View(draw(CAM_A, placed(2000.0, 2000.0, 0.0), []), K, np.zeros(5), CAM_A)
    with pytest.raises(pm.TeachError, match="no object"):
        pm.teach([empty], HEIGHT)
    with pytest.raises(pm.TeachError, match="height"):
        pm.teach([empty], -3.0)


@pytest.mark.parametrize("where, cam, dist", [((300.0, 160.0, 47.0), CAM_B, DIST), ((470.0, 230.0, -120.0), CAM_A, None)])
def test_repeat_placement_is_located_to_a_tenth(taught, where, cam, dist) -> None:
    """Another place, turn and camera pose (with distortion): x, y within 0.1 mm, turn within 0.03°,
    and the error within 3 sigma; the result has the CAD engine's shape."""
    model, T_teach = taught
    T_rep = placed(*where)
    view = pm.View(draw(cam, T_rep, plate_top()[1], dist=dist, seed=5), K, dist if dist is not None else np.zeros(5), cam)
    p = pm.locate(view, model, "plate")
    assert p, p.reason
    truth = T_rep @ np.linalg.inv(T_teach) @ model.T_table_obj_teach
    err = p.T_table_obj[:2, 3] - truth[:2, 3]
    dc = np.degrees(np.arctan2(p.T_table_obj[1, 0], p.T_table_obj[0, 0]) - np.arctan2(truth[1, 0], truth[0, 0]))
    assert np.hypot(*err) < 0.1 and abs((dc + 180) % 360 - 180) < 0.03, (err, dc)
    assert abs(err[0]) < 3 * p.sigma["x_mm"] + 0.02 and abs(err[1]) < 3 * p.sigma["y_mm"] + 0.02
    assert p.uncertainty_ok and p.score > 0.9 and p.T_table_obj[2, 3] == 0.0
    d = p.to_dict()
    assert {"T_cam_obj", "T_table_obj", "sigma", "cov6", "score", "margin", "flags", "photo"} <= set(d)
    np.testing.assert_allclose(p.T_cam_obj, cam @ p.T_table_obj)


@pytest.mark.slow
def test_a_look_alike_is_refused_and_told_apart(taught) -> None:
    """Plate B has a third hole. Asked for A in a picture of B: refused (edges inside the outline that A
    lacks); asked for B in a picture of A: refused (B's hole is not there); both located in one
    picture: the picture's own plate wins."""
    model_a, _ = taught
    extra = plate_top()[1] + [(50.0, 62.0, 8.0)]
    T_b = placed(380.0, 200.0, 10.0)
    model_b, _ = pm.teach([pm.View(draw(CAM_A, T_b, extra, seed=2), K, np.zeros(5), CAM_A)], HEIGHT)
    T_rep = placed(330.0, 180.0, 75.0)
    pic_a = pm.View(draw(CAM_B, T_rep, plate_top()[1], seed=7), K, np.zeros(5), CAM_B)
    pic_b = pm.View(draw(CAM_B, T_rep, extra, seed=8), K, np.zeros(5), CAM_B)
    wrong = pm.locate(pic_b, model_a, "A")
    assert not wrong and "inside its outline" in wrong.reason
    wrong = pm.locate(pic_a, model_b, "B")
    assert not wrong and "not in the picture" in wrong.reason
    # the two located without the checks (as recognition sees them), then decided
    for pic, right in ((pic_a, "A"), (pic_b, "B")):
        both = [(n, m, pm.locate(pic, m, n, max_unexplained_mm=1e9, min_score=0.5)) for n, m in
                (("A", model_a), ("B", model_b))]
        both = [b for b in both if b[2]]
        accepted, refused = pm.decide_lookalikes(pic, both)
        assert [both[i][0] for i in accepted] == [right], refused


def test_height_from_two_views() -> None:
    T = placed(380.0, 200.0, 10.0)
    views = [pm.View(draw(cam, T, plate_top()[1], seed=s), K, np.zeros(5), cam) for cam, s in ((CAM_A, 1), (CAM_B, 2))]
    h, agree = pm.measure_height(views, (300.0, 460.0, 130.0, 270.0), z_range_mm=(2.0, 40.0))
    assert abs(h - HEIGHT) <= 0.3 and agree > 0.5
    with pytest.raises(pm.TeachError, match="moved only"):
        pm.measure_height([views[0], views[0]], (300.0, 460.0, 130.0, 270.0))


# ------------------------------------------------------------------------------------------ sigma's table-pose terms
def _table_estimate(T_true: np.ndarray, centroid: np.ndarray, delta: np.ndarray) -> np.ndarray:
    """The T_cam_table estimate whose error is ``delta`` in locate_table's convention (rotation vector
    rad, shift mm, about ``centroid``): ``T_true = T_est Tc D(delta) Tc^-1``."""
    from scipy.spatial.transform import Rotation
    Tc = make_pose(None, centroid)
    D = make_pose(Rotation.from_rotvec(delta[:3]).as_matrix(), delta[3:])
    return T_true @ Tc @ np.linalg.inv(D) @ np.linalg.inv(Tc)


def _xyt(p) -> np.ndarray:
    return np.array([p.T_table_obj[0, 3], p.T_table_obj[1, 3], np.arctan2(p.T_table_obj[1, 0], p.T_table_obj[0, 0])])


@pytest.mark.parametrize("delta", [np.array([0.0, 0.0, 0.0, 0.3, -0.2, 0.5]),       # shift, mm
                                   np.array([4e-4, -3e-4, 5e-4, 0.0, 0.0, 0.0])])    # about 0.02-0.03 deg
def test_table_pose_error_enters_sigma_as_it_moves_the_fit(taught, delta) -> None:
    """A known error of the table pose moves the located pose by what sigma's table term propagates:
    with the table covariance ``delta delta^T`` (the error itself), the term's 1-sigma per axis is the
    move. The old sigma had no such term: the move (0.08-0.5 mm here) was not in it at all."""
    model, _ = taught
    centroid = np.array([400.0, 200.0, 0.0])
    img = draw(CAM_B, placed(300.0, 160.0, 47.0), plate_top()[1], seed=5)
    p0 = pm.locate(pm.View(img, K, np.zeros(5), CAM_B), model, "plate")
    T_est = _table_estimate(CAM_B, centroid, delta)
    plain = pm.locate(pm.View(img, K, np.zeros(5), T_est), model, "plate")
    with_cov = pm.locate(pm.View(img, K, np.zeros(5), T_est, None, np.outer(delta, delta), centroid), model, "plate")
    assert p0 and plain and with_cov
    moved = _xyt(plain) - _xyt(p0)
    idx = [0, 1, 5]
    term = (with_cov.covariance - plain.covariance)[np.ix_(idx, idx)]
    sd = np.sqrt(np.clip(np.diag(term), 0, None))
    assert np.all(np.abs(np.abs(moved) - sd) <= 0.1 * np.abs(moved) + np.array([0.01, 0.01, 2e-5])), (moved, sd)
    assert max(abs(moved[0]), abs(moved[1])) > 0.05         # a real error, not noise
    assert with_cov.sigma["x_mm"] > plain.sigma["x_mm"] and not np.allclose(with_cov.covariance, plain.covariance)


def test_teach_keeps_its_table_error_and_a_model_without_it_borrows_the_pictures(taught) -> None:
    """Teaching from a picture whose table pose is uncertain by 0.05 mm along x and y: the obj frame
    inherits that (``teach_table_cov``, 0.05 mm per axis) and every later pose carries it, with the edge
    bias of both pictures. A model stored before these terms existed takes the search picture's in
    their stead."""
    _, T_teach = taught
    centroid = np.array([400.0, 200.0, 0.0])
    cov = np.diag([0.0, 0.0, 0.0, 0.05 ** 2, 0.05 ** 2, 0.0])
    view = pm.View(draw(CAM_A, T_teach, plate_top()[1], seed=1), K, np.zeros(5), CAM_A, None, cov, centroid)
    m2, _ = pm.teach([view], HEIGHT)
    sd = np.sqrt(np.diag(m2.teach_table_cov))
    np.testing.assert_allclose(sd[:2], 0.05, rtol=0.05)
    assert sd[2] < 1e-5                                     # a shift of the plane does not turn the template
    again = pm.PhotoModel.from_dict(m2.to_dict())
    np.testing.assert_allclose(again.teach_table_cov, m2.teach_table_cov)
    legacy = {k: v for k, v in m2.to_dict().items() if k not in ("teach_table_cov", "teach_mm_per_px")}
    old = pm.PhotoModel.from_dict(legacy)
    assert old.teach_table_cov is None
    rep = pm.View(draw(CAM_B, placed(300.0, 160.0, 47.0), plate_top()[1], seed=5), K, np.zeros(5), CAM_B, None,
                  np.diag([0.0, 0.0, 0.0, 0.03 ** 2, 0.03 ** 2, 0.0]), centroid)
    pa, pb = (pm.locate(rep, m, "plate") for m in (m2, old))
    assert pa and pb
    ta, tb = (np.array(p.photo["cov_parts"]["table"]) for p in (pa, pb))
    # taught with 0.05 mm, searched with 0.03 mm: both in x and y; the legacy model 0.03 mm twice
    np.testing.assert_allclose(np.diag(ta)[:2], 0.05 ** 2 + 0.03 ** 2, rtol=0.05)
    np.testing.assert_allclose(np.diag(tb)[:2], 2 * 0.03 ** 2, rtol=0.05)
    # the edge bias of both pictures (the legacy model: the search picture's twice)
    here = pa.photo["cam_mm_per_px"]
    assert pa.photo["cov_parts"]["edge_bias_mm2"] == pytest.approx(m2.teach_mm_per_px ** 2 + here ** 2)
    assert pb.photo["cov_parts"]["edge_bias_mm2"] == pytest.approx(2 * here ** 2)
    assert 0.2 < m2.teach_mm_per_px < 1.0 and old.teach_mm_per_px is None
    bias = pm.EDGE_BIAS_PX ** 2 * (m2.teach_mm_per_px ** 2 + here ** 2)
    fit = np.array(pa.photo["cov_parts"]["fit"])
    assert pa.covariance[0, 0] == pytest.approx(fit[0, 0] + ta[0, 0] + bias, rel=1e-9)
