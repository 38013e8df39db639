"""``setupcam sheet`` on a generated bed image: the JSON answer against the ground truth."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from app.cli import main
from app.synth.bed_images import bed_camera, render_bed_image, scene_variant

CAM = bed_camera(640, 480, 1.0, target_bed_mm=(560, 400))


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    d = tmp_path_factory.mktemp("sheet")
    scene = scene_variant("scrap", sheet_size_mm=(300.0, 200.0), sheet_xy_mm=(410.0, 310.0), sheet_angle_deg=-4.0,
                          thickness_mm=4.0, seed=5)
    b = render_bed_image(scene, CAM)
    cv2.imwrite(str(d / "bed.png"), b.image)
    (d / "cam.json").write_text(json.dumps(CAM.intrinsics_dict()))
    (d / "bed_pose.json").write_text(json.dumps({"T_cam_bed": CAM.T_cam_bed.tolist()}))
    return d, b


def _args(d, *extra):
    return ["sheet", "--image", str(d / "bed.png"), "--intrinsics", str(d / "cam.json"),
            "--bed-pose", str(d / "bed_pose.json"), "--thickness", "4", *extra]


def test_json_answer(files, capsys):
    d, b = files
    code = main(_args(d, "--margin-mm", "10", "--json", "--baseline", "--draw", str(d / "out.png")))
    out = json.loads(capsys.readouterr().out)
    assert code == 0
    assert np.linalg.norm(np.array(out["corners_px"]) - b.corners_px, axis=1).max() < 0.6
    assert np.linalg.norm(np.array(out["corners_bed_mm"]) - b.corners_bed_mm, axis=1).max() < 0.6
    assert out["angle_deg"] == pytest.approx(b.angle_deg, abs=0.08)
    a = np.radians(out["angle_deg"])
    c0 = np.array(out["corners_bed_mm"][0])
    expected = c0 + 10 * np.array([np.cos(a) - np.sin(a), np.sin(a) + np.cos(a)])
    assert out["offset"]["x_mm"] == pytest.approx(expected[0], abs=1e-3)
    assert out["offset"]["y_mm"] == pytest.approx(expected[1], abs=1e-3)
    assert out["offset"]["c_deg"] == pytest.approx(out["angle_deg"], abs=1e-4)
    assert "baseline" in out and cv2.imread(str(d / "out.png")).shape == b.image.shape


def test_text_answer_and_no_sheet(files, capsys):
    d, _ = files
    assert main(_args(d)) == 0
    assert capsys.readouterr().out.startswith("sheet found: angle")
    cv2.imwrite(str(d / "bed.png"), np.full((480, 640, 3), 90, np.uint8))
    try:
        assert main(_args(d, "--json")) == 1
        assert json.loads(capsys.readouterr().out)["error"].startswith("sheet not found")
    finally:
        cv2.imwrite(str(d / "bed.png"), files[1].image)


def test_bad_input_exits_2(files, capsys, tmp_path):
    d, _ = files
    assert main(_args(d, "--margin-mm", "25")) == 2
    assert "outside 0..20 mm" in capsys.readouterr().err
    bad = tmp_path / "pose.json"
    bad.write_text(json.dumps({"T_cam_bed": np.eye(3).tolist()}))
    args = _args(d)
    args[args.index("--bed-pose") + 1] = str(bad)
    assert main(args) == 2
    assert "T_cam_bed: expected shape (4, 4)" in capsys.readouterr().err
    small = tmp_path / "small.png"
    cv2.imwrite(str(small), np.zeros((100, 100, 3), np.uint8))
    args = _args(d)
    args[args.index("--image") + 1] = str(small)
    assert main(args) == 2
    assert "intrinsics are for 640 x 480 px" in capsys.readouterr().err
