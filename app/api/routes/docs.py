"""The API reference pages, ``/docs`` (Swagger UI) and ``/redoc`` (ReDoc), with no CDN.

FastAPI's own pages load Swagger UI and ReDoc from a CDN, so they stay blank on a shop-floor network
without internet. Here the same two pages load the bundles that the ``fastapi-offline`` package ships
(a pinned dependency, see pyproject.toml) from ``/docs-assets/``. The pages carry no inline script
(Swagger UI is started by ``/static/api-docs.js``), so a strict Content-Security-Policy needs no
exception for them, and they load pictures from this service only.
"""

from __future__ import annotations

import html
from importlib import resources

from fastapi import APIRouter, HTTPException, Request
from fastapi.responses import HTMLResponse, Response

router = APIRouter(include_in_schema=False)

ASSETS_URL = "/docs-assets"
# The only files served from the package, with their media types (nothing else is reachable).
ASSETS = {"swagger-ui-bundle.js": "text/javascript", "swagger-ui.css": "text/css",
          "redoc.standalone.js": "text/javascript", "favicon.png": "image/png"}


def _asset_bytes(name: str) -> bytes:
    return (resources.files("fastapi_offline") / "static" / name).read_bytes()


def _head(title: str) -> str:
    return (f'<!doctype html>\n<html lang="en"><head><meta charset="utf-8">'
            f'<meta name="viewport" content="width=device-width, initial-scale=1">'
            f"<title>{html.escape(title)}</title>"
            # ReDoc's footer always loads the vendor's logo from its CDN; pictures come from here only
            # (a meta policy only narrows whatever header policy the service sends).
            f'<meta http-equiv="Content-Security-Policy" content="img-src \'self\' data:">'
            f'<link rel="icon" type="image/png" href="{ASSETS_URL}/favicon.png">')


@router.get("/docs")
def swagger_ui(request: Request) -> HTMLResponse:
    """Swagger UI for ``/openapi.json`` (try-it-out works with an API key or the session cookie)."""
    openapi = html.escape(request.app.openapi_url or "/openapi.json", quote=True)
    page = (_head(f"{request.app.title} API - Swagger UI")
            + f'<link rel="stylesheet" href="{ASSETS_URL}/swagger-ui.css"></head><body>'
            + f'<div id="swagger-ui" data-openapi="{openapi}"></div>'
            + f'<script src="{ASSETS_URL}/swagger-ui-bundle.js"></script>'
            + '<script src="/static/api-docs.js"></script></body></html>')
    return HTMLResponse(page)


@router.get("/redoc")
def redoc(request: Request) -> HTMLResponse:
    """ReDoc for ``/openapi.json`` (read-only reference; no web fonts, the system's are used)."""
    openapi = html.escape(request.app.openapi_url or "/openapi.json", quote=True)
    page = (_head(f"{request.app.title} API - ReDoc") + "</head><body>"
            + f'<redoc spec-url="{openapi}"></redoc>'
            + f'<script src="{ASSETS_URL}/redoc.standalone.js"></script></body></html>')
    return HTMLResponse(page)


@router.get(ASSETS_URL + "/{name}")
def asset(name: str) -> Response:
    """One of the bundled Swagger UI / ReDoc files; 404 for anything else."""
    if name not in ASSETS:
        raise HTTPException(404, f"no such file: {ASSETS_URL}/{name}")
    # The files change only with the package version, so browsers may keep them for a day.
    return Response(_asset_bytes(name), media_type=ASSETS[name], headers={"Cache-Control": "public, max-age=86400"})
