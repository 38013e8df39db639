"""The operator pages and the viewer relay over HTTP (no browser): every page served with its
navigation, static files confined to frontend/static, the 3D view only for signed-in users."""

from __future__ import annotations

import re

import pytest

from app.api.routes import pages as pages_module
from tests.support.live_server import live_server

pytestmark = pytest.mark.integration

PAGES = ("/", "/machines", "/setup", "/history", "/library", "/camera", "/cameras", "/users", "/login", "/probing")


@pytest.fixture(scope="module")
def service(tmp_path_factory):
    with live_server(tmp_path_factory.mktemp("pages"), "sqlite") as srv:
        yield srv


def test_pages_have_title_and_navigation(service):
    with service.client(None) as c:
        for path in PAGES:
            r = c.get(path)
            assert r.status_code == 200 and r.headers["content-type"].startswith("text/html"), path
            html = r.text
            assert html.startswith("<!doctype html>") and "· setupcam</title>" in html
            for link in ("/machines", "/setup", "/history", "/library", "/sheet", "/rotary", "/cameras", "/users"):
                assert f'href="{link}"' in html
            assert "{{" not in html and "<!-- title:" not in html


def test_setup_page_has_the_automation_ids(service):
    with service.client(None) as c:
        html = c.get("/setup").text
    for tid in ("machine-select", "part-select", "capture-button", "upload-input", "progress", "overlay-image",
                "viewer-frame", "offset-x", "offset-y", "offset-z", "offset-c", "uncertainty", "status-message",
                "refine-button", "confirm-button", "export-button", "export-status"):
        assert f'data-testid="{tid}"' in html, tid


def test_library_page_has_the_teach_from_camera_form(service):
    with service.client(None) as c:
        html = c.get("/library").text
        js = c.get("/static/library.js").text
    for tid in ("teach-form", "teach-machine", "teach-name", "teach-kind", "teach-height", "teach-pictures",
                "teach-grab", "teach-submit", "teach-message", "teach-picture"):
        assert f'data-testid="{tid}"' in html, tid
    assert "/api/v1/models/photo" in js and "T_obj_datum" in js


def test_static_files_and_no_way_out(service):
    with service.client(None) as c:
        assert c.get("/static/app.css").headers["content-type"].startswith("text/css")
        assert c.get("/static/setup.js").headers["content-type"].startswith("text/javascript")
        for bad in ("/static/../../app/config.py", "/static/%2e%2e/%2e%2e/pyproject.toml", "/static/nothing.js"):
            assert c.get(bad).status_code == 404, bad


def test_viewer_needs_sign_in(service):
    with service.client(None) as c:
        r = c.get("/viewer/setup/1/")
        assert r.status_code == 401 and "Sign in" in r.text
    with service.client("operator") as c:
        r = c.get("/viewer/setup/1/")
        assert r.status_code == 200 and len(r.text) > 100_000   # viser's self-contained client
        assert c.get("/viewer/other/1/").status_code == 422


def test_api_docs_load_only_from_the_service(service):
    """/docs and /redoc reference no outside address; their bundles come from /docs-assets/ only."""
    import re

    with service.client(None) as c:
        for path in ("/docs", "/redoc"):
            html = c.get(path).text
            refs = re.findall(r'(?:src|href|spec-url|data-openapi)="([^"]+)"', html)
            assert refs and all(r.startswith("/") for r in refs), (path, refs)
        for name, kind in (("swagger-ui-bundle.js", "text/javascript"), ("redoc.standalone.js", "text/javascript"),
                           ("swagger-ui.css", "text/css")):
            r = c.get(f"/docs-assets/{name}")
            assert r.status_code == 200 and r.headers["content-type"].startswith(kind) and len(r.content) > 100_000
        assert c.get("/docs-assets/core.py").status_code == 404          # package code is not served
        assert c.get("/docs-assets/..%2F__init__.py").status_code == 404


def test_probing_page_has_the_automation_ids(service):
    with service.client(None) as c:
        html = c.get("/probing").text
        assert c.get("/static/probing.js").status_code == 200 and c.get("/static/probing.css").status_code == 200
    for tid in ("probing-setup-input", "slot-select", "detour-select", "dialect-select", "clearance-input", "plan-button", "plan-svg",
                "frame-text", "refusal", "download-button", "no-go-input", "results-input", "results-upload",
                "results-button", "probe-verdict", "residual-table", "pose-before-after", "residual-chart"):
        assert f'data-testid="{tid}"' in html, tid
    with service.client(None) as c:
        assert 'data-testid="probing-link"' in c.get("/setup").text   # the setup page leads there


SCRIPT = re.compile(r"<script\b([^>]*)>(.*?)</script>", re.S | re.I)


def test_every_page_runs_only_scripts_from_static_starting_with_common_js(service):
    """One style (issue 15, item 6): no inline page script, common.js first, then the page's own file
    from /static (which must exist); each with the answer's CSP nonce."""
    with service.client(None) as c:
        for name in pages_module.PAGES:
            r = c.get(f"/{name}")
            nonce = re.search(r"'nonce-([^']+)'", r.headers["content-security-policy"]).group(1)
            scripts = SCRIPT.findall(r.text)
            srcs = []
            for attrs, body in scripts:
                assert not body.strip(), f"/{name} has an inline script: {body.strip()[:80]}"
                assert f'nonce="{nonce}"' in attrs, f"/{name}: a script without the nonce"
                src = re.search(r'src="([^"]+)"', attrs)
                assert src and src.group(1).startswith("/static/"), f"/{name}: script {attrs}"
                srcs.append(src.group(1))
            assert srcs[0] == "/static/common.js", (name, srcs)
            for src in srcs:
                assert c.get(src).status_code == 200, (name, src)


def test_page_scripts_use_the_common_helpers_and_ask_no_openapi():
    """The helpers of common.js are not declared again, and no page detects features through
    /openapi.json (the API documentation page is the one reader of the spec)."""
    static = pages_module.STATIC_DIR
    common = (static / "common.js").read_text(encoding="utf-8")
    helpers = re.findall(r"^(?:async )?function (\w+)\(", common, re.M) + ["\\$"]
    assert {"api", "say", "fmt", "el"} <= set(helpers)
    for js in sorted(static.glob("*.js")):
        if js.name == "common.js":
            continue
        text = js.read_text(encoding="utf-8")
        for h in helpers:
            again = re.search(rf"^\s*(?:(?:async )?function {h}\(|(?:const|let|var) {h} =)", text, re.M)
            assert again is None, f"{js.name} declares {h.lstrip(chr(92))} again; use the one in common.js"
        if js.name != "api-docs.js":
            assert "openapi.json" not in text, f"{js.name} asks /openapi.json"
