"""The viser server inside the service process: one scene PER BROWSER, chosen by the page's path.

A browser opens ``/viewer/setup/<id>/`` (or ``/viewer/model/<id>/``) on the service; the relay
(:mod:`app.api.routes.viewer`) forwards its websocket to viser at ``ws://127.0.0.1:<viser_port>/setup/<id>``.
On connect we read that path and build the scene into ``client.scene`` only, so two operators looking
at two setups never see each other's.

A light poll thread (every ``poll_s``) compares each open setup's version (result revision, confirmed
revision) with the one on screen and moves the objects when a nudge, a refine or another browser's gizmo
made a new revision, and draws the probing plan once the setup is confirmed.
"""

from __future__ import annotations

import dataclasses
import logging
import re
import secrets
import threading
import time
from urllib.parse import parse_qs
from dataclasses import dataclass
from typing import Any, Callable

import numpy as np
import viser

from app.viewer.scene import (SceneHandles, SetupView, build_setup_scene, initial_camera, move_objects,
                              update_paths)

log = logging.getLogger(__name__)

PATH_RE = re.compile(r"^/?(setup|model)/(\d+)/?$")


def parse_view_path(path: str) -> tuple[str, int] | None:
    """``/setup/5`` -> ("setup", 5); anything else -> None."""
    m = PATH_RE.match(path.partition("?")[0])
    return (m.group(1), int(m.group(2))) if m else None


def ticket_of(path: str) -> str | None:
    """The relay's one-time ticket in the upstream path's query (``?t=...``), or None."""
    return parse_qs(path.partition("?")[2]).get("t", [None])[0]


class Tickets:
    """One-time tickets the relay issues for a signed-in browser just before it connects upstream: the
    viewer believes nothing a connection says about itself, only what the ticket says (who, may edit).
    A connection to the inner port without one sees nothing and can move nothing."""

    def __init__(self, ttl_s: float = 30.0):
        self.ttl_s = ttl_s
        self._tickets: dict[str, tuple[float, str, bool]] = {}
        self._lock = threading.Lock()

    def issue(self, who: str, person: bool) -> str:
        ticket = secrets.token_urlsafe(32)
        now = time.monotonic()
        with self._lock:
            self._tickets = {t: v for t, v in self._tickets.items() if v[0] > now}
            self._tickets[ticket] = (now + self.ttl_s, who, person)
        return ticket

    def redeem(self, ticket: str | None) -> tuple[str, bool] | None:
        """(who, is_person) once per ticket; None for a missing, used or expired one."""
        if not ticket:
            return None
        with self._lock:
            entry = self._tickets.pop(ticket, None)
        if entry is None or entry[0] < time.monotonic():
            return None
        return entry[1], entry[2]


@dataclass
class _ClientView:
    kind: str
    ident: int
    revision: int
    handles: SceneHandles | None
    version: tuple = ()


