"""Read what the 3D view shows (through the services, never the store) into plain :mod:`app.viewer.scene` data.

Meshes are cached per (model id, revision): revisions are immutable, so a cached mesh never goes stale.
"""

from __future__ import annotations

import threading
from collections import OrderedDict

import cv2
import numpy as np
import trimesh

from app.geometry.mesh import load_mesh
from app.services import library, planning
from app.services import setups as setup_svc
from app.services.cameras import read_image
from app.services.errors import ServiceError
from app.services.machines import get_machine, picture_turn
from app.services.transaction import transaction
from app.viewer.scene import DEFAULT_OBJECT_RGB, TOUCH_RGB, SetupView, ViewCamera, ViewObject, ViewPath


class MeshCache:
    """Small LRU of library meshes (mm, own frame) keyed by (model_id, revision)."""

    def __init__(self, size: int = 32):
        self._size = size
        self._items: OrderedDict[tuple[int, int], trimesh.Trimesh] = OrderedDict()
        self._lock = threading.Lock()

    def get(self, session, files, model_id: int, revision: int | None) -> tuple[trimesh.Trimesh, int]:
        rev = library.get_revision(session, model_id, revision)
        key = (model_id, rev.revision)
        with self._lock:
            if key in self._items:
                self._items.move_to_end(key)
                return self._items[key], rev.revision
        mesh = load_mesh(files.read(rev.glb_sha256), "model.glb", "mm")
        with self._lock:
            self._items[key] = mesh
            while len(self._items) > self._size:
                self._items.popitem(last=False)
        return mesh, rev.revision


def setup_version(engine, setup_id: int) -> tuple:
    """What a setup's 3D view depends on: (result revision, confirmed revision); polled by the viewer."""
    with transaction(engine) as session:
        s = setup_svc.get_setup(session, setup_id)
        return s.result_revision, s.confirmed_revision


class PlanCache:
    """Probing plans drawn in the view, per (setup id, result revision): a revision is immutable, so a
    plan is made once per viewer, whoever opens the view."""

    def __init__(self, size: int = 32):
        self._size = size
        self._items: OrderedDict[tuple[int, int], tuple[tuple[ViewPath, ...], str]] = OrderedDict()
        self._lock = threading.Lock()

    def get(self, key):
        with self._lock:
            return self._items.get(key)

    def put(self, key, value) -> None:
        with self._lock:
            self._items[key] = value
            while len(self._items) > self._size:
                self._items.popitem(last=False)


def probing_paths(session, files, setup, plans: PlanCache | None = None,
                  settings=None) -> tuple[tuple[ViewPath, ...], str]:
    """The probing plan of a confirmed setup as paths to draw (safe travel, and each touch move from its
    approach point to the expected contact), or none and why."""
    if setup.confirmed_revision is None or setup.confirmed_revision != setup.result_revision:
        return (), "the probing plan is drawn once the setup is confirmed"
    key = (setup.id, setup.result_revision)
    cached = plans.get(key) if plans is not None else None
    if cached is not None:
        return cached
    try:
        # drawn before the export too: the controller's slot is not read back for a picture
        prog = planning.probing_plan(session, files, settings, setup.id, dry_run=True, check_frame=False)
        paths = tuple([ViewPath(f"travel{i}", np.asarray(p.waypoints, float)) for i, p in enumerate(prog.travel)] +
                      [ViewPath(f"touch_{t.name}", np.asarray([t.approach_tip, t.contact_tip], float), TOUCH_RGB)
                       for t in prog.touches])
        out = (paths, "")
    except ServiceError as exc:
        out = ((), f"no probing plan: {exc.detail}")
    if plans is not None:
        plans.put(key, out)
    return out


def _rgb(bgr) -> tuple[int, int, int]:
    if not bgr or len(bgr) != 3:
        return DEFAULT_OBJECT_RGB
    return int(bgr[2]), int(bgr[1]), int(bgr[0])


def load_setup_view(engine, files, meshes: MeshCache, setup_id: int,
                    plans: PlanCache | None = None, settings=None) -> SetupView | str:
    """The 3D view of a setup, or a sentence saying why there is nothing to show yet."""
    try:
        with transaction(engine) as session:
            s = setup_svc.get_setup(session, setup_id)
            machine = get_machine(session, s.machine_id)
            table_mesh, _ = meshes.get(session, files, machine.table_model_id, machine.table_revision)
            result = setup_svc.setup_result(s)
            objects = []
            editable = None
            for i, o in enumerate(result.objects):
                if o.model_id is None:
                    continue
                mesh, _ = meshes.get(session, files, int(o.model_id), o.revision)
                objects.append(ViewObject(name=o.name, kind=o.kind, mesh=mesh, T_table_obj=o.pose,
                                          rgb=_rgb(getattr(o, "colour_bgr", None)), result_index=i))
                if editable is None and o.kind == "workpiece":
                    editable = len(objects) - 1
            camera = None
            if result.table and result.table.get("T_cam_table") is not None and s.intrinsics:
                img = read_image(files.read(setup_svc.picture_sha256(session, s)))
                img = img if img.ndim == 3 else cv2.cvtColor(img, cv2.COLOR_GRAY2BGR)
                camera = ViewCamera(T_cam_table=result.T_cam_table,
                                    K=np.asarray(s.intrinsics["K"], float), width=int(s.intrinsics["width"]),
                                    height=int(s.intrinsics["height"]), image_rgb=img[:, :, ::-1].copy())
            paths, why = probing_paths(session, files, s, plans, settings)
            turn = picture_turn(machine, s.table_angle_deg)  # a rotary table: shown turned as at the picture
            placed = {} if turn is None else {"T_world_table": turn[0], "axis_mm": turn[1]}
            return SetupView(title=f"Setup {s.id}", revision=s.result_revision, table_mesh=table_mesh,
                             objects=tuple(objects), camera=camera, editable=editable, paths=paths,
                             notes=(why,) if why else (), version=(s.result_revision, s.confirmed_revision),
                             **placed)
    except ServiceError as exc:
        return exc.detail if isinstance(exc.detail, str) else str(exc.detail)


def load_model_view(engine, files, meshes: MeshCache, model_id: int) -> SetupView | str:
    """A library model alone at the origin (the library page's 3D preview)."""
    try:
        with transaction(engine) as session:
            m = library.get_model(session, model_id)
            mesh, rev = meshes.get(session, files, model_id, None)
            return SetupView(title=m.name, revision=rev, table_mesh=None,
                             objects=(ViewObject(m.name, m.kind, mesh, np.eye(4), (70, 130, 230)),))
    except ServiceError as exc:
        return exc.detail if isinstance(exc.detail, str) else str(exc.detail)
