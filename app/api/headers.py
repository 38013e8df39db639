"""Security headers on every answer (an ASGI middleware).

* ``X-Content-Type-Options: nosniff``, ``X-Frame-Options: SAMEORIGIN``, ``Referrer-Policy: same-origin``;
* ``Content-Security-Policy``:
  - operator pages: scripts only from the service and inline blocks carrying this answer's nonce
    (``request.state.csp_nonce``, stamped in by app/api/routes/pages.py), no plug-ins, framed only by the
    service itself (the 3D view sits in an iframe of the setup and library pages);
  - the 3D view (``/viewer/...``): viser's page unpacks its own bundle inline and runs WebAssembly, so
    scripts may be inline/eval there, but it connects only back to this host and is framed only by it;
  - everything else (JSON, images, SVG plots, files): nothing runs, nothing loads;
  - ``/docs`` and ``/redoc`` (FastAPI's API browser, loaded from its CDN) keep no CSP.
"""

from __future__ import annotations

import secrets

PAGE_CSP = ("default-src 'self'; script-src 'self' 'nonce-{nonce}'; style-src 'self' 'unsafe-inline'; "
            "img-src 'self' data: blob:; connect-src 'self'; frame-src 'self'; frame-ancestors 'self'; "
            "object-src 'none'; base-uri 'self'; form-action 'self'")
VIEWER_CSP = ("default-src 'self'; script-src 'self' 'unsafe-inline' 'unsafe-eval' 'wasm-unsafe-eval' blob: data:; "
              "style-src 'self' 'unsafe-inline' blob: data:; img-src 'self' data: blob:; font-src 'self' data: blob:; "
              "worker-src 'self' blob: data:; connect-src 'self' ws://{host} wss://{host} blob: data:; "
              "frame-ancestors 'self'; object-src 'none'; base-uri 'self'")
OTHER_CSP = "default-src 'none'; img-src 'self' data:; style-src 'unsafe-inline'; frame-ancestors 'self'; sandbox"
NO_CSP = ("/docs", "/redoc")


class SecurityHeaders:
    def __init__(self, app):
        self.app = app

    async def __call__(self, scope, receive, send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        nonce = secrets.token_urlsafe(16)
        scope.setdefault("state", {})["csp_nonce"] = nonce
        path = scope["path"]
        host = ""
        for k, v in scope.get("headers", []):
            if k == b"host":
                host = v.decode("latin-1")

        async def with_headers(message) -> None:
            if message["type"] == "http.response.start":
                headers = list(message.get("headers", []))
                names = {k.lower() for k, _ in headers}
                ctype = next((v for k, v in headers if k.lower() == b"content-type"), b"")
                extra = [(b"x-content-type-options", b"nosniff"), (b"x-frame-options", b"SAMEORIGIN"),
                         (b"referrer-policy", b"same-origin")]
                if not path.startswith(NO_CSP):
                    if path.startswith("/viewer/"):
                        csp = VIEWER_CSP.format(host=host)
                    elif ctype.startswith(b"text/html"):
                        csp = PAGE_CSP.format(nonce=nonce)
                    else:
                        csp = OTHER_CSP
                    extra.append((b"content-security-policy", csp.encode("latin-1")))
                headers += [(k, v) for k, v in extra if k not in names]
                message = {**message, "headers": headers}
            await send(message)

        await self.app(scope, receive, with_headers)
