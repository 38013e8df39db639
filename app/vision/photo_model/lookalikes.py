"""Look-alikes: photo models located at the same place in one picture compete
(:func:`decide_lookalikes`); the edges in which two templates differ decide
(:func:`lookalike_evidence`), or nothing is accepted there."""

from __future__ import annotations

import numpy as np

from app.vision.object_pose.results import ObjectPose
from app.vision.photo_model.fit import SUPPORT_MM, refine_fixed, supported
from app.vision.photo_model.model import PhotoModel, table_xyt
from app.vision.photo_model.plane import point_distance, point_grid
from app.vision.photo_model.view import View


def lookalike_evidence(view: View, a: PhotoModel, T_a: np.ndarray, b: PhotoModel, T_b: np.ndarray,
                       apart_mm: float = 1.5) -> tuple[float, float, int, int]:
    """How the picture decides between two models located at (nearly) the same place: the edges of
    ``a`` (at ``T_a``) farther than ``apart_mm`` from every edge of ``b`` (at ``T_b``), and the other
    way round. Returns (share of a's own edges that the picture shows, share of b's own edges it shows,
    number of a's own points, number of b's own points); a share is NaN when there are none."""
    def own(m1, T1, m2, T2):
        P1 = m1.points_mm @ T1[:2, :2].T + T1[:2, 3]
        P2 = m2.points_mm @ T2[:2, :2].T + T2[:2, 3]
        g = point_grid(np.vstack([P1, P2]), 5)
        d = point_distance(g, P2) * 0.25
        q, _ = g.pixels(P1)
        return d[q[:, 1], q[:, 0]] > apart_mm

    out = []
    for m, T, mo, To in ((a, T_a, b, T_b), (b, T_b, a, T_a)):
        sel = own(m, T, mo, To)
        if sel.sum() < 5:
            out.append((float("nan"), int(sel.sum())))
            continue
        fit = refine_fixed(view, m, table_xyt(T))
        ok = supported(fit.found, fit.residual_mm, SUPPORT_MM + 0.2)
        out.append((float(ok[sel].mean()), int(sel.sum())))
    return out[0][0], out[1][0], out[0][1], out[1][1]


def decide_lookalikes(view: View, located: list[tuple[str, PhotoModel, ObjectPose]], *, min_margin: float = 0.1,
                      own_present: float = 0.6, own_absent: float = 0.35) -> tuple[list[int], dict[int, str]]:
    """Which of several photo models located in one picture are accepted. Models located at the same
    place (centres closer than half the larger radius) compete: the best by edge IoU wins when it leads
    by ``min_margin``, or when :func:`lookalike_evidence` shows its own edges (>= ``own_present``) and
    not the rival's own (<= ``own_absent``). Otherwise none of the group is accepted. Returns (indices
    accepted, {index: reason refused})."""
    order = sorted(range(len(located)), key=lambda i: -located[i][2].photo["edge_iou"])
    accepted: list[int] = []
    undecided: list[int] = []          # places where look-alikes could not be told apart
    refused: dict[int, str] = {}

    def same_place(i: int, j: int) -> bool:
        (_, mi, pi), (_, mj, pj) = located[i], located[j]
        d = float(np.hypot(*(pi.T_table_obj[:2, 3] - pj.T_table_obj[:2, 3])))
        return d < 0.5 * max(mi.radius_mm, mj.radius_mm)

    for i in order:
        name, m, p = located[i]
        blocked = next((j for j in undecided if same_place(i, j)), None)
        if blocked is not None:
            refused[i] = refused[blocked]
            continue
        clash = next((j for j in accepted if same_place(i, j)), None)
        if clash is None:
            accepted.append(i)
            continue
        # i is the weaker at that place (sorted by edge IoU): it loses when the lead is clear or the
        # edges in which the two differ show the winner's and not its own
        nj, mj, pj = located[clash]
        lead = pj.photo["edge_iou"] - p.photo["edge_iou"]
        sa, sb, na, nb = lookalike_evidence(view, mj, pj.T_table_obj, m, p.T_table_obj)
        a_ok = (not np.isfinite(sa)) or sa >= own_present
        b_absent = (not np.isfinite(sb)) or sb <= own_absent
        if lead >= min_margin or (a_ok and b_absent and (na + nb) > 0):
            refused[i] = (f"lost to {nj} at the same place (edge IoU {p.photo['edge_iou']:.0%} against "
                          f"{pj.photo['edge_iou']:.0%}; edges only {name} has: {_pct(sb)} seen, only {nj} has: "
                          f"{_pct(sa)} seen)")
        else:
            accepted.remove(clash)
            undecided.append(clash)
            why = (f"{name} and {nj} look alike at the same place and the picture does not decide "
                   f"(edge IoU {p.photo['edge_iou']:.0%} against {pj.photo['edge_iou']:.0%}; edges only {name} has: "
                   f"{_pct(sb)} seen, only {nj} has: {_pct(sa)} seen)")
            refused[i] = refused[clash] = why
    return accepted, refused


def _pct(v: float) -> str:
    return "none to see" if not np.isfinite(v) else f"{v:.0%}"
