"""What the engine returns: a located part, a failure with its reason, a recognition.

Poses are 4x4 (mm), frames as in docs/design.md (``T_a_b``); sigmas in mm and degrees.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True, eq=False)
class ObjectPose:
    """A located part. Poses 4x4 (mm); ``sigma`` is 1-sigma of ``T_table_obj``: keys ``x_mm, y_mm,
    z_mm`` (the obj frame's origin, table axes) and ``rx_deg, ry_deg, rz_deg`` (small rotations about
    the table axes); NaN for a rotation that the part's round symmetry leaves undetermined.

    score : verification score in [0, 1] (share of visible model edge samples supported by an image
        edge within ``support_px`` after the fit)
    inlier_edge_fraction : same share counted with the fit's robust inliers (|residual| < 3 scale)
    residual_px : RMS of the inlier residuals along the edge normals
    visible_fraction : share of the model's edges in view that the given occluders do not hide
    supported_edge_px : length (px) of the model's visible edges supported by image edges
    unexplained_fraction : share of the image edge pixels inside the part's outline (3 px in) that no
        visible model edge explains (a smaller model fitted into a bigger part leaves many)
    margin : score minus the score of the best different (non-equivalent) pose found, or NaN if none
    distinctiveness : least drop of the score when the pose is moved by 4 px (x, y) or turned
    tilt_deg : angle between the part's resting normal and the table normal after the 6-DoF fit;
        ``tilt_sigma_deg`` its 1-sigma; flag "tilt" when it exceeds both ``max_tilt_deg`` and 3 sigma.
        ``T_table_obj`` is the flat fit; the free fit is ``T_table_obj_6dof``
    equivalent_poses : ``T_table_obj @ S`` for every symmetry S of the part (same look, other datum)
    datum_note : how the datum (which of the equivalent poses) was chosen, or why it could not be
    uncertainty_ok : every sigma within the tolerances given to :func:`locate_object`
    flags : warnings ("tilt", "datum_ambiguous", "uncertainty", "few_edges")
    """

    model_name: str
    T_cam_obj: np.ndarray
    T_table_obj: np.ndarray
    resting_state: int
    score: float
    inlier_edge_fraction: float
    residual_px: float
    visible_fraction: float
    supported_edge_px: float
    unexplained_fraction: float
    n_edge_samples: int
    sigma: dict
    uncertainty_ok: bool
    T_table_obj_6dof: np.ndarray
    tilt_deg: float
    tilt_sigma_deg: float
    height_offset_mm: float
    margin: float
    runner_up_score: float
    distinctiveness: float
    equivalent_poses: tuple
    datum_ambiguous: bool
    datum_note: str
    flags: tuple
    timings_ms: dict
    chain: tuple = ()          # what it rests on, nearest first, down to the table (set by the caller)
    held_by: tuple = ()        # fixtures whose faces hold it in the final fit (vise jaws: .clamping)
    guided_by: str | None = None   # the fixture whose guide it was searched along (a vise's moving jaw)
    riser_mm: float | None = None  # the declared riser it stands on (locate._declared_riser); None: none
    covariance: np.ndarray | None = None   # 6x6 of (origin x, y, z mm, rotation vector rad), table axes
    # the table pose's share of ``covariance`` (shared by every object in the picture: what one object
    # is known to relative to another, a part to its vise's jaw, leaves it out)
    table_covariance: np.ndarray | None = None
    # the intrinsics' share of ``table_covariance`` (the camera's calibration: what a sigma too large to
    # pass may owe to it)
    intrinsics_covariance: np.ndarray | None = None
    photo: dict | None = None  # a photo model's match (app/vision/photo_model/): edge IoU, unexplained edges

    def __bool__(self) -> bool:
        return True

    def to_dict(self) -> dict:
        return {
            "ok": True,
            "model": self.model_name,
            "T_cam_obj": self.T_cam_obj.tolist(),
            "T_table_obj": self.T_table_obj.tolist(),
            "resting_state": self.resting_state,
            "score": self.score,
            "inlier_edge_fraction": self.inlier_edge_fraction,
            "residual_px": self.residual_px,
            "visible_fraction": self.visible_fraction,
            "supported_edge_px": self.supported_edge_px,
            "unexplained_fraction": self.unexplained_fraction,
            "n_edge_samples": self.n_edge_samples,
            "sigma": {k: (None if not np.isfinite(v) else float(v)) for k, v in self.sigma.items()},
            "uncertainty_ok": self.uncertainty_ok,
            "T_table_obj_6dof": self.T_table_obj_6dof.tolist(),
            "tilt_deg": self.tilt_deg,
            "tilt_sigma_deg": None if not np.isfinite(self.tilt_sigma_deg) else self.tilt_sigma_deg,
            "height_offset_mm": self.height_offset_mm,
            "chain": list(self.chain),
            "held_by": list(self.held_by),
            "guided_by": self.guided_by,
            "riser_mm": self.riser_mm,
            "cov6": None if self.covariance is None else np.where(np.isfinite(self.covariance), self.covariance, 0.0).tolist(),
            "cov6_table": None if self.table_covariance is None else
            np.where(np.isfinite(self.table_covariance), self.table_covariance, 0.0).tolist(),
            "cov6_intrinsics": None if self.intrinsics_covariance is None else
            np.where(np.isfinite(self.intrinsics_covariance), self.intrinsics_covariance, 0.0).tolist(),
            "margin": None if not np.isfinite(self.margin) else self.margin,
            "runner_up_score": None if not np.isfinite(self.runner_up_score) else self.runner_up_score,
            "distinctiveness": self.distinctiveness,
            "equivalent_poses": [T.tolist() for T in self.equivalent_poses],
            "datum_ambiguous": self.datum_ambiguous,
            "datum_note": self.datum_note,
            "flags": list(self.flags),
            "timings_ms": dict(self.timings_ms),
            **({} if self.photo is None else {"photo": dict(self.photo)}),
        }


@dataclass(frozen=True, eq=False)
class ObjectFailure:
    """A part that was not located; ``reason`` is the sentence for the operator.

    kind : "not_found" | "ambiguous" | "bad_input"
    candidates : best hypotheses seen, each ``{"T_table_obj": 4x4 list, "score": float}``
    """

    model_name: str
    kind: str
    reason: str
    best_score: float
    candidates: tuple
    timings_ms: dict

    def __bool__(self) -> bool:
        return False

    def to_dict(self) -> dict:
        return {"ok": False, "model": self.model_name, "kind": self.kind, "reason": self.reason,
                "best_score": self.best_score, "candidates": list(self.candidates),
                "timings_ms": dict(self.timings_ms)}


@dataclass(frozen=True, eq=False)
class Recognition:
    """Outcome of :func:`recognise`.

    accepted : located parts that passed (score >= min_score, margin >= min_margin), best first
    ranked : every candidate as ``{"model", "score", "ok", "reason"}``, best first
    reason : "" when something was accepted, else why nothing was ("not recognised: ...")
    """

    accepted: tuple
    ranked: tuple
    reason: str
    timings_ms: dict

    @property
    def best(self) -> ObjectPose | None:
        return self.accepted[0] if self.accepted else None

    def __bool__(self) -> bool:
        return bool(self.accepted)

    def to_dict(self) -> dict:
        return {"ok": bool(self.accepted), "accepted": [a.to_dict() for a in self.accepted],
                "ranked": list(self.ranked), "reason": self.reason, "timings_ms": dict(self.timings_ms)}


@dataclass(frozen=True)
class Progress:
    """Where a long stage stands while it runs: ``done`` of ``total`` steps (recognition: each library
    model's search is a step, then each full fit of the best few), and what it is doing in words."""

    stage: str
    done: int
    total: int
    message: str

    def to_dict(self) -> dict:
        return {"stage": self.stage, "done": self.done, "total": self.total, "message": self.message}
