"""The fiducial layout of a table (or any model carrying markers), DESIGN format.

    {"dictionary": "DICT_5X5_100",
     "markers": [{"id": 7, "size_mm": 40.0, "T_table_marker": 4x4}]}

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


class FiducialLayout(BaseModel):
    dictionary: str = Field(examples=["DICT_5X5_100"])
    markers: list[MarkerPlacement] = Field(min_length=1)

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
