"""The table's tilt and height re-read from a fixture bolted to it, where few markers leave them open.

Two markers fix the table's tilt about the line between them only through each marker's own
perspective: devset tables seen through two markers were tilted by up to 0.4 deg (1.4 mm of height
under a vise 250 mm away), and a vise searched on that plane was lost. A vise stands on the true
table top to within a few hundredths of a millimetre, and its long straight edges show its own tilt
far better than two markers do. So, when the table's tilt sigma exceeds a fixture's contact sigma,
the biggest fixture is first searched over the heights the table's error allows, with its height
and tilt free by that error (:attr:`app.vision.object_pose.LocateOptions.table_tilt_sigmas`); its
stance (tilt about x and y, and the height of its base's centre above the located top) is then a
measurement of the table's own error, fused with the markers' estimate as a Kalman update
(:func:`level_table`). Everything is then located in the levelled frame, where the vise stands flat
again, with the fused covariance.

Frames: ``T_cam_table`` maps table into camera (mm); the table's error ``e`` = (rotation about the
table axes rad, shift mm) about the markers' centroid is as :func:`app.vision.fiducials.locate_table`
states it: the located frame is ``T_cam_table_true @ E(e)`` (:func:`.object_pose.uncertainty.table_error`).
Pure maths: nothing here imports from api/, store/ or services/.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from app.geometry.transforms import inv, transform_points
from app.vision.object_pose.uncertainty import covariance_at, table_error, table_height_row, table_plane_sigma

# The table is levelled when its tilt sigma exceeds this (deg): a fixture's own contact sigma
# (localize.FIXTURE_OPTIONS), beyond which the table knows the fixture's stance less well than the
# fixture itself. The devset's tables as rendered (4-8 markers) state at most 0.051 deg; through two
# markers 0.04-0.31 (median 0.084).
LEVEL_MIN_TILT_DEG = 0.05
# The levelling fixture is searched within this many of the table's height sigmas (and let tilt as
# far), in steps of HEIGHT_STEP_MM (a vise searched 0.7 mm off its true height is still found, 1.4 mm
# off it is not: devset setup_039 through two markers), at most MAX_HEIGHTS of them.
SEARCH_SIGMAS = 3.0
HEIGHT_STEP_MM = 0.7
MAX_HEIGHTS = 9
# How flat a fixture stands on the table top (1 sigma, deg and mm): ground bases on a ground table.
STANCE_SIGMA_DEG = 0.05
STANCE_SIGMA_MM = 0.05
# The fixture's stance and the markers' table disagreeing by more than this chi-square (3 degrees of
# freedom; 5 sigma in one) is a fixture read wrong or a table stated wrong: the table is not levelled.
GATE_CHI2 = 25.0


@dataclass(frozen=True)
class Stance:
    """A fixture's stance in the located table frame: ``m`` = (tilt about x rad, tilt about y rad,
    height mm of its base's centre above z = 0), its covariance ``C`` (3x3, the fit's own and the
    stance's), and that base centre ``at`` (table frame, mm)."""

    m: np.ndarray
    C: np.ndarray
    at: np.ndarray


@dataclass(frozen=True)
class Levelling:
    """The levelled table: its pose, its covariance (as ``TablePose.covariance``: rotation rad, shift mm
    about the same centroid), the correction it made at the fixture's base (tilt about x and y deg,
    height mm) and the chi-square of the fixture's stance against the markers' table (3 dof)."""

    T_cam_table: np.ndarray
    covariance: np.ndarray
    correction: np.ndarray
    chi2: float


def search_heights(table_cov, corners_xy) -> tuple[float, ...]:
    """Heights (mm above the located top) to search a fixture at: within :data:`SEARCH_SIGMAS` of the
    table's height sigma at the worst of ``corners_xy`` (the table top's corners, table frame), in
    steps of :data:`HEIGHT_STEP_MM`, 0 first."""
    sh = max(table_plane_sigma(table_cov, np.array([x, y, 0.0]))[0] for x, y in corners_xy)
    n = int(min(np.ceil(SEARCH_SIGMAS * sh / HEIGHT_STEP_MM), (MAX_HEIGHTS - 1) // 2)) if np.isfinite(sh) else 0
    return (0.0,) + tuple(s * k * HEIGHT_STEP_MM for k in range(1, n + 1) for s in (-1.0, 1.0))


def stance(T_table_obj: np.ndarray, cov_origin: np.ndarray, up_obj: np.ndarray, base_obj: np.ndarray) -> Stance:
    """The stance of a fixture fitted at ``T_table_obj`` with its own covariance ``cov_origin`` (6x6 of
    origin shift mm and rotation vector rad, table axes, the table's share left out); ``up_obj``: its
    up direction when it stands (obj frame), ``base_obj``: the centre of its base (obj frame, mm)."""
    u = T_table_obj[:3, :3] @ (np.asarray(up_obj, float) / np.linalg.norm(up_obj))
    b = transform_points(T_table_obj, np.asarray(base_obj, float)[None])[0]
    # a small turn w tips the up axis to (w_y, -w_x, 1)
    m = np.array([-u[1], u[0], b[2]])
    Cb = covariance_at(cov_origin, T_table_obj[:3, 3], b)        # (shift, rotation) at the base
    idx = [3, 4, 2]
    C = Cb[np.ix_(idx, idx)] + np.diag([np.radians(STANCE_SIGMA_DEG) ** 2] * 2 + [STANCE_SIGMA_MM ** 2])
    return Stance(m=m, C=C, at=b)


def level_table(T_cam_table: np.ndarray, table_cov: np.ndarray, centroid: np.ndarray, st: Stance) -> Levelling:
    """The table pose and covariance updated with a fixture's stance ``st`` (Kalman: the stance reads
    ``-A e`` plus its noise, ``A`` the table error's tilt and height at the base)."""
    S = np.asarray(table_cov, float)
    A = np.vstack([np.eye(6)[:2], table_height_row(st.at, centroid)])
    Sy = A @ S @ A.T + st.C
    Sy_inv = np.linalg.inv(Sy)
    chi2 = float(st.m @ Sy_inv @ st.m)
    G = S @ A.T @ Sy_inv
    e = -G @ st.m
    S_new = S - G @ A @ S
    S_new = 0.5 * (S_new + S_new.T)
    # the located frame is the true one moved by E(e): the levelled one undoes the estimate of it
    T_new = T_cam_table @ inv(table_error(e, centroid))
    done = -(A @ e)                 # what the levelling took out at the base: tilt rad, height mm
    return Levelling(T_cam_table=T_new, covariance=S_new,
                     correction=np.array([np.degrees(done[0]), np.degrees(done[1]), done[2]]), chi2=chi2)


def standing_base(T_rest_obj: np.ndarray, support_vertices_obj: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(up direction, centre of the base) of a part standing in the resting state ``T_rest_obj``, obj
    frame: the middle of the box of its support vertices within 0.5 mm of its lowest point."""
    T = np.asarray(T_rest_obj, float)
    P = transform_points(T, np.asarray(support_vertices_obj, float))
    base = P[P[:, 2] <= P[:, 2].min() + 0.5]
    centre = np.array([*(0.5 * (base[:, :2].min(axis=0) + base[:, :2].max(axis=0))), P[:, 2].min()])
    return T[:3, :3].T @ np.array([0.0, 0.0, 1.0]), transform_points(inv(T), centre[None])[0]
