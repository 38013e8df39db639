"""The 3D scene of one setup, built into a viser scene (pure: plain data in, viser calls out).

Frames: the viser world is the ``table`` frame (z up). Library meshes are in mm in their own
``obj`` frame; viser works in metres, so every pose and vertex goes through :func:`pose_to_viser`
/ :func:`viser_to_pose` and :data:`M_PER_MM` here and nowhere else.

Scene tree (names are stable, tests look them up in the browser):

* ``/table``                       the table mesh at the origin
* ``/objects/o{i}``                object ``i`` at ``T_table_obj`` (a transform gizmo when editable,
                                   else a plain frame); its mesh is the child ``/objects/o{i}/mesh``
* ``/camera``                      the camera frustum at ``inv(T_cam_table)`` showing the image
* ``/paths/{name}``                planned paths (e.g. the probing program's safe travel and its touch
                                   moves) as line segments, table frame
* ``/rotary_axis``                 a machine with a rotary table: its axis of rotation, as a line

A table on a rotary axis is shown turned as it was at the picture: the world is then the table frame at
the machine's export angle, and everything on the table (the table, its objects, the camera that saw it,
the paths) is placed through ``SetupView.T_world_table`` (docs/rotary-tables.md); a gizmo move is
handed back in the table frame. Identity otherwise, so the world is the table frame as before.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable

import cv2
import numpy as np
import trimesh
import viser.transforms as vtf

from app.geometry.transforms import check_pose, inv, make_pose

M_PER_MM = 1e-3
TABLE_RGB = (150, 154, 162)
FRUSTUM_RGB = (220, 60, 60)
DEFAULT_OBJECT_RGB = (40, 200, 60)
FRUSTUM_IMAGE_WIDTH_PX = 480     # the camera image shown on the frustum is downscaled to this width
TRAVEL_RGB = (30, 110, 240)
TOUCH_RGB = (240, 140, 0)
AXIS_RGB = (150, 60, 200)


def pose_to_viser(T_a_b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """4x4 pose in mm -> (wxyz quaternion, position in m) as viser wants them."""
    T = check_pose(np.asarray(T_a_b, float))
    wxyz = vtf.SO3.from_matrix(T[:3, :3]).wxyz
    return np.asarray(wxyz, float), T[:3, 3] * M_PER_MM


def viser_to_pose(wxyz, position_m) -> np.ndarray:
    """(wxyz quaternion, position in m) from viser -> 4x4 pose in mm (rotation re-orthonormalised)."""
    R = vtf.SO3(np.asarray(wxyz, float)).as_matrix()
    u, _s, vt = np.linalg.svd(R)
    R = u @ vt
    return make_pose(R, np.asarray(position_m, float) / M_PER_MM)


@dataclass(frozen=True, eq=False)
class ViewObject:
    """One located object: mesh in its own frame (mm), pose on the table (4x4, mm), colour (RGB 0..255)."""

    name: str
    kind: str
    mesh: trimesh.Trimesh
    T_table_obj: np.ndarray
    rgb: tuple[int, int, int] = DEFAULT_OBJECT_RGB
    result_index: int | None = None    # index in the setup's result.objects (what the adjust service takes)


@dataclass(frozen=True, eq=False)
class ViewCamera:
    """The camera that took the image: pose of the table in the camera (4x4, mm), OpenCV intrinsics,
    and the picture to show on the frustum (H, W, 3) RGB uint8 (any size; it is downscaled)."""

    T_cam_table: np.ndarray
    K: np.ndarray
    width: int
    height: int
    image_rgb: np.ndarray | None = None


@dataclass(frozen=True, eq=False)
class ViewPath:
    """A planned path: polyline of tool-tip positions in the table frame (N, 3), mm."""

    name: str
    points_mm: np.ndarray
    rgb: tuple[int, int, int] = TRAVEL_RGB


@dataclass(frozen=True, eq=False)
class SetupView:
    """Everything the 3D view of one setup shows. ``editable``: index into ``objects`` of the one that
    carries the adjust gizmo (the workpiece), or None."""

    title: str
    revision: int
    table_mesh: trimesh.Trimesh | None
    objects: tuple[ViewObject, ...] = ()
    camera: ViewCamera | None = None
    editable: int | None = None
    notes: tuple[str, ...] = field(default_factory=tuple)
    paths: tuple[ViewPath, ...] = ()
    version: tuple = ()       # changes whenever what is shown changes (the viewer polls it)
    # a rotary table: the table at the picture's angle seen from the world (the table at the export angle),
    # and the axis of rotation as two points in the world (mm); identity and None otherwise
    T_world_table: np.ndarray = field(default_factory=lambda: np.eye(4))
    axis_mm: np.ndarray | None = None

    def world(self, T_table_x: np.ndarray) -> np.ndarray:
        """A pose in the table frame -> the same in the world the viewer shows (4x4, mm)."""
        return np.asarray(self.T_world_table, float) @ np.asarray(T_table_x, float)


@dataclass(eq=False)
class SceneHandles:
    """viser handles of a built scene (to move objects later)."""

    frames: list[Any]
    gizmo_index: int | None
    frustum: Any | None
    scene: Any = None
    paths: list[Any] = field(default_factory=list)


def frustum_geometry(cam: ViewCamera) -> dict:
    """Frustum parameters: pose of the camera in the table frame, vertical fov (rad), aspect."""
    T_table_cam = inv(np.asarray(cam.T_cam_table, float))
    fy = float(np.asarray(cam.K, float)[1, 1])
    fov_rad = 2.0 * np.arctan(cam.height / 2.0 / fy)
    return {"T_table_cam": T_table_cam, "fov_rad": fov_rad, "aspect": cam.width / cam.height}


def _downscale(image_rgb: np.ndarray, width_px: int) -> np.ndarray:
    h, w = image_rgb.shape[:2]
    if w <= width_px:
        return np.ascontiguousarray(image_rgb)
    return cv2.resize(image_rgb, (width_px, round(h * width_px / w)), interpolation=cv2.INTER_AREA)


def _add_mesh(scene, name: str, mesh: trimesh.Trimesh, rgb, T_parent_mesh: np.ndarray | None = None) -> Any:
    """A mesh (vertices in mm, its own frame) under ``name``, placed at ``T_parent_mesh`` (default: as is)."""
    verts = np.asarray(mesh.vertices, np.float32) * M_PER_MM
    place = {}
    if T_parent_mesh is not None and not np.allclose(T_parent_mesh, np.eye(4)):
        wxyz, pos = pose_to_viser(T_parent_mesh)
        place = {"wxyz": wxyz, "position": pos}
    return scene.add_mesh_simple(name, verts, np.asarray(mesh.faces, np.uint32), color=tuple(int(c) for c in rgb),
                                 flat_shading=True, **place)


def scene_extent_m(view: SetupView) -> tuple[np.ndarray, float]:
    """Centre (m, table frame) and radius (m) of what is shown, for the initial view."""
    pts = []
    if view.table_mesh is not None:
        pts.append(np.asarray(view.table_mesh.bounds, float))
    for o in view.objects:
        b = np.asarray(o.mesh.bounds, float)
        corners = np.array([[x, y, z] for x in b[:, 0] for y in b[:, 1] for z in b[:, 2]])
        pts.append(corners @ np.asarray(o.T_table_obj)[:3, :3].T + np.asarray(o.T_table_obj)[:3, 3])
    if not pts:
        return np.zeros(3), 0.5
    if view.table_mesh is not None:  # the table's bounding box by its corners too, so that it turns with it
        b = pts[0]
        pts[0] = np.array([[x, y, z] for x in b[:, 0] for y in b[:, 1] for z in b[:, 2]])
    W = np.asarray(view.T_world_table, float)
    p = (np.vstack(pts) @ W[:3, :3].T + W[:3, 3]) * M_PER_MM
    lo, hi = p.min(axis=0), p.max(axis=0)
    return (lo + hi) / 2, float(np.linalg.norm(hi - lo) / 2) or 0.5


def build_setup_scene(scene, view: SetupView,
                      on_move: Callable[[int, np.ndarray], None] | None = None) -> SceneHandles:
    """Add the setup to ``scene`` (``server.scene`` or a per-client ``client.scene``).

    on_move : called as ``on_move(result_index, T_table_obj_mm)`` when the operator releases the
        gizmo (drag end). It runs in viser's callback thread; keep it short or hand work off.
    """
    scene.set_up_direction("+z")
    if view.table_mesh is not None:
        _add_mesh(scene, "/table", view.table_mesh, TABLE_RGB, view.T_world_table)
    frames = []
    gizmo_index = None
    W_inv = inv(check_pose(np.asarray(view.T_world_table, float), "T_world_table"))
    for i, obj in enumerate(view.objects):
        wxyz, pos = pose_to_viser(view.world(obj.T_table_obj))
        name = f"/objects/o{i}"
        if view.editable == i:
            radius = float(np.linalg.norm(obj.mesh.extents)) * M_PER_MM
            handle = scene.add_transform_controls(name, scale=max(0.08, 0.9 * radius), wxyz=wxyz, position=pos,
                                                  disable_sliders=True, depth_test=False)
            gizmo_index = i
            if on_move is not None:
                index = i if obj.result_index is None else obj.result_index

                def _moved(event, index=index) -> None:
                    if getattr(event, "phase", "end") == "end":
                        on_move(index, W_inv @ viser_to_pose(event.target.wxyz, event.target.position))

                handle.on_update(_moved)
        else:
            handle = scene.add_frame(name, show_axes=False, wxyz=wxyz, position=pos)
        _add_mesh(scene, f"{name}/mesh", obj.mesh, obj.rgb)
        frames.append(handle)
    frustum = None
    if view.camera is not None:
        g = frustum_geometry(view.camera)
        wxyz, pos = pose_to_viser(view.world(g["T_table_cam"]))
        image = None if view.camera.image_rgb is None else _downscale(view.camera.image_rgb, FRUSTUM_IMAGE_WIDTH_PX)
        frustum = scene.add_camera_frustum("/camera", fov=g["fov_rad"], aspect=g["aspect"], scale=0.1,
                                           thickness=2.0, thickness_units="screen", image=image, wxyz=wxyz,
                                           position=pos, color=FRUSTUM_RGB)
    handles = SceneHandles(frames=frames, gizmo_index=gizmo_index, frustum=frustum, scene=scene)
    _add_paths(handles, view)
    if view.axis_mm is not None:
        seg = (np.asarray(view.axis_mm, float).reshape(1, 2, 3) * M_PER_MM).astype(np.float32)
        scene.add_line_segments("/rotary_axis", seg, colors=AXIS_RGB, thickness=2.0, thickness_units="screen")
    return handles


def _add_paths(handles: SceneHandles, view: SetupView) -> None:
    W = np.asarray(view.T_world_table, float)
    for p in view.paths:
        pts = (np.asarray(p.points_mm, float).reshape(-1, 3) @ W[:3, :3].T + W[:3, 3]) * M_PER_MM
        if len(pts) < 2:
            continue
        segs = np.stack([pts[:-1], pts[1:]], axis=1).astype(np.float32)     # (N-1, 2, 3)
        handles.paths.append(handles.scene.add_line_segments(
            f"/paths/{p.name}", segs, colors=tuple(int(c) for c in p.rgb), thickness=3.0,
            thickness_units="screen"))


def update_paths(handles: SceneHandles, view: SetupView) -> None:
    """Replace the drawn paths by those of ``view`` (e.g. the probing plan once the setup is confirmed)."""
    for h in handles.paths:
        h.remove()
    handles.paths.clear()
    if handles.scene is not None:
        _add_paths(handles, view)


def move_objects(handles: SceneHandles, view: SetupView) -> None:
    """Put the objects of an already built scene at the poses of ``view`` (a newer revision)."""
    for handle, obj in zip(handles.frames, view.objects):
        wxyz, pos = pose_to_viser(view.world(obj.T_table_obj))
        handle.wxyz = wxyz
        handle.position = pos
    if handles.frustum is not None and view.camera is not None and view.camera.image_rgb is not None:
        handles.frustum.image = _downscale(view.camera.image_rgb, FRUSTUM_IMAGE_WIDTH_PX)


#: viser's default vertical field of view (its client camera starts with 75 degrees)
VIEWER_FOV_RAD = np.radians(75.0)


def initial_camera(view: SetupView, fov_rad: float | None = None, aspect: float = 16 / 9) -> tuple[np.ndarray, np.ndarray]:
    """(position, look_at) in m for the browser's first view: the table and the parts from 40 deg above
    the table, turned 70 deg about z from the real camera's line of sight (so its frustum is seen from
    the side, not looked through), just far enough that the sphere around the table and the parts fits
    the narrower of the vertical field of view ``fov_rad`` and the horizontal one (``aspect`` = w / h)."""
    centre, radius = scene_extent_m(view)
    az = np.radians(-60.0)
    if view.camera is not None:
        cam = view.world(frustum_geometry(view.camera)["T_table_cam"])[:3, 3] * M_PER_MM
        az = np.arctan2(cam[1] - centre[1], cam[0] - centre[0]) + np.radians(70.0)
    el = np.radians(40.0)
    d = np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
    vfov = float(fov_rad) if fov_rad and 0 < fov_rad < np.pi else VIEWER_FOV_RAD
    half = min(vfov / 2, np.arctan(np.tan(vfov / 2) * max(aspect, 1e-3)))
    return centre + d * radius * 1.05 / np.sin(half), centre
