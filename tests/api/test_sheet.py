"""Sheet alignment and drift monitoring over real HTTP on generated bed images (800 x 600 px, ~1 mm/px).

The controller is the headless LinuxCNC sim (its own status is the independent read-back): export,
re-datum and the stop of a running program. A camera-polled monitor reads a tmp folder source.
"""

from __future__ import annotations

import json
import shutil
import threading
import time
from concurrent.futures import ThreadPoolExecutor

import cv2
import httpx
import numpy as np
import pytest

from app.synth.bed_images import bed_camera, drift_sequence, render_bed_image, scene_variant
from tests.support.jobs import settled
from tests.support.factories import make_machine
from tests.support.live_server import LiveServer, live_server

pytestmark = pytest.mark.integration  # a live server; LinuxCNC where a controller is involved

CAM = bed_camera(800, 600, mm_per_px=1.0, target_bed_mm=(650.0, 420.0))
SCENE = scene_variant("plain", sheet_angle_deg=2.0, thickness_mm=3.0, seed=0)
T_MACHINE_BED = np.eye(4)
TRAVEL = {"x": [-100, 1500], "y": [-100, 1000], "z": [-400, 100]}


def _jpg(img) -> bytes:
    return cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, 95])[1].tobytes()


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    with live_server(tmp_path_factory.mktemp("sheet"), "sqlite", max_upload_mb=5) as srv:
        bus, srv.published = srv.app.state.events, []
        publish = bus.publish
        bus.publish = lambda kind, data: (srv.published.append((kind, data)), publish(kind, data))[1]
        yield srv


@pytest.fixture(scope="module")
def bed_image():
    return render_bed_image(SCENE, CAM)


@pytest.fixture(scope="module")
def camera(server):
    with server.client() as c:
        r = c.post("/api/v1/cameras", json={"name": "bed cam", "intrinsics": CAM.intrinsics_dict()})
        assert r.status_code == 201, r.text
        return r.json()


@pytest.fixture(scope="module")
def dry_machine(server):
    """A machine without a controller (alignment only)."""
    with server.client() as c:
        return make_machine(c, None, T_machine_table=T_MACHINE_BED, travel=TRAVEL)


def align(client, machine_id, camera_id, image_bytes, margin_mm=0.0, pose=True):
    data = {"machine_id": machine_id, "camera_id": camera_id, "thickness_mm": 3.0, "margin_mm": margin_mm}
    if pose:
        data["T_cam_bed"] = json.dumps(CAM.T_cam_bed.tolist())
    # a job: refused at once (4xx) or the alignment it made once it ran (200)
    return settled(client, client.post("/api/v1/sheet/alignments", data=data, files={"image": ("bed.jpg", image_bytes)}))


def expected_origin(corners_mm: np.ndarray, margin_mm: float) -> np.ndarray:
    ex = (corners_mm[1] - corners_mm[0]) / np.linalg.norm(corners_mm[1] - corners_mm[0])
    return corners_mm[0] + margin_mm * (ex + np.array([-ex[1], ex[0]]))


