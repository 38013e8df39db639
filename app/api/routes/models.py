"""/api/v1/models: the CAD model library (workpieces, clamps, supports, tables)."""

from __future__ import annotations

from typing import Annotated, Literal

from fastapi import APIRouter, Depends, File, Form, Query, Response, UploadFile, status
from starlette.concurrency import run_in_threadpool

from app.api.deps import AdminPrincipal, FilesDep, SessionDep, SettingsDep, get_principal
from app.api.schemas import ModelPublic, Page, RevisionPublic
from app.api.uploads import content_disposition, json_form, safe_filename
from app.services import library, photo_models
from app.services.audit import audit

router = APIRouter(prefix="/models", tags=["models"], dependencies=[Depends(get_principal)])

DATUM_EXAMPLE = "[[1,0,0,0],[0,1,0,0],[0,0,1,25],[0,0,0,1]]"
SURFACES_EXAMPLE = '[{"name": "top", "z_mm": 25, "outline_xy": [[-75, -4], [75, -4], [75, 4], [-75, 4]]}]'
SURFACES_HELP = ("Support surfaces JSON (clamps and supports): plane patches a part can rest on, model frame, mm; "
                 "at most 16, each {name, z_mm, outline_xy: >= 3 [x, y]}")
GUIDE_EXAMPLE = ('{"carrier": "vise_body", "T_carrier_obj": [[1,0,0,0],[0,1,0,0],[0,0,1,70],[0,0,0,1]], '
                 '"axis": [1, 0, 0], "travel_mm": [-95, 100]}')
GUIDE_HELP = ("Guide JSON (clamps and supports): what carries the model and how it moves there, in the carrier's "
              "frame, mm: {carrier: key or name of the carrying model, T_carrier_obj: 4x4 at travel 0, axis: [x, y, z], "
              "travel_mm: [lo, hi]} (a vise's moving jaw on its body); it is then searched only along the guide")


def to_public(model, rev) -> ModelPublic:
    """A library model (``LibraryModel`` row) at one of its revisions (``ModelRevision`` row)."""
    q = f"?revision={rev.revision}"
    public_rev = RevisionPublic.model_validate(rev, from_attributes=True)
    public_rev.photo = photo_models.photo_summary(rev.photo, model.id, rev.revision)
    return ModelPublic(
        **model.model_dump(include=set(ModelPublic.model_fields) - {"revision", "mesh_url", "thumbnail_url"}),
        revision=public_rev,
        mesh_url=f"/api/v1/models/{model.id}/mesh.glb{q}",
        thumbnail_url=f"/api/v1/models/{model.id}/thumbnail.png{q}",
    )


async def _read_upload(file: UploadFile, max_bytes: int) -> bytes:
    # Read one byte past the limit so an oversize upload is refused without reading it all.
    data = await file.read(max_bytes + 1)
    return data


@router.post("", status_code=status.HTTP_201_CREATED, response_model=ModelPublic,
             summary="Upload a CAD model (STL, OBJ, PLY, GLB, STEP/STP)")
async def create_model(
    session: SessionDep, files: FilesDep, settings: SettingsDep, admin: AdminPrincipal,
    file: Annotated[UploadFile, File(description="The CAD file")],
    kind: Annotated[str, Form(description="workpiece | clamp | support | table", examples=["workpiece"])],
    name: Annotated[str, Form(examples=["Bracket 4711"])],
    units: Annotated[str, Form(description="Units of the file: mm | inch (stored in mm)")] = "mm",
    T_obj_datum: Annotated[str | None, Form(description="4x4 JSON, pose of the datum in the model frame (mm)",
                                            examples=[DATUM_EXAMPLE])] = None,
    fiducials: Annotated[str | None, Form(description="Fiducial layout JSON (DESIGN format)")] = None,
    description: Annotated[str, Form()] = "",
    support_surfaces: Annotated[str | None, Form(description=SURFACES_HELP + "; left out: derived from the mesh",
                                                 examples=[SURFACES_EXAMPLE])] = None,
    guide: Annotated[str | None, Form(description=GUIDE_HELP + "; left out: it stands free",
                                      examples=[GUIDE_EXAMPLE])] = None,
) -> ModelPublic:
    max_bytes = int(settings.max_upload_mb * 1e6)
    surfaces = json_form(support_surfaces, "support_surfaces")
    guide_value = json_form(guide, "guide")
    data = await _read_upload(file, max_bytes)
    # reading and converting the mesh (a STEP file: seconds) in a worker thread, never on the event loop
    model = await run_in_threadpool(
        library.create_model, session, files, data=data, filename=safe_filename(file.filename), kind=kind,
        name=name, units=units, T_obj_datum=T_obj_datum, fiducials=fiducials, description=description,
        support_surfaces=surfaces, guide=guide_value, max_bytes=max_bytes, max_faces=settings.max_mesh_faces)
    audit(session, admin.label(), "model.create", model_id=model.id, kind=model.kind, name=model.name)
    return to_public(model, library.get_revision(session, model.id))


