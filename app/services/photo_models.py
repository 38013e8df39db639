"""Teach a library model from the machine's camera (issue 16): pictures -> table pose -> photo model.

The maths is in app/vision/photo_model/ (rectify, teach, measure_height, locate); this module checks
the request (4xx with the reason), locates the table in every picture with the machine's table
model, stores the pictures, the teach picture and the template, and makes a library model of kind
``workpiece`` or ``clamp`` with ``source = "photo"``: its mesh (for the 3D view, the overlay and the
support chain) is the taught outline with its holes extruded to the height
(:func:`app.geometry.parts.taught_prism`). Docs: docs/photo-models.md.
"""

from __future__ import annotations

import json
import logging
from typing import Any

import cv2
import numpy as np
from sqlmodel import Session

from app.geometry import mesh as meshlib
from app.geometry.model_edges import PreparedModel
from app.geometry.parts import taught_prism
from app.geometry.thumbnail import render_thumbnail
from app.geometry.transforms import inv, make_pose
from app.services import library
from app.services.cameras import grab_frame, image_media_type, read_image
from app.services.errors import Invalid, TooLarge
from app.services.machines import get_machine
from app.services.setups import calibrated_camera, library_candidates
from app.store.files import FileStore
from app.store.models import LibraryModel, ModelRevision
from app.vision import photo_model as pm
from app.vision.fiducials import locate_table
from app.vision.localize import marker_labels_table

log = logging.getLogger(__name__)

PHOTO_KINDS = ("workpiece", "clamp")
MAX_PICTURES = 8


def _box(value: Any, name: str, n: int) -> tuple[float, ...] | None:
    """``n`` finite numbers from JSON text or a list (None stays None); 422 with the reason."""
    if value is None or (isinstance(value, str) and not value.strip()):
        return None
    try:
        v = json.loads(value) if isinstance(value, str) else value
        out = tuple(float(x) for x in v)
    except (ValueError, TypeError):
        raise Invalid(f"{name}: give {n} numbers in mm as JSON, e.g. {[0] * n}") from None
    if len(out) != n or not all(np.isfinite(out)):
        raise Invalid(f"{name}: give {n} finite numbers in mm, got {value!r}")
    return out


def table_view(image: np.ndarray, K: np.ndarray, dist: np.ndarray, layout: dict, table: PreparedModel | None,
               what: str) -> pm.View:
    """One picture as :class:`app.vision.photo_model.View`: the table located by its markers, the
    table's own edges and the printed labels masked. 422 with the reason when the markers fail."""
    # a photo model's sigma takes the table pose's covariance only (View.of): no intrinsics jacobian
    tp = locate_table(image, K, dist, layout, intrinsics_sigma=None)
    if not tp:
        raise Invalid(f"{what}: {tp.reason}", code="table_not_found")
    known = [(table, np.eye(4))] if table is not None else []
    ign = pm.known_edge_mask(image.shape[:2], K, dist, tp.T_cam_table, known, marker_labels_table(layout))
    return pm.View.of(image, K, dist, tp, ign)


