"""Every write is bounded and checked before its body is read (an ASGI middleware).

FastAPI parses a request's body (form parts spooled to /tmp, JSON into memory) before it runs the
route's dependencies, so without this an anonymous caller could make the service buffer gigabytes and
only then hear 401. For each POST/PUT/PATCH/DELETE this middleware, in order:

1. finds the route and what it needs of its caller (any principal, a signed-in person, an admin:
   read off the route's dependencies) and refuses a caller without it (401/403, same words as the
   route's own check);
2. refuses a cookie-authenticated write from another origin (403; ``Origin``, else ``Referer``, must
   name this service): SameSite alone is not the CSRF defence;
3. refuses a body over the route's limit (413): uploads ``max_request_mb``, everything else
   ``max_json_kb``; by ``Content-Length`` before reading, and while streaming when it is absent;
4. refuses JSON nested deeper than ``max_json_depth`` (422) before the parser recurses into it, and
   JSON with NaN, Infinity or numbers that overflow to them (422).
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass
from typing import Any
from urllib.parse import urlsplit

import anyio
from fastapi import params
from fastapi.routing import APIRoute
from starlette.datastructures import Headers
from starlette.requests import cookie_parser

from app.api.problems import problem
from app.api.deps import GUARD_ADMIN, GUARD_ANY, GUARD_PERSON, get_principal, refusal, require_admin, \
    require_person, token_of
from app.services.audit import audit_refusal

SAFE_METHODS = ("GET", "HEAD", "OPTIONS", "TRACE")
# sign-in has no caller yet; sign-out only ends the caller's own session (refused cross-origin below)
OPEN_PATHS = ("/api/v1/auth/login", "/api/v1/auth/logout")
_GUARD_OF = {get_principal: GUARD_ANY, require_person: GUARD_PERSON, require_admin: GUARD_ADMIN}
_RANK = {None: 0, GUARD_ANY: 1, GUARD_PERSON: 2, GUARD_ADMIN: 3}
_JSON_TOKENS = re.compile(rb'"(?:[^"\\]|\\.)*"|[\[\]{}]')


@dataclass(frozen=True)
class RouteRule:
    guard: str | None     # None: open route
    upload: bool          # multipart form (files): the larger limit


def route_rule(route: APIRoute) -> RouteRule:
    """What a route needs of its caller and which body limit applies, read off its dependencies."""
    guard, stack = None, [route.dependant]
    while stack:
        dep = stack.pop()
        g = _GUARD_OF.get(dep.call)
        if _RANK[g] > _RANK[guard]:
            guard = g
        stack.extend(dep.dependencies)
    upload = isinstance(getattr(route.body_field, "field_info", None), params.Form)
    return RouteRule(guard, upload)


def json_depth(data: bytes) -> int:
    """Deepest nesting of arrays/objects in a JSON text (strings skipped), without parsing it."""
    if data.count(b"[") + data.count(b"{") <= 1:
        return min(1, data.count(b"[") + data.count(b"{"))
    depth = deepest = 0
    for m in _JSON_TOKENS.finditer(data):
        c = m.group()
        if c in (b"[", b"{"):
            depth += 1
            deepest = max(deepest, depth)
        elif c in (b"]", b"}"):
            depth -= 1
    return deepest


class _NonFinite(ValueError):
    pass


def _finite(text: str) -> float:
    value = float(text)
    if value != value or value in (float("inf"), float("-inf")):
        raise _NonFinite(text)
    return value


def _no_constant(text: str) -> float:
    raise _NonFinite(text)


def non_finite_number(data: bytes) -> str | None:
    """The first NaN / Infinity / overflowing number (e.g. 1e999) in a JSON text, or None. Python's parser
    takes them, JSON does not, and a NaN compares false with every limit. Not JSON at all: None (the
    route answers that)."""
    try:
        json.loads(data, parse_constant=_no_constant, parse_float=_finite)
    except _NonFinite as exc:
        return str(exc)
    except (ValueError, RecursionError):
        return None
    return None


def same_origin(headers: Headers, settings) -> bool:
    """True when the request's Origin (else Referer) names this service (its Host) or an allowed origin."""
    source = headers.get("origin") or headers.get("referer")
    if not source or source == "null":
        return False
    parts = urlsplit(source)
    origin = f"{parts.scheme}://{parts.netloc}".lower()
    if origin in {o.rstrip("/").lower() for o in getattr(settings, "allowed_origins", [])}:
        return True
    return parts.netloc.lower() == headers.get("host", "").lower()


def route_table(routers, prefix: str) -> list[tuple[re.Pattern, set[str], RouteRule]]:
    """(path regex, methods, rule) of every API route of ``routers`` as mounted under ``prefix``."""
    from starlette.routing import compile_path

    table = []
    for router in routers:
        for route in router.routes:
            if isinstance(route, APIRoute):
                table.append((compile_path(prefix + route.path)[0], set(route.methods), route_rule(route)))
    return table


