"""The camera's encoding gamma, read from the table's markers in the image itself.

Every subpixel edge in this project is the 50 % crossing between two plateaus in *linear* light
(``(I / 255) ** gamma``). Decoded with the wrong gamma, a blurred edge's 50 % point moves towards
its bright or dark side, by up to half the blur: bright regions look larger, dark ones smaller. A
camera that outputs linear light (gamma 1, the default of many machine-vision cameras) read as the
usual 2.2 moves every edge 0.2-0.6 px towards the bright side; on the devset that loses half the
parts and makes the sigma over-confident.

The markers carry the measurement: their black and white cells have known, equal widths. Along
every row and column of cells the 50 % crossings of the dark-to-bright and bright-to-dark
transitions are measured in marker-cell units (through the homography of the marker's corners);
per marker and direction one least-squares fit ``d = offset + scale * x + polarity * bias`` (x from
the marker's centre)
separates the edge bias (which moves the two polarities apart) from the errors of the rough corners
(which move them together). The bias is a function of the decoding gamma; its root is the image's
gamma. Only the marker's own cells are used (the quiet zone around a marker may not be white).
Pixels: OpenCV (u right, v down), in the raw (distorted) image; a marker is small enough for its
homography to hold through the lens distortion.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import asdict, dataclass

import cv2
import numpy as np
from scipy.ndimage import map_coordinates

# An edge bias below this (px, at the assumed gamma) is not acted on: on sharp renders (no blur)
# the reading itself is off by up to 0.09 px at the true gamma (devset first half), while the devset
# encoded without gamma reads 0.23-0.61 px.
BIAS_LIMIT_PX = 0.15
GAMMA_RANGE = (0.8, 3.0)          # a reading outside it is not a camera's gamma: the assumed one is kept
MIN_CELL_PX = 4.0                 # smaller markers' cells have no plateau to measure against
MIN_GROUPS = 4                    # (marker, direction) fits needed: two markers
_STEP = 0.05                      # profile step, cells
_HALF = 0.45                      # a transition's crossing is searched within this many cells of it
_LINES = (0.35, 0.5, 0.65)        # where across a row of cells its profiles run (cell fractions)


@dataclass(frozen=True)
class GammaReading:
    """What the markers say about the image's encoding.

    gamma : the gamma to decode this image with (the estimate where the assumed one is measurably
        wrong, else the assumed one)
    assumed : the gamma assumed before looking (2.2 unless the caller knows better)
    estimate : the gamma at which the markers' dark and bright cells measure equally wide; None if
        the markers are too few or too small, or no gamma searched (0.6-3.2) explains the bias
    bias_px : at ``assumed``, how far each edge's 50 % point lies towards its bright side (px)
    groups : (marker, direction) fits the reading rests on
    reason : one sentence for the operator and the log
    """

    gamma: float
    assumed: float
    estimate: float | None
    bias_px: float | None
    groups: int
    reason: str

    @property
    def changed(self) -> bool:
        """The image is decoded with another gamma than the one assumed."""
        return self.gamma != self.assumed

    def to_dict(self) -> dict:
        return asdict(self)


def _cell_grid(dictionary: cv2.aruco.Dictionary, marker_id: int) -> np.ndarray | None:
    """(n + 2, n + 2) int: the marker's cells, 1 white, with its black border; None for an unknown id."""
    if not 0 <= marker_id < len(dictionary.bytesList):
        return None
    n = int(dictionary.markerSize)
    bits = cv2.aruco.Dictionary.getBitsFromByteList(dictionary.bytesList[marker_id:marker_id + 1], n)
    grid = np.zeros((n + 2, n + 2), int)
    grid[1:-1, 1:-1] = bits
    return grid


