"""The typed result of a setup: the located table and objects, the review and the proposed offset.

A setup's ``result`` is stored as JSON (``Setup.result``) and answered as JSON by the REST API; these
types are how the services read and change it. Unknown keys are kept as they are (``extra="allow"``)
and only the keys a result actually has are written back (``exclude_unset``), so a stored result
round-trips unchanged and the REST shape stays what it was.

Frames and units (DESIGN.md): ``T_table_obj`` is the object's model frame in the table frame,
``T_cam_obj = T_cam_table @ T_table_obj`` in the camera frame, 4x4 lists, mm; sigmas in mm and degrees.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

Matrix = list[list[float]]


class LocatedObject(BaseModel):
    """One located object (workpiece, clamp or support) of a setup result."""

    model_config = ConfigDict(extra="allow")

    name: str
    kind: str = "workpiece"
    model_id: int | None = None
    revision: int | None = None
    T_table_obj: Matrix
    T_cam_obj: Matrix | None = None
    T_table_obj_fit: Matrix | None = Field(default=None, description="the pose the fit found, kept while an "
                                                                      "operator's move is judged against it")
    T_obj_datum: Matrix | None = None
    sigma: dict[str, float | None] = Field(default_factory=dict, description="1-sigma: x_mm, y_mm, z_mm, *_deg")
    score: float | None = None
    flags: list[str] = Field(default_factory=list)
    equivalent_poses: list[Matrix] = Field(default_factory=list)
    datum_ambiguous: bool = False
    datum_note: str = ""
    uncertainty_pass: bool = False
    uncertainty_reason: str = ""
    probe_fail: str | None = Field(default=None, description="why probing showed the pose wrong (absent: it did not)")

    @property
    def pose(self) -> np.ndarray:
        """``T_table_obj``, shape (4, 4), mm."""
        return np.asarray(self.T_table_obj, float)

    @property
    def datum(self) -> np.ndarray:
        """``T_obj_datum``, shape (4, 4), mm: the identity when the model defines no datum."""
        return np.asarray(self.T_obj_datum, float) if self.T_obj_datum else np.eye(4)

    def datum_candidates(self) -> list[np.ndarray]:
        """The pose as located first, then every pose that looks the same in the image."""
        return [self.pose] + [np.asarray(T, float) for T in self.equivalent_poses]

    def datum_undecided(self) -> bool:
        """Several listed poses fit equally and nobody has chosen one (a round part's free turn about
        its axis lists none: its note says the angle is arbitrary, there is nothing to choose)."""
        return self.datum_ambiguous and bool(self.equivalent_poses)

    def clear_probe_fail(self) -> None:
        """Forget a probing FAIL (it judged an earlier pose): the key leaves the stored result."""
        self.probe_fail = None
        self.model_fields_set.discard("probe_fail")

    def moved_to(self, T_table_obj: np.ndarray, **changes: Any) -> "LocatedObject":
        """A copy at a new pose (``T_cam_obj`` is set by :meth:`SetupResult.place`) with ``changes``."""
        return self.model_copy(update={"T_table_obj": np.asarray(T_table_obj, float).tolist(), **changes})


class SetupResult(BaseModel):
    """What a setup found and how it was reviewed; one revision of ``Setup.result``."""

    model_config = ConfigDict(extra="allow")

    ok: bool = True
    reason: str = ""
    table: dict | None = Field(default=None, description="T_cam_table, markers used / rejected, rms_px")
    objects: list[LocatedObject] = Field(default_factory=list)
    not_found: list[dict] = Field(default_factory=list)
    offset: dict | None = Field(default=None, description="the proposed work offset of the first workpiece")
    overlay_sha256: str | None = None
    note: str | None = None
    revised_by: str | None = None

    @classmethod
    def load(cls, data: dict | None) -> "SetupResult":
        """From the stored (or freshly computed) JSON dict."""
        return cls.model_validate(data or {})

    def dump(self) -> dict:
        """The JSON dict to store: the keys the result has, nothing added."""
        return self.model_dump(mode="json", exclude_unset=True)

    @property
    def T_cam_table(self) -> np.ndarray:
        """The table's pose in the camera frame, shape (4, 4), mm."""
        return np.asarray(self.table["T_cam_table"], float)

    def workpiece_index(self) -> int | None:
        """Index of the first workpiece (the one whose datum is the work offset), None without one."""
        return next((i for i, o in enumerate(self.objects) if o.kind == "workpiece"), None)

    def workpiece(self) -> LocatedObject | None:
        i = self.workpiece_index()
        return None if i is None else self.objects[i]

    def replace(self, index: int, obj: LocatedObject) -> "SetupResult":
        """A copy with object ``index`` replaced."""
        objs = [obj if i == index else o for i, o in enumerate(self.objects)]
        return self.model_copy(update={"objects": objs})

    def without(self, index: int) -> "SetupResult":
        """A copy without object ``index``."""
        return self.model_copy(update={"objects": [o for i, o in enumerate(self.objects) if i != index]})

    def place(self) -> None:
        """Every object's ``T_cam_obj`` from its ``T_table_obj`` (one source: the pose on the table)."""
        if not self.table or "T_cam_table" not in self.table:
            return
        T_cam_table = self.T_cam_table
        for o in self.objects:
            o.T_cam_obj = (T_cam_table @ o.pose).tolist()