@router.post("/photo", status_code=status.HTTP_201_CREATED, response_model=ModelPublic,
             summary="Teach a workpiece or clamp from the machine's camera (a photo model, no CAD)")
async def teach_photo_model(
    session: SessionDep, files: FilesDep, settings: SettingsDep, admin: AdminPrincipal,
    machine_id: Annotated[int, Form(description="The machine whose table (with its markers) the pictures show")],
    name: Annotated[str, Form(examples=["Fixture plate 7"])],
    kind: Annotated[str, Form(description="workpiece | clamp")] = "workpiece",
    height_mm: Annotated[float | None, Form(description="Height of the object's top face above the table, mm; "
                                                        "left out: measured from two or more pictures taken from "
                                                        "different camera poses (the object not moved)")] = None,
    camera_id: Annotated[int | None, Form(description="Camera (default: the machine's first)")] = None,
    grab: Annotated[bool, Form(description="Take the picture from the camera instead of uploads")] = False,
    pictures: Annotated[list[UploadFile] | None, File(description="One or more pictures of the object on the "
                                                                  "table, markers in view; more pictures (the object "
                                                                  "turned between them) keep only the edges all show")] = None,
    region_mm: Annotated[str | None, Form(description="[x_lo, x_hi, y_lo, y_hi] table box holding the object, mm "
                                                      "(left out: found)")] = None,
    datum_xy_mm: Annotated[str | None, Form(description="[x, y]: the datum on the top face in table coordinates of "
                                                        "the first picture, mm (left out: none; set it later as a "
                                                        "revision's T_obj_datum)")] = None,
    description: Annotated[str, Form()] = "",
) -> ModelPublic:
    max_bytes = int(settings.max_upload_mb * 1e6)
    data = [await _read_upload(f, max_bytes) for f in (pictures or []) if f.filename]
    model = await run_in_threadpool(
        photo_models.teach_photo_model, session, files, machine_id=machine_id, name=name, kind=kind,
        height_mm=height_mm, pictures=data, camera_id=camera_id, grab=grab, region_mm=region_mm,
        datum_xy_mm=datum_xy_mm, description=description, max_bytes=max_bytes)
    audit(session, admin.label(), "model.create", model_id=model.id, kind=model.kind, name=model.name, source="photo")
    return to_public(model, library.get_revision(session, model.id))


@router.get("/{model_id}/photo.png", response_class=Response, summary="A photo model's teach picture (PNG): the "
            "first picture seen on the top face's plane; pixel (u, v) is table x0 + u * mm_per_px, y0 + v * mm_per_px",
            responses={200: {"content": {"image/png": {}}}})
def get_teach_picture(session: SessionDep, files: FilesDep, model_id: int,
                      revision: Annotated[int | None, Query(ge=1)] = None) -> Response:
    rev = library.get_revision(session, model_id, revision)
    return Response(photo_models.teach_picture(session, files, model_id, rev.revision), media_type="image/png",
                    headers={"Cache-Control": "public, max-age=31536000, immutable"})


@router.get("", response_model=Page[ModelPublic], summary="List models (filter by kind and name)")
def list_models(
    session: SessionDep,
    kind: Annotated[Literal["workpiece", "clamp", "support", "table"] | None, Query()] = None,
    name: Annotated[str | None, Query(description="Case-insensitive part of the name")] = None,
    include_deleted: bool = False,
    offset: Annotated[int, Query(ge=0)] = 0,
    limit: Annotated[int, Query(ge=1, le=500)] = 100,
) -> Page[ModelPublic]:
    rows, count = library.list_models(session, kind=kind, name=name, include_deleted=include_deleted,
                                      offset=offset, limit=limit)
    return Page(data=[to_public(m, library.get_revision(session, m.id)) for m in rows], count=count)


@router.get("/{model_id}", response_model=ModelPublic, summary="One model at its current (or a given) revision")
def get_model(session: SessionDep, model_id: int, revision: Annotated[int | None, Query(ge=1)] = None) -> ModelPublic:
    return to_public(library.get_model(session, model_id), library.get_revision(session, model_id, revision))


@router.get("/{model_id}/revisions", response_model=list[RevisionPublic], summary="All revisions of a model")
def list_revisions(session: SessionDep, model_id: int) -> list[RevisionPublic]:
    return [RevisionPublic.model_validate(r, from_attributes=True) for r in library.list_revisions(session, model_id)]


