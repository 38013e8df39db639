"""The fiducial layout of a table (or any model carrying markers), DESIGN format.

    {"dictionary": "DICT_5X5_100",
     "markers": [{"id": 7, "size_mm": 40.0, "T_table_marker": 4x4}],
     "placement_sigma": {"position_mm": 0.02, "rotation_deg": 0.02, "scale_rel": 0.0005}}  # optional

Marker frame: origin at the marker centre, x along the top edge (corner 0 -> corner 1), y from the
bottom edge to the top edge, z out of the printed face; so corner 0 is at (-s/2, +s/2, 0).
"""

from __future__ import annotations

import cv2
import numpy as np
from pydantic import BaseModel, Field, ValidationError, field_validator, model_validator

from app.geometry.transforms import PoseError, check_pose


class MarkerPlacement(BaseModel):
    id: int = Field(ge=0)
    size_mm: float = Field(gt=0, le=2000, description="Side of the black square including its border, mm.")
    T_table_marker: list[list[float]]

    def corners_table_mm(self) -> np.ndarray:
        """The 4 corners (OpenCV order) in the table frame, shape (4, 3), mm."""
        h = self.size_mm / 2.0
        local = np.array([[-h, h, 0], [h, h, 0], [h, -h, 0], [-h, -h, 0]], dtype=float)
        T = np.asarray(self.T_table_marker, dtype=float)
        return local @ T[:3, :3].T + T[:3, 3]


# How far a marker may sit from where its layout puts it (1 sigma) when the layout does not say: its
# centre along each table axis (mm), its turn about its normal (deg), the print's scale (relative, one
# for all markers). A layout surveyed on the machine (a probe, or photogrammetry) is this good; markers
# set by hand to a drawing are not, and their layout should say so.
DEFAULT_PLACEMENT_SIGMA = (0.02, 0.02, 0.0005)
PLACEMENT_KEYS = ("position_mm", "rotation_deg", "scale_rel")


class PlacementSigma(BaseModel):
    """How well the markers sit where the layout says (1 sigma); a missing value is
    :data:`DEFAULT_PLACEMENT_SIGMA`'s. It enters the table pose's covariance, and so every located
    object's sigma, however many markers are seen."""

    position_mm: float | None = Field(default=None, ge=0.0, le=50.0, examples=[0.05],
                                      description="each marker's centre, along each table axis, mm")
    rotation_deg: float | None = Field(default=None, ge=0.0, le=10.0, examples=[0.05],
                                       description="each marker's turn about its normal, degrees")
    scale_rel: float | None = Field(default=None, ge=0.0, le=0.1, examples=[0.001],
                                    description="the print's scale, relative (0.001 = 0.1 %), one for all")


def placement_sigma(layout: dict) -> tuple[float, float, float]:
    """(position mm, rotation deg, scale relative): the layout dict's declared ``placement_sigma``,
    each missing value from :data:`DEFAULT_PLACEMENT_SIGMA`."""
    got = layout.get("placement_sigma") or {}
    return tuple(float(got[k]) if got.get(k) is not None else d for k, d in zip(PLACEMENT_KEYS, DEFAULT_PLACEMENT_SIGMA))


class FiducialLayout(BaseModel):
    dictionary: str = Field(examples=["DICT_5X5_100"])
    markers: list[MarkerPlacement] = Field(min_length=1)
    placement_sigma: PlacementSigma | None = Field(
        default=None, description="how well the markers sit where this layout says (absent: 0.02 mm, "
        "0.02 deg, 0.05 % print scale); it enters every located object's sigma")

    @field_validator("dictionary")
    @classmethod
    def _known_dictionary(cls, v: str) -> str:
        if not v.startswith("DICT_") or not hasattr(cv2.aruco, v):
            raise ValueError(f"unknown ArUco dictionary {v!r}; use an OpenCV name such as DICT_5X5_100")
        return v

    @model_validator(mode="after")
    def _check(self) -> "FiducialLayout":
        n_ids = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, self.dictionary)).bytesList.shape[0]
        seen: set[int] = set()
        for m in self.markers:
            if m.id in seen:
                raise ValueError(f"marker id {m.id} appears twice")
            if m.id >= n_ids:
                raise ValueError(f"marker id {m.id} is not in {self.dictionary} (ids 0..{n_ids - 1})")
            seen.add(m.id)
            try:
                check_pose(m.T_table_marker, f"T_table_marker of marker {m.id}", tol=1e-5)
            except PoseError as exc:
                raise ValueError(str(exc)) from None
        return self


def parse_layout(data: dict) -> FiducialLayout:
    """Validate a layout dict; raise ValueError with one readable sentence on bad input."""
    try:
        return FiducialLayout.model_validate(data)
    except ValidationError as exc:
        first = exc.errors()[0]
        where = ".".join(str(p) for p in first["loc"])
        msg = first["msg"].removeprefix("Value error, ")
        raise ValueError(f"fiducial layout invalid{' at ' + where if where else ''}: {msg}") from None
