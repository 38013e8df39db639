"""Camera intrinsic calibration from views of a chessboard or ChArUco board (Zhang's method via OpenCV).

Pure maths: images in, numbers and pictures out. No database, no web, no globals.

Pixel convention: OpenCV (u, v), u right, v down, in px, pixel centres at integer coordinates, so a
pixel is ``img[v, u]``. Board frame: origin at the first inner corner (chessboard) or at the board's
outer corner (ChArUco, OpenCV's own board frame), x along the rows of corners, y across them, z = x × y,
lengths in mm. Camera model: OpenCV pinhole with distortion [k1, k2, p1, p2, k3]; the intrinsics format
is the one in DESIGN.md (``{"width", "height", "K", "dist"}``).

Example (what a REST route does with uploaded files)::

    board = BoardSpec.model_validate_json('{"kind": "chessboard", "inner_corners": [9, 6], "square_mm": 25}')
    result = calibrate([f.read_bytes() for f in files], board, names=[f.name for f in files],
                       fix_aspect_ratio=True)
    if not result:                      # CalibrationFailure is falsy and carries the reason
        raise HTTPException(422, result.reason)
    intrinsics = result.intrinsics()    # {"width": 640, "height": 480, "K": [[...]], "dist": [...]}
    answer = result.to_dict()           # rms_px, per-view errors, coverage, warnings

A service that also wants the per-view corner pictures decodes and detects itself::

    images = [decode_image(b) for b in blobs]
    detections = [detect_board(img, board) for img in images]
    pictures = [draw_detection(img, det) for img, det in zip(images, detections)]
    result = calibrate_detections(detections, board, names=names)

References: Z. Zhang, "A flexible new technique for camera calibration", IEEE TPAMI 22(11), 2000
(the method behind ``cv2.calibrateCamera``); OpenCV samples/cpp/calibration.cpp (its detection
settings; ``subpix_half_window_px=11`` reproduces its published left01..14 reference, the default
caps the refinement window on small boards, see ``detect_board``).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any, Literal

import cv2
import numpy as np
from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

from app.vision.intrinsics import DEFAULT_SIGMA_C_PX, DEFAULT_SIGMA_F_REL, MAX_SIGMA_C_PX, MAX_SIGMA_F_REL

# ---------------------------------------------------------------------------------------------
# Board description
# ---------------------------------------------------------------------------------------------


class BoardSpec(BaseModel):
    """A calibration board: a chessboard (counted by inner corners) or a ChArUco board (by squares).

    For a chessboard give ``inner_corners`` (cols, rows), e.g. (9, 6) for a board of 10 x 7 squares;
    ``squares`` is accepted instead and converted (inner corners = squares - 1).
    For ChArUco give ``squares`` (cols, rows), ``marker_mm`` (< ``square_mm``) and ``dictionary``
    (an OpenCV predefined dictionary name such as "DICT_6X6_250"). ``legacy_pattern`` selects the
    marker layout of OpenCV < 4.6 for boards with an even number of rows printed by old software.
    """

    model_config = ConfigDict(
        frozen=True,
        extra="forbid",
        json_schema_extra={
            "examples": [
                {"kind": "chessboard", "inner_corners": [9, 6], "square_mm": 25.0},
                {
                    "kind": "charuco",
                    "squares": [5, 7],
                    "square_mm": 40.0,
                    "marker_mm": 20.0,
                    "dictionary": "DICT_6X6_250",
                },
            ]
        },
    )

    kind: Literal["chessboard", "charuco"]
    inner_corners: tuple[int, int] | None = Field(
        None, description="chessboard only: inner corners per row and per column (cols, rows)"
    )
    squares: tuple[int, int] | None = Field(None, description="number of squares (cols, rows)")
    square_mm: float = Field(gt=0, le=10_000, description="side of one square in mm")
    marker_mm: float | None = Field(None, gt=0, description="ChArUco only: side of one marker in mm")
    dictionary: str | None = Field(None, description='ChArUco only: OpenCV dictionary, e.g. "DICT_6X6_250"')
    legacy_pattern: bool = Field(False, description="ChArUco only: marker layout of OpenCV < 4.6")

    @field_validator("dictionary")
    @classmethod
    def _known_dictionary(cls, name: str | None) -> str | None:
        if name is None:
            return None
        if not name.startswith("DICT_") or not isinstance(getattr(cv2.aruco, name, None), int):
            raise ValueError(
                f"unknown ArUco dictionary {name!r}; use an OpenCV predefined name such as "
                '"DICT_4X4_50", "DICT_5X5_100", "DICT_6X6_250" or "DICT_APRILTAG_36h11"'
            )
        return name

    @model_validator(mode="after")
    def _complete(self) -> BoardSpec:
        if self.kind == "chessboard":
            if self.inner_corners is None:
                if self.squares is None:
                    raise ValueError("a chessboard needs inner_corners (cols, rows), e.g. [9, 6]")
                object.__setattr__(self, "inner_corners", (self.squares[0] - 1, self.squares[1] - 1))
            cols, rows = self.inner_corners  # type: ignore[misc]
            if min(cols, rows) < 2 or max(cols, rows) > 100:
                raise ValueError(f"chessboard inner_corners {cols} x {rows}: each must be 2..100")
        else:
            missing = [n for n in ("squares", "marker_mm", "dictionary") if getattr(self, n) is None]
            if missing:
                raise ValueError(f"a ChArUco board needs {', '.join(missing)}")
            cols, rows = self.squares  # type: ignore[misc]
            if min(cols, rows) < 2 or max(cols, rows) > 100:
                raise ValueError(f"ChArUco squares {cols} x {rows}: each must be 2..100")
            if self.marker_mm >= self.square_mm:  # type: ignore[operator]
                raise ValueError(
                    f"ChArUco marker_mm {self.marker_mm} must be smaller than square_mm {self.square_mm}"
                )
        return self

    def describe(self) -> str:
        """Short human description, e.g. "9 x 6 chessboard (25 mm)"."""
        if self.kind == "chessboard":
            c, r = self.inner_corners  # type: ignore[misc]
            return f"{c} x {r} chessboard ({self.square_mm:g} mm squares)"
        c, r = self.squares  # type: ignore[misc]
        return (
            f"{c} x {r} ChArUco board ({self.square_mm:g} mm squares, {self.marker_mm:g} mm "
            f"{self.dictionary} markers)"
        )

    @property
    def corner_count(self) -> int:
        """Number of corners the board offers (chessboard inner corners / ChArUco inner corners)."""
        if self.kind == "chessboard":
            c, r = self.inner_corners  # type: ignore[misc]
            return c * r
        c, r = self.squares  # type: ignore[misc]
        return (c - 1) * (r - 1)


def _charuco_board(board: BoardSpec) -> cv2.aruco.CharucoBoard:
    dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, board.dictionary))  # type: ignore[arg-type]
    cb = cv2.aruco.CharucoBoard(tuple(board.squares), board.square_mm, board.marker_mm, dictionary)  # type: ignore[arg-type]
    if board.legacy_pattern:
        cb.setLegacyPattern(True)
    return cb


def chessboard_object_points_mm(board: BoardSpec) -> np.ndarray:
    """Inner-corner positions of a chessboard in its own frame, shape (cols*rows, 3), mm, z = 0.

    Same order as ``cv2.findChessboardCorners``: row by row, x (along a row) varying fastest.
    """
    cols, rows = board.inner_corners  # type: ignore[misc]
    xy = np.mgrid[0:cols, 0:rows].T.reshape(-1, 2).astype(np.float64) * board.square_mm
    return np.hstack([xy, np.zeros((len(xy), 1))])


# ---------------------------------------------------------------------------------------------
# Detection
# ---------------------------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class BoardDetection:
    """Board corners found in one image (or the reason none could be used).

    found : bool, True when the view can enter a calibration.
    reason : str, empty when found, else a sentence ("board not found: ...").
    width, height : int, image size in px (0 when the file could not be decoded).
    uv_px : ndarray, shape (N, 2), detected corners, px.
    xyz_mm : ndarray, shape (N, 3), the same corners in the board frame, mm (z = 0).
    ids : ndarray, shape (N,), corner ids (chessboard: running index; ChArUco: OpenCV corner ids).
    marker_uv_px : ndarray, shape (M, 4, 2), ChArUco markers found (for the picture), px.
    marker_ids : ndarray, shape (M,).
    method : str, which detector produced the corners.
    board_kind : str, "chessboard" or "charuco".
    pattern : (cols, rows) of a complete chessboard corner grid, (0, 0) otherwise.
    """

    found: bool
    reason: str
    width: int
    height: int
    uv_px: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    xyz_mm: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    ids: np.ndarray = field(default_factory=lambda: np.zeros((0,), dtype=np.int64))
    marker_uv_px: np.ndarray = field(default_factory=lambda: np.zeros((0, 4, 2)))
    marker_ids: np.ndarray = field(default_factory=lambda: np.zeros((0,), dtype=np.int64))
    method: str = ""
    board_kind: str = "chessboard"
    pattern: tuple[int, int] = (0, 0)

    def __bool__(self) -> bool:
        return self.found


def decode_image(data: bytes | bytearray | memoryview) -> np.ndarray:
    """Decode an encoded image file (JPEG, PNG, BMP, TIFF, ...) to a BGR uint8 array, shape (H, W, 3).

    Raises ValueError with a sentence when the bytes are not an image OpenCV can read.
    """
    buf = np.frombuffer(bytes(data), dtype=np.uint8)
    image = cv2.imdecode(buf, cv2.IMREAD_COLOR) if buf.size else None
    if image is None:
        head = bytes(data[:8]).hex() if len(data) else "nothing"
        raise ValueError(
            f"not an image OpenCV can read ({len(data)} bytes, starting {head}); upload JPEG or PNG files"
        )
    return image


def _gray(image: np.ndarray) -> np.ndarray:
    if image.ndim == 2:
        gray = image
    elif image.ndim == 3 and image.shape[2] == 3:
        gray = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
    elif image.ndim == 3 and image.shape[2] == 4:
        gray = cv2.cvtColor(image, cv2.COLOR_BGRA2GRAY)
    elif image.ndim == 3 and image.shape[2] == 1:
        gray = image[:, :, 0]
    else:
        raise ValueError(f"image must have shape (H, W), (H, W, 3) or (H, W, 4); got {image.shape}")
    if gray.dtype != np.uint8:
        gray = cv2.normalize(gray, None, 0, 255, cv2.NORM_MINMAX).astype(np.uint8)
    return np.ascontiguousarray(gray)


# Detection works on at most this many pixels along the longer side; corners are then refined at
# full resolution. The classic detector gets slow and less reliable on 4K frames.
_DETECT_MAX_SIDE_PX = 1280
_SUBPIX_CRITERIA = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 30, 1e-4)


def _subpix_half_window(uv_px: np.ndarray, cols: int) -> int:
    """Half window for cornerSubPix: 11 px as in OpenCV's calibration sample, but never more than
    about 40 % of the smallest corner spacing, so that the window cannot reach a neighbouring corner."""
    grid = uv_px.reshape(-1, cols, 2)
    along = np.linalg.norm(np.diff(grid, axis=1), axis=2).min() if cols > 1 else np.inf
    across = np.linalg.norm(np.diff(grid, axis=0), axis=2).min() if grid.shape[0] > 1 else np.inf
    spacing = float(min(along, across))
    return int(np.clip(np.floor(0.4 * spacing), 2, 11))


def _detect_chessboard(gray: np.ndarray, board: BoardSpec, half_window_px: int | None) -> BoardDetection:
    h, w = gray.shape
    cols, rows = board.inner_corners  # type: ignore[misc]
    scale = min(1.0, _DETECT_MAX_SIDE_PX / max(h, w))
    small = cv2.resize(gray, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA) if scale < 1 else gray
    flags = cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE | cv2.CALIB_CB_FAST_CHECK
    ok, corners = cv2.findChessboardCorners(small, (cols, rows), flags)
    method = "findChessboardCorners+cornerSubPix"
    if not ok:
        # The sector-based detector copes better with blur, noise and large images.
        ok, corners = cv2.findChessboardCornersSB(
            small, (cols, rows), cv2.CALIB_CB_NORMALIZE_IMAGE | cv2.CALIB_CB_ACCURACY
        )
        method = "findChessboardCornersSB+cornerSubPix"
    if not ok or corners is None:
        return BoardDetection(
            found=False,
            reason=(
                f"board not found: no {cols} x {rows} inner-corner chessboard in this image; check that "
                "the whole board is visible, sharp and evenly lit, and that inner_corners counts inner "
                "corners (squares minus one)"
            ),
            width=w,
            height=h,
            board_kind="chessboard",
        )
    corners = corners.reshape(-1, 1, 2).astype(np.float32) / np.float32(scale)
    half = half_window_px if half_window_px is not None else _subpix_half_window(corners.reshape(-1, 2), cols)
    corners = cv2.cornerSubPix(gray, corners, (half, half), (-1, -1), _SUBPIX_CRITERIA)
    n = cols * rows
    return BoardDetection(
        found=True,
        reason="",
        width=w,
        height=h,
        uv_px=corners.reshape(-1, 2).astype(np.float64),
        xyz_mm=chessboard_object_points_mm(board),
        ids=np.arange(n, dtype=np.int64),
        method=method,
        board_kind="chessboard",
        pattern=(cols, rows),
    )


def _spans_plane(xyz_mm: np.ndarray) -> bool:
    """True when the board points are not all on one line (a homography needs a 2-D spread)."""
    if len(xyz_mm) < 4:
        return False
    centred = xyz_mm[:, :2] - xyz_mm[:, :2].mean(axis=0)
    s = np.linalg.svd(centred, compute_uv=False)
    return bool(s[1] > 1e-6 * max(s[0], 1e-12))


def _detect_charuco(gray: np.ndarray, board: BoardSpec, min_corners: int) -> BoardDetection:
    h, w = gray.shape
    cb = _charuco_board(board)
    detector = cv2.aruco.CharucoDetector(cb)
    ch_corners, ch_ids, m_corners, m_ids = detector.detectBoard(gray)
    markers = (
        np.asarray(m_corners, dtype=np.float64).reshape(-1, 4, 2) if m_ids is not None else np.zeros((0, 4, 2))
    )
    marker_ids = np.asarray(m_ids, dtype=np.int64).ravel() if m_ids is not None else np.zeros(0, np.int64)
    n = 0 if ch_ids is None else len(ch_ids)
    common = dict(width=w, height=h, marker_uv_px=markers, marker_ids=marker_ids,
                  method="CharucoDetector", board_kind="charuco")
    if n == 0:
        return BoardDetection(
            found=False,
            reason=(
                f"board not found: {len(marker_ids)} {board.dictionary} markers seen, no ChArUco corner "
                f"interpolated; check squares, dictionary and legacy_pattern against the printed board"
            ),
            **common,
        )
    ids = np.asarray(ch_ids, dtype=np.int64).ravel()
    uv = np.asarray(ch_corners, dtype=np.float64).reshape(-1, 2)
    xyz = np.asarray(cb.getChessboardCorners(), dtype=np.float64)[ids]
    if n < min_corners or not _spans_plane(xyz):
        return BoardDetection(
            found=False,
            reason=(
                f"too few board corners: {n} ChArUco corners found (need at least {min_corners}, not "
                "all on one line); show more of the board"
            ),
            uv_px=uv,
            xyz_mm=xyz,
            ids=ids,
            **common,
        )
    return BoardDetection(found=True, reason="", uv_px=uv, xyz_mm=xyz, ids=ids, **common)


def detect_board(
    image: np.ndarray,
    board: BoardSpec,
    min_charuco_corners: int = 6,
    subpix_half_window_px: int | None = None,
) -> BoardDetection:
    """Find the board's corners in one image.

    image : ndarray, shape (H, W) or (H, W, 3) BGR, uint8 (other depths are rescaled).
    board : BoardSpec.
    min_charuco_corners : int, a ChArUco view with fewer corners is reported as not usable.
    subpix_half_window_px : int or None, chessboard only: half side of the ``cornerSubPix`` search
        window. None (default) = 11 px capped at 40 % of the smallest corner spacing. 11 reproduces
        OpenCV's calibration sample exactly, including its failure on small boards: on left02.jpg of
        OpenCV's sample set an 11 px half window lets a corner jump 5.9 px to the wrong place (that
        view's 1.18 px error in the published left_intrinsics.yml); the capped window does not.

    Chessboard: ``findChessboardCorners`` (falls back to ``findChessboardCornersSB``) then
    ``cornerSubPix``; only complete boards count. ChArUco: ``cv2.aruco.CharucoDetector``; partial
    boards count. Never raises for "no board": the detection has ``found=False`` and a reason.
    """
    gray = _gray(np.asarray(image))
    if board.kind == "chessboard":
        return _detect_chessboard(gray, board, subpix_half_window_px)
    return _detect_charuco(gray, board, min_charuco_corners)


# ---------------------------------------------------------------------------------------------
# Coverage
# ---------------------------------------------------------------------------------------------

_CELL_NAMES = (
    ("top-left", "top", "top-right"),
    ("left", "centre", "right"),
    ("bottom-left", "bottom", "bottom-right"),
)
_CORNER_CELLS = ((0, 0), (0, 2), (2, 0), (2, 2))


@dataclass(frozen=True)
class Coverage:
    """How much of the image the detected corners reached, over all used views.

    area_fraction : float, fraction of the image area inside the union of the per-view convex hulls
        of the corners (0..1).
    cells_reached : tuple of 3 tuples of 3 bools, the image cut into a 3 x 3 grid (rows top to bottom,
        columns left to right); a cell is reached when at least one corner lies in it.
    grid_fraction : float, reached cells / 9.
    corners_missing : tuple[str, ...], the image-corner cells never reached ("top-left", ...).
    """

    area_fraction: float
    cells_reached: tuple[tuple[bool, bool, bool], ...]
    grid_fraction: float
    corners_missing: tuple[str, ...]

    def warning(self) -> str | None:
        """A sentence when the board never reached one or more image corners, else None."""
        if not self.corners_missing:
            return None
        missing = self.corners_missing
        where = missing[0] if len(missing) == 1 else ", ".join(missing[:-1]) + " and " + missing[-1]
        plural = "corner" if len(missing) == 1 else "corners"
        return (
            f"coverage: the board never reached the {where} {plural} of the image (detected corners "
            f"cover {100 * self.area_fraction:.0f}% of the image area, {round(9 * self.grid_fraction)} of 9 "
            f"grid cells); lens distortion there is extrapolated, add views with the board near "
            f"{'that corner' if len(missing) == 1 else 'those corners'}"
        )

    def to_dict(self) -> dict[str, Any]:
        return {
            "area_fraction": round(self.area_fraction, 4),
            "grid_fraction": round(self.grid_fraction, 4),
            "cells_reached": [list(r) for r in self.cells_reached],
            "corners_missing": list(self.corners_missing),
        }


def measure_coverage(uv_px_per_view: Sequence[np.ndarray], width: int, height: int) -> Coverage:
    """Coverage of the image by board corners.

    uv_px_per_view : sequence of ndarray, each shape (N_i, 2), corners of one view in px.
    width, height : int, image size in px.
    """
    if width <= 0 or height <= 0:
        raise ValueError(f"image size must be positive, got {width} x {height}")
    # Rasterise hulls on a grid of at most 320 px along the longer side: plenty for a fraction.
    s = min(1.0, 320.0 / max(width, height))
    mw, mh = max(1, round(width * s)), max(1, round(height * s))
    mask = np.zeros((mh, mw), np.uint8)
    reached = np.zeros((3, 3), bool)
    for uv in uv_px_per_view:
        uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
        if len(uv) == 0:
            continue
        inside = (uv[:, 0] >= 0) & (uv[:, 0] < width) & (uv[:, 1] >= 0) & (uv[:, 1] < height)
        uv_in = uv[inside]
        col = np.minimum((uv_in[:, 0] * 3 / width).astype(int), 2)
        row = np.minimum((uv_in[:, 1] * 3 / height).astype(int), 2)
        reached[row, col] = True
        if len(uv) >= 3:
            hull = cv2.convexHull(np.round(uv * s).astype(np.int32).reshape(-1, 1, 2))
            cv2.fillConvexPoly(mask, hull, 1)
    missing = tuple(_CELL_NAMES[r][c] for r, c in _CORNER_CELLS if not reached[r, c])
    return Coverage(
        area_fraction=float(mask.mean()),
        cells_reached=tuple(tuple(bool(x) for x in row) for row in reached),
        grid_fraction=float(reached.sum() / 9.0),
        corners_missing=missing,
    )


# ---------------------------------------------------------------------------------------------
# Calibration
# ---------------------------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class ViewReport:
    """One input image in a calibration.

    index : int, 0-based position in the input list.
    name : str, file name or "image <index+1>".
    found : bool, board detected.
    used : bool, entered the calibration.
    reason : str, why not found / not used (empty when used).
    n_points : int, corners detected.
    rms_px : float | None, reprojection RMS of this view after calibration, px (None when not used).
    detection : BoardDetection.
    """

    index: int
    name: str
    found: bool
    used: bool
    reason: str
    n_points: int
    rms_px: float | None
    detection: BoardDetection

    def to_dict(self) -> dict[str, Any]:
        return {
            "index": self.index,
            "name": self.name,
            "found": self.found,
            "used": self.used,
            "reason": self.reason,
            "n_points": self.n_points,
            "rms_px": None if self.rms_px is None else round(self.rms_px, 4),
        }


def _bounded(v: float, floor: float, ceiling: float) -> float:
    """``v`` between ``floor`` and ``ceiling``; ``ceiling`` where it is not finite."""
    return float(np.clip(v, floor, ceiling)) if np.isfinite(v) else float(ceiling)


@dataclass(frozen=True, eq=False)
class CalibrationResult:
    """Intrinsics from a successful calibration.

    width, height : int, image size in px.
    K : ndarray, shape (3, 3), camera matrix [[fx, 0, cx], [0, fy, cy], [0, 0, 1]], px.
    dist : ndarray, shape (5,), [k1, k2, p1, p2, k3] (OpenCV model, dimensionless).
    rms_px : float, reprojection RMS over all corners of all used views, px.
    std_px : dict, one-sigma uncertainty of fx, fy, cx, cy from OpenCV's covariance, px.
    views : tuple[ViewReport, ...], every input image in input order.
    coverage : Coverage.
    warnings : tuple[str, ...], sentences for the operator (coverage, outlier views).
    flags : tuple[str, ...], OpenCV calibration flags used.
    """

    width: int
    height: int
    K: np.ndarray
    dist: np.ndarray
    rms_px: float
    std_px: dict[str, float]
    views: tuple[ViewReport, ...]
    coverage: Coverage
    warnings: tuple[str, ...]
    flags: tuple[str, ...]
    board: BoardSpec

    def __bool__(self) -> bool:
        return True

    @property
    def n_used(self) -> int:
        return sum(v.used for v in self.views)

    def intrinsics(self) -> dict[str, Any]:
        """The DESIGN.md intrinsics format: {"width", "height", "K", "dist", "sigma"}.

        ``sigma`` ({"f_rel", "c_px"}, 1 sigma) says how well this calibration fixed K: OpenCV's own
        estimate (the larger of fx and fy relative, of cx and cy in px), never below
        :data:`~app.vision.intrinsics.DEFAULT_INTRINSICS_SIGMA`. OpenCV's estimate assumes independent
        corner errors and is too small for a good calibration (left01-14: 0.08 % in f, where two
        careful calibrations of those images differ by 0.5 %), so the default is its floor; for a poor
        one it is the larger (4 ChArUco views: 3.4 % in f, 11 px in cy) and every located object's
        sigma then says so."""
        f = np.array([self.K[0, 0], self.K[1, 1]], dtype=np.float64)
        f_rel = float(np.max(np.array([self.std_px.get("fx", 0.0), self.std_px.get("fy", 0.0)]) / f))
        c_px = float(np.max(np.array([self.std_px.get("cx", 0.0), self.std_px.get("cy", 0.0)])))  # NaN stays
        return {
            "width": self.width,
            "height": self.height,
            "K": [[float(x) for x in row] for row in self.K],
            "dist": [float(x) for x in self.dist],
            # within the DESIGN format's bounds; an estimate OpenCV could not make (a degenerate
            # calibration: not finite) is taken at those bounds, as unknown
            "sigma": {"f_rel": _bounded(f_rel, DEFAULT_SIGMA_F_REL, MAX_SIGMA_F_REL),
                      "c_px": _bounded(c_px, DEFAULT_SIGMA_C_PX, MAX_SIGMA_C_PX)},
        }

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready summary for the API."""
        return {
            "intrinsics": self.intrinsics(),
            "rms_px": round(self.rms_px, 4),
            "std_px": {k: round(v, 4) for k, v in self.std_px.items()},
            "n_views_used": self.n_used,
            "views": [v.to_dict() for v in self.views],
            "coverage": self.coverage.to_dict(),
            "warnings": list(self.warnings),
            "flags": list(self.flags),
            "board": self.board.model_dump(),
        }


