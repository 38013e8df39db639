"""Same-origin access to the viser server: the page ``/viewer/<kind>/<id>/`` and its websocket (the
viewer's only web door; the viewer itself, app/viewer, knows nothing of the web layer).

viser's web client is one self-contained ``index.html`` in the wheel. It builds its websocket URL from
the page's address (query dropped, trailing ``/`` stripped), so the page at ``/viewer/setup/5/``
connects to ``/viewer/setup/5``; we relay that socket to ``ws://127.0.0.1:<viser port>/setup/5``, and
the viewer reads the path to pick the scene. viser has no authentication of its own: this relay is the
only door. It checks the Origin (no other site's page may open the socket) and the session, then
hands viser a one-time ticket naming who is looking (``Tickets`` in app/viewer/server.py); a
connection to viser's inner port without a ticket sees and moves nothing.
"""

from __future__ import annotations

import asyncio
from functools import lru_cache
from pathlib import Path
from typing import Literal
from urllib.parse import urlencode

import viser
import websockets
from fastapi import APIRouter, HTTPException, Request, WebSocket, WebSocketDisconnect
from fastapi.responses import HTMLResponse

from app.api.deps import token_of
from app.api.limits import same_origin
from app.services.access import principal_of_token

router = APIRouter(tags=["viewer"], include_in_schema=False)

ViewKind = Literal["setup", "model"]


@lru_cache(maxsize=1)
def viser_index_html() -> str:
    return (Path(viser.__file__).parent / "client" / "build" / "index.html").read_text()


@lru_cache(maxsize=1)
def viewer_html() -> str:
    """viser's page plus our one script that closes its software-rendering notice (see the script)."""
    return viser_index_html().replace("</head>", '<script src="/static/viewer-quiet.js"></script></head>', 1)


def principal_of(app, cookies, headers):
    """The caller (``app.services.access.Principal``) from a bearer token or session cookie, or None.
    The relay lets through only what the REST API would."""
    token, _ = token_of(headers, cookies)
    return principal_of_token(app.state.engine, token)


def _viewer(app):
    viewer = getattr(app.state, "viewer", None)
    if viewer is None or viewer.server is None:
        raise HTTPException(503, "the 3D view is not running in this service (start_viewer was not called)")
    return viewer


@router.get("/viewer/{kind}/{ident}/", response_class=HTMLResponse)
def viewer_page(request: Request, kind: ViewKind, ident: int) -> HTMLResponse:
    _viewer(request.app)
    if principal_of(request.app, request.cookies, request.headers) is None:
        return HTMLResponse("<p style='font: 18px sans-serif'>Sign in first: <a href='/login' target='_top'>sign in</a>.</p>",
                            status_code=401)
    return HTMLResponse(viewer_html(), headers={"Cache-Control": "no-cache"})


@router.websocket("/viewer/{kind}/{ident}")
async def viewer_socket(ws: WebSocket, kind: ViewKind, ident: int) -> None:
    viewer = getattr(ws.app.state, "viewer", None)
    if viewer is None or viewer.server is None:
        await ws.close(code=1011)
        return
    if not same_origin(ws.headers, ws.app.state.settings):
        await ws.close(code=1008)  # another site's page in the operator's browser: refused (no CSRF by socket)
        return
    who = await asyncio.to_thread(principal_of, ws.app, ws.cookies, ws.headers)
    if who is None:
        await ws.close(code=1008)  # policy violation: not signed in
        return
    # Who is looking reaches the viewer only as a one-time ticket: the inner port believes nothing else.
    query = urlencode({"t": viewer.tickets.issue(who.label(), who.is_person)})
    protos = ws.scope.get("subprotocols", [])  # the client offers ["viser-v<version>"]
    async with websockets.connect(f"ws://{viewer.host}:{viewer.port}/{kind}/{ident}?{query}", subprotocols=protos,
                                  max_size=None, compression=None) as up:
        await ws.accept(subprotocol=up.subprotocol)

        async def down_to_up() -> None:
            while True:
                m = await ws.receive()
                if m["type"] == "websocket.disconnect":
                    return
                await up.send(m["bytes"] if m.get("bytes") is not None else m["text"])

        async def up_to_down() -> None:
            async for m in up:  # ends when viser closes
                await (ws.send_bytes(m) if isinstance(m, bytes) else ws.send_text(m))

        tasks = [asyncio.create_task(down_to_up()), asyncio.create_task(up_to_down())]
        _done, pending = await asyncio.wait(tasks, return_when=asyncio.FIRST_COMPLETED)
        for t in pending:
            t.cancel()
    try:
        await ws.close()  # viser ended first: tell the browser (it reconnects by itself)
    except (RuntimeError, WebSocketDisconnect):  # the browser is already gone
        pass
