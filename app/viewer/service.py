"""Start and stop the 3D viewer with the service: ``start_viewer(app)`` / ``stop_viewer(app)`` from the
app's lifespan. The viewer reads setups through the services and sends gizmo moves to the adjust
service (a new result revision, exactly as ``POST /api/v1/setups/{id}/adjust`` does)."""

from __future__ import annotations

import logging

import numpy as np

from app.services.errors import ServiceError
from app.services.setups import adjust_object
from app.services.transaction import transaction
from app.viewer.data import MeshCache, PlanCache, load_model_view, load_setup_view, setup_version
from app.viewer.server import ViewerServer

log = logging.getLogger(__name__)


def start_viewer(app) -> ViewerServer:
    """Start viser on ``settings.viser_port`` (127.0.0.1 only; browsers reach it through the relay)."""
    engine, files, settings = app.state.engine, app.state.files, app.state.settings
    meshes = MeshCache()
    plans = PlanCache()

    def load(kind: str, ident: int):
        if kind == "setup":
            return load_setup_view(engine, files, meshes, ident, plans, settings)
        return load_model_view(engine, files, meshes, ident)

    def on_move(setup_id: int, object_index: int, T_table_obj: np.ndarray, who: str) -> bool:
        try:
            with transaction(engine) as session:
                adjust_object(session, files, settings, setup_id, object_index=object_index,
                              T_table_obj=T_table_obj.tolist(), by=f"{who} in the 3D view")
            return True
        except ServiceError as exc:
            log.warning("viewer: adjustment refused", extra={"setup_id": setup_id, "reason": exc.detail})
            return False

    viewer = ViewerServer(load, lambda sid: setup_version(engine, sid), on_move, port=settings.viser_port)
    app.state.viewer = viewer.start()
    return viewer


def stop_viewer(app) -> None:
    viewer = getattr(app.state, "viewer", None)
    if viewer is not None:
        viewer.stop()
        app.state.viewer = None