@dataclass(frozen=True, eq=False)
class CalibrationFailure:
    """A calibration that could not be done; falsy, ``reason`` is the sentence for the operator."""

    reason: str
    views: tuple[ViewReport, ...]

    def __bool__(self) -> bool:
        return False

    def to_dict(self) -> dict[str, Any]:
        return {"reason": self.reason, "views": [v.to_dict() for v in self.views]}


def _flag_names(fix_aspect_ratio: bool, zero_tangent_dist: bool, fix_k3: bool) -> tuple[int, tuple[str, ...]]:
    flags, names = 0, []
    for on, value, name in (
        (fix_aspect_ratio, cv2.CALIB_FIX_ASPECT_RATIO, "CALIB_FIX_ASPECT_RATIO"),
        (zero_tangent_dist, cv2.CALIB_ZERO_TANGENT_DIST, "CALIB_ZERO_TANGENT_DIST"),
        (fix_k3, cv2.CALIB_FIX_K3, "CALIB_FIX_K3"),
    ):
        if on:
            flags |= value
            names.append(name)
    return flags, tuple(names)


def _list_failed(views: Sequence[ViewReport], limit: int = 6) -> str:
    bad = [v for v in views if not v.used]
    parts = [f"{v.name}: {v.reason}" for v in bad[:limit]]
    if len(bad) > limit:
        parts.append(f"and {len(bad) - limit} more")
    return "; ".join(parts)


