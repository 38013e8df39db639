"""A devset scene set up over HTTP as an operator does it: the shop's table model with the layout it
is told, the vise body with its seat, the moving jaw with its guide, the workpiece, the devset camera
and a machine; then one setup of the scene's image with those models, waited for. The scenes are read
from ../shared/data/devset (never copied into the repository)."""

from __future__ import annotations

import json
from pathlib import Path

from app.synth.devset import GUIDES, SUPPORT_SURFACES
from tests.support.sample_setup import wait_for

DEVSET = Path(__file__).resolve().parents[3] / "shared" / "data" / "devset"


def upload_model(client, name: str, kind: str, mesh: str, **form) -> dict:
    """POST one of the devset's meshes to the library; the created model."""
    r = client.post("/api/v1/models", files={"file": (mesh, (DEVSET / "meshes" / mesh).read_bytes())},
                    data={"kind": kind, "name": name, "units": "mm", **form})
    assert r.status_code == 201, r.text
    return r.json()


def vise_setup(client, scene_id: str, label: str, part_mesh: str, *, marker_ids=None) -> tuple[dict, dict, str]:
    """The devset scene ``scene_id`` set up with its workpiece (``part_mesh``) and the vise (body and
    jaw), the models named after ``label``; ``marker_ids``: the markers the table's layout declares
    (None: all). Returns (the finished setup, the scene's ground truth, the vise body's name)."""
    gt = json.loads((DEVSET / "setup" / f"{scene_id}.json").read_text())
    layout = json.loads((DEVSET / gt["marker_layout"]).read_text())
    if marker_ids is not None:
        layout = {**layout, "markers": [m for m in layout["markers"] if m["id"] in marker_ids]}
    table = upload_model(client, f"{label} table", "table", "table_800x400_tslot.stl", fiducials=json.dumps(layout))
    body_name = f"{label} vise body"
    body = upload_model(client, body_name, "clamp", "vise_body.stl",
                        support_surfaces=json.dumps(SUPPORT_SURFACES["vise_body"]))
    jaw = upload_model(client, f"{label} vise jaw", "clamp", "vise_jaw.stl",
                       guide=json.dumps({**GUIDES["vise_jaw"], "carrier": body_name}))
    part = upload_model(client, f"{label} part", "workpiece", part_mesh)
    cam = gt["camera"]
    w, h = cam["image_size"]
    c = client.post("/api/v1/cameras", json={"name": f"{label} cam", "intrinsics": {
        "width": w, "height": h, "K": cam["K"], "dist": cam["dist"]}})
    assert c.status_code == 201, c.text
    machine = client.post("/api/v1/machines", json={
        "name": f"{label} mill", "table_model_id": table["id"], "camera_ids": [c.json()["id"]],
        "T_machine_table": [[1, 0, 0, -450], [0, 1, 0, -250], [0, 0, 1, -320], [0, 0, 0, 1]],
        "travel_mm": {"x": [-600, 600], "y": [-400, 400], "z": [-500, 0]}})
    assert machine.status_code == 201, machine.text
    image = DEVSET / gt["image"]
    r = client.post("/api/v1/setups", data={
        "machine_id": str(machine.json()["id"]), "model_ids": f"{part['id']},{body['id']},{jaw['id']}"},
        files={"image": (image.name, image.read_bytes(), "image/png" if image.suffix == ".png" else "image/jpeg")})
    assert r.status_code == 202, r.text
    return wait_for(client, r.json()["url"], lambda b: b["status"] in ("located", "failed"), 300), gt, body_name


def workpiece_error(obj: dict, gt: dict, part_mesh: str):
    """(dx, dy, dz mm, rx, ry, rz deg) of the located workpiece ``obj`` (a result's object) against
    the scene's truth, and whether every component lies within 3 of its stated sigma."""
    import numpy as np
    import trimesh

    from app.geometry.model_edges import prepare_model
    from app.vision.pose_errors import pose_error_6dof

    truth = next(o for o in gt["objects"] if o["kind"] == "workpiece")
    model = prepare_model(trimesh.load(DEVSET / "meshes" / part_mesh, force="mesh"), name=part_mesh)
    err = pose_error_6dof(np.asarray(obj["T_table_obj"]), np.asarray(truth["T_table_object"]), model)
    return err, within_3_sigma(obj, err)


def within_3_sigma(obj: dict, err) -> bool:
    """Whether every component of ``err`` (x, y, z mm, rx, ry, rz deg) lies within 3 of the located
    object's stated sigma."""
    keys = ("x_mm", "y_mm", "z_mm", "rx_deg", "ry_deg", "rz_deg")
    return all(abs(e) <= 3 * obj["sigma"][k] for k, e in zip(keys, err))
