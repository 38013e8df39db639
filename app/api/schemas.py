"""What the API returns (Public families). Kept apart from the tables: the API shape is a promise."""

from __future__ import annotations

from datetime import datetime
from typing import Any, Generic, TypeVar

from pydantic import BaseModel, Field

T = TypeVar("T")


class Page(BaseModel, Generic[T]):
    data: list[T]
    count: int = Field(description="Number of matching rows (before offset/limit).")


class RevisionPublic(BaseModel):
    revision: int
    source_filename: str
    source_sha256: str
    glb_sha256: str
    units: str = Field(description="Units of the uploaded file; all geometry here is in mm.")
    T_obj_datum: list[list[float]] | None = Field(description="Pose of the datum (NC zero) in the model frame, mm.")
    fiducials: dict | None
    support_surfaces: list[dict[str, Any]] | None = Field(
        default=None, description="Fixtures: the plane patches a part can rest on, in the model frame (mm): "
                                  '[{"name", "z_mm", "outline_xy": [[x, y], ...]}]; null: derived from the '
                                  "mesh's upward faces; []: carries nothing.")
    guide: dict[str, Any] | None = Field(
        default=None, description="Fixtures: what carries the model and how it moves there, in the carrier's "
                                  'frame (mm): {"carrier": key or name, "T_carrier_obj": 4x4 at travel 0, "axis": '
                                  '[x, y, z] unit, "travel_mm": [lo, hi]}; null: it stands free.')
    summary: dict[str, Any] = Field(description="Bounding box (mm), face and vertex counts, watertightness.")
    resting_poses: list[dict[str, Any]] = Field(description="Stable poses on a plane: T_plane_obj and probability.")
    photo: dict[str, Any] | None = Field(
        default=None, description="A photo model's template (taught from pictures): height_mm, n_views, "
                                  "edge_length_mm, holes, teach_grid (maps a pixel of the teach picture to the table, "
                                  "mm), T_table_obj_teach, teach_picture_url; null for a CAD model.")
    note: str
    created_at: datetime


class ModelPublic(BaseModel):
    id: int
    key: str | None
    kind: str
    name: str
    description: str
    source: str = Field(default="cad", description="cad: from a CAD file; photo: taught from pictures")
    current_revision: int
    created_at: datetime
    deleted_at: datetime | None
    revision: RevisionPublic = Field(description="The current revision (or the one asked for).")
    mesh_url: str
    thumbnail_url: str