def calibrate_detections(
    detections: Sequence[BoardDetection],
    board: BoardSpec,
    *,
    names: Sequence[str] | None = None,
    fix_aspect_ratio: bool = False,
    zero_tangent_dist: bool = False,
    fix_k3: bool = False,
    min_views: int = 3,
    outlier_factor: float = 3.0,
) -> CalibrationResult | CalibrationFailure:
    """Calibrate from board detections (one per image, in input order).

    detections : sequence of BoardDetection from ``detect_board`` (or a decoding failure).
    board : BoardSpec the detections were made with.
    names : optional file names for the messages; default "image 1", "image 2", ...
    fix_aspect_ratio : keep fx / fy at 1 (``CALIB_FIX_ASPECT_RATIO``, as OpenCV's reference sample).
    zero_tangent_dist, fix_k3 : hold p1 = p2 = 0 / k3 = 0 (for lenses with little distortion or
        few views, and to compare with tools using a 2-term radial model).
    min_views : int, refuse with a reason when fewer usable views remain.
    outlier_factor : float, a used view whose RMS exceeds this multiple of the median view RMS (and
        0.5 px) gets a warning naming it.

    Views whose image size differs from the first decodable image are not used (reason given).
    Returns a CalibrationResult, or a falsy CalibrationFailure whose reason names the failed images.
    """
    if min_views < 1:
        raise ValueError(f"min_views must be at least 1, got {min_views}")
    n = len(detections)
    if names is None:
        names = [f"image {i + 1}" for i in range(n)]
    if len(names) != n:
        raise ValueError(f"{len(names)} names given for {n} images")
    sizes = [(d.width, d.height) for d in detections if d.width > 0 and d.height > 0]
    size = sizes[0] if sizes else (0, 0)

    reports: list[ViewReport] = []
    for i, (det, name) in enumerate(zip(detections, names)):
        reason, usable = det.reason, det.found
        if usable and (det.width, det.height) != size:
            usable = False
            reason = (
                f"image is {det.width} x {det.height} px but the first image is {size[0]} x {size[1]} px; "
                "calibrate one camera resolution at a time"
            )
        reports.append(ViewReport(i, str(name), det.found, usable, reason, len(det.uv_px), None, det))

    used = [r for r in reports if r.used]
    if len(used) < min_views:
        head = (
            f"too few usable views: the {board.describe()} was found in {len(used)} of {n} images, "
            f"need at least {min_views}"
        )
        detail = _list_failed(reports)
        return CalibrationFailure(
            reason=head + (f" ({detail})" if detail else "") + "; take more views showing the whole board",
            views=tuple(reports),
        )

    flags, flag_names = _flag_names(fix_aspect_ratio, zero_tangent_dist, fix_k3)
    obj = [r.detection.xyz_mm.astype(np.float32).reshape(-1, 1, 3) for r in used]
    img = [r.detection.uv_px.astype(np.float32).reshape(-1, 1, 2) for r in used]
    K0 = np.eye(3)  # with CALIB_FIX_ASPECT_RATIO OpenCV keeps fx/fy of the initial K, i.e. 1
    try:
        rms, K, dist, _rvecs, _tvecs, std_intr, _std_extr, per_view = cv2.calibrateCameraExtended(
            obj, img, size, K0, np.zeros(5), flags=flags
        )
    except cv2.error as exc:
        msg = str(exc).strip().splitlines()[-1] if str(exc).strip() else repr(exc)
        return CalibrationFailure(
            reason=(
                f"calibration failed in OpenCV with {len(used)} views ({msg}); the views are probably too "
                "similar: tilt the board differently between views"
            ),
            views=tuple(reports),
        )
    K = np.asarray(K, dtype=np.float64)
    dist = np.asarray(dist, dtype=np.float64).ravel()[:5]
    if not (np.all(np.isfinite(K)) and np.all(np.isfinite(dist)) and np.isfinite(rms)) or K[0, 0] <= 0:
        return CalibrationFailure(
            reason=f"calibration diverged with {len(used)} views (non-finite result); add more varied views",
            views=tuple(reports),
        )
    per_view = np.asarray(per_view, dtype=np.float64).ravel()
    it = iter(per_view)
    reports = [
        ViewReport(r.index, r.name, r.found, r.used, r.reason, r.n_points, float(next(it)) if r.used else None,
                   r.detection)
        for r in reports
    ]
    std = np.asarray(std_intr, dtype=np.float64).ravel()
    std_px = {k: float(std[j]) for j, k in enumerate(("fx", "fy", "cx", "cy"))}

    warnings: list[str] = []
    coverage = measure_coverage([r.detection.uv_px for r in reports if r.used], size[0], size[1])
    if (w := coverage.warning()) is not None:
        warnings.append(w)
    if len(used) < n:
        warnings.append(f"{n - len(used)} of {n} images not used: {_list_failed(reports)}")
    med = float(np.median(per_view))
    for r in reports:
        if r.used and r.rms_px is not None and r.rms_px > max(outlier_factor * med, 0.5):
            warnings.append(
                f"view {r.name} has a reprojection error of {r.rms_px:.2f} px, {r.rms_px / med:.1f} x the "
                f"median {med:.2f} px; check it for motion blur or a bent board and consider leaving it out"
            )

    return CalibrationResult(
        width=size[0],
        height=size[1],
        K=K,
        dist=dist,
        rms_px=float(rms),
        std_px=std_px,
        views=tuple(reports),
        coverage=coverage,
        warnings=tuple(warnings),
        flags=flag_names,
        board=board,
    )


