"""Locating a taught object in a picture (:func:`locate`), which reads as the stages: the coarse
search (:mod:`.search`), the fit of the best starts (:mod:`.fit`), the verification (:mod:`.verify`)
and the sigma (:mod:`.uncertainty`); the answer is the CAD engine's
:class:`~app.vision.object_pose.results.ObjectPose` or :class:`~app.vision.object_pose.results.ObjectFailure`."""

from __future__ import annotations

import time

import numpy as np

from app.geometry.transforms import make_pose
from app.vision.object_pose.results import ObjectFailure, ObjectPose
from app.vision.object_pose.uncertainty import CONTACT_SIGMA_DEG
from app.vision.photo_model.fit import refine, supported
from app.vision.photo_model.model import (
    TEMPLATE_SPACING_MM,
    PhotoModel,
    angle_gap,
    pose,
)
from app.vision.photo_model.plane import camera_mm_per_px
from app.vision.photo_model.search import coarse_starts
from app.vision.photo_model.uncertainty import pose_covariance
from app.vision.photo_model.verify import (
    distinctiveness,
    edge_iou,
    missing_inner,
    unexplained,
)
from app.vision.photo_model.view import View


def locate(view: View, model: PhotoModel, name: str, *,
           search_xy: tuple[float, float, float, float] = (0.0, 800.0, 0.0, 400.0), min_score: float = 0.6,
           min_margin: float = 0.1, max_sigma_mm: float = 0.3, max_sigma_deg: float = 0.05,
           max_unexplained_mm: float | None = None, n_starts: int = 3) -> ObjectPose | ObjectFailure:
    """Locate a photo model in a picture whose table pose is known (``view.T_cam_table``).

    search_xy : (x_lo, x_hi, y_lo, y_hi) table box to search (mm)
    min_score : least share of the template's edges supported after the fit
    min_margin : least lead of the score over the best different pose (symmetries are the same pose)
    max_unexplained_mm : longest piece of edge inside the outline that the model lacks before the
        fit is refused as another object (None: 8 mm or 3 % of the template's edge length)
    Returns the engine's :class:`ObjectPose` (resting on the table, ``T_table_obj`` turned about table
    z only, sigma and 6x6 covariance as the CAD fit's) or :class:`ObjectFailure` with the reason."""
    t0 = time.perf_counter()
    timings: dict[str, float] = {}
    starts = coarse_starts(view, model, search_xy, n_starts=n_starts)
    timings["search"] = (time.perf_counter() - t0) * 1e3
    if not starts:
        return ObjectFailure(name, "not_found", f"{name} not found: no edges on the table", 0.0, (), timings)
    t1 = time.perf_counter()
    fits = [refine(view, model, (x, y, t)) for _, x, y, t in starts]
    timings["fit"] = (time.perf_counter() - t1) * 1e3
    fits.sort(key=lambda f: -f.coverage)
    best = fits[0]
    rivals = [f for f in fits[1:] if np.hypot(f.x - best.x, f.y - best.y) > 3.0
              or angle_gap(f.theta, best.theta, model) > np.radians(3)]
    runner = max((f.coverage for f in rivals), default=float("nan"))
    cands = tuple({"T_table_obj": pose(model, f.x, f.y, f.theta).tolist(), "score": f.coverage} for f in fits[:3])
    T_table_obj = pose(model, best.x, best.y, best.theta)
    if best.coverage < min_score:
        return ObjectFailure(name, "not_found", f"{name} not found: the best fit has {best.coverage:.0%} of its edges "
                             f"in the picture (at least {min_score:.0%} needed)", best.coverage, cands, timings)
    margin = best.coverage - runner if np.isfinite(runner) else float("nan")
    if np.isfinite(margin) and margin < min_margin:
        return ObjectFailure(name, "ambiguous", f"{name} is ambiguous: another pose fits almost as well "
                             f"({best.coverage:.0%} against {runner:.0%})", best.coverage, cands, timings)
    share, unexpl_mm, longest = unexplained(best, model)
    limit = max_unexplained_mm if max_unexplained_mm is not None else max(8.0, 0.03 * model.edge_length_mm)
    if longest > limit:
        return ObjectFailure(name, "not_found", f"{name} not found: the object there has {longest:.0f} mm of edges "
                             f"inside its outline that {name} does not have (another object?)", best.coverage,
                             cands, timings)
    missing = missing_inner(best, model)
    if missing > limit:
        return ObjectFailure(name, "not_found", f"{name} not found: {missing:.0f} mm of its edges inside its outline "
                             "(a hole, a pocket) are not in the picture (another object, or that part hidden?)",
                             best.coverage, cands, timings)
    _cov3, cov6, parts = pose_covariance(best, model, view)
    sd = np.sqrt(np.maximum(np.diag(cov6), 0.0))
    sigma = {"x_mm": float(sd[0]), "y_mm": float(sd[1]), "z_mm": float(sd[2]), "rx_deg": float(np.degrees(sd[3])),
             "ry_deg": float(np.degrees(sd[4])), "rz_deg": float(np.degrees(sd[5]))}
    unc_ok = max(sd[:3]) <= max_sigma_mm and sigma["rz_deg"] <= max_sigma_deg
    xy = np.array([best.x, best.y])
    cam_mm = camera_mm_per_px(view.K, view.T_cam_table, xy, model.height_mm)
    distinct = distinctiveness(best, model, cam_mm)
    r = best.residual_mm
    inl = supported(best.found, r)
    flags = []
    if not unc_ok:
        flags.append("uncertainty")
    if inl.sum() < 100:
        flags.append("few_edges")
    equivalent = tuple(T_table_obj @ make_pose(np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0],
                                                         [0, 0, 1.0]]))
                       for a in np.radians(model.symmetry_deg))
    note = "" if not equivalent else (f"the outline looks the same turned by {', '.join(f'{s:g}°' for s in model.symmetry_deg)}"
                                      "; choose which pose is meant")
    if equivalent:
        flags.append("datum_ambiguous")
    timings["total"] = (time.perf_counter() - t0) * 1e3
    return ObjectPose(
        model_name=name, T_cam_obj=np.asarray(view.T_cam_table, float) @ T_table_obj, T_table_obj=T_table_obj,
        resting_state=0, score=float(best.coverage), inlier_edge_fraction=float(inl.mean()),
        residual_px=float(np.sqrt(np.mean(r[inl] ** 2)) / cam_mm) if inl.any() else float("nan"),
        visible_fraction=float(best.found.mean()), supported_edge_px=float(inl.sum() * TEMPLATE_SPACING_MM / cam_mm),
        unexplained_fraction=share, n_edge_samples=len(model.points_mm), sigma=sigma, uncertainty_ok=bool(unc_ok),
        T_table_obj_6dof=T_table_obj, tilt_deg=0.0, tilt_sigma_deg=float(CONTACT_SIGMA_DEG), height_offset_mm=0.0,
        margin=float(margin), runner_up_score=float(runner), distinctiveness=distinct,
        equivalent_poses=equivalent, datum_ambiguous=bool(equivalent), datum_note=note, flags=tuple(flags),
        timings_ms=timings, covariance=cov6,
        photo={"unexplained_mm": unexpl_mm, "longest_unexplained_mm": longest, "edge_length_mm": model.edge_length_mm,
               "edge_iou": edge_iou(best.coverage, model, unexpl_mm), "cam_mm_per_px": cam_mm,
               "cov_parts": parts})


def locate_near(view: View, model: PhotoModel, name: str, T_table_obj: np.ndarray,
                reach_mm: float = 20.0) -> ObjectPose | ObjectFailure:
    """:func:`locate` searched only within the model's size plus ``reach_mm`` of a pose (table frame):
    "refine from here" after an operator moved the object on the screen."""
    r = model.radius_mm + reach_mm
    x, y = float(T_table_obj[0, 3]), float(T_table_obj[1, 3])
    return locate(view, model, name, search_xy=(x - r, x + r, y - r, y + r))
