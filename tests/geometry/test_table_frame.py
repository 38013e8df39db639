"""T_machine_table from jogged points: the angle from either edge, both edges weighted, and refusals."""

from __future__ import annotations

import math

import numpy as np
import pytest

from app.geometry.table_figure import table_figure_svg
from app.geometry.table_frame import TableFrameError, table_frame_from_points

CORNER = np.array([120.0, -80.0, -300.0])


def _along(c_deg: float, span: float, turn: float = 0.0) -> np.ndarray:
    a = math.radians(c_deg + turn)
    return CORNER[:2] + span * np.array([math.cos(a), math.sin(a)])


@pytest.mark.parametrize("c_deg", [0.0, 12.25, -30.0, 179.5, -179.5])
def test_either_edge_gives_c_and_the_corner_gives_the_origin(c_deg):
    cases = ((table_frame_from_points(CORNER, x_point=_along(c_deg, 500)), [500, 0, 0, 1], _along(c_deg, 500)),
             (table_frame_from_points(CORNER, y_point=_along(c_deg, 300, turn=90.0)), [0, 300, 0, 1],
              _along(c_deg, 300, turn=90.0)))
    for fit, table_point, jogged in cases:
        assert fit.c_deg == pytest.approx(c_deg, abs=1e-9)
        assert fit.T_machine_table[:3, 3] == pytest.approx(CORNER)
        # the table point lands where the edge point was jogged
        assert (fit.T_machine_table @ table_point)[:2] == pytest.approx(jogged)


def test_two_edges_are_weighted_by_their_span_squared():
    # the x edge says 2.00°, the y edge 2.10° over half the span: 4:1 weights
    fit = table_frame_from_points(CORNER, x_point=_along(2.0, 600), y_point=_along(2.1, 300, turn=90.0))
    assert fit.c_deg == pytest.approx((4 * 2.0 + 1 * 2.1) / 5, abs=1e-9)
    assert fit.edge_disagreement_deg == pytest.approx(0.1, abs=1e-9)
    assert fit.c_sensitivity_deg_per_mm == pytest.approx(math.degrees(1 / math.hypot(600, 300)))


def test_typed_c_is_kept_only_without_edge_points():
    assert table_frame_from_points(CORNER, c_deg=7.0).c_deg == 7.0
    assert table_frame_from_points(CORNER, x_point=_along(3.0, 400), c_deg=7.0).c_deg == pytest.approx(3.0)
    assert table_frame_from_points(CORNER).c_deg == 0.0


@pytest.mark.parametrize("kwargs,why", [
    ({"x_point": _along(0, 20)}, "is 20.0 mm from the corner"),
    ({"x_point": _along(0, 500), "y_point": _along(0, 300)}, "Is point 3 on the left edge"),   # y point on the x edge
    ({"x_point": [1.0, float("nan")]}, "give X and Y"),
])
def test_bad_points_are_refused_with_the_reason(kwargs, why):
    with pytest.raises(TableFrameError, match=why):
        table_frame_from_points(CORNER, **kwargs)
    with pytest.raises(TableFrameError, match="give X, Y and Z"):
        table_frame_from_points(CORNER[:2])


def test_the_picture_puts_the_outline_and_points_where_the_pose_says():
    fit = table_frame_from_points(CORNER, x_point=_along(10.0, 500))
    svg = table_figure_svg((0, 0, -50), (800, 400, 0), fit.T_machine_table, markers=[(3, (40, 30), 40)],
                           points=[("1", CORNER[:2]), ("2", _along(10.0, 500))], title="T <&> table")
    assert svg.count('class="jog-point"') == 2 and 'data-id="3"' in svg
    assert "T &lt;&amp;&gt; table" in svg                 # names are escaped
    assert "C 10.0000°" in svg
