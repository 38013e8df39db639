"""The operator's pages (static HTML/CSS/JS from ``frontend/``, no build step, no CDN). Mounted at the
root (not under /api/v1), as is the 3D viewer's relay (app/api/routes/viewer.py)."""

from __future__ import annotations

from pathlib import Path

import re
from functools import lru_cache

from fastapi import APIRouter, HTTPException, Request
from fastapi.responses import FileResponse, HTMLResponse

from app.resources import bundled_dir

FRONTEND_DIR = bundled_dir("frontend")   # the checkout's frontend/ or the installed copy
STATIC_DIR = FRONTEND_DIR / "static"

# URL -> HTML file in frontend/
PAGES = {"": "index.html", "machines": "machines.html", "setup": "setup.html", "history": "history.html",
         "library": "library.html", "camera": "camera.html", "login": "login.html", "sheet": "sheet.html",
         "rotary": "rotary.html", "cameras": "cameras.html", "users": "users.html", "probing": "probing.html"}
STATIC_TYPES = {".css": "text/css", ".js": "text/javascript", ".svg": "image/svg+xml", ".png": "image/png",
                ".ico": "image/x-icon"}

router = APIRouter(include_in_schema=False)


TITLE_RE = re.compile(r"^<!-- title: ([^(]*?)\s*(\(.*\))? -->\n")


@lru_cache(maxsize=32)
def render_page(file: str, mtimes_ns: tuple[int, int]) -> str:
    """A page file is its title comment plus the body; ``_layout.html`` adds the head and the navigation."""
    text = (FRONTEND_DIR / file).read_text(encoding="utf-8")
    m = TITLE_RE.match(text)
    title, body = (m.group(1), text[m.end():]) if m else ("setupcam", text)
    layout = (FRONTEND_DIR / "_layout.html").read_text(encoding="utf-8")
    return layout.replace("{{title}}", title).replace("{{body}}", body)


def _page(name: str, request: Request) -> HTMLResponse:
    path = FRONTEND_DIR / PAGES[name]
    mtimes = (path.stat().st_mtime_ns, (FRONTEND_DIR / "_layout.html").stat().st_mtime_ns)  # edits show at once
    # every <script> carries this answer's nonce: the page's CSP runs no script without it (app/api/headers.py)
    nonce = getattr(request.state, "csp_nonce", "")
    html = render_page(PAGES[name], mtimes).replace("<script", f'<script nonce="{nonce}"')
    return HTMLResponse(html, headers={"Cache-Control": "no-cache"})


@router.get("/")
def index(request: Request) -> HTMLResponse:
    return _page("", request)


@router.get("/static/{path:path}")
def static(path: str) -> FileResponse:
    target = (STATIC_DIR / path).resolve()
    if not target.is_relative_to(STATIC_DIR) or not target.is_file() or target.suffix not in STATIC_TYPES:
        raise HTTPException(404, f"no such file: /static/{path}")
    return FileResponse(target, media_type=STATIC_TYPES[target.suffix], headers={"Cache-Control": "no-cache"})


def _add_page(name: str) -> None:
    def page(request: Request) -> HTMLResponse:
        return _page(name, request)

    router.add_api_route(f"/{name}", page, methods=["GET"], name=f"page_{name}")


for _name in PAGES:
    if _name:
        _add_page(_name)