def test_alignment_matches_ground_truth_and_margin(server, camera, dry_machine, bed_image):
    with server.client("mes") as c:
        r = align(c, dry_machine["id"], camera["id"], _jpg(bed_image.image), margin_mm=10.0)
        assert r.status_code == 200, r.text
        a = r.json()
        assert a["status"] == "located", a["reason"]
        res = a["result"]
        err_mm = np.linalg.norm(np.asarray(res["corners_bed_mm"]) - bed_image.corners_bed_mm, axis=1)
        assert err_mm.max() < 0.5, err_mm
        assert np.abs(np.asarray(res["corners_px"]) - bed_image.corners_px).max() < 0.5
        assert res["angle_deg"] == pytest.approx(bed_image.angle_deg, abs=0.05)
        origin = expected_origin(bed_image.corners_bed_mm, 10.0)
        assert [res["offset"]["x_mm"], res["offset"]["y_mm"]] == pytest.approx(origin.tolist(), abs=0.5)
        assert res["offset"]["c_deg"] == pytest.approx(bed_image.angle_deg, abs=0.05)
        pic = c.get(a["picture_url"])
        assert pic.status_code == 200 and pic.headers["content-type"] == "image/png"
        # the margin moves the origin by 10 mm along both edges and nothing else
        r0 = align(c, dry_machine["id"], camera["id"], _jpg(bed_image.image), margin_mm=0.0).json()["result"]
        d = np.subtract([res["offset"]["x_mm"], res["offset"]["y_mm"]], [r0["offset"]["x_mm"], r0["offset"]["y_mm"]])
        assert np.linalg.norm(d) == pytest.approx(10.0 * np.sqrt(2), abs=1e-3)
        r = align(c, dry_machine["id"], camera["id"], _jpg(bed_image.image), margin_mm=25.0)
        assert r.status_code == 422 and "0..20 mm" in r.json()["detail"]


def test_failed_alignment_says_why_and_bed_pose_per_camera(server, camera, dry_machine, bed_image):
    blank = np.full((600, 800, 3), 90, np.uint8)
    with server.client("admin") as c:
        r = align(c, dry_machine["id"], camera["id"], _jpg(blank))
        assert r.status_code == 200 and r.json()["status"] == "failed"
        assert "sheet" in r.json()["reason"] and r.json()["result"]["stage"]
        bad = np.eye(4)
        bad[0, 0] = 2
        r = c.put(f"/api/v1/sheet/cameras/{camera['id']}/bed-pose", json={"T_cam_bed": bad.tolist()})
        assert r.status_code == 422 and "T_cam_bed" in r.json()["detail"]
        assert c.put(f"/api/v1/sheet/cameras/{camera['id']}/bed-pose",
                     json={"T_cam_bed": CAM.T_cam_bed.tolist()}).status_code == 200
        r = align(c, dry_machine["id"], camera["id"], _jpg(bed_image.image), pose=False)
        assert r.status_code == 200 and r.json()["status"] == "located"
        assert np.allclose(r.json()["T_cam_bed"], CAM.T_cam_bed)


# ------------------------------------------------------------------------------------------------ LinuxCNC
@pytest.fixture(scope="module")
def lcnc_machine(server, lcnc):
    with server.client() as c:
        return make_machine(c, lcnc.settings, T_machine_table=T_MACHINE_BED, travel=TRAVEL)


def _g54(lcnc) -> tuple[np.ndarray, float]:
    st = lcnc.read_slot("G54")
    return np.asarray(st["g5x_offset"]), st["rotation_xy"]


@pytest.fixture(scope="module")
def exported(server, lcnc, lcnc_machine, camera, bed_image):
    """An alignment confirmed and exported to G54 of the sim (checked in the test below)."""
    lcnc.mdi("G10 L2 P1 X0 Y0 Z-12.5 R0")
    with server.client("operator") as c:
        a = align(c, lcnc_machine["id"], camera["id"], _jpg(bed_image.image), margin_mm=5.0).json()
        before = _g54(lcnc)
        r = c.post(f"/api/v1/sheet/alignments/{a['id']}/export", json={"slot": "G54"})
        assert r.status_code == 409 and "not confirmed" in r.json()["detail"]
        assert np.allclose(_g54(lcnc)[0], before[0]), "nothing written without confirmation"
    with server.client("mes") as c:
        assert c.post(f"/api/v1/sheet/alignments/{a['id']}/confirm").status_code == 403
    with server.client("operator") as c:
        r = c.post(f"/api/v1/sheet/alignments/{a['id']}/confirm")
        assert r.status_code == 200 and r.json()["confirmed_by"].startswith("test-operator")
        r = c.post(f"/api/v1/sheet/alignments/{a['id']}/export", json={"slot": "G54"})
        assert r.status_code == 200, r.text
        return a, r.json()


