"""Generated pictures for photo models (app/vision/photo_model/): plates with holes on the T-slot
table, a teach picture and repeat placements at other x, y, turns and camera poses, with the truth."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import trimesh
from shapely.geometry import Point, Polygon

from app.synth.scene import (
    Scene,
    SceneObject,
    default_table,
    look_at_pose,
    place_on_table,
    random_intrinsics,
    render_scene,
)


def plate(length_mm: float = 140.0, width_mm: float = 90.0, height_mm: float = 12.0,
          holes: tuple[tuple[float, float, float], ...] = ((30.0, 25.0, 8.0), (110.0, 25.0, 8.0)),
          notch_mm: float = 25.0) -> trimesh.Trimesh:
    """A plate (CAD frame: front-left bottom corner at the origin, z up) with a corner notch (so it has
    no symmetry) and through holes (x, y, radius mm)."""
    outline = Polygon([(0, 0), (length_mm, 0), (length_mm, width_mm - notch_mm),
                       (length_mm - notch_mm, width_mm), (0, width_mm)])
    for x, y, r in holes:
        outline = outline.difference(Point(x, y).buffer(r, 48))
    return trimesh.creation.extrude_polygon(outline, height_mm)


def plate_a() -> trimesh.Trimesh:
    """The look-alike pair: A has two holes ..."""
    return plate()


def plate_b() -> trimesh.Trimesh:
    """... B the same plate with a third hole."""
    return plate(holes=((30.0, 25.0, 8.0), (110.0, 25.0, 8.0), (50.0, 62.0, 8.0)))


@dataclass(frozen=True)
class PhotoShot:
    image: np.ndarray          # uint8 grey as the camera delivers it
    K: np.ndarray
    dist: np.ndarray
    T_cam_table: np.ndarray    # truth (the service finds its own from the markers)
    T_table_obj: np.ndarray    # truth of the plate's CAD frame
    layout: dict
    table_mesh: trimesh.Trimesh

    def intrinsics(self) -> dict:
        h, w = self.image.shape[:2]
        return {"width": w, "height": h, "K": self.K.tolist(), "dist": self.dist.tolist()}


def shot(mesh: trimesh.Trimesh, x_mm: float, y_mm: float, c_deg: float, *, seed: int, width: int = 1280,
         height: int = 800, cam_target: tuple[float, float] | None = None, distance_mm: float = 700.0,
         elevation_deg: float = 60.0, azimuth_deg: float = -90.0, focal_px: float = 1500.0,
         intrinsics: tuple[np.ndarray, np.ndarray] | None = None) -> PhotoShot:
    """One picture of ``mesh`` at (x, y, turn c) on the T-slot table, the camera ``distance_mm`` from
    ``cam_target`` (default: the table's centre) at ``elevation_deg`` and ``azimuth_deg`` (-90: from the
    front), with the seed's noise, lens distortion and texture."""
    table_mesh, layout = default_table()
    rng = np.random.default_rng(seed)
    T = place_on_table(mesh, x_mm, y_mm, c_deg)
    b = table_mesh.bounds
    tgt = np.array([*(cam_target if cam_target is not None else ((b[0, 0] + b[1, 0]) / 2, (b[0, 1] + b[1, 1]) / 2)), 0.0])
    el, az = np.radians(elevation_deg), np.radians(azimuth_deg)
    pos = tgt + distance_mm * np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
    K, dist = random_intrinsics(rng, width, height, (focal_px, focal_px + 1e-6))
    if intrinsics is not None:
        K, dist = (np.asarray(a, float) for a in intrinsics)
    scene = Scene(width=width, height=height, K=K, dist=dist, T_cam_table=look_at_pose(pos, tgt, rng.uniform(-5, 5)),
                  table_mesh=table_mesh, table_layout=layout, objects=[SceneObject("plate", mesh, T)],
                  texture_seed=int(seed))
    r = render_scene(scene, rng)
    return PhotoShot(r.image, K, dist, scene.T_cam_table, T, layout, table_mesh)