class RequestGuard:
    """ASGI middleware: see the module docstring. ``fastapi_app`` gives the settings and engine, ``routes``
    the :func:`route_table`."""

    def __init__(self, app, fastapi_app, routes: list[tuple[re.Pattern, set[str], RouteRule]]):
        self.app = app
        self.fastapi_app = fastapi_app
        self.routes = routes

    def _rule(self, scope) -> RouteRule | None:
        path, method = scope["path"], scope["method"]
        for regex, methods, rule in self.routes:
            if method in methods and regex.match(path):
                return rule
        return None

    async def __call__(self, scope, receive, send) -> None:
        if scope["type"] != "http" or scope["method"] in SAFE_METHODS:
            await self.app(scope, receive, send)
            return
        state = self.fastapi_app.state
        settings = state.settings
        headers = Headers(scope=scope)
        rule = self._rule(scope)
        path = scope["path"]

        token, from_cookie = token_of(headers, cookie_parser(headers.get("cookie", "")))
        if rule is not None and rule.guard is not None and path not in OPEN_PATHS:
            principal = await anyio.to_thread.run_sync(_resolve, state.engine, token) if token else None
            why = refusal(principal, bool(token), rule.guard)
            if why is not None and why[0] == 403:
                client = scope.get("client") or ("unknown", 0)
                await anyio.to_thread.run_sync(audit_refusal, state.engine, principal.label(),
                                               f"{scope['method']} {path}", client[0], why[1])
            if why is not None:
                await _answer(send, why[0], why[1], {"www-authenticate": "Bearer"} if why[0] == 401 else None,
                              code=why[2])
                return
        if path in OPEN_PATHS:  # no session needed: refused only when the request names another origin
            foreign = bool(headers.get("origin") or headers.get("referer")) and not same_origin(headers, settings)
        else:
            foreign = from_cookie and not same_origin(headers, settings)
        if foreign:
            await _answer(send, 403, "cross-origin write refused: a request signed in by the session cookie must "
                                     "come from this service's own pages (Origin or Referer header)", code="cross_origin")
            return

        upload = rule is not None and rule.upload
        limit = int(settings.max_request_mb * 1e6) if upload else int(settings.max_json_kb * 1000)
        what = f"{settings.max_request_mb:g} MB" if upload else f"{settings.max_json_kb:g} KB"
        length = headers.get("content-length")
        if length is not None:
            try:
                too_big = int(length) > limit
            except ValueError:
                await _answer(send, 400, "Content-Length is not a number", code="bad_content_length")
                return
            if too_big:
                await _answer(send, 413, f"request body is {int(length):,} bytes; this route takes at most {what}")
                return

        if not upload and "json" in headers.get("content-type", ""):
            body, over = await _read_all(receive, limit)
            if over:
                await _answer(send, 413, f"request body is over {what}")
                return
            depth = json_depth(body)
            if depth > settings.max_json_depth:
                await _answer(send, 422, f"JSON nested {depth} deep; at most {settings.max_json_depth} levels", code="json_too_deep")
                return
            bad = non_finite_number(body)
            if bad:
                await _answer(send, 422, f"JSON numbers must be finite: {bad} is not a number here "
                                         "(NaN, Infinity and overflowing values are refused)", code="non_finite_number")
                return
            await self.app(scope, _replay(body, receive), send)
            return

        await self._stream_bounded(scope, receive, send, limit, what)

    async def _stream_bounded(self, scope, receive, send, limit: int, what: str) -> None:
        """Pass the body through, counting; past ``limit`` the app sees a disconnect and the client a 413."""
        seen = 0
        tripped = False
        started = False

        async def counting_receive() -> dict[str, Any]:
            nonlocal seen, tripped
            if tripped:
                return {"type": "http.disconnect"}
            message = await receive()
            if message["type"] == "http.request":
                seen += len(message.get("body", b""))
                if seen > limit:
                    tripped = True
                    return {"type": "http.disconnect"}
            return message

        async def guarded_send(message: dict[str, Any]) -> None:
            nonlocal started
            if tripped:
                return  # the app's answer to the cut-off body is replaced by the 413 below
            started = started or message["type"] == "http.response.start"
            await send(message)

        try:
            await self.app(scope, counting_receive, guarded_send)
        except Exception:
            if not tripped:
                raise
        if tripped and not started:
            await _answer(send, 413, f"request body is over {what}")


def _resolve(engine, token: str):
    from app.services.access import resolve_token
    from app.store.db import session_scope

    with session_scope(engine) as session:
        return resolve_token(session, token)


async def _read_all(receive, limit: int) -> tuple[bytes, bool]:
    """The whole body (at most ``limit`` bytes), and whether it was longer."""
    chunks, size = [], 0
    while True:
        message = await receive()
        if message["type"] != "http.request":
            break
        body = message.get("body", b"")
        size += len(body)
        if size > limit:
            return b"", True
        chunks.append(body)
        if not message.get("more_body", False):
            break
    return b"".join(chunks), False


def _replay(body: bytes, receive):
    sent = False

    async def replay() -> dict[str, Any]:
        nonlocal sent
        if not sent:
            sent = True
            return {"type": "http.request", "body": body, "more_body": False}
        return await receive()

    return replay


async def _answer(send, status: int, detail: str, extra: dict[str, str] | None = None, code: str | None = None) -> None:
    body = json.dumps(problem(status, detail, code)).encode()
    headers = [(b"content-type", b"application/json"), (b"content-length", str(len(body)).encode())]
    headers += [(k.encode(), v.encode()) for k, v in (extra or {}).items()]
    await send({"type": "http.response.start", "status": status, "headers": headers})
    await send({"type": "http.response.body", "body": body})