@pytest.mark.linuxcnc
def test_export_writes_xy_c_to_linuxcnc_and_keeps_z(server, lcnc, exported):
    a, body = exported
    assert body["status"] == "verified"
    off = a["result"]["offset"]
    g5x, rot = _g54(lcnc)  # LinuxCNC's own status
    assert g5x[:2] == pytest.approx([off["x_mm"], off["y_mm"]], abs=1e-3)
    assert g5x[2] == pytest.approx(-12.5, abs=1e-4), "Z is left as the controller had it"
    assert rot == pytest.approx(off["c_deg"], abs=1e-3)
    with server.client("admin") as c:
        actions = [e["action"] for e in c.get("/api/v1/audit").json() if e["detail"].get("alignment_id") == a["id"]]
        assert "sheet.export.write" in actions and "sheet.export.verified" in actions and "sheet.confirm" in actions


def test_export_to_a_slot_never_written_is_a_note_not_a_502(server, camera, bed_image, tmp_path):
    """A file controller that holds nothing for G54 yet: the alignment cannot keep a Z it does not
    have, so the export is refused (409, code no_offset_yet) with what to do, and nothing is written."""
    with server.client() as c:
        m = make_machine(c, {"kind": "file", "dialect": "linuxcnc", "folder": str(tmp_path)},
                         T_machine_table=T_MACHINE_BED, travel=TRAVEL)
    with server.client("operator") as c:
        a = align(c, m["id"], camera["id"], _jpg(bed_image.image)).json()
        assert c.post(f"/api/v1/sheet/alignments/{a['id']}/confirm").status_code == 200
        r = c.post(f"/api/v1/sheet/alignments/{a['id']}/export", json={"slot": "G54"})
        assert r.status_code == 409 and r.json()["code"] == "no_offset_yet", r.text
        assert "written yet for G54" in r.json()["detail"] and "write a full offset to G54 first" in r.json()["detail"]
    assert list(tmp_path.iterdir()) == []


def _read_sse(url: str, token: str, out: list, timeout_s: float = 120.0) -> None:
    with httpx.stream("GET", url, headers={"Authorization": f"Bearer {token}"}, timeout=timeout_s) as r:
        event = None
        for line in r.iter_lines():
            if line.startswith("event: "):
                event = line[7:]
            elif line.startswith("data: "):
                out.append((event, json.loads(line[6:])))
                if event == "end":
                    return


