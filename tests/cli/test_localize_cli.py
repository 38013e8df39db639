"""``setupcam localize`` on generated images with ground truth, as a batch user runs it."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from app.cli import main
from app.geometry.transforms import rotation_angle_deg
from tests.support.scenes import LIBRARY, library_entry, library_scene

pytestmark = pytest.mark.slow


def write_inputs(tmp_path, sc):
    cv2.imwrite(str(tmp_path / "img.png"), sc.image)
    (tmp_path / "cam.json").write_text(json.dumps(sc.intrinsics()))
    (tmp_path / "layout.json").write_text(json.dumps(sc.layout))
    part = tmp_path / f"{sc.workpiece_key}.stl"
    sc.workpiece_mesh.export(part)
    return part


def test_localize_cli_finds_the_part(tmp_path, capsys):
    sc = library_scene()
    part = write_inputs(tmp_path, sc)
    table = LIBRARY / library_entry("tslot_table_800x400").file
    rc = main(["localize", "--image", str(tmp_path / "img.png"), "--intrinsics", str(tmp_path / "cam.json"),
               "--table", str(table), "--layout", str(tmp_path / "layout.json"), "--model", str(part), "--json",
               "--overlay", str(tmp_path / "overlay.png")])
    out = json.loads(capsys.readouterr().out)
    assert rc == 0 and out["ok"], out["reason"]
    (obj,) = out["objects"]
    assert obj["name"] == part.name and obj["chain"] == ["table"]          # the support chain ran
    T = np.array(obj["T_table_obj"])
    assert np.linalg.norm(T[:2, 3] - sc.T_table_obj[:2, 3]) < 0.3, (T[:3, 3], sc.T_table_obj[:3, 3])
    assert rotation_angle_deg(T, sc.T_table_obj) < 0.1
    T_cam_table = np.array(out["table"]["T_cam_table"])
    assert np.allclose(np.linalg.inv(T_cam_table) @ np.array(obj["T_cam_obj"]), T, atol=1e-6)
    assert cv2.imread(str(tmp_path / "overlay.png")) is not None


def test_localize_cli_reads_a_camera_without_gamma(tmp_path, capsys):
    """A machine-vision camera's default: linear light, no gamma. The table's markers say so (the
    edges of their black and white cells), and the part is decoded with the gamma read."""
    sc = library_scene(camera=(("gamma", 1.0), ("blur_sigma_px", 1.0)))
    part = write_inputs(tmp_path, sc)
    table = LIBRARY / library_entry("tslot_table_800x400").file
    rc = main(["localize", "--image", str(tmp_path / "img.png"), "--intrinsics", str(tmp_path / "cam.json"),
               "--table", str(table), "--layout", str(tmp_path / "layout.json"), "--model", str(part), "--json"])
    out = json.loads(capsys.readouterr().out)
    assert rc == 0 and out["ok"], out["reason"]
    assert out["table"]["gamma"] == pytest.approx(1.0, abs=0.15), out["table"]["gamma_reading"]
    (obj,) = out["objects"]
    T = np.array(obj["T_table_obj"])
    assert np.linalg.norm(T[:2, 3] - sc.T_table_obj[:2, 3]) < 0.3, (T[:3, 3], sc.T_table_obj[:3, 3])
    assert rotation_angle_deg(T, sc.T_table_obj) < 0.1


def test_localize_cli_says_why_without_markers(tmp_path, capsys):
    sc = library_scene(hide_markers=True)
    part = write_inputs(tmp_path, sc)
    rc = main(["localize", "--image", str(tmp_path / "img.png"), "--intrinsics", str(tmp_path / "cam.json"),
               "--layout", str(tmp_path / "layout.json"), "--model", str(part), "--json"])
    out = json.loads(capsys.readouterr().out)
    assert rc == 1 and not out["ok"]
    assert out["reason"].startswith("table markers not found"), out["reason"]


def test_localize_cli_bad_input(tmp_path, capsys):
    (tmp_path / "cam.json").write_text('{"width": 10}')
    rc = main(["localize", "--image", str(tmp_path / "missing.png"), "--intrinsics", str(tmp_path / "cam.json"),
               "--layout", str(tmp_path / "cam.json")])
    assert rc == 2 and "not a readable image" in capsys.readouterr().err


@pytest.mark.parametrize("value, why", [("-5", "a riser is a positive height in mm"), ("twenty", "not a number")])
def test_localize_cli_refuses_a_riser_that_is_not_a_height(tmp_path, capsys, value, why):
    with pytest.raises(SystemExit) as stop:
        main(["localize", "--image", str(tmp_path / "img.png"), "--intrinsics", str(tmp_path / "cam.json"),
              "--layout", str(tmp_path / "layout.json"), "--riser", value])
    assert stop.value.code == 2 and why in capsys.readouterr().err
