"""The operator pages and the viewer relay over HTTP (no browser): every page served with its
navigation, static files confined to frontend/static, the 3D view only for signed-in users."""

from __future__ import annotations

import pytest

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
    for tid in ("probing-setup-input", "slot-select", "dialect-select", "clearance-input", "plan-button", "plan-svg",
                "frame-text", "refusal", "download-button", "no-go-input", "results-input", "results-upload",
                "results-button", "probe-verdict", "residual-table", "pose-before-after", "residual-chart"):
        assert f'data-testid="{tid}"' in html, tid
    with service.client(None) as c:
        assert 'data-testid="probing-link"' in c.get("/setup").text   # the setup page leads there
