"""The shop's declared risers (app.vision.localize.riser_heights): the heights a part over a riser of
unknown height is tested against."""

from __future__ import annotations

import trimesh

from app.vision.localize import Candidate, riser_heights


def test_riser_heights_come_from_the_supports_among_the_candidates():
    par = trimesh.creation.box(bounds=[[-75.0, -4.0, 0.0], [75.0, 4.0, 25.0]])
    block = trimesh.creation.box(bounds=[[0.0, 0.0, -5.0], [40.0, 40.0, 27.5]])     # frame not on its base
    cands = [Candidate("part", trimesh.creation.box((50.0, 50.0, 50.0))),             # a workpiece: not a riser
             Candidate("vise", trimesh.creation.box((100.0, 100.0, 90.0)), kind="clamp"),
             Candidate("parallel_150x25", par, kind="support"),
             Candidate("parallel_150x25_again", par.copy(), kind="support"),
             Candidate("block", block, kind="support",
                       support_surfaces=[{"name": "top", "z_mm": 27.5, "outline_xy": [[0, 0], [40, 0], [40, 40]]}])]
    assert riser_heights(cands) == (25.0, 32.5)           # each height once, above each support's base
    assert riser_heights(cands[:2]) == ()
