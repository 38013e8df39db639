"""Scene generator: geometry of the rendered image against its ground truth."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
import trimesh
from scipy.ndimage import map_coordinates

from app.geometry.transforms import inv, transform_points
from app.synth.scene import (Scene, SceneObject, look_at_pose, place_on_table, project_points,
                             random_scene, render_scene)
from app.synth.table import marker_corners_table, printed_markers


def _plane_depth(K, dist, T_cam_table, u: int, v: int, z_table: float) -> float:
    """Camera z (mm) where the ray of pixel centre (u, v) meets the table plane z = z_table."""
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 50, 1e-14)
    ray = cv2.undistortPoints(np.array([[[u, v]]], float), K, dist, criteria=crit)
    d = np.array([*ray.reshape(2), 1.0])
    n = T_cam_table[:3, 2]                     # table z axis in the camera frame
    p0 = T_cam_table[:3, 3] + z_table * n      # a point of the plane
    return float(n @ p0 / (n @ d))


def _small_scene(seed: int, **kw) -> Scene:
    return random_scene(np.random.default_rng(seed), width=960, height=600, focal_px=(750, 950),
                        distance_mm=(500, 800), min_visible_markers=4, **kw)


@pytest.fixture(scope="module")
def rendered():
    scene = _small_scene(3)
    return scene, render_scene(scene, np.random.default_rng(0))


def _edge_crossings(scene, r):
    """Signed distance (px) from each visible marker edge's true position to the 50 % crossing of
    the linear radiance, measured along the edge normal at the edge midpoint."""
    errs = []
    K, dist, T = scene.K, scene.dist, scene.T_cam_table
    for m in printed_markers(scene.table_layout):
        if not r.truth["marker_visible"][m.id]:
            continue
        c = marker_corners_table(m)
        centre = c.mean(axis=0)
        for i in range(4):
            a, b = c[i], c[(i + 1) % 4]
            out = (a + b) / 2 - centre
            out /= np.linalg.norm(out)
            # averaged over 13 profiles along the middle of the edge (pixel phase and the
            # renderer's jitter average out); each profile from 2 mm inside (black) to 2 mm outside
            # (white label), 0.01 mm apart
            e = []
            for t in np.linspace(0.2, 0.8, 13):
                mid = a + t * (b - a)
                s = np.linspace(-2.0, 2.0, 401)
                uv = project_points(K, dist, T, mid + s[:, None] * out)
                val = map_coordinates(r.radiance, [uv[:, 1], uv[:, 0]], order=1)
                lo, hi = val[:50].mean(), val[-50:].mean()
                k = np.nonzero(val > (lo + hi) / 2)[0][0]
                s50 = s[k - 1] + (s[k] - s[k - 1]) * ((lo + hi) / 2 - val[k - 1]) / (val[k] - val[k - 1])
                uv_true = project_points(K, dist, T, mid[None])[0]
                uv50 = project_points(K, dist, T, (mid + s50 * out)[None])[0]
                e.append(np.sign(s50) * np.linalg.norm(uv50 - uv_true))
            errs.append(np.mean(e))
    return np.array(errs)


def test_marker_edges_lie_where_the_truth_projects(rendered):
    scene, r = rendered
    errs = _edge_crossings(scene, r)
    assert len(errs) >= 16
    assert np.median(np.abs(errs)) < 0.04, errs
    assert np.max(np.abs(errs)) < 0.12, errs
    assert abs(np.mean(errs)) < 0.03, "edge positions biased"


def test_aruco_finds_the_visible_markers_at_their_true_corners(rendered):
    from app.vision.bed_scale import distort_px
    from app.vision.fiducials import refine_marker_corners

    scene, r = rendered
    params = cv2.aruco.DetectorParameters()
    params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
    det = cv2.aruco.ArucoDetector(cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_5X5_100), params)
    corners, ids, _ = det.detectMarkers(r.image)
    assert ids is not None
    found = {int(i): c.reshape(4, 2) for i, c in zip(ids.ravel(), corners)}
    visible = {k for k, v in r.truth["marker_visible"].items() if v}
    assert len(visible) >= 4
    assert visible <= set(found)
    gray = cv2.cvtColor(r.image, cv2.COLOR_GRAY2BGR)[:, :, 0]
    errs = []
    for i in visible:
        truth = r.truth["marker_corners_px"][i]
        # OpenCV's own corners sit ~0.5 px inside the true square (its known bias, worse on these
        # ~20-40 px markers), roughly symmetric about the centre: loose checks only
        assert np.abs(found[i] - truth).max() < 1.5
        assert np.linalg.norm(found[i].mean(0) - truth.mean(0)) < 0.5
        # line fits to the marker border land on the true corners
        ideal = refine_marker_corners(gray, found[i], scene.K, scene.dist, 5)
        errs.append(np.linalg.norm(distort_px(ideal, scene.K, scene.dist) - truth, axis=1))
    errs = np.concatenate(errs)
    assert np.median(errs) < 0.08 and errs.max() < 0.3, errs


def test_depth_and_labels_agree_with_the_truth(rendered):
    scene, r = rendered
    T = r.truth["T_cam_table"]
    n_checked = 0
    for m in printed_markers(scene.table_layout):
        if not r.truth["marker_visible"][m.id]:
            continue
        uv = project_points(scene.K, scene.dist, T, m.T_table_marker[:3, 3][None])[0]
        u, v = np.round(uv).astype(int)
        assert r.labels[v, u] == 1
        z = _plane_depth(scene.K, scene.dist, T, u, v, 0.0)
        assert r.depth_mm[v, u] == pytest.approx(z, abs=1e-3)
        n_checked += 1
    assert n_checked >= 4
    # objects are labelled 2 + i where they are seen
    for i, ob in enumerate(scene.objects):
        top = ob.mesh.vertices[:, 2].max()
        b = ob.mesh.bounds
        c_obj = np.array([(b[0, 0] + b[1, 0]) / 2, (b[0, 1] + b[1, 1]) / 2, top])
        uv = project_points(scene.K, scene.dist, T @ ob.T_table_obj, c_obj[None])[0]
        u, v = np.round(uv).astype(int)
        if 0 <= u < scene.width and 0 <= v < scene.height:
            p_cam = transform_points(T @ ob.T_table_obj, c_obj[None])[0]
            if abs(r.depth_mm[v, u] - p_cam[2]) < 1.0:
                assert r.labels[v, u] == 2 + i


def test_background_label_and_infinite_depth():
    mesh = trimesh.creation.box(extents=(100, 80, 40))
    mesh.apply_translation((0, 0, 20))
    obj = SceneObject("block", mesh, place_on_table(mesh, 400, 200, 30))
    base = random_scene(np.random.default_rng(1), width=480, height=300, objects=[obj])
    # a low camera looking along the table: the top rows see past the table
    T = look_at_pose(np.array([400.0, -600.0, 250.0]), np.array([400.0, 200.0, 0.0]))
    K = np.array([[500.0, 0, 240], [0, 500, 150], [0, 0, 1]])
    scene = Scene(width=480, height=300, K=K, dist=np.zeros(5), T_cam_table=T,
                  table_mesh=base.table_mesh, table_layout=base.table_layout, objects=[obj],
                  jpeg_quality=None)
    r = render_scene(scene, np.random.default_rng(0))
    assert r.labels[0, 240] == 0 and np.isinf(r.depth_mm[0, 240])
    u, v = np.round(project_points(K, scene.dist, T, np.array([[400.0, 200.0, 40.0]]))[0]).astype(int)
    assert r.labels[v, u] == 2
    assert r.depth_mm[v, u] == pytest.approx(_plane_depth(K, scene.dist, T, u, v, 40.0), abs=1e-3)
    # the block casts a shadow towards the camera (light from behind, +y, 37 deg above the table,
    # shadow ~53 mm long): a table point 85 mm in front of the block's centre (on a flat land, not
    # in a T-slot) is in the shadow, the same point 150 mm to the side is not
    light = np.array([0.0, 0.8, 0.6])
    scene.light_dir_table = light
    r = render_scene(scene, np.random.default_rng(0))
    shade_pt = np.array([[400.0, 115.0, 0.0]])
    side_pt = np.array([[550.0, 115.0, 0.0]])
    ua, va = np.round(project_points(K, scene.dist, T, shade_pt)[0]).astype(int)
    ub, vb = np.round(project_points(K, scene.dist, T, side_pt)[0]).astype(int)
    assert r.labels[va, ua] == 1 and r.labels[vb, ub] == 1
    assert r.radiance[va, ua] < 0.75 * r.radiance[vb, ub]


def test_same_seed_same_image_and_another_seed_another_noise():
    scene = _small_scene(5, objects=[])
    scene.width, scene.height = 320, 200
    scene.K = scene.K * np.array([[1 / 3], [1 / 3], [1]])
    a = render_scene(scene, np.random.default_rng(7)).image
    b = render_scene(scene, np.random.default_rng(7)).image
    c = render_scene(scene, np.random.default_rng(8)).image
    assert np.array_equal(a, b)
    assert not np.array_equal(a, c)
    assert np.abs(a.astype(int) - c.astype(int)).mean() < 4   # only noise differs


def test_markers_off_the_table_top_are_refused():
    scene = _small_scene(2, objects=[])
    lay = {"dictionary": "DICT_5X5_100",
           "markers": [{"id": 1, "size_mm": 40.0,
                        "T_table_marker": [[1, 0, 0, 100], [0, 1, 0, 100], [0, 0, 1, 5], [0, 0, 0, 1]]}]}
    scene.table_layout = lay
    with pytest.raises(ValueError, match="only flat on the table top"):
        render_scene(scene, np.random.default_rng(0))


def test_truth_poses_are_consistent(rendered):
    scene, r = rendered
    for name, T_to in r.truth["T_table_obj"].items():
        assert np.allclose(r.truth["T_cam_obj"][name], r.truth["T_cam_table"] @ T_to)
    assert np.allclose(inv(inv(r.truth["T_cam_table"])), r.truth["T_cam_table"])


def test_inside_out_mesh_renders_like_the_right_one():
    """User CAD with flipped normals: neither culled away nor left dark."""
    good = trimesh.creation.box(extents=(120, 80, 50))
    good.apply_translation((0, 0, 25))
    bad = good.copy()
    bad.invert()
    base = _small_scene(4, objects=[])
    out = []
    for mesh in (good, bad):
        scene = Scene(width=320, height=200, K=base.K * np.array([[1 / 3], [1 / 3], [1]]),
                      dist=base.dist, T_cam_table=base.T_cam_table, table_mesh=base.table_mesh,
                      table_layout=base.table_layout,
                      objects=[SceneObject("block", mesh, place_on_table(mesh, 400, 200, 20))],
                      noise_sigma=0.0, jpeg_quality=None)
        out.append(render_scene(scene, np.random.default_rng(0)))
    assert (out[0].labels == 2).sum() > 500
    assert np.array_equal(out[0].labels, out[1].labels)
    assert np.allclose(out[0].depth_mm, out[1].depth_mm, equal_nan=True)
    assert np.abs(out[0].radiance - out[1].radiance).max() < 0.05


def test_tessellated_flat_face_has_no_speckles():
    """A flat face made of sliver triangles (a 256-section cylinder's top is a fan) shades evenly:
    the seams between coplanar triangles are not edges, and samples in slivers no pixel centre
    sees fall on the face's plane instead of through it."""
    cyl = trimesh.creation.cylinder(radius=60.0, height=40.0, sections=256)
    cyl.apply_translation((0, 0, 20.0))
    base = _small_scene(6, objects=[])
    T = look_at_pose(np.array([400.0, 150.0, 500.0]), np.array([400.0, 200.0, 0.0]))
    K = np.array([[600.0, 0, 160], [0, 600, 100], [0, 0, 1]])
    scene = Scene(width=320, height=200, K=K, dist=np.zeros(5), T_cam_table=T,
                  table_mesh=base.table_mesh, table_layout=base.table_layout,
                  objects=[SceneObject("disk", cyl, place_on_table(cyl, 400, 200, 0))],
                  noise_sigma=0.0, jpeg_quality=None, light_dir_table=np.array([0.0, 0.0, 1.0]))
    r = render_scene(scene, np.random.default_rng(0))
    c = project_points(K, scene.dist, T, np.array([[400.0, 200.0, 40.0]]))[0]
    vv, uu = np.mgrid[0:200, 0:320]
    inner = (np.hypot(uu - c[0], vv - c[1]) < 25) & (r.labels == 2)   # well inside the top (r ~ 60 px)
    assert inner.sum() > 1000
    top = r.radiance[inner]
    assert np.abs(top - np.median(top)).max() < 1e-3


def test_vignetting_darkens_the_corners_not_the_centre():
    """A top view of the table: with 50 % vignetting the corner's grey falls to about 0.5 ** (1 /
    gamma) of its value, the centre keeps its grey."""
    base = random_scene(np.random.default_rng(1), width=320, height=200, objects=[])
    T = look_at_pose(np.array([400.0, 200.0, 900.0]), np.array([400.0, 200.0, 0.0]))
    K = np.array([[250.0, 0, 160], [0, 250, 100], [0, 0, 1]])
    kw = dict(width=320, height=200, K=K, dist=np.zeros(5), T_cam_table=T, table_mesh=base.table_mesh,
              table_layout=base.table_layout, objects=[], jpeg_quality=None, noise_sigma=0.0, shadows=False)
    plain = render_scene(Scene(**kw), np.random.default_rng(0)).image.astype(float)
    vign = render_scene(Scene(**kw, vignetting=0.5), np.random.default_rng(0)).image.astype(float)
    centre = (slice(95, 105), slice(155, 165))
    corner = (slice(0, 6), slice(0, 6))
    assert vign[centre].mean() == pytest.approx(plain[centre].mean(), rel=0.02)
    ratio = vign[corner].mean() / plain[corner].mean()
    assert ratio == pytest.approx(0.5 ** (1 / 2.2), rel=0.08)
