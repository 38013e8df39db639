"""The pure 3D scene builder: poses and units into viser, gizmo moves back to mm poses."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from app.geometry.transforms import inv, pose_from_xyz_euler, rotation_angle_deg
from app.viewer.scene import (M_PER_MM, SetupView, ViewCamera, ViewObject, ViewPath, build_setup_scene,
                              frustum_geometry, initial_camera, move_objects, pose_to_viser, update_paths,
                              viser_to_pose)
from app.viewer.server import Tickets, parse_view_path, ticket_of


class Handle:
    def __init__(self, kind, name, kw):
        self.kind, self.name, self.kw = kind, name, kw
        self.wxyz, self.position = kw.get("wxyz"), kw.get("position")
        self.callbacks = []
        self.removed = False

    def remove(self):
        self.removed = True

    def on_update(self, cb):
        self.callbacks.append(cb)
        return cb


class FakeScene:
    """Records what the builder asks of viser's scene API."""

    def __init__(self):
        self.nodes: dict[str, Handle] = {}

    def set_up_direction(self, d):
        self.up = d

    def _add(self, kind, name, **kw):
        h = Handle(kind, name, kw)
        self.nodes[name] = h
        return h

    def add_mesh_simple(self, name, vertices, faces, **kw):
        return self._add("mesh", name, vertices=vertices, faces=faces, **kw)

    def add_transform_controls(self, name, **kw):
        return self._add("gizmo", name, **kw)

    def add_frame(self, name, **kw):
        return self._add("frame", name, **kw)

    def add_camera_frustum(self, name, **kw):
        return self._add("frustum", name, **kw)

    def add_line_segments(self, name, points, **kw):
        return self._add("lines", name, points=points, **kw)


def view(rng) -> SetupView:
    box = trimesh.creation.box(extents=(100.0, 60.0, 30.0))
    table = trimesh.creation.box(extents=(800.0, 400.0, 70.0))
    table.apply_translation((400.0, 200.0, -35.0))
    wp = ViewObject("block", "workpiece", box, pose_from_xyz_euler(300.0, 150.0, 15.0, c_deg=25.0), result_index=1)
    clamp = ViewObject("clamp", "clamp", box, pose_from_xyz_euler(500.0, 120.0, 15.0), result_index=0)
    T_cam_table = inv(pose_from_xyz_euler(400.0, -500.0, 600.0, a_deg=-135.0))
    K = np.array([[1000.0, 0, 640], [0, 1000.0, 400], [0, 0, 1]])
    img = rng.integers(0, 255, (800, 1280, 3), dtype=np.uint8)
    return SetupView("Setup 1", 1, table, (clamp, wp), ViewCamera(T_cam_table, K, 1280, 800, img), editable=1)


def test_pose_round_trip_and_units():
    T = pose_from_xyz_euler(123.4, -56.7, 89.0, a_deg=3.0, b_deg=-4.0, c_deg=170.0)
    wxyz, pos_m = pose_to_viser(T)
    assert pos_m == pytest.approx([0.1234, -0.0567, 0.089])
    assert np.linalg.norm(wxyz) == pytest.approx(1.0)
    back = viser_to_pose(wxyz, pos_m)
    assert back[:3, 3] == pytest.approx(T[:3, 3], abs=1e-9)
    assert rotation_angle_deg(back, T) < 1e-6


