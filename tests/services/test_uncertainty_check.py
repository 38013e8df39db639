"""The gate's reason says what a sigma too large to pass is mostly made of (services.setups.uncertainty_check)."""

from __future__ import annotations

import numpy as np

from app.services.setup_result import LocatedObject
from app.services.setups import uncertainty_check


def _obj(image_mm2: float, table_mm2: float, intrinsics_mm2: float, **extra) -> LocatedObject:
    """A workpiece whose x variance (mm^2) is made of the image fit's, the table's and the intrinsics'
    shares, y and z far inside the tolerance."""
    def cov(v: float) -> list:
        return np.diag([v, 1e-4, 1e-4, 0.0, 0.0, 1e-8]).tolist()
    total = image_mm2 + table_mm2 + intrinsics_mm2
    return LocatedObject(name="block", T_table_obj=np.eye(4).tolist(),
                         sigma={"x_mm": float(np.sqrt(total)), "y_mm": 0.01, "z_mm": 0.01, "rz_deg": 0.001},
                         cov6=cov(total), cov6_table=cov(table_mm2 + intrinsics_mm2),
                         cov6_intrinsics=cov(intrinsics_mm2),
                         **extra)


def test_a_sigma_made_of_the_calibration_says_so():
    ok, why = uncertainty_check(_obj(0.01, 0.005, 0.07), max_sigma_mm=0.2, max_sigma_deg=0.1)
    assert not ok
    assert why.startswith("x ±0.292 mm > 0.2 mm; mostly the camera's calibration (82 % of its variance): if its ")
    assert "(0.4 % and 3 px where none is stated), state it in the camera" in why


def test_the_largest_share_is_named_only_when_it_is_most_of_it():
    ok, why = uncertainty_check(_obj(0.06, 0.005, 0.01), 0.2, 0.1)
    assert not ok and "; mostly the part's own edges in the picture (80 % of its variance): a closer" in why
    ok, why = uncertainty_check(_obj(0.02, 0.02, 0.02), 0.2, 0.1)     # a third each: no source named
    assert not ok and why == "x ±0.245 mm > 0.2 mm"
    ok, why = uncertainty_check(_obj(0.01, 0.01, 0.01), 0.2, 0.1)     # passes: nothing to say
    assert ok and why == ""


def test_a_result_without_its_covariances_gives_the_plain_reason():
    obj = LocatedObject(name="block", T_table_obj=np.eye(4).tolist(),
                        sigma={"x_mm": 0.3, "y_mm": 0.01, "z_mm": 0.01, "rz_deg": 0.2})
    ok, why = uncertainty_check(obj, 0.2, 0.1)
    assert not ok and why == "x ±0.300 mm > 0.2 mm; C ±0.200° > 0.1°"
