"""/docs and /redoc render in a real headless Chromium with every request that leaves the machine cut off.

The browser context aborts any request whose host is not 127.0.0.1 (and records it): Swagger UI and
ReDoc must come from setupcam itself. The test then looks for what a reader sees: the operation list
in Swagger UI (and an operation opened), the operation summaries in ReDoc.
"""

from __future__ import annotations

import urllib.parse

import pytest

from tests.support.browser import ARTIFACTS, CHROMIUM, skip_without_chromium
from tests.support.live_server import live_server

pytestmark = pytest.mark.integration

skip_without_chromium()


@pytest.fixture(scope="module")
def service(tmp_path_factory):
    with live_server(tmp_path_factory.mktemp("docs"), "sqlite", load_example_library=False) as srv:
        yield srv


@pytest.fixture()
def offline_page(service):
    """(page, requests that tried to leave the machine, JS errors) with the network cut off."""
    from playwright.sync_api import sync_playwright

    ARTIFACTS.mkdir(exist_ok=True)
    with sync_playwright() as p:
        # --no-proxy-server / no DNS: even a request that slipped past the route could not get out.
        browser = p.chromium.launch(executable_path=str(CHROMIUM), headless=True,
                                    args=["--disable-gpu", "--no-proxy-server",
                                          "--host-resolver-rules=MAP * ~NOTFOUND, EXCLUDE 127.0.0.1"])
        try:
            ctx = browser.new_context(viewport={"width": 1280, "height": 900})
            outside: list[str] = []

            def cut_off(route):
                host = urllib.parse.urlsplit(route.request.url).hostname
                if host in ("127.0.0.1", "localhost"):
                    route.continue_()
                else:
                    outside.append(route.request.url)
                    route.abort("internetdisconnected")

            ctx.route("**/*", cut_off)
            page = ctx.new_page()
            errors: list[str] = []
            page.on("pageerror", lambda e: errors.append(str(e)))
            yield page, outside, errors
        finally:
            browser.close()


def test_swagger_ui_renders_offline(service, offline_page):
    page, outside, errors = offline_page
    page.goto(f"{service.url}/docs")
    # Swagger UI builds one block per operation; the health check is one of them.
    health = page.locator("#operations-health-health-health")
    health.wait_for(timeout=30_000)
    assert page.locator(".opblock").count() > 20
    assert page.locator(".info .title").inner_text().startswith("setupcam")
    health.locator(".opblock-summary").click()   # open it: the response schema renders
    page.get_by_text("database_backend").first.wait_for(timeout=10_000)
    page.screenshot(path=str(ARTIFACTS / "docs-offline.png"))
    assert outside == [], f"/docs tried to reach the internet: {outside}"
    assert errors == []


def test_redoc_renders_offline(service, offline_page):
    page, outside, errors = offline_page
    page.goto(f"{service.url}/redoc")
    # Each operation gets a heading in the main column (the side menu keeps its copy folded).
    page.locator("h2", has_text="Service, database and worker status").wait_for(timeout=30_000)
    assert page.locator("h1").first.inner_text().startswith("setupcam")
    page.screenshot(path=str(ARTIFACTS / "redoc-offline.png"))
    assert outside == [], f"/redoc tried to reach the internet: {outside}"
    assert errors == []
