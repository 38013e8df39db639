"""Drift monitoring of a sheet during cutting: four corner ROIs, errors in mm, three bands.

:class:`DriftMonitor` is a pure state machine. It is started from the four sheet corners found by
:func:`app.vision.sheet.find_sheet` (ordered nearest-to-origin first, counter-clockwise from above)
and fed one frame at a time. Each frame every corner is re-found inside a square region of interest
(``roi_px``, default 100 x 100 px) around its last position, from its two edges (subpixel 50 %
crossings, RANSAC + least-squares lines, intersection; see :func:`app.vision.sheet.refine_corner`).
The error of a corner is its distance in mm, on the sheet's top plane in the bed frame, from where
it was at the current datum. With thresholds ``l1_mm < l2_mm`` the decision is

* ``"ok"``: every corner error below L1: nothing to do;
* ``"redatum"``: the largest error in [L1, L2): a new work origin and angle are computed from the
  corners of this frame (``new_offset``); they become the datum for the following frames;
* ``"stop"``: the largest error at or above L2. A stop is latched: later frames answer ``"stop"``
  until :meth:`DriftMonitor.reset`;
* ``"frame_missing"``: no frame, bytes that do not decode, or a blank image;
* ``"corner_not_found"``: at least one corner was not found in its ROI (covered, sparks, moved out).

Missing frames and lost corners are never "ok": the caller (the monitoring service) decides whether
to pause. This module knows nothing about controllers, events or pages.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import ArrayLike

from app.vision.bed_scale import BedPlane
from app.vision.intrinsics import distort_px, undistort_px
from app.vision.sheet import BedOffset, SheetResult, refine_corner, to_gray, work_origin

OK = "ok"
REDATUM = "redatum"
STOP = "stop"
FRAME_MISSING = "frame_missing"
CORNER_NOT_FOUND = "corner_not_found"
DECISIONS = (OK, REDATUM, STOP, FRAME_MISSING, CORNER_NOT_FOUND)


@dataclass(frozen=True)
class DriftDecision:
    """What one frame means.

    Attributes
    ----------
    frame_index : int
        0 for the first frame given to :meth:`DriftMonitor.update`.
    decision : str
        One of ``DECISIONS``.
    reason : str
        A sentence with the measured numbers and the thresholds.
    errors_mm : ndarray (4,)
        Per corner: distance (mm, bed frame, sheet top plane) from the current datum; NaN if not found
        or no frame.
    errors_from_start_mm : ndarray (4,)
        The same against the corners the monitor was started with.
    corners_px : ndarray (4, 2) or None
        Corners found in this frame (raw px), NaN rows for corners not found.
    corners_bed_mm : ndarray (4, 2) or None
        The same in the bed frame.
    new_offset : BedOffset or None
        The new work offset when ``decision == "redatum"``.
    """

    frame_index: int
    decision: str
    reason: str
    errors_mm: np.ndarray
    errors_from_start_mm: np.ndarray
    corners_px: np.ndarray | None = None
    corners_bed_mm: np.ndarray | None = None
    new_offset: BedOffset | None = None

    @property
    def max_error_mm(self) -> float:
        e = self.errors_mm[np.isfinite(self.errors_mm)]
        return float(e.max()) if len(e) else float("nan")

    def as_dict(self) -> dict:
        def _f(a):
            return None if a is None else [None if not np.all(np.isfinite(x)) else np.round(x, 4).tolist() for x in a]

        return {
            "frame_index": self.frame_index,
            "decision": self.decision,
            "reason": self.reason,
            "errors_mm": [None if not np.isfinite(x) else round(float(x), 4) for x in self.errors_mm],
            "errors_from_start_mm": [None if not np.isfinite(x) else round(float(x), 4) for x in self.errors_from_start_mm],
            "corners_px": _f(self.corners_px),
            "corners_bed_mm": _f(self.corners_bed_mm),
            "new_offset": None if self.new_offset is None else self.new_offset.as_dict(),
        }


class DriftMonitor:
    """Track the four sheet corners frame by frame and decide ok / redatum / stop.

    Parameters
    ----------
    start_corners_px : array-like (4, 2)
        Raw pixels of the sheet's corners at the start, ordered as :class:`SheetResult` orders them.
    plane : BedPlane
        Intrinsics, ``T_cam_bed`` and the sheet's top plane (``height_mm`` = thickness).
    l1_mm, l2_mm : float
        Thresholds, ``0 < l1_mm < l2_mm``.
    margin_mm : float
        Origin margin used for the new offset on a redatum (0..20 mm).
    roi_px : int
        Side of the square region searched around each corner (default 100).
    band_px : float
        How far (px) each edge may have moved since the last frame.
    min_contrast : float
        Smallest grey-level step taken as an edge.
    rigid_tol_mm : float, optional
        How much the distance between two corners may change before one of them is taken as found on
        something else (default max(0.75 mm, L1 / 2)).
    start_frame : ndarray, optional
        The image the start corners came from. When given, the start corners are re-found in it with
        the ROI method itself, so that later errors compare like with like (the full-sheet fit and the
        short ROI edges can differ by a few tenths of a pixel on the same image).
    """

    def __init__(
        self, start_corners_px: ArrayLike, plane: BedPlane, l1_mm: float, l2_mm: float,
        margin_mm: float = 0.0, roi_px: int = 100, band_px: float = 12.0, min_contrast: float = 10.0,
        start_frame: np.ndarray | None = None, rigid_tol_mm: float | None = None,
    ) -> None:
        c = np.asarray(start_corners_px, dtype=np.float64)
        if c.shape != (4, 2) or not np.all(np.isfinite(c)):
            raise ValueError(f"start corners: expected 4 finite (u, v) px, got shape {c.shape}")
        if not 0.0 < l1_mm < l2_mm:
            raise ValueError(f"thresholds must satisfy 0 < L1 < L2, got L1 = {l1_mm} mm, L2 = {l2_mm} mm")
        if not 20 <= roi_px <= 1000:
            raise ValueError(f"ROI size {roi_px} px is outside 20..1000 px")
        work_origin(np.zeros((4, 2)) + [[0, 0], [1, 0], [1, 1], [0, 1]], margin_mm)  # validates the margin
        self.plane = plane
        self.l1_mm = float(l1_mm)
        self.l2_mm = float(l2_mm)
        self.margin_mm = float(margin_mm)
        self.roi_px = int(roi_px)
        self.band_px = float(min(band_px, roi_px / 2 - 4))
        self.min_contrast = float(min_contrast)
        self.rigid_tol_mm = float(rigid_tol_mm) if rigid_tol_mm is not None else max(0.75, 0.5 * self.l1_mm)
        self._start_px = c.copy()
        self.reset()
        if start_frame is not None:
            first = self.update(start_frame)
            if first.decision in (CORNER_NOT_FOUND, FRAME_MISSING, STOP):
                raise ValueError(f"start frame: the ROI corners do not confirm the start corners: {first.reason}")
            self._start_px = first.corners_px.copy()
            self.reset()

    @classmethod
    def from_sheet(cls, sheet: SheetResult, plane: BedPlane, l1_mm: float, l2_mm: float, **kwargs) -> "DriftMonitor":
        """Start from a :class:`SheetResult` (uses its corners and margin)."""
        kwargs.setdefault("margin_mm", sheet.margin_mm)
        return cls(sheet.corners_px, plane, l1_mm, l2_mm, **kwargs)

    def reset(self) -> None:
        """Back to the start corners as datum; clears a latched stop and the frame counter."""
        ideal = undistort_px(self._start_px, self.plane.K, self.plane.dist)
        self._pos_ideal = ideal.copy()
        self._dirs = self._edge_dirs(ideal)
        self._start_bed = self.plane.ideal_to_bed(ideal)
        self._datum_bed = self._start_bed.copy()
        self._stopped: str | None = None
        self._frame = 0

    def state(self) -> dict:
        """What the monitor has learnt since its start (tracked corners in ideal px, the datum in bed mm
        after re-datums, the frame count, a latched stop): JSON, so that a monitor resumes after a restart."""
        return {"pos_ideal": self._pos_ideal.tolist(), "datum_bed": self._datum_bed.tolist(), "frame": self._frame,
                "stopped": self._stopped}

    def restore(self, state: dict) -> None:
        """Continue from :meth:`state` (the start corners and thresholds are the constructor's)."""
        self.reset()  # edge directions and the start in bed mm come from the start corners, as at the start
        self._pos_ideal = np.asarray(state["pos_ideal"], np.float64).reshape(4, 2)
        self._datum_bed = np.asarray(state["datum_bed"], np.float64).reshape(4, 2)
        self._frame = int(state["frame"])
        self._stopped = state.get("stopped")

    @property
    def datum_corners_bed_mm(self) -> np.ndarray:
        """The corners (4, 2) bed mm that errors are measured against (start, or the last redatum)."""
        return self._datum_bed.copy()

    @property
    def stopped(self) -> bool:
        return self._stopped is not None

    def _not_rigid(self, found_ideal: np.ndarray) -> dict[int, float]:
        """Corners whose position breaks the sheet's rigidity: {corner: worst distance change mm}.

        The sheet moves as a rigid body, so the distances between its corners stay those at the start.
        A corner found on something else (the cutting head, a spark, a scrap part over the corner)
        changes its distances to the others by more than ``rigid_tol_mm``; the worst such corner is
        dropped, one at a time.
        """
        ok = np.isfinite(found_ideal[:, 0])
        bed = np.full((4, 2), np.nan)
        if ok.any():
            bed[ok] = self.plane.ideal_to_bed(found_ideal[ok])
        d_now = np.linalg.norm(bed[:, None] - bed[None], axis=2)
        d_ref = np.linalg.norm(self._start_bed[:, None] - self._start_bed[None], axis=2)
        dev = np.abs(d_now - d_ref)
        out: dict[int, float] = {}
        alive = set(np.flatnonzero(ok).tolist())
        while len(alive) >= 2:
            idx = sorted(alive)
            sub = dev[np.ix_(idx, idx)]
            if np.nanmax(sub) <= self.rigid_tol_mm:
                break
            if len(idx) == 2:  # two corners that disagree: no telling which one is wrong
                for k in idx:
                    out[k] = float(sub[0, 1])
                break
            bad = (sub > self.rigid_tol_mm).sum(axis=1) + np.nansum(sub, axis=1) / (1e3 * self.rigid_tol_mm + 1e-9)
            k = idx[int(np.argmax(bad))]
            out[k] = float(np.nanmax(dev[k, idx]))
            alive.discard(k)
        return out

    @staticmethod
    def _edge_dirs(ideal: np.ndarray) -> np.ndarray:
        """(4, 2, 2): per corner the unit directions to the next and to the previous corner."""
        out = np.zeros((4, 2, 2))
        for k in range(4):
            for j, other in enumerate((ideal[(k + 1) % 4], ideal[k - 1])):
                d = other - ideal[k]
                out[k, j] = d / np.linalg.norm(d)
        return out

    def _crop_gray(self, img: np.ndarray, k: int) -> tuple[np.ndarray, tuple[float, float]]:
        """Grey float32 crop around corner k's ROI (plus the search band), and its raw-pixel origin."""
        c = distort_px(self._pos_ideal[k][None], self.plane.K, self.plane.dist)[0]
        r = int(np.ceil(self.roi_px / 2 + self.band_px + 4))
        h, w = img.shape[:2]
        u0, v0 = max(0, int(c[0]) - r), max(0, int(c[1]) - r)
        u1, v1 = min(w, int(c[0]) + r + 1), min(h, int(c[1]) + r + 1)
        if u1 - u0 < 8 or v1 - v0 < 8:
            return np.zeros((1, 1), np.float32), (0.0, 0.0)
        return to_gray(img[v0:v1, u0:u1]), (float(u0), float(v0))

    def _decode(self, frame) -> tuple[np.ndarray | None, str]:
        if frame is None:
            return None, "frame missing: the camera returned no image"
        if isinstance(frame, (bytes, bytearray, memoryview)):
            data = np.frombuffer(bytes(frame), dtype=np.uint8)
            img = cv2.imdecode(data, cv2.IMREAD_GRAYSCALE) if data.size else None  # grey is all we use
            if img is None:
                return None, f"frame unreadable: {data.size} bytes do not decode as an image"
            frame = img
        img = np.asarray(frame)
        if img.ndim not in (2, 3) or img.size == 0 or min(img.shape[:2]) < self.roi_px:
            return None, f"frame unreadable: image of shape {img.shape} is smaller than one {self.roi_px} px ROI"
        sub = img[::7, ::7]
        if float(sub.max()) - float(sub.min()) < 1.0:
            return None, f"frame unreadable: blank image (every pixel {float(img.flat[0]):.0f})"
        return img, ""

    def update(self, frame) -> DriftDecision:
        """Process one frame: ndarray (H, W[, 3]) BGR, encoded image bytes, or ``None`` (missing)."""
        i = self._frame
        self._frame += 1
        nan4 = np.full(4, np.nan)
        img, why = self._decode(frame)
        if img is None:
            return DriftDecision(i, FRAME_MISSING, why, nan4, nan4.copy())
        found = np.full((4, 2), np.nan)
        lost: dict[int, str] = {}
        for k in range(4):
            crop, origin = self._crop_gray(img, k)
            r = refine_corner(crop, self.plane, self._pos_ideal[k], self._dirs[k, 0], self._dirs[k, 1],
                              self.roi_px, self.band_px, self.min_contrast, origin_px=origin)
            if r is None:
                lost[k] = ""
                continue
            found[k] = r[0]
        for k, off in self._not_rigid(found).items():
            found[k] = np.nan
            lost[k] = f", its edges put it {off:.1f} mm off the rigid sheet"
        ok = np.isfinite(found[:, 0])
        corners_px = np.full((4, 2), np.nan)
        corners_bed = np.full((4, 2), np.nan)
        if ok.any():
            corners_px[ok] = distort_px(found[ok], self.plane.K, self.plane.dist)
            corners_bed[ok] = self.plane.ideal_to_bed(found[ok])
            self._pos_ideal[ok] = found[ok]
            if ok.all():
                self._dirs = self._edge_dirs(found)
        err = np.linalg.norm(corners_bed - self._datum_bed, axis=1)
        err_start = np.linalg.norm(corners_bed - self._start_bed, axis=1)
        emax = float(np.nanmax(err)) if ok.any() else float("nan")

        if self._stopped is not None:
            return DriftDecision(i, STOP, f"stopped earlier ({self._stopped}); reset the monitor after re-aligning the sheet",
                                 err, err_start, corners_px, corners_bed)
        if emax >= self.l2_mm:  # a found corner beyond L2 stops even when another corner is lost
            k = int(np.nanargmax(err))
            why = f"corner {k} moved {emax:.2f} mm, at or above L2 = {self.l2_mm:g} mm: stop the machine"
            self._stopped = f"frame {i}: corner {k} moved {emax:.2f} mm"
            return DriftDecision(i, STOP, why, err, err_start, corners_px, corners_bed)
        if lost:
            where = "; ".join(
                f"corner {k} not found in its {self.roi_px} x {self.roi_px} px ROI around "
                f"({distort_px(self._pos_ideal[k][None], self.plane.K, self.plane.dist)[0][0]:.0f}, "
                f"{distort_px(self._pos_ideal[k][None], self.plane.K, self.plane.dist)[0][1]:.0f}) px{lost[k]}"
                for k in sorted(lost))
            return DriftDecision(i, CORNER_NOT_FOUND, where + " (covered, sparks, or moved more than "
                                 f"{self.band_px:.0f} px since the last frame)", err, err_start, corners_px, corners_bed)
        if emax < self.l1_mm:
            return DriftDecision(i, OK, f"largest corner error {emax:.3f} mm is below L1 = {self.l1_mm:g} mm",
                                 err, err_start, corners_px, corners_bed)
        _, offset = work_origin(corners_bed, self.margin_mm)
        self._datum_bed = corners_bed.copy()
        k = int(np.argmax(err))
        why = (f"corner {k} moved {emax:.2f} mm, between L1 = {self.l1_mm:g} mm and L2 = {self.l2_mm:g} mm: "
               f"new origin ({offset.x_mm:.2f}, {offset.y_mm:.2f}) mm, angle {offset.c_deg:.3f} deg")
        return DriftDecision(i, REDATUM, why, err, err_start, corners_px, corners_bed, offset)


_COLOURS = {OK: (0, 200, 0), REDATUM: (0, 200, 255), STOP: (0, 0, 255), FRAME_MISSING: (255, 0, 255),
            CORNER_NOT_FOUND: (255, 0, 255)}


def draw_drift(image: np.ndarray, decision: DriftDecision, roi_px: int = 100) -> np.ndarray:
    """BGR picture of one monitoring frame: each corner's ROI (colour of the decision), the corner
    found with its error in mm, and the decision's reason along the top."""
    img = np.asarray(image)
    out = cv2.cvtColor(img, cv2.COLOR_GRAY2BGR) if img.ndim == 2 else img.copy()
    colour = _COLOURS.get(decision.decision, (255, 255, 255))
    sc = max(1, int(round(max(out.shape[:2]) / 800)))
    if decision.corners_px is not None:
        for k, (p, e) in enumerate(zip(decision.corners_px, decision.errors_mm)):
            if not np.all(np.isfinite(p)):
                continue
            u, v = np.round(p).astype(int)
            h = roi_px // 2
            cv2.rectangle(out, (u - h, v - h), (u + h, v + h), colour, sc)
            cv2.drawMarker(out, (u, v), colour, cv2.MARKER_CROSS, 12 * sc, sc)
            cv2.putText(out, f"{k}: {e:.2f} mm", (u - h, v - h - 6 * sc), cv2.FONT_HERSHEY_SIMPLEX, 0.5 * sc, colour, sc)
    cv2.putText(out, f"{decision.frame_index}: {decision.decision}: {decision.reason}"[:120], (10, 30 * sc),
                cv2.FONT_HERSHEY_SIMPLEX, 0.55 * sc, colour, 2 * sc)
    return out


__all__ = ["CORNER_NOT_FOUND", "DECISIONS", "FRAME_MISSING", "OK", "REDATUM", "STOP", "DriftDecision", "DriftMonitor",
           "draw_drift"]
