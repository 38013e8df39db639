"""Which of the poses that look alike is meant: the part's symmetries, near symmetries decided (or
not) by small features, and the part turned over onto another face. The operator confirms what the
image cannot decide; this says why."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from app.geometry.model_edges import PreparedModel
from app.vision.object_pose.verify import pose_distance


@dataclass(frozen=True)
class Datum:
    """``equivalent``: ``T_table_obj`` of every pose that looks the same (4x4, mm); ``ambiguous``:
    the image does not decide between them; ``note``: the sentence for the operator."""

    equivalent: tuple
    ambiguous: bool
    note: str


def choose_datum(model: PreparedModel, T_table_obj: np.ndarray, score: float, sym_scores: list, flips: list,
                 flips_open: list, flip_runner: float, min_margin: float) -> Datum:
    """The datum of the located pose ``T_table_obj`` (verification ``score``).

    sym_scores : (near symmetry, score of the pose turned by it) for each near symmetry tried
    flips : fits of the part turned over onto another face (same place); ``flips_open`` those within
        twice ``min_margin`` of ``score`` that do not leave clearly more of the image unexplained (the
        face up is then not decided); ``flip_runner`` the best of their scores
    """
    exact = [s for s in model.symmetries if s.exact]
    listed = list(exact)
    ambiguous = False
    note = ""
    if model.continuous_axis_obj is not None:
        note = ("the part is round: its rotation about its axis cannot be seen; the datum's angle "
                "about that axis is arbitrary (its sigma is reported as undetermined)")
        ambiguous = True
    elif exact:
        note = (f"the part looks the same after {len(exact)} rotation(s) "
                f"({', '.join(f'{s.angle_deg:.0f} deg' for s in exact)}): {len(exact) + 1} equivalent "
                f"poses, the datum cannot be chosen from the image; confirm which one is meant")
        ambiguous = True
    elif not sym_scores:
        note = "the part has no rotational symmetry: the datum follows from the fit"
    if sym_scores:
        gap = min(score - sc for _, sc in sym_scores)
        alts = ", ".join(f"{sc:.0%} turned {s.angle_deg:.0f} deg" for s, sc in sym_scores)
        head = "" if not (exact or model.continuous_axis_obj is not None) else note + "; "
        if gap >= 0.5 * min_margin:
            note = (f"{head}the outline is near-symmetric; the datum was chosen by the small features that "
                    f"break the symmetry (score {score:.0%} vs {alts})")
        else:
            note = (f"{head}the outline is near-symmetric and the features that break the symmetry are not "
                    f"clear enough in this image (score {score:.0%} vs {alts}): the datum is not "
                    f"decided; all {len(sym_scores) + 1} candidate poses are listed, confirm which one is meant")
            ambiguous = True
            listed += [s for s, _ in sym_scores]
    equivalent = tuple(T_table_obj @ s.S for s in listed)
    if flips_open:
        turned = ", ".join(f"{r.score:.0%}" for r in flips_open)
        head = note + "; " if ambiguous else ""
        note = (f"{head}the part fits almost as well turned over onto another face ({score:.0%} as "
                f"shown, {turned} turned over): the features that tell the faces apart are not clear in "
                f"this view, so which face is up is not decided; the turned-over pose is listed, confirm "
                f"which one is meant")
        ambiguous = True
        # each turned-over pose with the turns that are not decided either (a square plate that may be
        # upside down may as well be turned by 90 deg that way up: the true pose must be among those
        # listed, or the operator can only choose a wrong one)
        for r in flips_open:
            turns = [np.eye(4)] + [s.S for s in listed
                                   if s.exact or abs(float((r.T[:3, :3] @ s.axis_obj)[2])) > 0.99]
            equivalent += tuple(r.T @ S for S in turns)
    elif flips and flip_runner > score:
        note += (f"; turned over onto another face it supports a higher share of its fewer visible edges "
                 f"({flip_runner:.0%} against {score:.0%}) but leaves clearly more of the image inside its "
                 f"outline unexplained: the face up is decided")
    elif flips:
        note += (f"; turned over onto another face it fits clearly worse ({flip_runner:.0%} against "
                 f"{score:.0%}): the face up is decided")
    equivalent = _distinct_poses(equivalent, T_table_obj)
    return Datum(equivalent=equivalent, ambiguous=ambiguous, note=note)


def _distinct_poses(poses: tuple, T_first: np.ndarray, tol_mm: float = 0.5, tol_deg: float = 0.5) -> tuple:
    """``poses`` without repeats (within ``tol_mm`` and ``tol_deg``) and without ``T_first`` itself."""
    kept: list = []
    for T in poses:
        if all(not _same_pose(T, U, tol_mm, tol_deg) for U in [T_first] + kept):
            kept.append(T)
    return tuple(kept)


def _same_pose(T1: np.ndarray, T2: np.ndarray, tol_mm: float, tol_deg: float) -> bool:
    d_mm, a_deg = pose_distance(T1, T2, np.zeros(3))          # the obj origins, and the turn between
    return d_mm < tol_mm and a_deg < tol_deg