def teach_photo_model(session: Session, files: FileStore, *, machine_id: int, name: str, kind: str,
                      height_mm: float | None, pictures: list[bytes], camera_id: int | None = None,
                      grab: bool = False, region_mm: Any = None, datum_xy_mm: Any = None,
                      description: str = "", table_model: PreparedModel | None = None,
                      max_bytes: int = 64_000_000) -> LibraryModel:
    """Teach a photo model from ``pictures`` (uploaded bytes) or one grabbed frame (``grab``).

    machine_id : the machine whose table (markers, model) the pictures show
    height_mm : the top face's height above the table; None: measured from two or more pictures
        taken from different camera poses (the object unmoved)
    region_mm : optional JSON [x_lo, x_hi, y_lo, y_hi] (table frame) that holds the object
    datum_xy_mm : optional JSON [x, y]: the datum on the top face, in table coordinates of the first
        picture (the teach picture's click); T_obj_datum = that point at the top face's height
    table_model : the machine's table, prepared (its edges are masked); None: read from the library
    max_bytes : largest picture (413 above)
    """
    name = (name or "").strip()
    if not name:
        raise Invalid("name must not be empty")
    if kind not in PHOTO_KINDS:
        raise Invalid(f"kind {kind!r}: a photo model is a {' or a '.join(PHOTO_KINDS)}")
    machine = get_machine(session, machine_id)
    table_rev = library.get_revision(session, machine.table_model_id, machine.table_revision)
    layout = table_rev.fiducials
    if not layout:
        raise Invalid(f"machine {machine_id}'s table has no fiducial layout: the pictures cannot be put on "
                      "the table", code="table_without_markers")
    cam = calibrated_camera(session, machine, camera_id)
    if grab and pictures:
        raise Invalid("give pictures or grab=true, not both")
    if grab:
        frame = grab_frame(cam)
        pictures = [cv2.imencode(".jpg", frame, [cv2.IMWRITE_JPEG_QUALITY, 95])[1].tobytes()]
    if not pictures:
        raise Invalid("no picture: upload one or more, or set grab=true to take one from the camera")
    for i, data in enumerate(pictures, start=1):
        if len(data) > max_bytes:
            raise TooLarge(f"picture {i} is larger than the limit of {max_bytes / 1e6:.1f} MB")
    if len(pictures) > MAX_PICTURES:
        raise Invalid(f"{len(pictures)} pictures: at most {MAX_PICTURES}")
    region = _box(region_mm, "region_mm", 4)
    datum = _box(datum_xy_mm, "datum_xy_mm", 2)
    if datum is not None and max(abs(v) for v in datum) > 10_000:
        raise Invalid(f"datum_xy_mm {list(datum)}: more than 10 m from the table origin")
    if height_mm is not None and not (0.5 <= float(height_mm) <= 1000.0):
        raise Invalid(f"height_mm {height_mm}: give the top face's height above the table, 0.5 to 1000 mm")
    K, dist = np.asarray(cam.intrinsics["K"], float), np.asarray(cam.intrinsics["dist"], float)
    if table_model is None:
        (table_cand,) = library_candidates(session, files, [{"model_id": machine.table_model_id,
                                                             "revision": machine.table_revision}])
        table_model = table_cand.prepare()
    views = []
    for i, data in enumerate(pictures, start=1):
        img = read_image(data, f"picture {i}")
        if (img.shape[1], img.shape[0]) != (cam.intrinsics["width"], cam.intrinsics["height"]):
            raise Invalid(f"picture {i} is {img.shape[1]} x {img.shape[0]} px but camera {cam.id} is calibrated for "
                          f"{cam.intrinsics['width']} x {cam.intrinsics['height']} px", code="image_size_mismatch")
        views.append(table_view(img, K, dist, layout, table_model, f"picture {i}"))
    b = table_model.mesh.bounds
    table_xy = (float(b[0, 0]), float(b[1, 0]), float(b[0, 1]), float(b[1, 1]))
    height_source = "given"
    try:
        if height_mm is None:
            if len(views) < 2:
                raise Invalid("give height_mm, or two or more pictures from different camera poses to measure it",
                              code="height_needed")
            first, _ = pm.teach(views[:1], 10.0, region_mm=region, table_xy_mm=table_xy)
            g = first.teach_grid
            box = region or (g.x0_mm - 20, g.x0_mm + g.width * g.mm_per_px + 20,
                             g.y0_mm - 20, g.y0_mm + g.height * g.mm_per_px + 20)
            height_mm, _ = pm.measure_height(views, box)
            height_source = "measured"
            views = views[:1]         # the others showed the same placement from elsewhere
        model, teach_pic = pm.teach(views, float(height_mm), region_mm=region, table_xy_mm=table_xy)
    except pm.TeachError as exc:
        raise Invalid(str(exc), code="teach_failed") from None
    body = taught_prism(model.outline_mm, list(model.holes_mm), model.height_mm)
    T_obj_datum = None
    if datum is not None:
        p_obj = inv(model.T_table_obj_teach) @ np.array([datum[0], datum[1], model.height_mm, 1.0])
        T_obj_datum = make_pose(t=p_obj[:3]).tolist()
    shas = [files.put(session, data, image_media_type(data)) for data in pictures]
    teach_sha = files.put(session, cv2.imencode(".png", teach_pic)[1].tobytes(), "image/png")
    template = model.to_dict()
    source = json.dumps(template).encode()
    photo = {**template, "pictures": shas, "teach_picture_sha256": teach_sha, "camera_id": cam.id,
             "machine_id": machine.id, "height_source": height_source}
    row = LibraryModel(kind=kind, name=name, description=description, source="photo", current_revision=1)
    session.add(row)
    session.flush()
    session.add(ModelRevision(
        model_id=row.id, revision=1, source_filename="photo-model.json",
        source_sha256=files.put(session, source, "application/json"),
        glb_sha256=files.put(session, meshlib.to_glb(body), "model/gltf-binary"),
        thumbnail_sha256=files.put(session, render_thumbnail(body), "image/png"), units="mm",
        T_obj_datum=T_obj_datum, summary={**library.jsonable(meshlib.mesh_summary(body)), "units_source": "photo"},
        resting_poses=library.jsonable(meshlib.resting_poses(body)), photo=photo,
        note=f"taught from {len(pictures)} picture(s), height {model.height_mm:.1f} mm ({height_source})"))
    session.flush()
    log.info("photo model taught", extra={"model_id": row.id, "model_name": name, "kind": kind,
                                          "pictures": len(pictures), "edge_mm": model.edge_length_mm})
    return row


def photo_summary(photo: dict | None, model_id: int, revision: int) -> dict | None:
    """What the API shows of a revision's photo model: not the template's points, but its size, how
    it was taught and where its teach picture is (with the grid that maps a click on it to the table)."""
    if not photo:
        return None
    return {"height_mm": photo["height_mm"], "height_source": photo.get("height_source", "given"),
            "n_views": photo.get("n_views", 1), "pictures": len(photo.get("pictures", [])),
            "edge_length_mm": len(photo["points_mm"]) * pm.TEMPLATE_SPACING_MM,
            "holes": len(photo.get("holes_mm", [])), "symmetry_deg": photo.get("symmetry_deg", []),
            "T_table_obj_teach": photo.get("T_table_obj_teach"), "teach_grid": photo.get("teach_grid"),
            "camera_id": photo.get("camera_id"), "machine_id": photo.get("machine_id"),
            "teach_picture_url": f"/api/v1/models/{model_id}/photo.png?revision={revision}"}


def teach_picture(session: Session, files: FileStore, model_id: int, revision: int | None) -> bytes:
    """The rectified teach picture (PNG) of a photo model's revision; 422 for a CAD model."""
    rev = library.get_revision(session, model_id, revision)
    if not rev.photo:
        raise Invalid(f"model {model_id} is not a photo model", code="not_a_photo_model")
    return files.read(rev.photo["teach_picture_sha256"])

