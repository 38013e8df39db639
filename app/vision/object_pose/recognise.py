"""Which of several library models are in the image: the coarse stages for all, the full
:func:`~app.vision.object_pose.locate.locate_object` for the best few, then accepted by score, margin
and how much of the image each explains at the same place."""

from __future__ import annotations

import time
from typing import Callable

import numpy as np

from app.geometry.model_edges import PreparedModel
from app.geometry.transforms import check_pose, transform_points
from app.vision.blas_threads import one_blas_thread
from app.vision.object_pose.edge_image import mask_known_edges, mask_table_regions, prepare_image
from app.vision.object_pose.locate import coarse_starts, locate_object
from app.vision.object_pose.options import OPTION_NAMES, LocateOptions
from app.vision.object_pose.results import ObjectFailure, ObjectPose, Progress, Recognition


@one_blas_thread
def recognise(image, K, dist, T_cam_table, candidates: list[PreparedModel], *, min_score: float = 0.6,
              min_margin: float = 0.1, gamma: float = 2.2, n_full: int = 4,
              on_progress: Callable[[Progress], None] | None = None, **locate_kw) -> Recognition:
    """Which of ``candidates`` are in the image?

    Every candidate goes through the search and the planar fit (stages 1 and 2 of
    :func:`locate_object`, the located jaws' starts included); the best by that coarse score are
    located completely, in its order, until ``n_full`` of them fit with ``min_score`` (at most
    ``2 * n_full`` tried: a coarse score that the full fit does not keep, a bar fitted to a vise's
    edges, does not use up a place), and ranked by their verification score; the others keep their
    coarse score ("coarse only"). Each is located with ``min_margin`` as a named part is (its readings
    chosen and its own ambiguity judged by it), with no least score (the ranking applies ``min_score``);
    a best fit under ``min_score`` is refused there before its rivals, contact fit and sigma are worked
    out (``LocateOptions.min_verified_score``): it can neither be accepted nor stand in another's way,
    and it is ranked by the same score ("supports only ...").
    ``table_extent_xy`` (x0, x1, y0, y1 mm, in ``locate_kw``): the table top, where a part's centre is
    searched (grown by half its size); without it, wherever image edges meet the plane (a tool
    over the table's back edge, seen beyond it, would be searched too).
    A candidate is accepted when its score reaches ``min_score`` and no other candidate at the same
    place (centres closer than half the larger diameter) explains clearly more image edges
    (``supported_edge_px`` 25 % higher) or, explaining about as much, scores within ``min_margin``.
    Different objects at different places can all be accepted (a workpiece and its clamps).
    Nothing accepted: ``reason`` starts with "not recognised:" and names the top candidates.
    ``on_progress`` is told after each model's search and before each full fit (stage
    "recognition"; ``total`` counts every search and the most full fits there may be), and once at
    the end with ``done == total``. An exception it raises (the job stopped) ends the recognition.
    """
    t0 = time.perf_counter()
    K = np.asarray(K, dtype=float)
    dist = np.zeros(5) if dist is None else np.asarray(dist, dtype=float).ravel()
    T_cam_table = check_pose(T_cam_table, "T_cam_table")
    eimg = prepare_image(image, gamma=gamma)
    known = locate_kw.pop("known_models", ())
    if known:
        eimg = mask_known_edges(eimg, [(m, T_cam_table @ np.asarray(T, float)) for m, T in known], K, dist)
    regions = locate_kw.pop("known_regions", ())
    if len(regions):
        eimg = mask_table_regions(eimg, regions, T_cam_table, K, dist)
    # the search as locate_object will run it (its options, the jaws' starts): its results are kept
    # in ``eimg.cache`` and reused by the full locate of the best few
    # a shadow line across a part is set aside only where the part was asked for (LocateOptions.lines_across)
    opts = LocateOptions(gamma=gamma, lines_across=False).with_(
        **{k: v for k, v in locate_kw.items() if k in OPTION_NAMES})
    scene_kw = {k: v for k, v in locate_kw.items() if k not in OPTION_NAMES}   # what locate_object is told
    n, total = len(candidates), len(candidates) + min(2 * n_full, len(candidates))

    def told(done: int, message: str) -> None:
        if on_progress is not None:
            on_progress(Progress("recognition", done, total, message))

    coarse = []
    for k, m in enumerate(candidates):
        found = coarse_starts(eimg, K, dist, T_cam_table, m, opts, scene_kw.get("table_extent_xy"),
                              scene_kw.get("clamp_faces", ()))
        coarse.append(0.0 if isinstance(found, str) or not found[0] else float(found[0][0].score))
        told(k + 1, f"searched {k + 1} of {n} models")
    order = np.argsort(-np.asarray(coarse), kind="stable")
    res = []
    fitted = tried = 0
    for i in order:
        m = candidates[i]
        if fitted < n_full and tried < 2 * n_full:
            # every score comes back to be ranked, but a model's own readings are chosen as for a named
            # part (the clearer, the sharper; two poses of it within the margin are ambiguous): with a
            # margin of 0 setup_001's bracket took the reading a named locate sets aside, then found it
            # "ambiguous" against the one it keeps
            told(n + tried, f"fitting {m.name}, the {_ordinal(tried + 1)} best of the search")
            r = locate_object(None, K, dist, T_cam_table, m, edge_image=eimg,
                              options=opts.with_(min_score=0.0, min_verified_score=min_score, min_margin=min_margin),
                              **scene_kw)
            tried += 1
            fitted += isinstance(r, ObjectPose) and r.score >= min_score
        else:
            r = ObjectFailure(model_name=m.name, kind="not_found", reason="coarse only", best_score=coarse[i],
                              candidates=(), timings_ms={})
        res.append((m, r))

    def score(r):
        return r.score if isinstance(r, ObjectPose) else r.best_score

    told(total, f"searched {n} models, fitted {tried}")
    res.sort(key=lambda mr: -score(mr[1]))
    accepted = []
    ranked = []
    for i, (m, r) in enumerate(res):
        ok = isinstance(r, ObjectPose) and r.score >= min_score
        reason = ""
        if isinstance(r, ObjectPose) and not ok:
            reason = f"score {r.score:.0%} below {min_score:.0%}"
        elif isinstance(r, ObjectPose):
            c_i = transform_points(r.T_table_obj, m.center_obj[None])[0]
            for j, (m2, r2) in enumerate(res):
                if j == i or not isinstance(r2, ObjectPose) or r2.score < min_score:
                    continue
                c_j = transform_points(r2.T_table_obj, m2.center_obj[None])[0]
                if np.linalg.norm(c_i[:2] - c_j[:2]) >= 0.5 * max(m.diameter_mm, m2.diameter_mm):
                    continue            # different places: both may be there (workpiece and clamp)
                if r2.supported_edge_px > 1.25 * r.supported_edge_px:
                    ok = False          # e.g. a small block fitted into a bigger part's edges
                    reason = (f"{m2.name} explains more of the image at the same place "
                              f"({r2.supported_edge_px:.0f} px of edges vs {r.supported_edge_px:.0f} px)")
                    break
                if r.supported_edge_px <= 1.25 * r2.supported_edge_px and r.score - r2.score < min_margin:
                    ok = False
                    reason = (f"{m2.name} fits the same place almost as well "
                              f"({r.score:.0%} vs {r2.score:.0%})")
                    break
        else:
            reason = r.reason
        ranked.append({"model": m.name, "score": round(float(score(r)), 4), "ok": bool(ok), "reason": reason})
        if ok:
            accepted.append(r)
    ranked.sort(key=lambda d: (not d["ok"], -d["score"]))
    reason = ""
    if not accepted:
        top = ", ".join(f"{d['model']} {d['score']:.0%}" for d in ranked[:3])
        reason = f"not recognised: no candidate reached {min_score:.0%} with a margin of {min_margin:.0%} (top: {top})"
    return Recognition(accepted=tuple(accepted), ranked=tuple(ranked), reason=reason,
                       timings_ms={"total": (time.perf_counter() - t0) * 1e3})


def _ordinal(k: int) -> str:
    return {1: "1st", 2: "2nd", 3: "3rd"}.get(k, f"{k}th")
