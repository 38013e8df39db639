"""Model library use cases: upload, revise, list, fetch, soft delete, load the example library.

Geometry work (parsing, normalising to mm GLB, resting poses, thumbnail) is in app/geometry/mesh.py;
this module joins it with the file store and the tables. Revisions are immutable: any change of
geometry or frames creates revision n+1, and older revisions stay readable.
"""

from __future__ import annotations

import hashlib
import json
import logging
from dataclasses import asdict, is_dataclass
from pathlib import Path
from typing import Any

import numpy as np
from sqlmodel import Session, col, func, select

from app.geometry import mesh as meshlib
from app.geometry.fiducial_layout import parse_layout
from app.geometry.guides import parse_guide
from app.geometry.library_manifest import load_library_manifest
from app.geometry.support_surfaces import check_within_bounds, parse_support_surfaces
from app.geometry.thumbnail import render_thumbnail
from app.geometry.transforms import PoseError, check_pose
from app.services.errors import Invalid, NotFound, TooLarge
from app.store.files import FileStore
from app.store.models import LibraryModel, ModelRevision, utcnow

log = logging.getLogger(__name__)

KINDS = ("workpiece", "clamp", "support", "table")
UNITS = ("mm", "inch")
_UNSET: Any = object()


def _jsonable(obj: Any) -> Any:
    if is_dataclass(obj):
        obj = asdict(obj)
    if isinstance(obj, dict):
        return {k: _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, np.generic):
        return obj.item()
    return obj


jsonable = _jsonable


def check_kind_units(kind: str | None, units: str | None) -> None:
    if kind is not None and kind not in KINDS:
        raise Invalid(f"unknown kind {kind!r}; use one of: {', '.join(KINDS)}")
    if units is not None and units not in UNITS:
        raise Invalid(f"unknown units {units!r}; use one of: {', '.join(UNITS)}")


def _from_json_text(value: Any, name: str) -> Any:
    """JSON text parsed, anything else as given; 422 with the reason when the text is not JSON."""
    if not isinstance(value, str):
        return value
    try:
        return json.loads(value)
    except json.JSONDecodeError as exc:
        raise Invalid(f"{name}: not valid JSON ({exc.msg})") from None


def parse_frame(value: Any, name: str) -> list[list[float]] | None:
    """A 4x4 pose from JSON text or nested lists (None stays None); 422 with the reason otherwise."""
    if value is None or value == "":
        return None
    try:
        return check_pose(_from_json_text(value, name), name, tol=1e-5).tolist()
    except PoseError as exc:
        raise Invalid(str(exc)) from None


def parse_fiducials(value: Any) -> dict | None:
    """A fiducial layout (DESIGN format) from JSON text or a dict (None stays None); 422 with the reason."""
    if value is None or value == "":
        return None
    try:
        return parse_layout(_from_json_text(value, "fiducials")).model_dump()
    except ValueError as exc:
        raise Invalid(str(exc)) from None


def parse_surfaces(value: Any, kind: str) -> list[dict] | None:
    """Declared support surfaces from JSON text or a list (None stays None, [] is kept); 422 with the
    reason otherwise (``app/geometry/support_surfaces.py``)."""
    if isinstance(value, str) and value.strip() == "":
        return None
    try:
        return parse_support_surfaces(_from_json_text(value, "support_surfaces"), kind)
    except ValueError as exc:
        raise Invalid(str(exc)) from None


def parse_guide_field(value: Any, kind: str, own: tuple[str | None, ...] = ()) -> dict | None:
    """A guide from JSON text or a dict (None or '' stays None); 422 with the reason otherwise
    (``app/geometry/guides.py``). ``own``: the model's key and name, which its carrier may not be."""
    if isinstance(value, str) and value.strip() == "":
        return None
    try:
        guide = parse_guide(_from_json_text(value, "guide"), kind)
    except ValueError as exc:
        raise Invalid(str(exc)) from None
    if guide is not None and guide["carrier"] in {o for o in own if o}:
        raise Invalid(f"guide.carrier {guide['carrier']!r} names the model itself; give the model that carries it")
    return guide


def _check_surfaces_on_model(surfaces: list[dict] | None, summary: dict) -> None:
    """The surfaces lie on the model (its bounding box, give or take 2 mm); 422 naming the one that does not."""
    lo, hi = summary.get("bbox_min_mm"), summary.get("bbox_max_mm")
    if not surfaces or lo is None or hi is None:
        return
    try:
        check_within_bounds(surfaces, [lo, hi])
    except ValueError as exc:
        raise Invalid(f"{exc}; support surfaces are given in mm in the model's own frame") from None