class ViewerServer:
    """viser + per-client scenes.

    load(kind, ident) -> SetupView | str : the scene data, or a sentence why there is none.
    version(ident) -> tuple : what a setup's view depends on, e.g. (result revision, confirmed revision)
        (cheap; polled: a change reloads the view, moves the objects and redraws the paths).
    on_move(setup_id, object_index, T_table_obj_mm, who) -> bool : the operator released the gizmo; False when
        the move was refused (the part is then put back where the result has it).
    """

    def __init__(self, load: Callable[[str, int], SetupView | str], version: Callable[[int], tuple],
                 on_move: Callable[[int, int, np.ndarray, str], bool] | None = None,
                 host: str = "127.0.0.1", port: int = 8081, poll_s: float = 1.0):
        self._load, self._version, self._on_move = load, version, on_move
        self.host, self.requested_port, self.poll_s = host, port, poll_s
        self._clients: dict[int, _ClientView] = {}
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self.server: Any = None
        self._poller: threading.Thread | None = None
        self.tickets = Tickets()

    # ------------------------------------------------------------------ life cycle
    def start(self) -> "ViewerServer":
        self.server = viser.ViserServer(host=self.host, port=self.requested_port, verbose=False)
        if self.port != self.requested_port:  # viser silently takes the next free port
            log.warning("viser port busy; using another", extra={"requested": self.requested_port, "port": self.port})
        self.server.gui.configure_theme(control_layout="floating", control_width="small", show_logo=False,
                                        show_share_button=False)
        self.server.gui.main_panel.minimize()  # the operator's controls are on the page, not in viser's panel
        self.server.on_client_connect(self._connected)
        self.server.on_client_disconnect(self._disconnected)
        self._poller = threading.Thread(target=self._poll, name="viewer-poll", daemon=True)
        self._poller.start()
        return self

    @property
    def port(self) -> int:
        return int(self.server.get_port())

    def stop(self) -> None:
        self._stop.set()
        if self._poller is not None:
            self._poller.join(timeout=5)
        if self.server is not None:
            self.server.stop()

    def client_views(self) -> dict[int, tuple[str, int, int]]:
        """client id -> (kind, id, revision on screen): for tests and /health-like checks."""
        with self._lock:
            return {cid: (v.kind, v.ident, v.revision) for cid, v in self._clients.items()}

    # ------------------------------------------------------------------ clients
    def _client_path(self, client_id: int) -> str:
        # viser keeps the websocket connection of each client; its request path is the one the relay
        # connected with. (No public API exposes it in viser 1.1.)
        conn = self.server._websock_server._live_connections.get(client_id)
        request = getattr(conn, "request", None)
        return getattr(request, "path", "") or ""

    def _connected(self, client) -> None:
        path = self._client_path(client.client_id)
        what = parse_view_path(path)
        admitted = self.tickets.redeem(ticket_of(path))
        if admitted is None:  # not through the service's relay: nothing to see, nothing to move
            log.warning("viewer: connection without a relay ticket refused", extra={"client": client.client_id})
            client.gui.add_markdown("Open the 3D view through setupcam (a setup or the library page).")
            return
        who, person = admitted
        if what is None:
            client.gui.add_markdown("Open the 3D view from a setup or the library page.")
            return
        kind, ident = what
        try:
            view = self._load(kind, ident)
        except Exception:  # noqa: BLE001 - a broken scene must not kill viser's thread
            log.exception("viewer: loading the scene failed", extra={"kind": kind, "id": ident})
            view = "the 3D view could not be built; the error has been logged"
        if isinstance(view, str):
            client.gui.add_markdown(f"**Nothing to show:** {view}")
            with self._lock:
                self._clients[client.client_id] = _ClientView(kind, ident, -1, None)
            return
        on_move = None
        if kind == "setup" and self._on_move is not None and person:  # API keys and anonymous: look, don't touch
            def on_move(index: int, T: np.ndarray, setup_id=ident, cid=client.client_id) -> None:
                if not self._on_move(setup_id, index, T, who or "operator (3D view)"):
                    self._put_back(cid)
        elif kind == "setup" and view.editable is not None:
            view = dataclasses.replace(view, editable=None)
        handles = build_setup_scene(client.scene, view, on_move)
        cam = client.camera  # a client that has not reported its camera yet says fov 0: the default then
        pos, look = initial_camera(view, getattr(cam, "fov", None) or None, getattr(cam, "aspect", None) or 16 / 9)
        client.camera.position = tuple(pos)
        client.camera.look_at = tuple(look)
        with self._lock:
            self._clients[client.client_id] = _ClientView(kind, ident, view.revision, handles, view.version)

    def _disconnected(self, client) -> None:
        with self._lock:
            self._clients.pop(client.client_id, None)

    def _put_back(self, client_id: int) -> None:
        """A refused move: show the part where the current result has it again."""
        with self._lock:
            v = self._clients.get(client_id)
        if v is None or v.handles is None:
            return
        view = self._load("setup", v.ident)
        if not isinstance(view, str) and len(view.objects) == len(v.handles.frames):
            move_objects(v.handles, view)
            v.revision = view.revision

    # ------------------------------------------------------------------ follow new revisions
    def _poll(self) -> None:
        while not self._stop.wait(self.poll_s):
            with self._lock:
                views = [(cid, v) for cid, v in self._clients.items() if v.kind == "setup" and v.handles is not None]
            for cid, v in views:
                try:
                    if tuple(self._version(v.ident)) == v.version:
                        continue
                    view = self._load("setup", v.ident)
                    if isinstance(view, str) or len(view.objects) != len(v.handles.frames):
                        continue
                    move_objects(v.handles, view)
                    update_paths(v.handles, view)
                    v.revision, v.version = view.revision, view.version
                except Exception:  # noqa: BLE001 - keep polling the others
                    log.exception("viewer: refresh failed", extra={"client": cid, "setup_id": v.ident})