def calibrate(
    images: Sequence[np.ndarray | bytes],
    board: BoardSpec,
    *,
    names: Sequence[str] | None = None,
    fix_aspect_ratio: bool = False,
    zero_tangent_dist: bool = False,
    fix_k3: bool = False,
    min_views: int = 3,
    min_charuco_corners: int = 6,
    subpix_half_window_px: int | None = None,
) -> CalibrationResult | CalibrationFailure:
    """Calibrate a camera from images of a board.

    images : sequence of decoded images (ndarray, (H, W) or (H, W, 3) BGR uint8) or encoded file
        bytes (JPEG/PNG/...); bytes that do not decode become a failed view with the reason.
    board : BoardSpec.
    Other arguments: see ``calibrate_detections`` and ``detect_board``.

    Returns CalibrationResult (truthy) or CalibrationFailure (falsy, with ``reason``).
    """
    detections = []
    for image in images:
        if isinstance(image, (bytes, bytearray, memoryview)):
            try:
                image = decode_image(image)
            except ValueError as exc:
                detections.append(BoardDetection(found=False, reason=str(exc), width=0, height=0,
                                                 board_kind=board.kind))
                continue
        detections.append(
            detect_board(
                image, board, min_charuco_corners=min_charuco_corners, subpix_half_window_px=subpix_half_window_px
            )
        )
    return calibrate_detections(
        detections,
        board,
        names=names,
        fix_aspect_ratio=fix_aspect_ratio,
        zero_tangent_dist=zero_tangent_dist,
        fix_k3=fix_k3,
        min_views=min_views,
    )