def _process_geometry(files: FileStore, session: Session, data: bytes, filename: str, units: str,
                      max_bytes: int, max_faces: int) -> dict[str, Any]:
    """Parse and normalise one upload; returns the revision's geometry fields."""
    if len(data) > max_bytes:
        raise TooLarge(f"file is {len(data) / 1e6:.1f} MB; the limit is {max_bytes / 1e6:.1f} MB")
    if not data:
        raise Invalid("file is empty")
    try:
        mesh = meshlib.load_mesh(data, filename, units, max_faces=max_faces)
    except meshlib.MeshError as exc:
        raise (TooLarge if getattr(exc, "status", 422) == 413 else Invalid)(str(exc)) from None
    glb = meshlib.to_glb(mesh)

    return {
        "source_sha256": files.put(session, data, "application/octet-stream"),
        "glb_sha256": files.put(session, glb, "model/gltf-binary"),
        "thumbnail_sha256": files.put(session, render_thumbnail(mesh), "image/png"),
        # STEP carries its own length unit: then the caller's units are not used (units_source "file").
        "summary": {**_jsonable(meshlib.mesh_summary(mesh)),
                    "units_source": mesh.metadata.get("units_source", "caller")},
        "resting_poses": _jsonable(meshlib.resting_poses(mesh)),
        "source_filename": Path(filename).name[:255],
        "units": units,
    }


def create_model(session: Session, files: FileStore, *, data: bytes, filename: str, kind: str, name: str,
                 units: str = "mm", T_obj_datum: Any = None, fiducials: Any = None, description: str = "",
                 key: str | None = None, support_surfaces: Any = None, guide: Any = None, max_bytes: int = 64_000_000,
                 max_faces: int = 2_000_000) -> LibraryModel:
    check_kind_units(kind, units)
    name = (name or "").strip()
    if not name:
        raise Invalid("name must not be empty")
    datum = parse_frame(T_obj_datum, "T_obj_datum")
    layout = parse_fiducials(fiducials)
    surfaces = parse_surfaces(support_surfaces, kind)
    guide_ = parse_guide_field(guide, kind, (key, name))
    if kind == "table" and layout is None:
        log.info("table model %r uploaded without fiducial layout", name)
    geometry = _process_geometry(files, session, data, filename, units, max_bytes, max_faces)
    _check_surfaces_on_model(surfaces, geometry["summary"])
    model = LibraryModel(kind=kind, name=name, description=description, key=key, current_revision=1)
    session.add(model)
    session.flush()
    session.add(ModelRevision(model_id=model.id, revision=1, T_obj_datum=datum, fiducials=layout,
                              support_surfaces=surfaces, guide=guide_, **geometry))
    session.flush()
    log.info("model created", extra={"model_id": model.id, "model_name": name, "kind": kind})
    return model


def add_revision(session: Session, files: FileStore, model_id: int, *, data: bytes | None = None,
                 filename: str | None = None, units: str | None = None, T_obj_datum: Any = _UNSET,
                 fiducials: Any = _UNSET, support_surfaces: Any = _UNSET, guide: Any = _UNSET, note: str = "",
                 max_bytes: int = 64_000_000, max_faces: int = 2_000_000) -> ModelRevision:
    """Make revision n+1 from revision n with the given changes (geometry and/or frames)."""
    model = get_model(session, model_id)
    check_kind_units(None, units)
    prev = get_revision(session, model_id)
    fields = prev.model_dump(exclude={"id", "revision", "created_at", "note"})
    changed = False
    if prev.photo and (data is not None or units is not None):
        raise Invalid(f"model {model_id} was taught from pictures: its geometry comes from them, not from a "
                      "file (teach it again to change it)", code="photo_model_geometry")
    if data is not None:
        fields.update(_process_geometry(files, session, data, filename or prev.source_filename,
                                        units or prev.units, max_bytes, max_faces))
        changed = True
    elif units is not None and units != prev.units:
        # Same file, other units: re-read the stored original.
        fields.update(_process_geometry(files, session, files.read(prev.source_sha256), prev.source_filename,
                                        units, max_bytes, max_faces))
        changed = True
    if T_obj_datum is not _UNSET:
        fields["T_obj_datum"] = parse_frame(T_obj_datum, "T_obj_datum")
        changed = True
    if fiducials is not _UNSET:
        fields["fiducials"] = parse_fiducials(fiducials)
        changed = True
    if support_surfaces is not _UNSET:
        fields["support_surfaces"] = parse_surfaces(support_surfaces, model.kind)
        changed = True
    if guide is not _UNSET:
        fields["guide"] = parse_guide_field(guide, model.kind, (model.key, model.name))
        changed = True
    if not changed:
        raise Invalid("nothing to change: give a file, units, T_obj_datum, fiducials, support_surfaces or guide")
    # new geometry or new surfaces: the surfaces must still lie on the model
    _check_surfaces_on_model(fields.get("support_surfaces"), fields["summary"])
    rev = ModelRevision(**{**fields, "revision": model.current_revision + 1, "note": note[:500]})
    model.current_revision = rev.revision
    session.add(rev)
    session.add(model)
    session.flush()
    return rev