def test_scene_has_table_objects_gizmo_and_frustum():
    rng = np.random.default_rng(0)
    v = view(rng)
    scene = FakeScene()
    moves = []
    handles = build_setup_scene(scene, v, on_move=lambda i, T: moves.append((i, T)))
    assert scene.up == "+z"
    assert set(scene.nodes) == {"/table", "/objects/o0", "/objects/o0/mesh", "/objects/o1", "/objects/o1/mesh",
                                "/camera"}
    assert scene.nodes["/objects/o1"].kind == "gizmo" and scene.nodes["/objects/o0"].kind == "frame"
    # meshes are in metres, children of their pose frame
    verts = scene.nodes["/objects/o1/mesh"].kw["vertices"]
    assert np.ptp(verts, axis=0) == pytest.approx(np.array([100.0, 60.0, 30.0]) * M_PER_MM, rel=1e-6)
    assert scene.nodes["/objects/o1"].position == pytest.approx([0.3, 0.15, 0.015])
    # frustum at inv(T_cam_table), image downscaled, fov from fy
    fr = scene.nodes["/camera"].kw
    assert fr["position"] == pytest.approx(inv(v.camera.T_cam_table)[:3, 3] * M_PER_MM)
    assert fr["fov"] == pytest.approx(2 * np.arctan(400.0 / 1000.0))
    assert fr["aspect"] == pytest.approx(1.6)
    assert fr["image"].shape == (300, 480, 3)
    # a gizmo release reports the result index (not the scene index) and the pose in mm
    T_new = pose_from_xyz_euler(310.0, 150.0, 15.0, c_deg=30.0)
    wxyz, pos = pose_to_viser(T_new)

    class Ev:
        phase = "end"
        target = type("T", (), {"wxyz": wxyz, "position": pos})()

    scene.nodes["/objects/o1"].callbacks[0](Ev())
    assert moves[0][0] == 1 and moves[0][1] == pytest.approx(T_new, abs=1e-9)
    Ev.phase = "update"      # dragging: nothing is sent until the operator lets go
    scene.nodes["/objects/o1"].callbacks[0](Ev())
    assert len(moves) == 1
    # a newer revision moves the objects
    newer = SetupView("Setup 1", 2, v.table_mesh, (v.objects[0], ViewObject("block", "workpiece", v.objects[1].mesh,
                                                                             T_new)), v.camera, 1)
    move_objects(handles, newer)
    assert handles.frames[1].position == pytest.approx(T_new[:3, 3] * M_PER_MM)


def test_initial_camera_looks_at_the_scene_from_above():
    v = view(np.random.default_rng(1))
    pos, look = initial_camera(v)
    assert pos[2] > look[2] + 0.2
    assert 0.5 < np.linalg.norm(pos - look) < 5.0
    g = frustum_geometry(v.camera)
    assert g["T_table_cam"][:3, 3] == pytest.approx(inv(v.camera.T_cam_table)[:3, 3])


def _look_at_camera(pos, look):
    """World-to-camera rotation (rows: right, up, backward) of a camera at ``pos`` looking at ``look``, z up."""
    fwd = (look - pos) / np.linalg.norm(look - pos)
    right = np.cross(fwd, [0, 0, 1.0])
    right /= np.linalg.norm(right)
    return np.vstack([right, np.cross(right, fwd), -fwd])


@pytest.mark.parametrize("fov_deg,aspect", [(75.0, 16 / 9), (50.0, 4 / 3), (75.0, 0.6)])
def test_initial_view_frames_the_table_and_the_parts(fov_deg, aspect):
    """Every corner of the table and of each part lies inside the first view (a pinhole with the viewer's
    field of view), and together they fill a good part of it: framed, not lost in the distance."""
    v = view(np.random.default_rng(2))
    pos, look = initial_camera(v, np.radians(fov_deg), aspect)
    R = _look_at_camera(pos, look)
    corners = []
    for mesh, T in [(v.table_mesh, np.eye(4))] + [(o.mesh, o.T_table_obj) for o in v.objects]:
        b = np.asarray(mesh.bounds)
        c = np.array([[x, y, z] for x in b[:, 0] for y in b[:, 1] for z in b[:, 2]])
        corners.append(c @ np.asarray(T)[:3, :3].T + np.asarray(T)[:3, 3])
    p = (np.vstack(corners) * M_PER_MM - pos) @ R.T
    assert np.all(p[:, 2] < 0), "everything in front of the camera"
    t = np.tan(np.radians(fov_deg) / 2)
    u, w = p[:, 0] / -p[:, 2] / (t * aspect), p[:, 1] / -p[:, 2] / t     # -1..1 across the view
    assert np.all(np.abs(u) <= 1) and np.all(np.abs(w) <= 1), (u.min(), u.max(), w.min(), w.max())
    assert max(u.max() - u.min(), w.max() - w.min()) > 1.0, "the scene fills at least half the view"


@pytest.mark.parametrize("path,expected", [("/setup/5", ("setup", 5)), ("setup/12/", ("setup", 12)),
                                           ("/model/3?x=1", ("model", 3)), ("/", None), ("/setup/x", None),
                                           ("/other/1", None)])
def test_parse_view_path(path, expected):
    assert parse_view_path(path) == expected


