"""Support surfaces of located fixtures and the planes the workpiece is searched on."""

from __future__ import annotations

import numpy as np
import trimesh

from app.geometry.transforms import make_pose
from app.vision.support_chain import (FIXTURE_RISERS_MM, TABLE_RISERS_MM, placed_height_above, search_planes,
                                      share_of_base_within,
                                      support_surfaces, table_surface)


def _vise_like() -> trimesh.Trimesh:
    """A base 200 x 100 x 70 with two jaws 20 mm wide rising to 105 (CAD z up, base at z = 0)."""
    base = trimesh.creation.box(bounds=[[0, 0, 0], [200, 100, 70]])
    jaw1 = trimesh.creation.box(bounds=[[0, 0, 70], [20, 100, 105]])
    jaw2 = trimesh.creation.box(bounds=[[180, 0, 70], [200, 100, 105]])
    return trimesh.util.concatenate([base, jaw1, jaw2])


def test_support_surfaces_are_the_upward_faces_at_their_heights_in_the_table_frame():
    T = make_pose(np.array([[0.0, -1, 0], [1, 0, 0], [0, 0, 1]]), [300.0, 100.0, 0.0])   # turned 90 deg
    surf = support_surfaces(_vise_like(), T, "vise")
    heights = [round(s.height_mm, 3) for s in surf]
    assert heights == [105.0, 70.0]
    seat = surf[1]
    # the seat (and the faces under the jaws, same height) spans the base: x 200..300, y 100..300
    lo, hi = seat.outline_xy.min(axis=0), seat.outline_xy.max(axis=0)
    np.testing.assert_allclose(lo, [200.0, 100.0], atol=1e-6)
    np.testing.assert_allclose(hi, [300.0, 300.0], atol=1e-6)
    assert seat.extent(10.0) == (190.0, 310.0, 90.0, 310.0)


def test_search_planes_cover_risers_above_each_surface_within_its_outline():
    surf = [table_surface()] + support_surfaces(_vise_like(), np.eye(4), "vise")
    planes = search_planes(surf, part_radius_mm=30.0)
    table_h = [h for h, ext in planes if ext is None]
    assert table_h == [round(r, 1) for r in TABLE_RISERS_MM]
    seat_h = sorted(h for h, ext in planes if ext is not None)
    assert {round(70.0 + r, 1) for r in FIXTURE_RISERS_MM} <= set(seat_h)
    ext = next(ext for h, ext in planes if h == 70.0 and ext is not None)
    assert ext == (-30.0, 230.0, -30.0, 130.0)
    assert len(planes) == len({(h, ext) for h, ext in planes})          # no plane twice


def test_the_carrier_is_the_highest_surface_under_the_part():
    surf = [table_surface()] + support_surfaces(_vise_like(), np.eye(4), "vise")
    part = trimesh.creation.box(bounds=[[0, 0, 0], [60, 40, 30]])
    on_seat = make_pose(None, [70.0, 30.0, 70.0])
    assert placed_height_above(surf, on_seat, part.vertices).carrier == "vise"
    on_riser = make_pose(None, [70.0, 30.0, 92.0])                          # 22 mm above the seat
    s = placed_height_above(surf, on_riser, part.vertices)
    assert s.carrier == "vise" and s.height_mm == 70.0
    beside = make_pose(None, [400.0, 30.0, 0.0])
    assert placed_height_above(surf, beside, part.vertices).carrier == "table"


def test_the_share_of_a_base_over_the_table_top():
    """A 460 x 220 mm box on an 800 x 400 mm table top: all of its base over it in the middle, 30 % off
    where it stands 138 mm over the end, its base turned 90 deg over a corner a quarter on; an upright
    cylinder's round base likewise; a base without area (a knife edge) is on or off."""
    box = trimesh.creation.box((460.0, 220.0, 130.0))
    box.apply_translation([0.0, 0.0, 65.0])
    top = (0.0, 800.0, 0.0, 400.0)
    assert share_of_base_within(top, make_pose(np.eye(3), [400.0, 200.0, 0.0]), box.vertices) == 1.0
    over_end = share_of_base_within(top, make_pose(np.eye(3), [92.0, 200.0, 0.0]), box.vertices)
    assert abs(over_end - 0.7) < 0.03, over_end
    turned = make_pose(np.array([[0.0, -1, 0], [1, 0, 0], [0, 0, 1]]), [800.0, 400.0, 0.0])
    assert abs(share_of_base_within(top, turned, box.vertices) - 0.25) < 0.03
    cyl = trimesh.creation.cylinder(radius=50.0, height=40.0, sections=64)
    cyl.apply_translation([0.0, 0.0, 20.0])
    assert abs(share_of_base_within(top, make_pose(np.eye(3), [0.0, 200.0, 0.0]), cyl.vertices) - 0.5) < 0.03
    knife = np.array([[-50.0, 0, 0], [50, 0, 0], [0, -10, 30], [0, 10, 30]])
    assert share_of_base_within(top, make_pose(np.eye(3), [400.0, 200.0, 0.0]), knife) == 1.0
    assert share_of_base_within(top, make_pose(np.eye(3), [20.0, 200.0, 0.0]), knife) == 0.0