def _marker_transitions(gray: np.ndarray, grid: np.ndarray, corners_px: np.ndarray):
    """Profiles across one marker's inner transitions, in cell units.

    Returns per direction (rows, columns) a tuple (windows (M, S) grey levels, x_t (M,) transition
    positions in cells, polarity (M,) +1 dark-to-bright along x, -1 the other way, line
    (M,) index into the two level arrays, which hold per profile line the median grey level of its
    black and of its white cell middles. Transition positions are measured from the marker's centre."""
    n = grid.shape[0]
    H = cv2.getPerspectiveTransform(np.float32([[0, 0], [n, 0], [n, n], [0, n]]), np.float32(corners_px))
    xs = np.arange(0.0, n + 1e-9, _STEP)
    frac = xs - np.floor(xs)
    cell = np.minimum(np.floor(xs).astype(int), n - 1)
    middle = (frac > 0.3) & (frac < 0.7)
    win = np.arange(-_HALF, _HALF + 1e-9, _STEP)
    out = []
    for axis in (0, 1):
        windows, x_t, pol, lines = [], [], [], []
        dark_lv, bright_lv = [], []
        for r in range(n):
            cells = grid[r, :] if axis == 0 else grid[:, r]
            is_white = cells[cell] == 1
            if not (np.any(middle & is_white) and np.any(middle & ~is_white)):
                continue
            ks = [k for k in range(1, n) if cells[k] != cells[k - 1]]      # the marker's own
            for f in _LINES:
                pts = np.stack([xs, np.full_like(xs, r + f)], 1) if axis == 0 else \
                    np.stack([np.full_like(xs, r + f), xs], 1)
                uv = cv2.perspectiveTransform(pts[None], H)[0]
                val = map_coordinates(gray, [uv[:, 1], uv[:, 0]], order=1, mode="nearest")
                li = len(dark_lv)
                dark_lv.append(val[middle & ~is_white])
                bright_lv.append(val[middle & is_white])
                for k in ks:
                    wx = k + win
                    windows.append(np.interp(wx, xs, val))
                    x_t.append(k - n / 2)
                    pol.append(1 if cells[k] == 1 else -1)
                    lines.append(li)
        if windows:
            out.append((np.array(windows), np.array(x_t), np.array(pol), np.array(lines),
                        np.array([np.median(d) for d in dark_lv]), np.array([np.median(b) for b in bright_lv])))
    return out


def _group_bias(group, gamma: float) -> float | None:
    """The polarity term (cells) of one (marker, direction) fit at ``gamma``; None if too few crossings."""
    windows, x_t, pol, lines, dark_lv, bright_lv = group
    dec = lambda v: (np.asarray(v) / 255.0) ** gamma        # noqa: E731  grey (bilinear, float) -> linear light
    lo, hi = dec(dark_lv)[lines], dec(bright_lv)[lines]     # the decode is monotonic: it keeps medians
    ok = hi - lo > 0.05
    p = (dec(windows) - lo[:, None]) / np.maximum(hi - lo, 1e-9)[:, None]
    p = p * pol[:, None]                     # every window rising
    level = 0.5 * pol
    s = np.sign(p - level[:, None])
    change = s[:, :-1] * s[:, 1:] < 0
    one = ok & (change.sum(axis=1) == 1)
    if one.sum() < 12:
        return None
    rows = np.nonzero(one)[0]
    j = np.argmax(change[rows], axis=1)
    p0, p1 = p[rows, j], p[rows, j + 1]
    x_cross = -_HALF + _STEP * (j + (level[rows] - p0) / (p1 - p0))
    A = np.stack([np.ones(len(rows)), x_t[rows], pol[rows].astype(float)], axis=1)
    y = x_cross
    keep = np.ones(len(y), bool)
    for _ in range(3):                       # trimmed least squares: a crossing on a scratch is no edge
        coef, *_ = np.linalg.lstsq(A[keep], y[keep], rcond=None)
        r = y - A @ coef
        mad = 1.4826 * float(np.median(np.abs(r[keep]))) + 1e-6
        keep = np.abs(r) < 3 * mad
        if keep.sum() < 12:
            return None
    return float(coef[2])


#: a marker's white cells whose median grey reaches this are clipped at the sensor's top
CLIP_GREY = 250.0


def marker_transitions(gray: np.ndarray, corners_px: dict[int, np.ndarray],
                       dictionary: cv2.aruco.Dictionary) -> dict[int, tuple[list, float]]:
    """Each marker's profiles across its inner transitions (:func:`_marker_transitions`), read once for
    the gamma (:func:`read_encoding_gamma`) and for the clipping (:func:`clipped_edge_bias_px`):
    ``{id: (groups, cell px)}``. A marker of an unknown id or with cells under :data:`MIN_CELL_PX` is
    left out. gray : (H, W) uint8 raw image; corners_px : rough corners (4, 2) per id, OpenCV's order."""
    gray = np.asarray(gray, np.float64)
    out: dict[int, tuple[list, float]] = {}
    for mid, c in corners_px.items():
        c = np.asarray(c, float).reshape(4, 2)
        grid = _cell_grid(dictionary, int(mid))
        if grid is None:
            continue
        side = float(np.linalg.norm(np.roll(c, -1, axis=0) - c, axis=1).min()) / grid.shape[0]
        if side < MIN_CELL_PX:
            continue
        out[int(mid)] = (_marker_transitions(gray, grid, c), side)
    return out


def clipped_edge_bias_px(transitions: tuple[list, float], gamma: float) -> float:
    """How far a clipped marker's 50 % crossings lie towards their bright side (px; negative: towards
    the dark side), read from its own cells (``transitions``: one marker's entry of
    :func:`marker_transitions`) as :func:`read_encoding_gamma` reads the gamma; 0.0 where its white
    cells do not clip (there the crossings hold at the right gamma) or too few crossings are read.

    A white cell brighter than the sensor's top reads flat at 255: the level an edge's 50 % crossing
    is taken against is cut off, and the crossing moves towards the dark side, the marker's black
    square (and each black cell) looking smaller. Its cells have known, equal widths, so their
    crossings tell by how much; the border's edges, printed and lit alike, move as much."""
    groups, side = transitions
    if not groups or np.median(np.concatenate([g[5] for g in groups])) < CLIP_GREY:
        return 0.0
    b = [v for v in (_group_bias(g, gamma) for g in groups) if v is not None]
    return float(np.mean(b)) * side if b else 0.0


