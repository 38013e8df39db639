"""A part lying on parallels that it hides, set up as an operator does it: the parallels are named in
the setup beside the part, so their height is declared, and the result says the part stands on them
(real HTTP, database and the service's own worker)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from tests.support.sample_setup import wait_for

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def flange_on_parallels():
    """Our generator's scene 5: the 80 mm flange plate on two 25 mm parallels on the table."""
    from app.synth.fixtures import synth_entry, synth_scene

    sc, image = synth_scene(synth_entry(5))
    assert sc.gt["fixture_mode"] == "parallels"
    ok, jpg = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, 95])
    assert ok
    return sc, image.shape, jpg.tobytes()


def test_part_on_hidden_parallels_named_in_the_setup_stands_on_them(client, flange_on_parallels):
    sc, shape, jpg = flange_on_parallels
    # the camera states how well its calibration is known (it is exact here; 0.2 % and 1.5 px stated)
    cam = client.post("/api/v1/cameras", json={"name": "riser cam", "intrinsics": {
        "width": shape[1], "height": shape[0], "K": sc.K.tolist(), "dist": sc.dist.tolist(),
        "sigma": {"f_rel": 0.002, "c_px": 1.5}}})
    assert cam.status_code == 201, cam.text
    models = {m["key"]: m["id"] for m in client.get("/api/v1/models", params={"limit": 200}).json()["data"]}
    machine = client.post("/api/v1/machines", json={
        "name": "riser mill", "table_model_id": models["tslot_table_800x400"], "camera_ids": [cam.json()["id"]],
        "T_machine_table": [[1, 0, 0, -450], [0, 1, 0, -250], [0, 0, 1, -320], [0, 0, 0, 1]],
        "travel_mm": {"x": [-600, 600], "y": [-400, 400], "z": [-500, 0]}})
    assert machine.status_code == 201, machine.text
    r = client.post("/api/v1/setups", data={
        "machine_id": str(machine.json()["id"]),
        "model_ids": f"{models['flange_plate_80']},{models['parallel_150x25x8']}"},
        files={"image": ("flange_on_parallels.jpg", jpg, "image/jpeg")})
    assert r.status_code == 202, r.text
    setup = wait_for(client, r.json()["url"], lambda b: b["status"] in ("located", "failed"), 300)
    objs = (setup.get("result") or {}).get("objects", [])
    part = next((o for o in objs if o["kind"] == "workpiece"), None)
    assert part is not None, (setup["status"], setup["reason"], objs)
    assert part["chain"] == ["a declared riser 25 mm high", "table"], part["chain"]
    assert part["riser_mm"] == 25.0
    T, truth = np.asarray(part["T_table_obj"]), np.asarray(sc.workpiece["T_table_object"])
    assert np.linalg.norm(T[:3, 3] - truth[:3, 3]) < 0.3, (T[:3, 3], truth[:3, 3])
    # the stated calibration sigma reached the engine: the table says so, the part's sigma holds its share
    assert setup["result"]["table"]["intrinsics_sigma"] == {"f_rel": 0.002, "cx_px": 1.5, "cy_px": 1.5}
    C_k, C_frame = np.diag(part["cov6_intrinsics"]), np.diag(part["cov6_table"])
    assert np.all(C_k[:3] > 0) and np.all(C_k <= C_frame + 1e-12)
