"""The image's encoding gamma read from the markers' cells: synthetic markers blurred in linear light
and encoded with a known gamma, and devset images as rendered (gamma 2.2) and re-encoded without
gamma (a machine-vision camera's default)."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from app.vision.encoding_gamma import BIAS_LIMIT_PX, GAMMA_RANGE, _nearest_zero, read_encoding_gamma
from app.vision.fiducials import detect_markers, locate_table

DICT = "DICT_5X5_100"
DEVSET = Path(__file__).resolve().parents[3] / "shared" / "data" / "devset"


def _markers_image(gamma: float, blur_px: float, ids=(3, 17, 42, 71), cell_px: int = 12,
                   dark: float = 0.04, bright: float = 0.75):
    """Markers on a mid-grey field: radiance blurred (Gaussian, px) in linear light, then encoded
    ``255 * L ** (1 / gamma)``; a slight perspective so the cells are not pixel-aligned."""
    dic = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_5X5_100)
    side = 7 * cell_px
    L = np.full((480, 640), 0.3, np.float32)
    for k, mid in enumerate(ids):
        m = cv2.aruco.generateImageMarker(dic, mid, 7 * 40)          # 40 px per cell, then warped
        quiet = np.full((9 * 40, 9 * 40), 255, np.uint8)
        quiet[40:-40, 40:-40] = m
        x0, y0 = 60 + (k % 2) * 300, 50 + (k // 2) * 220
        pad = side / 7
        dst = np.float32([[x0 - pad, y0 - pad + 3], [x0 + side + pad + 2.3, y0 - pad],
                          [x0 + side + pad, y0 + side + pad + 1.7], [x0 - pad - 1.1, y0 + side + pad]])
        H = cv2.getPerspectiveTransform(np.float32([[0, 0], [360, 0], [360, 360], [0, 360]]), dst)
        # area-integrated: warp at 4x and average down (a pixel sums the light on it)
        big = cv2.warpPerspective(np.where(quiet > 0, bright, dark).astype(np.float32),
                                  np.diag([4, 4, 1]) @ H, (640 * 4, 480 * 4), flags=cv2.INTER_LINEAR,
                                  borderValue=-1)
        cover = cv2.warpPerspective(np.ones_like(quiet, np.float32), np.diag([4, 4, 1]) @ H, (640 * 4, 480 * 4))
        big = cv2.resize(np.where(cover > 0.5, big, 0), (640, 480), interpolation=cv2.INTER_AREA)
        cov = cv2.resize(cover, (640, 480), interpolation=cv2.INTER_AREA)
        L = np.where(cov > 0.999, big, L * (1 - cov) + big)
    if blur_px > 0:
        L = cv2.GaussianBlur(L, (0, 0), blur_px)
    return np.clip(np.rint(255 * np.clip(L, 0, 1) ** (1 / gamma)), 0, 255).astype(np.uint8)


def _read(image, assumed=2.2):
    found, gray = detect_markers(image, DICT)
    dic = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_5X5_100)
    return read_encoding_gamma(gray, {i: c[0] for i, c in found.items() if len(c) == 1}, dic, assumed=assumed)


@pytest.mark.parametrize("gamma", [1.0, 1.6, 2.2])
def test_gamma_is_read_from_blurred_markers(gamma):
    r = _read(_markers_image(gamma, blur_px=1.2))
    assert r.groups >= 6, r
    assert r.estimate == pytest.approx(gamma, abs=0.15), r
    if gamma == 2.2:
        assert r.gamma == 2.2 and abs(r.bias_px) < BIAS_LIMIT_PX, r
    if gamma == 1.0:      # read as 2.2 its edges sit far towards the bright side: the reading is used
        assert r.bias_px > 0.3 and r.gamma == r.estimate, r
        assert "read from the markers" in r.reason


@pytest.mark.parametrize("gamma", [1.0, 2.2])
def test_a_sharp_image_is_read_too(gamma):
    """Without blur the pixel's own area spreads each edge over one pixel: decoded with the wrong
    gamma, the 50 % point between two pixels still moves by a third of a pixel."""
    r = _read(_markers_image(gamma, blur_px=0.0))
    assert r.gamma == pytest.approx(gamma, abs=0.15), r


def test_too_few_markers_say_so():
    r = _read(_markers_image(1.0, blur_px=1.2, ids=(3,)))
    assert r.gamma == 2.2 and r.estimate is None and "too few or too small" in r.reason, r


def _devset(scene: str):
    if not (DEVSET / "manifest.json").exists():
        pytest.skip(f"the devset is not beside the repository ({DEVSET})")
    gt = json.loads((DEVSET / "setup" / f"{scene}.json").read_text())
    layout = json.loads((DEVSET / gt["marker_layout"]).read_text()) if isinstance(gt["marker_layout"], str) \
        else gt["marker_layout"]
    return gt, cv2.imread(str(DEVSET / gt["image"]), cv2.IMREAD_UNCHANGED), layout


def test_devset_image_as_rendered_and_without_gamma():
    gt, image, layout = _devset("setup_000")        # blur 0.99 px, gamma 2.2
    K, dist = np.asarray(gt["camera"]["K"], float), np.asarray(gt["camera"]["dist"], float)
    as_rendered = locate_table(image, K, dist, layout)
    assert as_rendered.gamma == 2.2 and as_rendered.gamma_reading.estimate == pytest.approx(2.2, abs=0.2)
    linear = np.clip(np.rint(255 * (image.astype(np.float64) / 255) ** 2.2), 0, 255).astype(np.uint8)
    got = locate_table(linear, K, dist, layout)
    assert got.gamma == pytest.approx(1.0, abs=0.1), got.gamma_reading
    assert any("read from the markers" in w for w in got.warnings)
    assert got.to_dict()["gamma_reading"]["bias_px"] > 0.4
    # the table read with it is as good as the table as rendered; read as 2.2 its markers disagree
    T_true = np.asarray(gt["T_cam_table"], float)
    off = lambda tp: float(np.linalg.norm(tp.T_cam_table[:3, 3] - T_true[:3, 3]))     # noqa: E731
    assert off(got) < max(1.5 * off(as_rendered), 0.1), (off(got), off(as_rendered))
    blind = locate_table(linear, K, dist, layout, read_gamma=False)
    assert not blind and "disagree" in blind.reason, blind


def _sweep(bias, assumed: float):
    """The whole grid read, as the reading did before it was read outward (the reference)."""
    gs = np.round(np.arange(GAMMA_RANGE[0] - 0.2, GAMMA_RANGE[1] + 0.2 + 1e-9, 0.1), 2)
    bs = np.array([bias(float(g)) for g in gs], dtype=float)
    fin = np.isfinite(bs)
    cross = np.nonzero(fin[:-1] & fin[1:] & (np.sign(bs[:-1]) * np.sign(bs[1:]) <= 0))[0]
    if not len(cross):
        return None
    i = cross[np.argmin(np.abs(gs[cross] - assumed))]
    return round(float(gs[i] + (gs[i + 1] - gs[i]) * bs[i] / (bs[i] - bs[i + 1] + 1e-12)), 2)


def test_the_sign_change_read_outward_is_the_one_the_whole_grid_gives():
    """Read from the assumed gamma outward, and only as far as a nearer change of sign could lie:
    the same estimate as the whole grid, for one zero, several, none, ties and unreadable points,
    in fewer readings where the zero lies near the assumed gamma."""
    rng = np.random.default_rng(3)
    cases = [lambda g: 0.3 * (g - 2.34), lambda g: -(g - 1.05), lambda g: 0.2, lambda g: None,
             lambda g: np.sin(4.0 * g), lambda g: (g - 2.05) * (g - 2.35),          # zeros both sides, a tie
             lambda g: None if 1.9 < g < 2.5 else g - 2.2, lambda g: (g - 2.15) * (g - 2.35)]
    for k in range(40):                                      # random wiggles with gaps
        c = rng.normal(0, 1, 4)
        gaps = rng.random(27) < 0.15
        cases.append(lambda g, c=c, gaps=gaps: None if gaps[int(round((g - 0.6) / 0.1))] else
                     float(np.polyval(c, g - 2.0)))
    for bias in cases:
        for assumed in (2.2, 1.0, 1.8, 2.23, 1.37, 2.96):
            calls = []
            got = _nearest_zero(lambda g: calls.append(g) or bias(g), assumed)
            assert got == _sweep(bias, assumed)
    calls = []
    assert _nearest_zero(lambda g: calls.append(g) or 0.3 * (g - 2.26), 2.2) == 2.26
    assert len(calls) <= 5
