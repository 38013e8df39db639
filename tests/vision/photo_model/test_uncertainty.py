"""Sigma's table-pose terms (app/vision/photo_model/uncertainty.py) on drawn pictures
(tests/vision/photo_model/drawn.py): a known table-pose error moves the fit by what the term
propagates; the teach picture's table error and edge bias are kept in the model and carried by every
later pose. Its calibration on rendered scenes: test_sigma_coverage.py."""

from __future__ import annotations

import numpy as np
import pytest

from app.geometry.transforms import make_pose
from app.vision import photo_model as pm
from tests.vision.photo_model.drawn import (
    CAM_A,
    CAM_B,
    HEIGHT,
    K,
    draw,
    placed,
    plate_top,
)


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
