"""Generated setup images of the example library (table + parts) with exact ground truth, cached per run."""

from __future__ import annotations

import json
from dataclasses import dataclass, replace
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
                  hide_markers: bool = False, camera: tuple[tuple[str, float], ...] = ()) -> LibraryScene:
    """A part of the example library on the example table in a random view; ``camera`` overrides the
    render's camera settings as (name, value) pairs (``gamma``, ``blur_sigma_px``, ...; hashable, as
    the calls are cached)."""
    table = library_entry("tslot_table_800x400")
    layout = json.loads((LIBRARY / table.fiducials).read_text())
    mesh = library_mesh(workpiece_key)
    T = place_on_table(mesh, x_mm, y_mm, c_deg)
    rng = np.random.default_rng(seed)
    scene_layout = {"dictionary": layout["dictionary"], "markers": []} if hide_markers else layout
    scene = random_scene(rng, width=width, height=height, objects=[SceneObject(workpiece_key, mesh, T)],
                         table_mesh=library_mesh("tslot_table_800x400"), table_layout=scene_layout,
                         min_visible_markers=0 if hide_markers else 4, distance_mm=(600.0, 1000.0))
    r = render_scene(replace(scene, **dict(camera)), rng)
    return LibraryScene(r.image, scene.K, scene.dist, layout, T, scene.T_cam_table, workpiece_key, mesh)


@dataclass(frozen=True)
class RotaryScene:
    """A picture of the example table on a rotary axis, taken by a camera fixed in the machine."""

    image: np.ndarray
    K: np.ndarray
    dist: np.ndarray
    T_cam_machine: np.ndarray    # the camera, fixed in the machine (mm)
    T_cam_table: np.ndarray      # = T_cam_machine @ T_machine_table(angle)
    T_table_obj: np.ndarray      # ground truth of the workpiece on the turning table
    angle_deg: float
    visible_markers: int

    def intrinsics(self) -> dict:
        h, w = self.image.shape[:2]
        return {"width": w, "height": h, "K": self.K.tolist(), "dist": self.dist.tolist()}


def rotary_scene(T_machine_table_at, angle_deg: float, cam_pos_machine, target_machine,
                 workpiece_key: str = "bracket_140", x_mm: float = 420.0, y_mm: float = 210.0,
                 c_deg: float = 17.0, seed: int = 3, width: int = 1280, height: int = 800,
                 focal_px: float = 1500.0) -> RotaryScene:
    """Render the example T-slot table turned to ``angle_deg`` on its axis (``T_machine_table_at(angle)``,
    the chain), with ``workpiece_key`` on it at table (x, y) turned ``c_deg``, seen by a camera at
    ``cam_pos_machine`` looking at ``target_machine`` (machine coordinates, mm; no distortion)."""
    from app.geometry.transforms import inv
    from app.synth.scene import Scene, look_at_pose, render_scene

    table = library_entry("tslot_table_800x400")
    layout = json.loads((LIBRARY / table.fiducials).read_text())
    mesh = library_mesh(workpiece_key)
    T = place_on_table(mesh, x_mm, y_mm, c_deg)
    T_cam_machine = look_at_pose(np.asarray(cam_pos_machine, float), np.asarray(target_machine, float))
    T_cam_table = T_cam_machine @ np.asarray(T_machine_table_at(angle_deg), float)
    K = np.array([[focal_px, 0, width / 2], [0, focal_px, height / 2], [0, 0, 1.0]])
    scene = Scene(width=width, height=height, K=K, dist=np.zeros(5), T_cam_table=T_cam_table,
                  table_mesh=library_mesh("tslot_table_800x400"), table_layout=layout,
                  objects=[SceneObject(workpiece_key, mesh, T)])
    r = render_scene(scene, np.random.default_rng(seed))
    assert np.allclose(inv(T_cam_machine) @ T_cam_table, T_machine_table_at(angle_deg))
    return RotaryScene(r.image, K, np.zeros(5), T_cam_machine, T_cam_table, T, float(angle_deg),
                       int(sum(r.truth["marker_visible"].values())))
