"""Headless Chromium for the page tests: Debian's /usr/bin/chromium driven by Playwright (never a
downloaded browser), and a page signed in as a test user of a live server."""

from __future__ import annotations

from contextlib import contextmanager
from pathlib import Path

import pytest

CHROMIUM = Path("/usr/bin/chromium")
ARTIFACTS = Path(__file__).resolve().parents[2] / "test-artifacts"   # screenshots, kept by CI


def skip_without_chromium() -> None:
    """Call at module level of a page test."""
    if not CHROMIUM.exists():
        pytest.skip("Debian package chromium is not installed (scripts/apt-packages.txt)", allow_module_level=True)


@contextmanager
def signed_in_page(srv, role: str = "operator", viewport: tuple[int, int] = (1280, 800)):
    """(page, JS errors seen) of a fresh browser whose session cookie is ``role``'s on ``srv``."""
    from playwright.sync_api import sync_playwright

    ARTIFACTS.mkdir(exist_ok=True)
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=str(CHROMIUM), headless=True, args=["--disable-gpu"])
        try:
            ctx = browser.new_context(viewport={"width": viewport[0], "height": viewport[1]})
            ctx.add_cookies([{"name": "setupcam_session", "value": srv.tokens[role], "url": srv.url}])
            page = ctx.new_page()
            errors: list[str] = []
            page.on("pageerror", lambda e: errors.append(str(e)))
            yield page, errors
        finally:
            browser.close()


def upload_photo(page, files) -> None:
    """Put a photo into the setup page's upload input once an operator could: the input stays disabled
    until the machines are listed, and Playwright sets files on a disabled input all the same (the page
    then says "Choose the machine first" and nothing is started). ``files`` is what
    ``set_input_files`` takes."""
    page.wait_for_selector("[data-testid=upload-input]:enabled", timeout=30_000)
    page.get_by_test_id("upload-input").set_input_files(files)
