"""The unexplained-edge test (app/vision/object_pose/verify.py): a straight line across the part (a cast
shadow) is set aside, clutter inside its outline is not."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
import trimesh

from app.geometry.model_edges import prepare_model, project_points_px
from app.geometry.transforms import make_pose, transform_points
from app.synth.scene import look_at_pose
from app.vision.object_pose.edge_image import prepare_image
from app.vision.object_pose.verify import MAX_LINES_ACROSS, on_lines_across, unexplained_edges


def _pixels(points: list[tuple[int, int]]) -> tuple[np.ndarray, np.ndarray]:
    P = np.unique(np.asarray(points, int), axis=0)
    return P[:, 0], P[:, 1]


def _segment(a, b) -> list[tuple[int, int]]:
    img = np.zeros((300, 300), np.uint8)
    cv2.line(img, a, b, 255, 1)
    v, u = np.nonzero(img)
    return list(zip(u, v))


OUTLINE = np.ones((300, 300), np.uint8)


def test_a_line_across_the_outline_is_set_aside_and_the_rest_is_not():
    line = _segment((10, 40), (290, 230))
    rng = np.random.default_rng(1)
    dots = [tuple(int(x) for x in rng.integers(0, 300, 2)) for _ in range(60)]
    iu, iv = _pixels(line + dots)
    far = np.ones(len(iu), bool)
    across = on_lines_across(iu, iv, far, OUTLINE)
    on_line = set(line)
    got = {(u, v) for u, v, a in zip(iu, iv, across) if a}
    assert len(got & on_line) >= 0.95 * len(on_line)
    assert len(got - on_line) <= 3                  # only dots that happen to lie on the line


def test_clutter_of_short_edges_is_not_a_line_across():
    rng = np.random.default_rng(2)
    pts: list = []
    for _ in range(40):                             # 40 edges of 15-30 px in all directions
        a = rng.integers(20, 280, 2)
        ang, n = rng.uniform(0, np.pi), rng.uniform(15, 30)
        b = np.clip(a + n * np.array([np.cos(ang), np.sin(ang)]), 0, 299).astype(int)
        pts += _segment(tuple(int(x) for x in a), tuple(int(x) for x in b))
    iu, iv = _pixels(pts)
    assert not on_lines_across(iu, iv, np.ones(len(iu), bool), OUTLINE).any()


def test_at_most_the_longest_lines_are_set_aside():
    lines = [_segment((10, y), (290, y + 20)) for y in (40, 120, 200)]
    iu, iv = _pixels([p for L in lines for p in L])
    across = on_lines_across(iu, iv, np.ones(len(iu), bool), OUTLINE)
    per_line = [sum(1 for u, v, a in zip(iu, iv, across) if a and (u, v) in set(L)) for L in lines]
    assert sum(n > 0.9 * len(L) for n, L in zip(per_line, lines)) == MAX_LINES_ACROSS


@pytest.fixture(scope="module")
def plate():
    """A 160 x 120 x 20 mm plate seen from above (1280 x 800 px, 600 mm away): the model, the camera,
    and its top face's corners in pixels."""
    mesh = trimesh.creation.box(bounds=[[0, 0, 0], [160, 120, 20]])
    model = prepare_model(mesh, "plate")
    K = np.array([[1400.0, 0, 640], [0, 1400.0, 400], [0, 0, 1]])
    T_table_obj = make_pose(None, [300.0, 200.0, 0.0])
    T_cam_table = look_at_pose(np.array([420.0, 150.0, 600.0]), np.array([380.0, 260.0, 0.0]))
    top = transform_points(T_cam_table @ T_table_obj, [[0, 0, 20], [160, 0, 20], [160, 120, 20], [0, 120, 20]])
    return model, K, T_cam_table @ T_table_obj, project_points_px(top, K, np.zeros(5))


def _picture(top_px: np.ndarray, inside) -> np.ndarray:
    img = np.full((800, 1280), 70, np.uint8)
    face = np.zeros_like(img)
    cv2.fillPoly(face, [np.rint(top_px * 16).astype(np.int32)], 255, cv2.LINE_AA, shift=4)
    img[face > 0] = 170
    inside(img, face > 0)
    noise = np.random.default_rng(3).normal(0, 1.5, img.shape)
    return np.clip(img + noise, 0, 255).astype(np.uint8)


def test_a_shadow_across_the_part_leaves_nothing_unexplained_but_clutter_does(plate):
    model, K, T_cam_obj, top = plate
    c, d = top.mean(axis=0), top[1] - top[0]

    def shadow(img, face):                      # a spindle's shadow: a dark band across the top face
        band = np.zeros_like(img)
        n = np.array([-d[1], d[0]]) / np.linalg.norm(d)
        corners = [c - 0.5 * n * 400 - 0.15 * d, c + 0.5 * n * 400 - 0.15 * d,
                   c + 0.5 * n * 400 + 0.1 * d, c - 0.5 * n * 400 + 0.1 * d]
        cv2.fillPoly(band, [np.rint(np.array(corners)).astype(np.int32)], 255)
        img[(band > 0) & face] = 95

    def clutter(img, face):                     # chips and small parts behind a part read in error
        rng = np.random.default_rng(4)
        for _ in range(30):
            p = c + rng.uniform(-0.4, 0.4, 2) * np.abs(d).max()
            cv2.rectangle(img, tuple(int(x) for x in p), tuple(int(x) for x in p + rng.uniform(6, 18, 2)), 30, -1)

    plain = unexplained_edges(prepare_image(_picture(top, lambda img, face: None)), model, T_cam_obj, K, np.zeros(5))
    shaded = unexplained_edges(prepare_image(_picture(top, shadow)), model, T_cam_obj, K, np.zeros(5))
    cluttered = unexplained_edges(prepare_image(_picture(top, clutter)), model, T_cam_obj, K, np.zeros(5))
    assert plain < 0.1 and shaded < 0.2, (plain, shaded)
    assert cluttered > 0.7, cluttered
    # recognition keeps the plain share (LocateOptions.lines_across off): the line counts there
    told = unexplained_edges(prepare_image(_picture(top, shadow)), model, T_cam_obj, K, np.zeros(5), lines_across=False)
    assert told > 0.7, told
