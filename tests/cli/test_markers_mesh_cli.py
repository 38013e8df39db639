import json
import xml.etree.ElementTree as ET

import cv2
import numpy as np
import trimesh

from app.cli import main
from app.geometry import parts


def test_markers_cli_writes_pdf_and_svg(tmp_path, capsys):
    layout = tmp_path / "layout.json"
    layout.write_text(json.dumps(parts.tslot_table_layout(parts.TSlotTableSpec())))
    assert main(["markers", str(layout), "--out", str(tmp_path / "s.pdf"), "--page-size", "A4"]) == 0
    assert (tmp_path / "s.pdf").read_bytes().startswith(b"%PDF-")
    assert "12 markers, DICT_5X5_100, 2 page(s)" in capsys.readouterr().out
    assert main(["markers", str(layout), "--out", str(tmp_path / "s.svg"), "--page-size", "A4", "--page", "1"]) == 0
    root = ET.parse(tmp_path / "s.svg").getroot()
    ids = [g.get("id") for g in root.iter("{http://www.w3.org/2000/svg}g") if g.get("id", "").startswith("marker-")]
    assert ids == ["marker-9", "marker-10", "marker-11"]  # 9 markers on page 0, the rest on page 1


def test_markers_cli_bad_input(tmp_path, capsys):
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({"dictionary": "DICT_5X5_100", "markers": []}))
    assert main(["markers", str(bad), "--out", str(tmp_path / "s.pdf")]) == 2
    assert "fiducial layout invalid" in capsys.readouterr().err
    good = tmp_path / "good.json"
    good.write_text(json.dumps(parts.tslot_table_layout(parts.TSlotTableSpec())))
    assert main(["markers", str(good), "--out", str(tmp_path / "s.png")]) == 2
    assert "use a .pdf or .svg" in capsys.readouterr().err


def test_mesh_cli_reports_size_poses_and_writes_files(tmp_path, capsys, external_data):
    step = external_data / "trimesh_models" / "featuretype.STEP"
    png, glb = tmp_path / "t.png", tmp_path / "m.glb"
    assert main(["mesh", str(step), "--json", "--thumbnail", str(png), "--glb", str(glb)]) == 0
    out = json.loads(capsys.readouterr().out)
    assert np.allclose(out["extents_mm"], [127.0, 63.5, 34.925], atol=0.01)
    assert out["units_source"] == "file" and out["watertight"]
    assert abs(sum(p["probability"] for p in out["resting_poses"]) - 1.0) < 1e-6
    assert cv2.imread(str(png)).shape == (256, 256, 3)
    assert glb.read_bytes()[:4] == b"glTF"


def test_mesh_cli_rejection_has_status_and_reason(tmp_path, capsys):
    ball = tmp_path / "ball.stl"
    ball.write_bytes(trimesh.creation.icosphere(subdivisions=3).export(file_type="stl"))
    assert main(["mesh", str(ball), "--max-faces", "100"]) == 1
    assert "rejected (413): mesh has 1280 faces; the limit is 100" in capsys.readouterr().err
    assert main(["mesh", str(tmp_path / "missing.stl")]) == 2
    assert main(["mesh", str(ball), "--units", "inch"]) == 0
    assert "faces, watertight True" in capsys.readouterr().out
