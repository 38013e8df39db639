"""Scenes of the independent devset (``shared/data/devset``, another renderer than ours) in the shape
our localisation takes: intrinsics, the table's fiducial layout, the table model, the fixtures as
library candidates and the ground truth. Read from its folder, never copied into the repository.

Format (the devset's README): millimetres, ``T_a_b`` maps b into a, OpenCV camera frame; the table
frame's origin is the front-left top corner of its 800 x 400 T-slot table, z up.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path

import numpy as np
import trimesh

from app.vision.localize import Candidate

# The fixtures a shop with the devset's machines keeps in its library: the vise (body with the fixed
# jaw, and the moving jaw) and its parallels. Parallels under a part standing on the table are not
# listed: the engine searches free height for supports it does not know.
FIXTURES = (("vise_body", "clamp"), ("vise_jaw", "clamp"))
# What the admin declares for the devset's vise (read off its mesh once, as for any library vise):
# the seat between the jaws at z 70, where parts stand on parallels. The moving jaw carries nothing.
SUPPORT_SURFACES = {
    "vise_body": [{"name": "seat", "z_mm": 70.0, "outline_xy": [[-150, -60], [100, -60], [100, 60], [-150, 60]]}],
    "vise_jaw": [],
}

# The moving jaw rides on the body's guide ways (its frame on the ways' top at z 70 in the body frame,
# same rotation) and slides along the body's x axis: from its back against the ways' rear end
# (x -150, the jaw 55 mm long: -95) to its face against the fixed jaw (x 100). Read off the meshes once.
GUIDES = {
    "vise_jaw": {"carrier": "vise_body", "T_carrier_obj": [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 70], [0, 0, 0, 1]],
                 "axis": [1, 0, 0], "travel_mm": [-95, 100]},
}


@lru_cache(maxsize=64)
def _mesh(path: str) -> trimesh.Trimesh:
    return trimesh.load(path, force="mesh")


@dataclass
class DevsetScene:
    gt: dict
    K: np.ndarray
    dist: np.ndarray
    layout: dict
    workpiece: dict                                        # the ground-truth object entry
    table_candidate: Candidate
    fixture_candidates: list[Candidate] = field(default_factory=list)


def devset_scene(root: Path, entry: dict, fixtures=FIXTURES, guides: dict | None = None) -> DevsetScene:
    """The scene of a manifest entry (``manifest.json`` -> families -> setup/moved). ``guides``: the
    fixtures' guides by name (None: :data:`GUIDES`; ``{}``: every fixture stands free)."""
    guides = GUIDES if guides is None else guides
    root = Path(root)
    gt = json.loads((root / entry["gt"]).read_text())
    cam = gt["camera"]
    layout = json.loads((root / gt["marker_layout"]).read_text()) if isinstance(gt["marker_layout"], str) \
        else gt["marker_layout"]
    wp = next(o for o in gt["objects"] if o["kind"] == "workpiece")
    wp = dict(wp, name=entry.get("workpiece", wp.get("subtype", "workpiece")))
    table = Candidate("table", _mesh(str(root / "meshes" / "table_800x400_tslot.stl")), kind="table")
    fx = [Candidate(name, _mesh(str(root / "meshes" / f"{name}.stl")), kind=kind,
                    support_surfaces=SUPPORT_SURFACES.get(name), guide=guides.get(name)) for name, kind in fixtures]
    return DevsetScene(gt=gt, K=np.asarray(cam["K"], float), dist=np.asarray(cam["dist"], float).ravel(),
                       layout=layout, workpiece=wp, table_candidate=table, fixture_candidates=fx)
