"""Shared test fixtures.

Real outside data lives in ``../shared/data/external`` beside the checkout (CI has it too); tests read
it from there and never copy it into the repo.
"""

from __future__ import annotations

from pathlib import Path

import pytest

REPO_ROOT = Path(__file__).resolve().parent.parent
EXTERNAL_DATA = (REPO_ROOT.parent / "shared" / "data" / "external").resolve()


@pytest.fixture(scope="session")
def external_data() -> Path:
    """Folder of real third-party data (calibration images, CAD parts); see its SOURCES.md."""
    if not EXTERNAL_DATA.is_dir():
        pytest.fail(f"external test data missing: expected {EXTERNAL_DATA} (../shared beside the clone)")
    return EXTERNAL_DATA
