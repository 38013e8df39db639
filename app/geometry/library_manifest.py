"""The example library's manifest (``models_library/library.json``): read and validate it.

    {"models": [{"key": "tslot_table_800x400", "kind": "table", "name": "...",
                 "file": "tslot_table_800x400.stl", "units": "mm",
                 "fiducials": "tslot_table_800x400.fiducials.json" | null,
                 "T_obj_datum": 4x4 | null, "description": "...",
                 "support_surfaces": [{"name": "seat", "z_mm": 70.0, "outline_xy": [[x, y], ...]}],
                 "guide": {"carrier": "vise_body", "T_carrier_obj": 4x4, "axis": [1, 0, 0],
                           "travel_mm": [-95, 100]} | null}]}

``support_surfaces`` (optional, clamps and supports only): the plane patches a part can rest on, in
the model's own frame (``app/geometry/support_surfaces.py``); left out or null: derived from the
mesh's upward faces; []: the model carries nothing.

``guide`` (optional, clamps and supports only): what carries the model and how it moves there (a
vise's moving jaw on its body), in the carrier's frame (``app/geometry/guides.py``); ``carrier`` is
the key or name of another model. Left out or null: the model stands free.

Paths are relative to the manifest's folder. Pure: reads files, no database.
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from app.geometry.fiducial_layout import FiducialLayout, parse_layout
from app.geometry.guides import parse_guide
from app.geometry.mesh import SUPPORTED_SUFFIXES, UNIT_SCALE_TO_MM
from app.geometry.support_surfaces import parse_support_surfaces
from app.geometry.transforms import PoseError, check_pose

KINDS = ("workpiece", "clamp", "support", "table")
MANIFEST_NAME = "library.json"
_KEY_RE = re.compile(r"^[a-z0-9][a-z0-9_\-]{0,63}$")


class LibraryManifestError(ValueError):
    """A manifest that cannot be loaded; the message names the entry and the field."""


@dataclass(frozen=True)
class LibraryEntry:
    """One model of the library. ``file`` / ``fiducials`` are relative to the library folder;
    ``T_obj_datum`` (4x4, mm) or None; ``layout`` is the parsed fiducial layout or None;
    ``support_surfaces`` the declared surfaces (model frame, mm) or None (derive from the mesh);
    ``guide`` what carries the model and how it moves there (``app/geometry/guides.py``) or None."""

    key: str
    kind: str
    name: str
    file: str
    units: str
    fiducials: str | None
    T_obj_datum: np.ndarray | None = field(repr=False)
    description: str
    layout: FiducialLayout | None = field(default=None, repr=False)
    library_dir: Path = field(default=Path("."), repr=False)
    support_surfaces: list[dict] | None = field(default=None, repr=False, hash=False)
    guide: dict | None = field(default=None, repr=False, hash=False)

    @property
    def path(self) -> Path:
        return self.library_dir / self.file

    @property
    def fiducials_path(self) -> Path | None:
        return None if self.fiducials is None else self.library_dir / self.fiducials


def _entry(raw: object, i: int, library_dir: Path) -> LibraryEntry:
    if not isinstance(raw, dict):
        raise LibraryManifestError(f"models[{i}] must be an object, got {type(raw).__name__}")
    key = raw.get("key")
    where = f"models[{i}] ({key!r})" if key else f"models[{i}]"
    if not isinstance(key, str) or not _KEY_RE.match(key):
        raise LibraryManifestError(f"{where}: key must be 1-64 characters of a-z, 0-9, _ or -")
    for f in ("name", "file"):
        if not isinstance(raw.get(f), str) or not raw[f].strip():
            raise LibraryManifestError(f"{where}: {f!r} is required (a non-empty string)")
    kind = raw.get("kind")
    if kind not in KINDS:
        raise LibraryManifestError(f"{where}: kind {kind!r} unknown; use one of {', '.join(KINDS)}")
    units = raw.get("units", "mm")
    if units not in UNIT_SCALE_TO_MM:
        raise LibraryManifestError(f"{where}: units {units!r} unknown; use 'mm' or 'inch'")
    file = raw["file"]
    if Path(file).is_absolute() or ".." in Path(file).parts:
        raise LibraryManifestError(f"{where}: file {file!r} must be a path inside the library folder")
    if Path(file).suffix.lower() not in SUPPORTED_SUFFIXES:
        raise LibraryManifestError(f"{where}: file {file!r} is not a supported mesh ({', '.join(SUPPORTED_SUFFIXES)})")
    if not (library_dir / file).is_file():
        raise LibraryManifestError(f"{where}: file {file!r} not found in {library_dir}")

    T = raw.get("T_obj_datum")
    if T is not None:
        try:
            T = check_pose(T, f"{where}: T_obj_datum", tol=1e-6)
        except PoseError as exc:
            raise LibraryManifestError(str(exc)) from None

    fid = raw.get("fiducials")
    layout = None
    if fid is not None:
        if not isinstance(fid, str) or Path(fid).is_absolute() or ".." in Path(fid).parts:
            raise LibraryManifestError(f"{where}: fiducials must be a file name inside the library folder or null")
        fpath = library_dir / fid
        if not fpath.is_file():
            raise LibraryManifestError(f"{where}: fiducials file {fid!r} not found in {library_dir}")
        try:
            layout = parse_layout(json.loads(fpath.read_text()))
        except json.JSONDecodeError as exc:
            raise LibraryManifestError(f"{where}: fiducials file {fid!r} is not JSON ({exc})") from None
        except ValueError as exc:
            raise LibraryManifestError(f"{where}: {exc}") from None
    elif kind == "table":
        raise LibraryManifestError(f"{where}: a table needs a fiducial layout (fiducials: file name)")

    try:
        surfaces = parse_support_surfaces(raw.get("support_surfaces"), kind)
    except ValueError as exc:
        raise LibraryManifestError(f"{where}: {exc}") from None
    try:
        guide = parse_guide(raw.get("guide"), kind)
    except ValueError as exc:
        raise LibraryManifestError(f"{where}: {exc}") from None
    if guide is not None and guide["carrier"] in (key, raw["name"].strip()):
        raise LibraryManifestError(f"{where}: guide.carrier names the model itself; give the model that carries it")

    return LibraryEntry(key=key, kind=kind, name=raw["name"].strip(), file=file, units=units,
                        fiducials=fid, T_obj_datum=T, description=str(raw.get("description", "")),
                        layout=layout, library_dir=library_dir, support_surfaces=surfaces,
                        guide=guide)


def load_library_manifest(library_dir: Path | str) -> list[LibraryEntry]:
    """Read ``<library_dir>/library.json`` and validate every entry (files exist, kinds, units,
    poses via ``check_pose``, fiducial layouts via ``parse_layout``, support surfaces via
    ``parse_support_surfaces``, guides via ``parse_guide``, unique keys, every guide's carrier
    another entry's key or name).

    Raises
    ------
    LibraryManifestError
        One sentence naming the entry and what is wrong.
    """
    library_dir = Path(library_dir)
    mpath = library_dir / MANIFEST_NAME
    if not mpath.is_file():
        raise LibraryManifestError(f"no {MANIFEST_NAME} in {library_dir}")
    try:
        doc = json.loads(mpath.read_text())
    except json.JSONDecodeError as exc:
        raise LibraryManifestError(f"{mpath} is not valid JSON: {exc}") from None
    if not isinstance(doc, dict) or not isinstance(doc.get("models"), list):
        raise LibraryManifestError(f'{mpath}: expected an object {{"models": [...]}}')
    entries = [_entry(raw, i, library_dir) for i, raw in enumerate(doc["models"])]
    seen: set[str] = set()
    for e in entries:
        if e.key in seen:
            raise LibraryManifestError(f"key {e.key!r} appears twice in {mpath}")
        seen.add(e.key)
    names = seen | {e.name for e in entries}
    for e in entries:
        if e.guide is not None and e.guide["carrier"] not in names:
            raise LibraryManifestError(f"model {e.key!r}: guide.carrier {e.guide['carrier']!r} is no key or name "
                                       f"in {mpath}")
    return entries