def list_models(session: Session, *, kind: str | None = None, name: str | None = None,
                include_deleted: bool = False, offset: int = 0, limit: int = 100) -> tuple[list[LibraryModel], int]:
    check_kind_units(kind, None)
    q = select(LibraryModel)
    if kind:
        q = q.where(LibraryModel.kind == kind)
    if name:
        q = q.where(func.lower(LibraryModel.name).contains(name.lower()))
    if not include_deleted:
        q = q.where(col(LibraryModel.deleted_at).is_(None))
    count = session.exec(select(func.count()).select_from(q.subquery())).one()
    rows = session.exec(q.order_by(LibraryModel.id).offset(offset).limit(limit)).all()
    return list(rows), int(count)


def get_model(session: Session, model_id: int, *, include_deleted: bool = True) -> LibraryModel:
    model = session.get(LibraryModel, model_id)
    if model is None or (model.deleted_at is not None and not include_deleted):
        raise NotFound(f"model {model_id} not found")
    return model


def get_revision(session: Session, model_id: int, revision: int | None = None) -> ModelRevision:
    model = get_model(session, model_id)
    rev_no = revision or model.current_revision
    rev = session.exec(select(ModelRevision).where(ModelRevision.model_id == model_id,
                                                   ModelRevision.revision == rev_no)).first()
    if rev is None:
        raise NotFound(f"model {model_id} has no revision {rev_no}")
    return rev


def list_revisions(session: Session, model_id: int) -> list[ModelRevision]:
    get_model(session, model_id)
    return list(session.exec(select(ModelRevision).where(ModelRevision.model_id == model_id)
                             .order_by(ModelRevision.revision)).all())


def soft_delete(session: Session, model_id: int) -> None:
    """Hide the model from lists; its revisions stay, so setups that used it still reproduce."""
    model = get_model(session, model_id, include_deleted=False)
    model.deleted_at = utcnow()
    session.add(model)


def load_example_library(session: Session, files: FileStore, library_dir: Path) -> list[str]:
    """Load models_library/ once: entries whose key already exists are skipped. Returns keys added.

    One exception keeps older installations current: an example model still at its first revision,
    from the same file, that has no support surfaces while the manifest now declares some gets them
    as revision 2 (once: then it has them; a model the admin revised is left alone)."""
    manifest = Path(library_dir) / "library.json"
    if not manifest.exists():
        log.warning("example library not found at %s", manifest)
        return []

    added, updated = [], []
    for entry in load_library_manifest(Path(library_dir)):
        existing = session.exec(select(LibraryModel).where(LibraryModel.key == entry.key)).first()
        if existing is not None:
            # (the file is read only when an upgrade is possible: not on every start for every model)
            if entry.support_surfaces is not None and existing.current_revision == 1:
                rev = get_revision(session, existing.id)
                if rev.support_surfaces is None and \
                        rev.source_sha256 == hashlib.sha256((Path(library_dir) / entry.file).read_bytes()).hexdigest():
                    add_revision(session, files, existing.id, support_surfaces=entry.support_surfaces,
                                 note="support surfaces declared in the example library")
                    updated.append(entry.key)
            continue
        fiducials = None
        if entry.fiducials:
            fiducials = json.loads((Path(library_dir) / entry.fiducials).read_text())
        create_model(session, files, data=(Path(library_dir) / entry.file).read_bytes(), filename=entry.file,
                     kind=entry.kind, name=entry.name, units=entry.units,
                     T_obj_datum=_jsonable(entry.T_obj_datum), fiducials=fiducials,
                     description=entry.description, key=entry.key, support_surfaces=entry.support_surfaces,
                     guide=entry.guide)
        added.append(entry.key)
    if added:
        log.info("example library loaded", extra={"keys": added})
    if updated:
        log.info("example library: support surfaces added", extra={"keys": updated})
    return added
