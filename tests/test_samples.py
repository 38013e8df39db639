"""samples/ is what scripts/make_sample.py renders: the intrinsics and the ground truth are the script's,
and the photo is the script's picture (compared after decoding, so a different JPEG library may differ
by a grey level here and there). The README of samples/ names the intrinsics file."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import cv2
import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[1]
SAMPLES = REPO / "samples"

pytestmark = pytest.mark.slow


def _script():
    spec = importlib.util.spec_from_file_location("make_sample", REPO / "scripts" / "make_sample.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_committed_sample_is_the_scripts_rendering():
    from app.resources import bundled_dir

    jpeg, intrinsics, truth = _script().render(bundled_dir("models_library"))
    assert json.loads((SAMPLES / "camera-intrinsics.json").read_text()) == intrinsics
    assert json.loads((SAMPLES / "bracket_on_table.truth.json").read_text()) == truth
    committed = cv2.imread(str(SAMPLES / "bracket_on_table.jpg"), cv2.IMREAD_GRAYSCALE)
    fresh = cv2.imdecode(np.frombuffer(jpeg, np.uint8), cv2.IMREAD_GRAYSCALE)
    assert committed.shape == fresh.shape == (intrinsics["height"], intrinsics["width"])
    assert np.abs(committed.astype(int) - fresh.astype(int)).mean() < 1.0
    assert (SAMPLES / "bracket_on_table.jpg").stat().st_size < 400_000
    assert "`camera-intrinsics.json`" in (SAMPLES / "README.md").read_text()