# ---------------------------------------------------------------------------------------------
# Picture
# ---------------------------------------------------------------------------------------------


def _wrap(text: str, width_px: int, scale: float) -> list[str]:
    char_px = max(1, int(cv2.getTextSize("M", cv2.FONT_HERSHEY_SIMPLEX, scale, 1)[0][0]))
    per_line = max(10, width_px // char_px)
    lines, line = [], ""
    for word in text.split():
        if line and len(line) + 1 + len(word) > per_line:
            lines.append(line)
            line = word
        else:
            line = f"{line} {word}".strip()
    if line:
        lines.append(line)
    return lines


def draw_detection(image: np.ndarray, detection: BoardDetection) -> np.ndarray:
    """Picture of one view: corners (OpenCV's coloured chessboard rows / ChArUco corner ids), ChArUco
    markers, and a banner with the outcome ("54 corners" or the failure reason).

    image : ndarray, the image the detection was made on, (H, W) or (H, W, 3) BGR uint8; returned
        picture is a new BGR uint8 array of the same size (the input is not modified).
    """
    if image is None or np.asarray(image).size == 0:
        canvas = np.full((240, 320, 3), 64, np.uint8)
    else:
        image = np.asarray(image)
        if image.dtype != np.uint8:
            image = cv2.normalize(image, None, 0, 255, cv2.NORM_MINMAX).astype(np.uint8)
        canvas = cv2.cvtColor(image, cv2.COLOR_GRAY2BGR) if image.ndim == 2 else image[:, :, :3].copy()
    h, w = canvas.shape[:2]
    thickness = max(1, round(max(h, w) / 640))
    if len(detection.marker_ids):
        cv2.aruco.drawDetectedMarkers(
            canvas, detection.marker_uv_px.astype(np.float32).reshape(-1, 1, 4, 2),
            detection.marker_ids.reshape(-1, 1).astype(np.int32),
        )
    if len(detection.uv_px):
        uv = detection.uv_px.astype(np.float32).reshape(-1, 1, 2)
        cols, rows = detection.pattern
        if detection.board_kind == "chessboard" and cols * rows == len(uv):
            cv2.drawChessboardCorners(canvas, (cols, rows), uv, detection.found)
        else:
            cv2.aruco.drawDetectedCornersCharuco(
                canvas, uv, detection.ids.reshape(-1, 1).astype(np.int32), (0, 255, 0)
            )
    if detection.found:
        text = f"{len(detection.uv_px)} corners found ({detection.method})"
        colour = (0, 160, 0)
    else:
        text = detection.reason or "board not found"
        colour = (0, 0, 200)
    scale = 0.45 * max(1.0, w / 640)
    lines = _wrap(text, w - 12, scale)
    line_h = int(cv2.getTextSize("Mg", cv2.FONT_HERSHEY_SIMPLEX, scale, 1)[0][1] * 1.9) + 2
    banner_h = line_h * len(lines) + 8
    cv2.rectangle(canvas, (0, 0), (w, min(h, banner_h)), colour, -1)
    for k, line in enumerate(lines):
        cv2.putText(canvas, line, (6, 4 + line_h * (k + 1) - line_h // 4), cv2.FONT_HERSHEY_SIMPLEX, scale,
                    (255, 255, 255), thickness, cv2.LINE_AA)
    return canvas
