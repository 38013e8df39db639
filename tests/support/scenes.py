"""Generated setup images of the example library (table + parts) with exact ground truth, cached per run."""

from __future__ import annotations

import json
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np
import trimesh

from app.geometry.library_manifest import load_library_manifest
from app.geometry.mesh import load_mesh
from app.synth.scene import SceneObject, place_on_table, random_scene, render_scene

LIBRARY = Path(__file__).resolve().parents[2] / "models_library"


@dataclass(frozen=True)
class LibraryScene:
    image: np.ndarray            # uint8 grey, as the camera delivers it
    K: np.ndarray
    dist: np.ndarray
    layout: dict
    T_table_obj: np.ndarray      # ground truth of the workpiece
    T_cam_table: np.ndarray
    workpiece_key: str
    workpiece_mesh: trimesh.Trimesh

    def intrinsics(self) -> dict:
        h, w = self.image.shape[:2]
        return {"width": w, "height": h, "K": self.K.tolist(), "dist": self.dist.tolist()}


@lru_cache(maxsize=None)
def library_entry(key: str):
    return next(e for e in load_library_manifest(LIBRARY) if e.key == key)


@lru_cache(maxsize=None)
def library_mesh(key: str) -> trimesh.Trimesh:
    e = library_entry(key)
    return load_mesh((LIBRARY / e.file).read_bytes(), e.file, e.units)


@lru_cache(maxsize=None)
def library_scene(workpiece_key: str = "bracket_140", x_mm: float = 420.0, y_mm: float = 210.0,
                  c_deg: float = 17.0, seed: int = 3, width: int = 1280, height: int = 800,
                  hide_markers: bool = False) -> LibraryScene:
    table = library_entry("tslot_table_800x400")
    layout = json.loads((LIBRARY / table.fiducials).read_text())
    mesh = library_mesh(workpiece_key)
    T = place_on_table(mesh, x_mm, y_mm, c_deg)
    rng = np.random.default_rng(seed)
    scene_layout = {"dictionary": layout["dictionary"], "markers": []} if hide_markers else layout
    scene = random_scene(rng, width=width, height=height, objects=[SceneObject(workpiece_key, mesh, T)],
                         table_mesh=library_mesh("tslot_table_800x400"), table_layout=scene_layout,
                         min_visible_markers=0 if hide_markers else 4, distance_mm=(600.0, 1000.0))
    r = render_scene(scene, rng)
    return LibraryScene(r.image, scene.K, scene.dist, layout, T, scene.T_cam_table, workpiece_key, mesh)