@pytest.mark.linuxcnc
def test_monitor_bands_redatum_missing_and_stop_on_linuxcnc(server, lcnc, exported):
    a, _ = exported
    # frames: still, small shift (ok), 1.8 mm (redatum), missing, unreadable, same place (ok vs the new datum),
    # 7 mm more (stop)
    shifts = [(0, 0, 0), (0.3, 0.0, 0.0), (1.5, 0.8, 0.1), (0, 0, 0), (0, 0, 0), (1.5, 0.8, 0.1), (8.0, 2.0, 0.1)]
    seq = drift_sequence(SCENE, CAM, shifts, missing=(3,), unreadable=(4,))
    with server.client("operator") as c:
        r = c.post("/api/v1/sheet/monitors", json={"alignment_id": a["id"], "l1_mm": 1.0, "l2_mm": 4.0})
        assert r.status_code == 201, r.text
        mid = r.json()["id"]
        got: list = []
        reader = threading.Thread(target=_read_sse, args=(f"{server.url}/api/v1/sheet/monitors/{mid}/events",
                                                          server.tokens["operator"], got), daemon=True)
        reader.start()
        decisions = []
        for i, frame in enumerate(seq.frames[:6]):
            files = None if frame is None else {"frame": ("f.jpg", frame if isinstance(frame, bytes) else _jpg(frame))}
            r = c.post(f"/api/v1/sheet/monitors/{mid}/frames", files=files)
            assert r.status_code == 200, r.text
            decisions.append(r.json())
        assert [d["decision"] for d in decisions] == ["ok", "ok", "redatum", "frame_missing", "frame_missing", "ok"]
        red = decisions[2]
        assert red["action"]["redatum"]["status"] == "verified" and red["picture_url"]
        g5x, rot = _g54(lcnc)
        assert g5x[:2] == pytest.approx([red["new_offset"]["x_mm"], red["new_offset"]["y_mm"]], abs=1e-3)
        assert rot == pytest.approx(red["new_offset"]["c_deg"], abs=1e-3)
        # the new origin follows the sheet: 1.5, 0.8 mm and 0.1 deg about the sheet's centre
        old = a["result"]["offset"]
        assert rot - old["c_deg"] == pytest.approx(0.1, abs=0.03)
        assert "no image" in decisions[3]["reason"] and "do not decode" in decisions[4]["reason"]
        assert decisions[3]["errors_mm"] == [None] * 4

        lcnc.mdi("G53 G0 X0 Y0 Z0")
        lcnc.run_program("G90 G21\nG53 G1 X300 F300\nG53 G1 X0\nM2\n", "sheet_long.ngc")
        assert not lcnc.status()["interp_idle"]
        r = c.post(f"/api/v1/sheet/monitors/{mid}/frames", files={"frame": ("f.jpg", _jpg(seq.frames[6]))})
        stop = r.json()
        assert stop["decision"] == "stop" and stop["action"]["stop"] == "done", stop
        deadline = time.monotonic() + 5
        while not lcnc.status()["interp_idle"] and time.monotonic() < deadline:
            time.sleep(0.05)
        st = lcnc.status()
        assert st["interp_idle"] and st["position"][0] < 290, "the program was aborted before its end"
        mon = c.get(f"/api/v1/sheet/monitors/{mid}").json()
        assert mon["state"] == "stopped" and mon["frames"] == 7 and mon["last_decision"]["decision"] == "stop"
        assert [d["decision"] for d in mon["decisions"]][-1] == "stop"
        r = c.post(f"/api/v1/sheet/monitors/{mid}/frames", files={"frame": ("f.jpg", _jpg(seq.frames[0]))})
        assert r.status_code == 409
        reader.join(timeout=30)
    assert [d["decision"] for e, d in got if e == "decision"] == [d["decision"] for d in decisions] + ["stop"]
    assert got[-1] == ("end", {"state": "stopped", "reason": stop["reason"]})
    # the MES hears every decision but ok, each with its frame (when there was one) and picture
    mine = [(k, d) for k, d in server.published if k.startswith("sheet.") and d.get("monitor_id") == mid]
    assert [k for k, _ in mine] == ["sheet.redatum", "sheet.frame_missing", "sheet.frame_missing", "sheet.stop"]
    assert mine[0][1]["frame_url"] and mine[0][1]["picture_url"] and mine[0][1]["errors_mm"][0] > 1.0
    assert mine[1][1]["frame_url"] is None and mine[2][1]["frame_url"]  # nothing came; bytes that did not decode
    assert mine[3][1]["action"] == {"stop": "done"}
    with server.client("mes") as c:
        assert c.get(mine[2][1]["frame_url"]).content == seq.frames[4], "the frame as it was received"
        assert c.get(mine[3][1]["picture_url"]).headers["content-type"] == "image/jpeg"
    assert any(k == "sheet.offset_exported" and d["alignment_id"] == a["id"] for k, d in server.published)
    assert all(len(d["errors_mm"]) == 4 for e, d in got if e == "decision")


