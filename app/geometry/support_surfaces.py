"""Declared support surfaces of a fixture model (a vise's seat, a parallel's top face): the plane
patches a part can rest on, in the model's own CAD frame (mm, z up).

    [{"name": "seat", "z_mm": 70.0, "outline_xy": [[0, -55], [80, -55], [80, 55], [0, 55]]}]

``None`` (not declared) lets the localisation derive them from the mesh's upward faces; ``[]`` says
the model carries nothing. Only fixtures (kinds ``clamp`` and ``support``) carry parts. Read by the
library manifest and the REST API alike; see ``app.vision.support_chain.declared_surfaces`` for
how the localisation uses them. Pure: no database.
"""

from __future__ import annotations

from typing import Annotated, Any

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

MAX_SURFACES = 16
MAX_OUTLINE_POINTS = 256
MAX_COORD_MM = 100_000.0        # 100 m: anything larger is a unit or frame mistake
MIN_AREA_MM2 = 1.0
CARRYING_KINDS = ("clamp", "support")

Coord = Annotated[float, Field(strict=True, allow_inf_nan=False, ge=-MAX_COORD_MM, le=MAX_COORD_MM)]


def polygon_area_mm2(xy: Any) -> float:
    """Area enclosed by a polygon (N, 2) in order around it (shoelace formula), mm²."""
    xy = np.asarray(xy, float).reshape(-1, 2)
    return 0.5 * abs(float(np.dot(xy[:, 0], np.roll(xy[:, 1], 1)) - np.dot(xy[:, 1], np.roll(xy[:, 0], 1))))


class SupportSurfaceSpec(BaseModel):
    """One horizontal plane patch a part can rest on, in the model frame (mm)."""

    model_config = ConfigDict(extra="forbid")

    name: str = Field(min_length=1, max_length=100, examples=["seat"])
    z_mm: Coord = Field(description="Height of the plane in the model frame, mm.")
    outline_xy: list[Annotated[list[Coord], Field(min_length=2, max_length=2)]] = Field(
        min_length=3, max_length=MAX_OUTLINE_POINTS,
        description="Outline of the patch in the model's xy-plane: at least 3 [x, y] points, mm.")

    @field_validator("outline_xy", mode="before")
    @classmethod
    def _points(cls, v: Any) -> Any:
        if isinstance(v, list):
            for i, p in enumerate(v):
                if not isinstance(p, (list, tuple)) or len(p) != 2:
                    raise ValueError(f"point {i} must be [x, y] (two numbers, mm), got {p!r}")
        return v

    @field_validator("name")
    @classmethod
    def _name(cls, v: str) -> str:
        v = v.strip()
        if not v:
            raise ValueError("name must not be empty")
        return v

    @model_validator(mode="after")
    def _area(self) -> "SupportSurfaceSpec":
        area = polygon_area_mm2(self.outline_xy)
        if area < MIN_AREA_MM2:
            raise ValueError(f"outline_xy of {self.name!r} encloses {area:.3g} mm²; give a polygon with an area "
                             f"(at least {MIN_AREA_MM2:g} mm², points in order around it)")
        return self


class _Surfaces(BaseModel):
    surfaces: list[SupportSurfaceSpec]          # (their count is checked before, with its own message)

    @model_validator(mode="after")
    def _unique(self) -> "_Surfaces":
        seen: set[str] = set()
        for s in self.surfaces:
            if s.name in seen:
                raise ValueError(f"name {s.name!r} appears twice")
            seen.add(s.name)
        return self


def _reason(exc: ValidationError) -> str:
    """The first error as one sentence, located like ``support_surfaces[0].outline_xy[2]``."""
    first = exc.errors()[0]
    where = "support_surfaces"
    for p in first["loc"][1:]:          # loc starts with the wrapper's field "surfaces"
        where += f"[{p}]" if isinstance(p, int) else f".{p}"
    return f"{where}: {first['msg'].removeprefix('Value error, ')}"


def parse_support_surfaces(value: Any, kind: str | None = None) -> list[dict] | None:
    """Validate declared support surfaces; ``None`` stays None (derive from the mesh), ``[]`` is kept.

    Returns plain dicts ``{"name", "z_mm", "outline_xy"}`` (floats). ``kind`` given: only clamps and
    supports may declare surfaces (a workpiece or table carrying one is a mistake, not silently ignored).

    Raises
    ------
    ValueError
        One sentence naming the surface and what is wrong.
    """
    if value is None:
        return None
    if not isinstance(value, list):
        raise ValueError(f"support_surfaces: expected a list of surfaces (or null), got {type(value).__name__}")
    if kind is not None and kind not in CARRYING_KINDS and value:
        raise ValueError(f"support_surfaces: a {kind} carries no parts; only {' and '.join(CARRYING_KINDS)} "
                         "models declare support surfaces")
    if len(value) > MAX_SURFACES:
        raise ValueError(f"support_surfaces: {len(value)} surfaces; at most {MAX_SURFACES}")
    try:
        parsed = _Surfaces.model_validate({"surfaces": value})
    except ValidationError as exc:
        raise ValueError(_reason(exc)) from None
    return [{"name": s.name, "z_mm": float(s.z_mm), "outline_xy": [[float(x), float(y)] for x, y in s.outline_xy]}
            for s in parsed.surfaces]


def check_within_bounds(surfaces: list[dict] | None, bounds: Any, tol_mm: float = 2.0) -> None:
    """Each surface lies within the model's bounding box (``bounds`` (2, 3), mm) give or take
    ``tol_mm``: a surface off the model is a unit or frame mistake. Raises ValueError naming it."""
    if not surfaces:
        return
    lo, hi = np.asarray(bounds, float)
    for s in surfaces:
        xy = np.asarray(s["outline_xy"], float)
        if not (lo[2] - tol_mm <= s["z_mm"] <= hi[2] + tol_mm):
            raise ValueError(f"support surface {s['name']!r} at z {s['z_mm']:g} mm is outside the model "
                             f"(z {lo[2]:g} to {hi[2]:g} mm in its own frame)")
        if np.any(xy < lo[:2] - tol_mm) or np.any(xy > hi[:2] + tol_mm):
            raise ValueError(f"support surface {s['name']!r}: outline_xy reaches outside the model (x {lo[0]:g} to "
                             f"{hi[0]:g}, y {lo[1]:g} to {hi[1]:g} mm in its own frame)")