@router.post("/{model_id}/revisions", status_code=status.HTTP_201_CREATED, response_model=ModelPublic,
             summary="Make a new revision: new geometry, units, datum frame, fiducials, support surfaces or guide")
async def add_revision(
    session: SessionDep, files: FilesDep, settings: SettingsDep, admin: AdminPrincipal, model_id: int,
    file: Annotated[UploadFile | None, File()] = None,
    units: Annotated[str | None, Form()] = None,
    T_obj_datum: Annotated[str | None, Form(description="4x4 JSON; the text 'null' removes the datum",
                                            examples=[DATUM_EXAMPLE])] = None,
    fiducials: Annotated[str | None, Form(description="Layout JSON; 'null' removes it")] = None,
    support_surfaces: Annotated[str | None, Form(description=SURFACES_HELP + "; 'null' removes them (derived "
                                                             "from the mesh again), '[]' says it carries nothing",
                                                 examples=[SURFACES_EXAMPLE])] = None,
    guide: Annotated[str | None, Form(description=GUIDE_HELP + "; 'null' removes it (it stands free)",
                                      examples=[GUIDE_EXAMPLE])] = None,
    note: Annotated[str, Form()] = "",
) -> ModelPublic:
    max_bytes = int(settings.max_upload_mb * 1e6)
    kwargs: dict = {}
    if file is not None and file.filename:
        kwargs.update(data=await _read_upload(file, max_bytes), filename=safe_filename(file.filename))
    if T_obj_datum is not None:
        kwargs["T_obj_datum"] = None if T_obj_datum.strip() == "null" else T_obj_datum
    if fiducials is not None:
        kwargs["fiducials"] = None if fiducials.strip() == "null" else fiducials
    if support_surfaces is not None:
        kwargs["support_surfaces"] = json_form(support_surfaces.strip(), "support_surfaces")
    if guide is not None:
        kwargs["guide"] = json_form(guide.strip(), "guide")        # 'null' parses to None: removed
    rev = await run_in_threadpool(library.add_revision, session, files, model_id, units=units, note=note,
                                  max_bytes=max_bytes, max_faces=settings.max_mesh_faces, **kwargs)
    audit(session, admin.label(), "model.revision", model_id=model_id, revision=rev.revision,
          changed=sorted(k for k in kwargs if k != "data"))
    return to_public(library.get_model(session, model_id), rev)


def _file_response(files, sha: str, media_type: str, filename: str) -> Response:
    return Response(files.read(sha), media_type=media_type,
                    headers={"Content-Disposition": content_disposition(filename), "ETag": f'"{sha}"',
                             "Cache-Control": "public, max-age=31536000, immutable"})


@router.get("/{model_id}/mesh.glb", response_class=Response, summary="Normalised mesh (GLB, mm)",
            responses={200: {"content": {"model/gltf-binary": {}}}})
def get_mesh(session: SessionDep, files: FilesDep, model_id: int,
             revision: Annotated[int | None, Query(ge=1)] = None) -> Response:
    rev = library.get_revision(session, model_id, revision)
    return _file_response(files, rev.glb_sha256, "model/gltf-binary", f"model{model_id}-r{rev.revision}.glb")


@router.get("/{model_id}/source", response_class=Response, summary="The original uploaded file")
def get_source(session: SessionDep, files: FilesDep, model_id: int,
               revision: Annotated[int | None, Query(ge=1)] = None) -> Response:
    rev = library.get_revision(session, model_id, revision)
    return _file_response(files, rev.source_sha256, "application/octet-stream", rev.source_filename)


@router.get("/{model_id}/thumbnail.png", response_class=Response, summary="Thumbnail (PNG)",
            responses={200: {"content": {"image/png": {}}}})
def get_thumbnail(session: SessionDep, files: FilesDep, model_id: int,
                  revision: Annotated[int | None, Query(ge=1)] = None) -> Response:
    rev = library.get_revision(session, model_id, revision)
    return _file_response(files, rev.thumbnail_sha256, "image/png", f"model{model_id}-r{rev.revision}.png")


@router.delete("/{model_id}", status_code=status.HTTP_204_NO_CONTENT, response_class=Response,
               summary="Soft delete: hidden from lists, revisions kept for reproducibility")
def delete_model(session: SessionDep, admin: AdminPrincipal, model_id: int) -> Response:
    library.soft_delete(session, model_id)
    audit(session, admin.label(), "model.delete", model_id=model_id)
    return Response(status_code=status.HTTP_204_NO_CONTENT)