# ------------------------------------------------------------------------------------------------ polling
def test_camera_polled_monitor_from_a_folder(server, dry_machine, bed_image, tmp_path):
    folder = tmp_path / "cam"
    folder.mkdir()
    cv2.imwrite(str(folder / "f000.jpg"), bed_image.image)
    with server.client("admin") as c:
        cam = c.post("/api/v1/cameras", json={"name": "polled bed cam", "intrinsics": CAM.intrinsics_dict(),
                                              "source": {"kind": "folder", "path": str(folder), "only_new": True}}).json()
    with server.client("operator") as c:
        r = c.post("/api/v1/sheet/alignments", data={"machine_id": dry_machine["id"], "camera_id": cam["id"],
                                                     "thickness_mm": 3.0, "grab": "true",
                                                     "T_cam_bed": json.dumps(CAM.T_cam_bed.tolist())})
        r = settled(c, r)
        assert r.status_code == 200 and r.json()["status"] == "located", r.text
        aid = r.json()["id"]
        r = c.post("/api/v1/sheet/monitors", json={"alignment_id": aid, "l1_mm": 1.0, "l2_mm": 4.0, "interval_s": 0.2})
        assert r.status_code == 409 and "not confirmed" in r.json()["detail"]
        c.post(f"/api/v1/sheet/alignments/{aid}/confirm")
        r = c.post("/api/v1/sheet/monitors", json={"alignment_id": aid, "l1_mm": 1.0, "l2_mm": 4.0, "interval_s": 0.2})
        assert r.status_code == 201, r.text
        mid = r.json()["id"]

        def wait_for(pred, what):
            deadline = time.monotonic() + 30
            while time.monotonic() < deadline:
                mon = c.get(f"/api/v1/sheet/monitors/{mid}").json()
                if pred([d["decision"] for d in mon["decisions"]]):
                    return mon
                time.sleep(0.1)
            raise AssertionError(f"no {what}: {[d['decision'] for d in mon['decisions']]}")

        # the first poll takes f000 (the sheet as aligned); then the folder has no new image: frame_missing,
        # never ok
        mon = wait_for(lambda ds: ds[:1] == ["ok"] and "frame_missing" in ds, "ok then frame_missing")
        assert "no new image" in next(d for d in mon["decisions"] if d["decision"] == "frame_missing")["reason"]
        seq = drift_sequence(SCENE, CAM, [(0.2, 0.0, 0.0), (6.0, 0.0, 0.0)])
        cv2.imwrite(str(folder / "f001.jpg"), seq.frames[0])
        wait_for(lambda ds: "ok" in ds[ds.index("frame_missing"):], "ok after the new file")
        cv2.imwrite(str(folder / "f002.jpg"), seq.frames[1])
        mon = wait_for(lambda ds: "stop" in ds, "stop")
        assert mon["state"] == "stopped" and "not sent" in mon["last_decision"]["action"]["stop"]
        n = mon["frames"]
        time.sleep(0.5)
        assert c.get(f"/api/v1/sheet/monitors/{mid}").json()["frames"] == n, "a stopped monitor polls no more"


def test_monitor_stop_ends_monitoring(server, dry_machine, camera, bed_image):
    with server.client("operator") as c:
        aid = align(c, dry_machine["id"], camera["id"], _jpg(bed_image.image)).json()["id"]
        c.post(f"/api/v1/sheet/alignments/{aid}/confirm")
        r = c.post("/api/v1/sheet/monitors", json={"alignment_id": aid, "l1_mm": 2.0, "l2_mm": 1.0})
        assert r.status_code == 422
        mid = c.post("/api/v1/sheet/monitors", json={"alignment_id": aid, "l1_mm": 1.0, "l2_mm": 4.0}).json()["id"]
        assert c.post(f"/api/v1/sheet/monitors/{mid}/frames").json()["decision"] == "frame_missing"
        r = c.post(f"/api/v1/sheet/monitors/{mid}/stop")
        assert r.status_code == 200 and r.json()["state"] == "finished"
        assert c.post(f"/api/v1/sheet/monitors/{mid}/frames").status_code == 409
        got: list = []
        _read_sse(f"{server.url}/api/v1/sheet/monitors/{mid}/events", server.tokens["operator"], got, 20)
        assert [e for e, _ in got] == ["decision", "end"] and got[-1][1]["state"] == "finished"