def test_tickets_are_one_time_and_expire():
    t = Tickets(ttl_s=30)
    ticket = t.issue("anna (operator)", True)
    assert ticket_of(f"/setup/5?t={ticket}") == ticket and ticket_of("/setup/5?who=anna&person=1") is None
    assert t.redeem(ticket) == ("anna (operator)", True)
    assert t.redeem(ticket) is None, "used once"
    assert t.redeem(None) is None and t.redeem("made-up") is None   # straight to viser's port: nothing
    expired = Tickets(ttl_s=-1)
    assert expired.redeem(expired.issue("x", True)) is None


def test_paths_are_drawn_in_metres_and_replaced_on_a_new_version():
    import dataclasses

    v = view(np.random.default_rng(0))
    scene = FakeScene()
    h = build_setup_scene(scene, v)
    assert not any(n.startswith("/paths/") for n in scene.nodes)          # nothing planned yet
    travel = ViewPath("travel0", np.array([[20.0, 20.0, 100.0], [20.0, 20.0, 60.0], [250.0, 140.0, 60.0]]))
    touch = ViewPath("touch_x", np.array([[255.0, 140.0, 10.0], [250.5, 140.0, 10.0]]), (240, 140, 0))
    update_paths(h, dataclasses.replace(v, paths=(travel, touch)))
    seg = scene.nodes["/paths/travel0"].kw["points"]
    assert seg.shape == (2, 2, 3)                                           # N points -> N-1 segments
    np.testing.assert_allclose(seg[1], [[0.020, 0.020, 0.060], [0.250, 0.140, 0.060]], atol=1e-6)
    assert scene.nodes["/paths/touch_x"].kw["colors"] == (240, 140, 0)
    old = scene.nodes["/paths/travel0"]
    update_paths(h, dataclasses.replace(v, paths=()))
    assert old.removed and h.paths == []


def test_a_rotary_table_is_shown_turned_as_at_the_picture_and_moves_come_back_in_the_table_frame():
    """World = the table at the export angle; the table, its objects, the camera and the paths are placed
    through T_world_table (here: turned 37° about an axis through table (400, 200)); the axis is a line."""
    from app.geometry.rotary_chain import RotaryChain

    base = view(np.random.default_rng(0))
    chain = RotaryChain("C", pose_from_xyz_euler(40, 30, -200), pose_from_xyz_euler(-400, -200, 0))
    W = chain.turn(0.0, 37.0)
    axis = np.array([[400.0, 200.0, -500.0], [400.0, 200.0, 500.0]])
    v = SetupView(base.title, base.revision, base.table_mesh, base.objects, base.camera, base.editable,
                  paths=(ViewPath("travel0", np.array([[0.0, 0, 50], [100, 0, 50]])),), T_world_table=W, axis_mm=axis)
    scene = FakeScene()
    moves = []
    build_setup_scene(scene, v, on_move=lambda i, T: moves.append((i, T)))
    assert "/rotary_axis" in scene.nodes
    assert np.asarray(scene.nodes["/rotary_axis"].kw["points"]) == pytest.approx(axis.reshape(1, 2, 3) * M_PER_MM)
    # the table mesh turned about the axis: the table's centre stays, its corner moves
    t = scene.nodes["/table"]
    assert viser_to_pose(t.kw["wxyz"], t.kw["position"]) == pytest.approx(W, abs=1e-6)
    assert (W @ [400, 200, 0, 1])[:2] == pytest.approx([400, 200])
    obj = scene.nodes["/objects/o1"]
    assert viser_to_pose(obj.wxyz, obj.position) == pytest.approx(W @ v.objects[1].T_table_obj, abs=1e-6)
    fr = scene.nodes["/camera"].kw
    assert fr["position"] == pytest.approx((W @ inv(v.camera.T_cam_table))[:3, 3] * M_PER_MM)
    assert np.asarray(scene.nodes["/paths/travel0"].kw["points"])[0, 0] == pytest.approx(
        (W @ [0, 0, 50, 1])[:3] * M_PER_MM)
    # a release of the gizmo at a pose in the world is a pose on the table
    T_world = W @ pose_from_xyz_euler(310.0, 150.0, 15.0, c_deg=30.0)
    wxyz, pos = pose_to_viser(T_world)

    class Ev:
        phase = "end"
        target = type("T", (), {"wxyz": wxyz, "position": pos})()

    obj.callbacks[0](Ev())
    assert moves[0][1] == pytest.approx(pose_from_xyz_euler(310.0, 150.0, 15.0, c_deg=30.0), abs=1e-6)
