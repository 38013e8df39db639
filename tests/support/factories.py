"""Rows for tests that need a located setup without running the vision (gate and export logic).

The end-to-end tests (tests/e2e) run the real pipeline on generated images; these factories serve
the tests whose subject is what happens after localisation.
"""

from __future__ import annotations

import json

import cv2
import numpy as np
import sqlalchemy as sa
import trimesh

from app.geometry.transforms import pose_from_xyz_euler
from app.services.setups import review_fields
from app.store.db import session_scope
from app.store.models import Capture, Machine, Setup

LAYOUT = {"dictionary": "DICT_5X5_100",
          "markers": [{"id": i, "size_mm": 40, "T_table_marker": pose_from_xyz_euler(50 + 100 * i, 30, 0).tolist()}
                      for i in range(4)]}
INTRINSICS = {"width": 320, "height": 200, "K": [[300, 0, 160], [0, 300, 100], [0, 0, 1]], "dist": [0, 0, 0, 0, 0]}


def make_machine(client, controller: dict | None, T_machine_table=None, travel=None) -> dict:
    """A table model, a camera with intrinsics and a machine, all over REST (as an admin)."""
    stl = trimesh.creation.box(extents=(800, 400, 60)).export(file_type="stl")
    table = client.post("/api/v1/models", files={"file": ("table.stl", stl)},
                        data={"kind": "table", "name": "test table", "fiducials": json.dumps(LAYOUT)}).json()
    cam = client.post("/api/v1/cameras", json={"name": "test cam", "intrinsics": INTRINSICS}).json()
    r = client.post("/api/v1/machines", json={
        "name": "test mill", "table_model_id": table["id"], "camera_ids": [cam["id"]],
        "T_machine_table": (T_machine_table if T_machine_table is not None else pose_from_xyz_euler(-400, -200, -300)).tolist()
        if hasattr(T_machine_table, "tolist") or T_machine_table is None else T_machine_table,
        "travel_mm": travel or {"x": [-500, 500], "y": [-300, 300], "z": [-400, 0]}, "controller": controller})
    assert r.status_code == 201, r.text
    return r.json()


def located_setup(server, machine_id: int, T_table_obj: np.ndarray, *, sigma_mm: float = 0.05,
                  sigma_deg: float = 0.005, T_obj_datum: np.ndarray | None = None,
                  model: tuple[int, int] | None = None, more: tuple[dict, ...] = ()) -> int:
    """Insert a setup in state 'located' with one workpiece at T_table_obj (and the objects ``more``:
    ``name``, ``kind``, ``T_table_obj`` each, after it); returns its id."""
    engine, files, settings = server.app.state.engine, server.app.state.files, server.settings
    with session_scope(engine) as session:
        machine = session.get(Machine, machine_id)
        img = np.full((200, 320, 3), 128, np.uint8)
        cap = Capture(camera_id=machine.camera_ids[0], width=320, height=200,
                      image_sha256=files.put(session, cv2.imencode(".png", img)[1].tobytes(), "image/png"))
        session.add(cap)
        session.flush()
        T_cam_table = pose_from_xyz_euler(-400, -200, 900, 180, 0, 0)
        obj = {"name": "block", "kind": "workpiece", "model_id": model[0] if model else None,
               "revision": model[1] if model else None, "score": 0.9,
               "T_table_obj": np.asarray(T_table_obj).tolist(), "T_cam_obj": (T_cam_table @ T_table_obj).tolist(),
               "T_obj_datum": None if T_obj_datum is None else np.asarray(T_obj_datum).tolist(),
               "sigma": {"x_mm": sigma_mm, "y_mm": sigma_mm, "z_mm": sigma_mm, "rx_deg": sigma_deg,
                         "ry_deg": sigma_deg, "rz_deg": sigma_deg}}
        others = [{**obj, "model_id": None, "revision": None, "T_obj_datum": None, "score": 0.7, **o,
                   "T_table_obj": np.asarray(o["T_table_obj"]).tolist(),
                   "T_cam_obj": (T_cam_table @ np.asarray(o["T_table_obj"])).tolist()} for o in more]
        result = review_fields({"ok": True, "table": {"T_cam_table": T_cam_table.tolist()}, "objects": [obj, *others]},
                               machine, settings)
        s = Setup(machine_id=machine_id, camera_id=machine.camera_ids[0], capture_id=cap.id,
                  intrinsics=INTRINSICS, status="located", result=result, result_revision=1)
        session.add(s)
        session.flush()
        return s.id


def old_machine_row(engine, T_machine_table: str = "[[1,0,0,0],[0,1,0,0],[0,0,1,0],[0,0,0,1]]") -> None:
    """Machine 1 ('Mill 1') on table model 1, inserted by plain SQL into a database migrated only to an older
    revision (the columns every revision has), to check what a migration does to an existing machine."""
    with engine.begin() as conn:
        conn.execute(sa.text("INSERT INTO library_model (id, kind, name, description, current_revision, created_at) "
                             "VALUES (1, 'table', 'old table', '', 1, CURRENT_TIMESTAMP)"))
        conn.execute(sa.text(
            "INSERT INTO machine (id, name, table_model_id, table_revision, \"T_machine_table\", travel_mm, "
            f"camera_ids, created_at) VALUES (1, 'Mill 1', 1, 1, '{T_machine_table}', '{{\"x\": [0, 1]}}', '[]', "
            "CURRENT_TIMESTAMP)"))