def test_one_running_monitor_per_camera(server, dry_machine, bed_image):
    """A second monitor on a camera that already has a running one is refused (409) with the running
    one named, also when two starts race; another camera is free; once the first ends the camera is free."""
    with server.client("admin") as c:
        cams = [c.post("/api/v1/cameras", json={"name": f"bed cam {i}", "intrinsics": CAM.intrinsics_dict()}).json()
                for i in (1, 2)]
    with server.client("operator") as c:
        aids = [align(c, dry_machine["id"], cam["id"], _jpg(bed_image.image)).json()["id"]
                for cam in (cams[0], cams[0], cams[1])]
        for aid in aids:
            assert c.post(f"/api/v1/sheet/alignments/{aid}/confirm").status_code == 200
        start = {"l1_mm": 1.0, "l2_mm": 4.0}
        first = c.post("/api/v1/sheet/monitors", json={"alignment_id": aids[0], **start})
        assert first.status_code == 201 and first.json()["camera_id"] == cams[0]["id"], first.text
        mid = first.json()["id"]
        for aid in aids[:2]:  # the same alignment again, or another alignment seen by the same camera
            r = c.post("/api/v1/sheet/monitors", json={"alignment_id": aid, **start})
            assert r.status_code == 409 and r.json()["code"] == "camera_monitored", r.text
            detail = r.json()["detail"]
            assert f"camera {cams[0]['id']} (bed cam 1) is already watched by monitor {mid}" in detail, detail
            assert f"alignment {aids[0]}, started by test-operator" in detail and f"stop monitor {mid} first" in detail
        other = c.post("/api/v1/sheet/monitors", json={"alignment_id": aids[2], **start})
        assert other.status_code == 201, "another camera has its own monitor"
        assert c.post(f"/api/v1/sheet/monitors/{mid}/stop").json()["state"] == "finished"
        # the camera is free again; two starts at the same moment: one runs, the other is told why
        with ThreadPoolExecutor(2) as pool:
            answers = list(pool.map(lambda aid: c.post("/api/v1/sheet/monitors", json={"alignment_id": aid, **start}),
                                    aids[:2]))
        assert sorted(r.status_code for r in answers) == [201, 409], [r.text for r in answers]
        won = next(r.json() for r in answers if r.status_code == 201)
        assert f"monitor {won['id']}" in next(r.json()["detail"] for r in answers if r.status_code == 409)
        running = c.get("/api/v1/sheet/monitors", params={"state": "running"}).json()
        assert sorted(m["camera_id"] for m in running if m["camera_id"] in (cams[0]["id"], cams[1]["id"])) == \
            sorted([cams[0]["id"], cams[1]["id"]])
        for m in (won, other.json()):
            c.post(f"/api/v1/sheet/monitors/{m['id']}/stop")


def _wait_idle(lcnc, timeout_s: float = 5.0) -> dict:
    deadline = time.monotonic() + timeout_s
    while not lcnc.status()["interp_idle"] and time.monotonic() < deadline:
        time.sleep(0.05)
    return lcnc.status()


