"""Target description: validation messages, true-scale SVG and PDF."""

from __future__ import annotations

import re

import pytest

from app.vision.printables import target_pdf, target_svg
from app.vision.rotary_target import TargetError, default_target, target_from_dict


def _square(r=(10.0, 6.0), d=40.0):
    return {"groups": [{"center_mm": [x, y], "circle_radii_mm": list(r)}
                       for x, y in [(d, d), (-d, d), (-d, -d), (d, -d)]]}


def test_valid_target_sorts_radii_and_round_trips():
    t = target_from_dict({**_square(r=(6.0, 10.0)), "mark_mm": [0, 20]})
    assert t.groups[0].circle_radii_mm == (10.0, 6.0)
    assert target_from_dict(t.to_dict()) == t


@pytest.mark.parametrize("data, match", [
    ({"groups": _square()["groups"][:3]}, "at least 4 circle groups"),
    ({**_square(d=8.0)}, "groups 0 and 1 overlap"),
    ({**_square(r=(10.0, 9.8))}, "0.200 mm apart"),
    ({**_square(r=(10.0, -1.0))}, "positive numbers"),
    ({**_square(), "mark_mm": [40, 45]}, "mark_mm .* touches group 0"),
    ({**_square(), "colour": "red"}, "unknown keys"),
    ({"groups": [{"center_mm": [x, 0], "circle_radii_mm": [5]} for x in (0, 20, 40, 60)]}, "collinear"),
    ({**_square(), "disc_radius_mm": 30}, "smaller than the printed layout"),
    ([1, 2], "JSON object"),
])
def test_bad_targets_are_refused_with_a_reason(data, match):
    with pytest.raises(TargetError, match=match):
        target_from_dict(data)


def test_svg_is_true_scale():
    t = default_target()
    svg = target_svg(t, margin_mm=10.0)
    side = 2 * (t.extent_mm() + 10.0)
    assert f'width="{side:.3f}mm"' in svg and f'height="{side:.3f}mm"' in svg
    assert f'viewBox="{-side / 2:.4f} {-side / 2:.4f} {side:.4f} {side:.4f}"' in svg
    radii = sorted({float(r) for r in re.findall(r'<circle cx="[-0-9.]+" cy="[-0-9.]+" r="([0-9.]+)" fill', svg)})
    want = {t.mark_radius_mm, t.disc_radius_mm} | {r for g in t.groups for r in g.circle_radii_mm}
    assert radii == sorted(want)  # mark, every group edge, disc outline


def test_pdf_page_is_true_scale():
    t = default_target()
    pdf = target_pdf(t, margin_mm=10.0)
    assert pdf.startswith(b"%PDF")
    side_pt = 2 * (t.extent_mm() + 10.0) / 25.4 * 72.0
    box = re.search(rb"/MediaBox \[\s*0 0 ([0-9.]+) ([0-9.]+)\s*\]", pdf)
    assert box is not None
    assert float(box.group(1)) == pytest.approx(side_pt, abs=0.01)
    assert float(box.group(2)) == pytest.approx(side_pt, abs=0.01)
