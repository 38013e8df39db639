"""A fixture's guide: what carries it and how it moves there (a vise's moving jaw slides along its
screw axis on the body's guide ways, at the body's rotation and height). In the carrier's own CAD
frame (mm):

    {"carrier": "vise_body",                 # library key or name of the carrying model
     "T_carrier_obj": 4x4,                   # pose of this model in the carrier frame at travel 0
     "axis": [1, 0, 0],                      # direction of travel in the carrier frame (made unit)
     "travel_mm": [-95, 100]}                # travel range along the axis, lo < hi

At travel ``s`` the model is at ``T_table_obj = T_table_carrier @ Trans(s * axis) @ T_carrier_obj``.
``None`` (not declared): the fixture stands free, anywhere on what carries it. Only clamps and
supports are guided. Read by the library manifest and the REST API alike; the localisation
(``app.vision.localize``) searches a guided fixture only along its guide, once its carrier is
located. Pure: no database.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Annotated, Any

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator

from app.geometry.support_surfaces import CARRYING_KINDS, MAX_COORD_MM
from app.geometry.transforms import (
    PoseError,
    check_pose,
    inv,
    make_pose,
    rotation_angle_deg,
)

#: longest travel a guide may declare (mm): a camera-located slide longer than the largest table
#: is a unit mistake, and it bounds the number of search starts
MAX_TRAVEL_SPAN_MM = 2000.0
#: spacing of the search starts along a guide (mm) and how far around each one it is searched
#: (``object_pose.search.starts_from_poses``: x, y within +-capture mm, rotation within +-capture
#: deg): the windows overlap (capture > half the spacing) and reach across the guide past
#: OFF_GUIDE_MM and past the carrier's own rotation error. Not the default +-30 mm, 8 deg of an
#: operator's rough pose: the grid costs the square of the capture (a vise's jaw: 70 s -> ~5 s)
GUIDE_STEP_MM = 20.0
GUIDE_CAPTURE_MM = 12.0
GUIDE_CAPTURE_DEG = 3.0
#: a located fixture this far off its guide (mm across the axis or beyond its travel, deg of
#: rotation) has left it: the local search slid onto other edges
OFF_GUIDE_MM = 3.0
OFF_GUIDE_DEG = 2.0

Coord = Annotated[float, Field(strict=False, allow_inf_nan=False, ge=-MAX_COORD_MM, le=MAX_COORD_MM)]


def _numbers(v: Any, n: int, form: str) -> Any:
    """``v`` as a list when it is a list or tuple of ``n`` items, else the error ``form, got v``."""
    if not isinstance(v, (list, tuple)) or len(v) != n:
        raise ValueError(f"{form}, got {v!r}")
    return list(v)


class GuideSpec(BaseModel):
    """The guide of a fixture on its carrier (carrier frame, mm)."""

    model_config = ConfigDict(extra="forbid")

    carrier: str = Field(min_length=1, max_length=200, examples=["vise_body"],
                         description="Library key or name of the model that carries this one.")
    T_carrier_obj: list[list[float]] = Field(description="4x4 pose of this model in the carrier frame at travel 0, mm.")
    axis: list[Coord] = Field(description="[x, y, z] direction of travel in the carrier frame.")
    travel_mm: list[Coord] = Field(description="[lo, hi] travel along the axis, mm.")

    @field_validator("carrier")
    @classmethod
    def _carrier(cls, v: str) -> str:
        v = v.strip()
        if not v:
            raise ValueError("carrier must not be empty (the library key or name of the carrying model)")
        return v

    @field_validator("T_carrier_obj", mode="before")
    @classmethod
    def _pose(cls, v: Any) -> Any:
        try:
            return check_pose(v, "T_carrier_obj", tol=1e-5).tolist()
        except PoseError as exc:
            raise ValueError(f"{exc}; give a rigid 4x4 pose in mm") from None

    @field_validator("axis", mode="before")
    @classmethod
    def _axis_shape(cls, v: Any) -> Any:
        return _numbers(v, 3, "axis must be [x, y, z] (three numbers)")

    @field_validator("axis")
    @classmethod
    def _axis_unit(cls, v: list[float]) -> list[float]:
        n = math.sqrt(sum(c * c for c in v))
        if n < 1e-9:
            raise ValueError("axis is zero; give the direction of travel, e.g. [1, 0, 0]")
        return [c / n for c in v]

    @field_validator("travel_mm", mode="before")
    @classmethod
    def _travel_shape(cls, v: Any) -> Any:
        return _numbers(v, 2, "travel_mm must be [lo, hi] (two numbers, mm)")

    @field_validator("travel_mm")
    @classmethod
    def _travel(cls, v: list[float]) -> list[float]:
        lo, hi = v
        if not lo < hi:
            raise ValueError(f"[{lo:g}, {hi:g}]: lo must be less than hi")
        if hi - lo > MAX_TRAVEL_SPAN_MM:
            raise ValueError(f"spans {hi - lo:g} mm; at most {MAX_TRAVEL_SPAN_MM:g} mm (mm, not um?)")
        return v


def parse_guide(value: Any, kind: str | None = None) -> dict | None:
    """Validate a guide; ``None`` stays None (the fixture stands free).

    Returns a plain dict ``{"carrier", "T_carrier_obj", "axis" (unit), "travel_mm"}`` of floats.
    ``kind`` given: only clamps and supports are guided (a workpiece or table with a guide is a
    mistake, not silently ignored).

    Raises
    ------
    ValueError
        One sentence starting with ``guide`` that names the field and what is wrong.
    """
    if value is None:
        return None
    if not isinstance(value, dict):     # (a ValueError like every other bad input: callers answer 422)
        raise ValueError(  # noqa: TRY004
            f"guide: expected an object {{carrier, T_carrier_obj, axis, travel_mm}} (or null), "
            f"got {type(value).__name__}")
    if kind is not None and kind not in CARRYING_KINDS:
        raise ValueError(f"guide: a {kind} is not guided; only {' and '.join(CARRYING_KINDS)} models ride on a carrier")
    try:
        g = GuideSpec.model_validate(value)
    except ValidationError as exc:
        first = exc.errors()[0]
        where = "guide" + "".join(f"[{p}]" if isinstance(p, int) else f".{p}" for p in first["loc"])
        raise ValueError(f"{where}: {first['msg'].removeprefix('Value error, ')}") from None
    return {"carrier": g.carrier, "T_carrier_obj": [[float(x) for x in row] for row in g.T_carrier_obj],
            "axis": [float(c) for c in g.axis], "travel_mm": [float(t) for t in g.travel_mm]}


def pose_at_travel(guide: dict, T_table_carrier: np.ndarray, s_mm: float) -> np.ndarray:
    """``T_table_obj`` of the guided model at travel ``s_mm`` on a carrier at ``T_table_carrier``."""
    step = make_pose(None, float(s_mm) * np.asarray(guide["axis"], float))
    return np.asarray(T_table_carrier, float) @ step @ np.asarray(guide["T_carrier_obj"], float)


def guide_start_poses(guide: dict, T_table_carrier: np.ndarray, step_mm: float = GUIDE_STEP_MM) -> list[np.ndarray]:
    """Poses ``T_table_obj`` along the whole travel, both ends included, at most ``step_mm`` apart:
    where to start a local search for the guided model on its located carrier."""
    lo, hi = guide["travel_mm"]
    n = max(2, math.ceil((hi - lo) / max(step_mm, 1e-3) - 1e-9) + 1)
    return [pose_at_travel(guide, T_table_carrier, s) for s in np.linspace(lo, hi, n)]


@dataclass(frozen=True)
class GuideDeviation:
    """Where a located model is against its guide: travel along the axis (mm), distance across it
    (mm, in the carrier frame), distance beyond the travel range (mm, 0 inside) and rotation off the
    guide's (deg)."""

    travel_mm: float
    across_mm: float
    beyond_mm: float
    angle_deg: float

    def on_guide(self, tol_mm: float = OFF_GUIDE_MM, tol_deg: float = OFF_GUIDE_DEG) -> bool:
        return self.across_mm <= tol_mm and self.beyond_mm <= tol_mm and self.angle_deg <= tol_deg


def guide_deviation(guide: dict, T_table_carrier: np.ndarray, T_table_obj: np.ndarray) -> GuideDeviation:
    """How far ``T_table_obj`` is from the guide of its carrier at ``T_table_carrier``."""
    T_carrier_obj = inv(np.asarray(T_table_carrier, float)) @ np.asarray(T_table_obj, float)
    T0 = np.asarray(guide["T_carrier_obj"], float)
    axis = np.asarray(guide["axis"], float)
    d = T_carrier_obj[:3, 3] - T0[:3, 3]
    s = float(d @ axis)
    lo, hi = guide["travel_mm"]
    return GuideDeviation(travel_mm=s, across_mm=float(np.linalg.norm(d - s * axis)),
                          beyond_mm=max(0.0, lo - s, s - hi),
                          angle_deg=rotation_angle_deg(T_carrier_obj[:3, :3], T0[:3, :3]))
