"""The plane search's compiled loops (app.vision.object_pose.search_kernels) against the numpy they
replace: the image scorer's scores for every pose, every distortion model OpenCV has, with and
without the visibility rule, for poses off the image and behind the camera too; the correlation's
spectra sums bit for bit."""

from __future__ import annotations

import numpy as np
import pytest

from app.vision.object_pose.search import _image_scorer
from app.vision.object_pose.search_kernels import conj_product_sum
from tests.vision.object_pose.test_locate import DIST, K
from tests.vision.object_pose.test_search import _bracket_scene, _horizontal_template

DISTORTIONS = {
    "none": None,
    "4": DIST[:4],
    "5": DIST,
    "8 rational": np.r_[DIST, 0.02, -0.01, 0.005],
    "12 thin prism": np.r_[DIST, 0.02, -0.01, 0.005, 1e-4, -2e-4, 3e-4, -1e-4],
}


def _template_and_poses(model, T_true, n=300, seed=5):
    M, P, D, normals = _horizontal_template(model, T_true, 3)
    rng = np.random.default_rng(seed)
    # most poses about the part, some far off the image (metres away, or where the camera stands)
    x = M[0, 3] + np.r_[rng.uniform(-30, 30, n - 20), rng.uniform(-3000, 3000, 20)]
    y = M[1, 3] + np.r_[rng.uniform(-30, 30, n - 20), rng.uniform(-3000, 3000, 20)]
    th = np.arctan2(M[1, 0], M[0, 0]) + rng.uniform(-np.pi, np.pi, n)
    w = np.where(np.arange(len(P)) % 3 == 0, 1.0, 0.5)
    return (x, y, th, P, D, w), normals


@pytest.mark.parametrize("name", list(DISTORTIONS))
def test_the_compiled_scorer_gives_the_numpy_scorers_numbers(name):
    model, T_true, scene, eimg = _bracket_scene()
    args, normals = _template_and_poses(model, T_true)
    dist = DISTORTIONS[name]
    fast = _image_scorer(eimg, K, dist, scene.T_cam_table)
    ref = _image_scorer(eimg, K, dist, scene.T_cam_table, compiled=False)
    for nrm in (normals, None):
        got, want = fast(*args, normals=nrm), ref(*args, normals=nrm)
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-12)
        assert np.all(got[-20:] == 0.0)          # off the image: nothing seen
        assert np.mean(got[:-20] > 0) > 0.5        # while about the part most poses see some edges


def test_behind_the_camera_and_tilted_sensors():
    model, T_true, scene, eimg = _bracket_scene()
    args, normals = _template_and_poses(model, T_true, n=60)
    # the camera turned round: every point behind it scores nothing, in both scorers
    T_back = np.diag([1.0, -1.0, -1.0, 1.0]) @ scene.T_cam_table
    for T in (T_back, scene.T_cam_table):
        got = _image_scorer(eimg, K, DIST, T)(*args, normals=normals)
        np.testing.assert_allclose(got, _image_scorer(eimg, K, DIST, T, compiled=False)(*args, normals=normals),
                                   rtol=0, atol=1e-12)
    assert np.all(_image_scorer(eimg, K, DIST, T_back)(*args, normals=normals) == 0.0)
    # a tilted sensor (14 coefficients) is left to the numpy scorer, which OpenCV projects for it
    tilted = np.r_[DIST, np.zeros(7), 0.01, -0.01]
    got = _image_scorer(eimg, K, tilted, scene.T_cam_table)(*args, normals=normals)
    np.testing.assert_array_equal(got, _image_scorer(eimg, K, tilted, scene.T_cam_table, compiled=False)(
        *args, normals=normals))


@pytest.mark.parametrize("k", [1, 4, 24])
def test_the_spectra_are_summed_as_numpy_sums_them(k):
    rng = np.random.default_rng(k)
    a, b = ((rng.standard_normal((k, 37, 20)) + 1j * rng.standard_normal((k, 37, 20))).astype(np.complex64)
            for _ in range(2))
    got = conj_product_sum(a, b)
    assert got.dtype == np.complex64
    np.testing.assert_array_equal(got, np.conj(np.einsum("kij,kij->ij", a, b)))
