"""Rendered pictures of a plate on the example T-slot table for the photo-model tests (API and page):
two teach pictures and a repeat placement from one camera, with the truth, and the machine they need."""

from __future__ import annotations

from functools import cache

import cv2
import numpy as np

from app.synth.photo_scenes import plate_a, shot

K = np.array([[1500.0, 0, 645.0], [0, 1500.0, 398.0], [0, 0, 1]])
DIST = np.array([-0.09, 0.06, 2e-4, -3e-4, 0.0])
INTRINSICS = {"width": 1280, "height": 800, "K": K.tolist(), "dist": DIST.tolist()}


@cache
def pictures():
    """Two teach pictures (the plate turned between them, the camera elsewhere) and one repeat placement
    (another place, turn and camera pose), all from one camera; with the truth of each placement."""
    plate = plate_a()
    kw = {"intrinsics": (K, DIST)}
    teach1 = shot(plate, 380, 200, 10, seed=11, **kw)
    teach2 = shot(plate, 430, 180, 130, seed=12, azimuth_deg=-60, elevation_deg=55, **kw)
    repeat = shot(plate, 300, 160, 47, seed=13, azimuth_deg=-110, elevation_deg=62, distance_mm=650,
                  cam_target=(330, 170), **kw)
    return teach1, teach2, repeat


def jpeg(img: np.ndarray) -> bytes:
    return cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, 95])[1].tobytes()


def photo_machine(client) -> int:
    """(as admin) A camera with INTRINSICS and a machine on the example T-slot table; the machine's id."""
    cam = client.post("/api/v1/cameras", json={"name": "photo cam", "intrinsics": INTRINSICS})
    assert cam.status_code == 201, cam.text
    models = client.get("/api/v1/models", params={"limit": 200}).json()["data"]
    table = next(m["id"] for m in models if m["key"] == "tslot_table_800x400")
    r = client.post("/api/v1/machines", json={
        "name": "photo mill", "table_model_id": table, "camera_ids": [cam.json()["id"]],
        "T_machine_table": [[1, 0, 0, -450], [0, 1, 0, -250], [0, 0, 1, -320], [0, 0, 0, 1]],
        "travel_mm": {"x": [-600, 600], "y": [-400, 400], "z": [-500, 0]}})
    assert r.status_code == 201, r.text
    return r.json()["id"]


@cache
def other_camera_pose():
    """The first teach placement seen from another camera pose (the height from two views)."""
    return shot(plate_a(), 380, 200, 10, seed=14, azimuth_deg=-45, elevation_deg=50, distance_mm=750,
                intrinsics=(K, DIST))