def _nearest_zero(bias: Callable[[float], float | None], assumed: float) -> float | None:
    """The gamma where ``bias`` (px, None where it cannot be read) changes sign, on a 0.1 grid over
    :data:`GAMMA_RANGE` grown by 0.2, linearly between the two grid points around it; of several, the
    one whose lower point lies nearest ``assumed``. The grid is read outward from ``assumed`` and only
    as far as a nearer change of sign could still lie: the same answer as reading it all, in a few
    readings instead of 27 when the image's gamma is near the assumed one."""
    gs = np.round(np.arange(GAMMA_RANGE[0] - 0.2, GAMMA_RANGE[1] + 0.2 + 1e-9, 0.1), 2)
    bs = np.full(len(gs), np.nan)
    read = np.zeros(len(gs), bool)
    dist = np.abs(gs - assumed)
    best = None
    for j in np.argsort(dist, kind="stable"):
        if best is not None and dist[j] > dist[best] + 0.1 + 1e-9:
            break                  # every pair whose lower point is as near as the best is read
        b = bias(float(gs[j]))
        bs[j], read[j] = (np.nan if b is None else b), True
        fin = read & np.isfinite(bs)
        cross = np.nonzero(fin[:-1] & fin[1:] & (np.sign(bs[:-1]) * np.sign(bs[1:]) <= 0))[0]
        if len(cross):
            best = int(cross[np.argmin(dist[cross])])
    if best is None:
        return None
    return round(float(gs[best] + (gs[best + 1] - gs[best]) * bs[best] / (bs[best] - bs[best + 1] + 1e-12)), 2)


def read_encoding_gamma(gray: np.ndarray, corners_px: dict[int, np.ndarray],
                        dictionary: cv2.aruco.Dictionary, assumed: float = 2.2,
                        transitions: dict[int, tuple[list, float]] | None = None) -> GammaReading:
    """The gamma to decode ``gray`` with, read from its markers.

    gray : (H, W) uint8 raw image; corners_px : rough corners (4, 2) per marker id, in OpenCV's
    order (the detector's); dictionary : the markers' ArUco dictionary; assumed : the gamma
    otherwise assumed; transitions : :func:`marker_transitions` of those markers if already read.
    The estimate replaces ``assumed`` only where the edge bias at ``assumed`` exceeds
    :data:`BIAS_LIMIT_PX` and the estimate lies in :data:`GAMMA_RANGE`.
    """
    if transitions is None:
        transitions = marker_transitions(gray, corners_px, dictionary)
    groups, cell_px = [], []
    for got, side in transitions.values():
        groups += got
        cell_px += [side] * len(got)

    def bias_px(g: float) -> tuple[float | None, int]:
        per = [(b, s) for b, s in ((_group_bias(gr, g), s) for gr, s in zip(groups, cell_px)) if b is not None]
        if len(per) < MIN_GROUPS:
            return None, len(per)
        return float(np.median([b * s for b, s in per])), len(per)

    b0, n = bias_px(assumed)
    if b0 is None:
        return GammaReading(assumed, assumed, None, None, n,
                            f"gamma {assumed:g} assumed: the markers are too few or too small to read it "
                            f"({n} usable of {MIN_GROUPS} needed)")
    estimate = _nearest_zero(lambda g: bias_px(g)[0] if abs(g - assumed) > 1e-9 else b0, assumed)
    if abs(b0) <= BIAS_LIMIT_PX:
        return GammaReading(assumed, assumed, estimate, round(b0, 3), n,
                            f"gamma {assumed:g} holds: edges sit {b0:+.2f} px off at it "
                            f"(within {BIAS_LIMIT_PX} px)")
    side = f"{abs(b0):.2f} px towards their {'bright' if b0 > 0 else 'dark'} side"
    if estimate is None or not GAMMA_RANGE[0] <= estimate <= GAMMA_RANGE[1]:
        return GammaReading(assumed, assumed, estimate, round(b0, 3), n,
                            f"gamma {assumed:g} kept: at it the markers' edges sit {side}, but no gamma in "
                            f"{GAMMA_RANGE[0]:g}-{GAMMA_RANGE[1]:g} explains that")
    return GammaReading(estimate, assumed, estimate, round(b0, 3), n,
                        f"gamma {estimate:g} read from the markers: at {assumed:g} their edges sit {side} "
                        f"(a camera with another gamma setting, or a scaled image)")
