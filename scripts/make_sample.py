#!/usr/bin/env python
"""Render the sample setup photo in samples/ with the project's own scene generator (app/synth).

The picture shows the example library's T-slot table (tslot_table_800x400, with its printed markers)
and the 140 mm bracket (bracket_140) lying on it, seen by a camera at the front of the cabin. It is
what a camera would deliver for a first run without hardware (README, "First run without hardware").

    .venv/bin/python scripts/make_sample.py [--out samples]

Writes (the same bytes every run):
  bracket_on_table.jpg          the photo (grey JPEG)
  camera-intrinsics.json        the camera's intrinsics {width, height, K, dist} (pixels)
  bracket_on_table.truth.json   where the bracket really is (T_table_obj, mm) and where the camera is
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import cv2
import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))  # run from a checkout without installing

from app.geometry.library_manifest import load_library_manifest  # noqa: E402
from app.geometry.mesh import load_mesh  # noqa: E402
from app.resources import bundled_dir  # noqa: E402
from app.synth.scene import Scene, SceneObject, look_at_pose, place_on_table, render_scene  # noqa: E402

WIDTH, HEIGHT, F_PX = 1600, 1000, 1200.0           # a 1.6 MP industrial camera with a ~4 mm lens
# In the table frame: in front of the table's left end, 0.4 m above it, looking at the part. This close
# the one image fixes the bracket to about 0.1 mm (x, y), 0.2 mm (z) and 0.02 deg, within the default
# export limits (SETUPCAM_MAX_SIGMA_MM / _DEG); from farther away the height would ask for a probe.
CAMERA_AT_MM = (150.0, -50.0, 400.0)
LOOK_AT_MM = (380.0, 190.0, 0.0)
PART, X_MM, Y_MM, C_DEG = "bracket_140", 380.0, 190.0, 20.0   # bracket centre on the table, its turn
JPEG_QUALITY = 90
SEED = 7


def _mesh(library: Path, key: str):
    entry = next(e for e in load_library_manifest(library) if e.key == key)
    return entry, load_mesh((library / entry.file).read_bytes(), entry.file, entry.units)


def render(library: Path) -> tuple[bytes, dict, dict]:
    """(JPEG bytes, intrinsics, truth) of the sample scene."""
    table_entry, table = _mesh(library, "tslot_table_800x400")
    layout = json.loads((library / table_entry.fiducials).read_text())
    part_entry, part = _mesh(library, PART)
    K = np.array([[F_PX, 0.0, WIDTH / 2], [0.0, F_PX, HEIGHT / 2], [0.0, 0.0, 1.0]])
    T_cam_table = look_at_pose(np.array(CAMERA_AT_MM), np.array(LOOK_AT_MM))
    T_table_obj = place_on_table(part, X_MM, Y_MM, C_DEG)
    scene = Scene(width=WIDTH, height=HEIGHT, K=K, dist=np.zeros(5), T_cam_table=T_cam_table, table_mesh=table,
                  table_layout=layout, objects=[SceneObject(PART, part, T_table_obj)],
                  jpeg_quality=None)   # compressed once, below
    image = render_scene(scene, np.random.default_rng(SEED)).image
    ok, jpeg = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])
    assert ok
    intrinsics = {"width": WIDTH, "height": HEIGHT, "K": K.tolist(), "dist": [0.0] * 5}
    truth = {"table": table_entry.key, "part": PART, "part_name": part_entry.name,
             "T_table_obj": np.round(T_table_obj, 9).tolist(),
             "T_cam_table": np.round(T_cam_table, 9).tolist(),
             "note": "ground truth of the rendering: mm, the table frame of the library's table model"}
    return jpeg.tobytes(), intrinsics, truth


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=Path, default=REPO / "samples", help="output folder (default: samples/)")
    args = ap.parse_args(argv)
    jpeg, intrinsics, truth = render(bundled_dir("models_library"))
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "bracket_on_table.jpg").write_bytes(jpeg)
    (args.out / "camera-intrinsics.json").write_text(json.dumps(intrinsics, indent=2) + "\n")
    (args.out / "bracket_on_table.truth.json").write_text(json.dumps(truth, indent=2) + "\n")
    print(f"wrote {args.out}/bracket_on_table.jpg ({len(jpeg) / 1024:.0f} KiB), camera-intrinsics.json, "
          "bracket_on_table.truth.json")
    return 0


if __name__ == "__main__":
    sys.exit(main())