@pytest.mark.linuxcnc
def test_redatum_during_a_program_holds_it_and_unseen_frames_hold_it(server, lcnc, exported):
    """LinuxCNC refuses offset changes while a program runs: the re-datum holds the program instead; frames
    without the sheet hold it after hold_after_unseen in a row; the operator's stop aborts it."""
    a, _ = exported
    seq = drift_sequence(SCENE, CAM, [(1.5, 0.8, 0.1)])
    with server.client("operator") as c:
        r = c.post("/api/v1/sheet/monitors", json={"alignment_id": a["id"], "l1_mm": 1.0, "l2_mm": 4.0,
                                                   "hold_after_unseen": 2})
        assert r.status_code == 201, r.text
        mid = r.json()["id"]
        lcnc.mdi("G53 G0 X0 Y0 Z0")
        before = _g54(lcnc)
        lcnc.run_program("G90 G21\nG53 G1 X300 F300\nG53 G1 X0\nM2\n", "sheet_hold.ngc")
        d = c.post(f"/api/v1/sheet/monitors/{mid}/frames", files={"frame": ("f.jpg", _jpg(seq.frames[0]))}).json()
        assert d["decision"] == "redatum", d
        assert d["action"]["redatum"]["status"] == "failed" and "a program is running" in d["action"]["redatum"]["reason"]
        assert d["action"]["pause"] == "done"
        st = lcnc.status()
        assert st["paused"] or st["interp_paused"]
        assert st["g5x_index"] == 1 and np.allclose(st["g5x_offset"], before[0]), "the refused write changed nothing"
        r = c.post(f"/api/v1/sheet/monitors/{mid}/stop", json={"stop_machine": True})
        assert r.status_code == 200 and r.json()["state"] == "finished" and "machine stop: done" in r.json()["reason"]
        assert _wait_idle(lcnc)["interp_idle"]

        mid = c.post("/api/v1/sheet/monitors", json={"alignment_id": a["id"], "l1_mm": 1.0, "l2_mm": 4.0,
                                                     "hold_after_unseen": 2}).json()["id"]
        lcnc.run_program("G90 G21\nG53 G1 X300 F300\nG53 G1 X0\nM2\n", "sheet_hold2.ngc")
        first = c.post(f"/api/v1/sheet/monitors/{mid}/frames").json()
        assert first["decision"] == "frame_missing" and first["action"] is None
        assert not lcnc.status()["paused"]
        second = c.post(f"/api/v1/sheet/monitors/{mid}/frames").json()
        assert second["decision"] == "frame_missing" and second["action"] == {"pause": "done"}
        st = lcnc.status()
        assert st["paused"] or st["interp_paused"]
        c.post(f"/api/v1/sheet/monitors/{mid}/stop", json={"stop_machine": True})
        assert _wait_idle(lcnc)["interp_idle"]
    with server.client("admin") as c:
        actions = {e["action"] for e in c.get("/api/v1/audit").json()}
        assert {"sheet.redatum.read_failed", "sheet.redatum_pause", "sheet.unseen_hold", "sheet.operator_stop"} <= actions


def test_a_monitor_that_cannot_resume_after_a_restart_says_why(tmp_path, bed_image):
    """Monitors resume after a restart from their stored drift state (tests/jobs/test_monitor_resume.py);
    one whose alignment picture is gone cannot, and ends 'finished' with the reason."""
    with live_server(tmp_path, "sqlite") as srv:
        with srv.client("admin") as c:
            cam = c.post("/api/v1/cameras", json={"name": "bed cam", "intrinsics": CAM.intrinsics_dict()}).json()
            machine = make_machine(c, None, T_machine_table=T_MACHINE_BED, travel=TRAVEL)
        with srv.client("operator") as c:
            aid = align(c, machine["id"], cam["id"], _jpg(bed_image.image)).json()["id"]
            c.post(f"/api/v1/sheet/alignments/{aid}/confirm")
            mid = c.post("/api/v1/sheet/monitors", json={"alignment_id": aid, "l1_mm": 1.0, "l2_mm": 4.0}).json()["id"]
            assert c.get(f"/api/v1/sheet/monitors/{mid}").json()["state"] == "running"
        srv.stop()
        shutil.rmtree(srv.settings.files_dir)  # the alignment's picture with it
        again = LiveServer(srv.settings).start()
        try:
            again.tokens = srv.tokens
            with again.client("operator") as c:
                mon = c.get(f"/api/v1/sheet/monitors/{mid}").json()
                assert mon["state"] == "finished", mon
                assert mon["reason"].startswith("could not resume after the service restarted"), mon["reason"]
                assert c.post(f"/api/v1/sheet/monitors/{mid}/frames").status_code == 409
        finally:
            again.stop()
