"""Sheet monitors belong to the service's lifetime and keep their drift state in the database: after a
restart a running monitor carries on from where it was (its datum after a re-datum included)."""

from __future__ import annotations

import json

import cv2
import pytest

from app.synth.bed_images import bed_camera, drift_sequence, render_bed_image, scene_variant
from tests.support.factories import make_machine
from tests.support.jobs import settled
from tests.support.live_server import LiveServer, live_server

pytestmark = pytest.mark.integration

CAM = bed_camera(800, 600, mm_per_px=1.0, target_bed_mm=(650.0, 420.0))
SCENE = scene_variant("plain", sheet_angle_deg=2.0, thickness_mm=3.0, seed=0)


def _jpg(img) -> bytes:
    return cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, 95])[1].tobytes()


def test_a_running_monitor_resumes_after_a_restart_with_its_datum(tmp_path):
    moved = drift_sequence(SCENE, CAM, [(0, 0, 0), (1.5, 0.5, 0.1)]).frames
    with live_server(tmp_path / "data") as srv:
        with srv.client("admin") as c:
            cam = c.post("/api/v1/cameras", json={"name": "bed cam", "intrinsics": CAM.intrinsics_dict()}).json()
            machine = make_machine(c, None, T_machine_table=[[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]],
                                   travel={"x": [0, 1500], "y": [0, 1000], "z": [-100, 100]})
        with srv.client("operator") as c:
            r = c.post("/api/v1/sheet/alignments", data={
                "machine_id": machine["id"], "camera_id": cam["id"], "thickness_mm": 3.0,
                "T_cam_bed": json.dumps(CAM.T_cam_bed.tolist())},
                files={"image": ("bed.jpg", _jpg(render_bed_image(SCENE, CAM).image))})
            aid = settled(c, r).json()["id"]
            c.post(f"/api/v1/sheet/alignments/{aid}/confirm")
            mid = c.post("/api/v1/sheet/monitors", json={"alignment_id": aid, "l1_mm": 1.0, "l2_mm": 4.0}).json()["id"]
            decisions = [c.post(f"/api/v1/sheet/monitors/{mid}/frames", files={"frame": ("f.jpg", _jpg(f))}).json()
                         for f in moved]
            # the sheet moved 1.5 mm: re-datum (no controller here, so nothing is written, but the datum moves)
            assert [d["decision"] for d in decisions] == ["ok", "redatum"], decisions
        srv.stop()  # the lifespan ends: monitors stop, their rows stay 'running'
        again = LiveServer(srv.settings).start()
        try:
            again.tokens = srv.tokens  # same database: the same sessions
            with again.client("operator") as c:
                mon = c.get(f"/api/v1/sheet/monitors/{mid}").json()
                assert mon["state"] == "running" and mon["frames"] == 2, mon
                d = c.post(f"/api/v1/sheet/monitors/{mid}/frames", files={"frame": ("f.jpg", _jpg(moved[1]))}).json()
                # measured against the datum after the re-datum: the sheet has not moved since
                assert d["decision"] == "ok" and d["frame_index"] == decisions[-1]["frame_index"] + 1, d
                assert max(d["errors_mm"]) < 0.5
        finally:
            again.stop()
