"""A path-planning request as plain JSON data (CLI and REST share it): parse, plan, answer.

Request (mm, degrees)::

    {"points": [[x, y, z], ...],                      # focal-plane positions, table frame
     "probe": {"working_distance_mm": 30, "clearance_mm": 5, "radius_mm": 0, "length_mm": 100},
     "obstacles": ONE OF
        {"per_move_mm": [6, 6, ...]}                  # (a) one height per move
        {"part_top_mm": 6}                            # (b) the part's highest point
        {"regions": [{"rect_mm": [x0, y0, x1, y1], "height_mm": 20, "name": "plate"},
                     {"polygon_xy_mm": [[x, y], ...], "height_mm": 5}],
         "priority": "later_wins" | "narrower_wins" | "highest", "base_height_mm": 0}   # (c)
        {"meshes": [{"mesh": <trimesh.Trimesh> | "path": "part.stl", "T_table_obj": 4x4, "name": "..."}],
         "uncertainty_mm": 0.5, "base_height_mm": 0, "cell_mm": 1}                     # (d)
     "method": "reference" | "profile",               # default "reference"
     "options": {"diagonal_down": false, "up_diagonal": false, "orthogonal": false, "box_margin_mm": 0,
                 "step_mm": 1, "detours": true},               # the last two: profile method only
     "speeds": {"x_mm_min": 10000, "y_mm_min": 10000, "z_mm_min": 5000}}

With meshes the reference uses (d) (one region per mesh, grown by uncertainty + probe radius), the
profile planner the lower of a 1 mm height grid and the un-grown hull regions; the answer then also carries the independent collision check
of the path against those meshes. Every error is a ValueError with a sentence naming the field.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from app.planning.collision import ProbeBody, Scene, check_path
from app.planning.obstacles import (
    LowestOf,
    PartTop,
    PerMoveHeights,
    Region,
    RegionMap,
    height_grid_from_meshes,
    regions_from_meshes,
)
from app.planning.path import AxisSpeeds, PlannedPath, ProbeParams, as_points, path_length_mm, path_time_s
from app.planning.profile import ProfileOptions, plan_path_profile
from app.planning.reference import ReferenceOptions, plan_path_reference

METHODS = ("reference", "profile")


def _kw(d: dict, allowed: tuple[str, ...], what: str) -> dict:
    if not isinstance(d, dict):
        raise ValueError(f"{what} must be an object, got {type(d).__name__}")
    extra = sorted(set(d) - set(allowed))
    if extra:
        raise ValueError(f"{what}: unknown field(s) {extra}; allowed: {list(allowed)}")
    return d


def parse_probe(d: dict) -> ProbeParams:
    _kw(d, ("working_distance_mm", "clearance_mm", "radius_mm", "length_mm", "lateral_margin_mm"), "probe")
    for req in ("working_distance_mm", "clearance_mm"):
        if req not in d:
            raise ValueError(f"probe: {req} is required (mm)")
    return ProbeParams(**{k: float(v) for k, v in d.items()})


def _region(d: dict, k: int) -> Region:
    _kw(d, ("rect_mm", "polygon_xy_mm", "height_mm", "name"), f"obstacles.regions[{k}]")
    if "height_mm" not in d:
        raise ValueError(f"obstacles.regions[{k}]: height_mm is required")
    name = str(d.get("name", f"region_{k}"))
    if "rect_mm" in d:
        r = [float(v) for v in d["rect_mm"]]
        if len(r) != 4:
            raise ValueError(f"obstacles.regions[{k}].rect_mm: expected [x0, y0, x1, y1], got {len(r)} numbers")
        return Region.rectangle(*r, height_mm=float(d["height_mm"]), name=name)
    if "polygon_xy_mm" in d:
        poly = tuple((float(x), float(y)) for x, y in d["polygon_xy_mm"])
        if len(poly) < 3:
            raise ValueError(f"obstacles.regions[{k}].polygon_xy_mm: need at least 3 corners")
        return Region(poly, float(d["height_mm"]), name)
    raise ValueError(f"obstacles.regions[{k}]: give rect_mm or polygon_xy_mm")


def _meshes(d: dict, base_dir: Path | None):
    meshes, poses, names = [], [], []
    for k, m in enumerate(d["meshes"]):
        _kw(m, ("mesh", "path", "T_table_obj", "name", "units"), f"obstacles.meshes[{k}]")
        if "mesh" in m:
            mesh = m["mesh"]
        elif "path" in m:
            from app.geometry.mesh import load_mesh

            p = Path(m["path"])
            if not p.is_absolute() and base_dir is not None:
                p = base_dir / p
            mesh = load_mesh(p.read_bytes(), p.name, m.get("units", "mm"))
        else:
            raise ValueError(f"obstacles.meshes[{k}]: give a mesh file path")
        if "T_table_obj" not in m:
            raise ValueError(f"obstacles.meshes[{k}]: T_table_obj (4x4, mm) is required")
        meshes.append(mesh)
        poses.append(np.asarray(m["T_table_obj"], dtype=float))
        names.append(str(m.get("name", f"mesh_{k}")))
    return meshes, poses, names


def plan_request(req: dict[str, Any], base_dir: Path | None = None) -> dict[str, Any]:
    """Plan a path for a request dict (module doc) and return the JSON-ready answer:
    the path (``PlannedPath.to_dict``) plus ``length_mm``, ``time_s`` and, with meshes, ``collision``."""
    _kw(req, ("points", "probe", "obstacles", "method", "options", "speeds"), "request")
    if "points" not in req or "probe" not in req or "obstacles" not in req:
        raise ValueError("request: points, probe and obstacles are required")
    points = as_points(req["points"])
    probe = parse_probe(req["probe"])
    method = req.get("method", "reference")
    if method not in METHODS:
        raise ValueError(f"request.method {method!r} is unknown; use one of {list(METHODS)}")
    opts = _kw(dict(req.get("options", {})), ("diagonal_down", "up_diagonal", "orthogonal", "box_margin_mm", "step_mm", "detours"),
               "options")
    speeds = AxisSpeeds(**_kw(dict(req.get("speeds", {})), ("x_mm_min", "y_mm_min", "z_mm_min"), "speeds"))
    ob = req["obstacles"]
    kinds = [k for k in ("per_move_mm", "part_top_mm", "regions", "meshes") if isinstance(ob, dict) and k in ob]
    if len(kinds) != 1:
        raise ValueError("obstacles: give exactly one of per_move_mm, part_top_mm, regions, meshes")
    scene = None
    if kinds[0] == "per_move_mm":
        _kw(ob, ("per_move_mm",), "obstacles")
        source = PerMoveHeights(tuple(float(v) for v in ob["per_move_mm"]))
        if len(source.heights_mm) != len(points) - 1:
            raise ValueError(f"obstacles.per_move_mm: {len(source.heights_mm)} heights for {len(points) - 1} moves; "
                             "give one per move")
        grid = source
    elif kinds[0] == "part_top_mm":
        _kw(ob, ("part_top_mm",), "obstacles")
        source = grid = PartTop(float(ob["part_top_mm"]))
    elif kinds[0] == "regions":
        _kw(ob, ("regions", "priority", "base_height_mm"), "obstacles")
        regions = tuple(_region(r, k) for k, r in enumerate(ob["regions"]))
        source = grid = RegionMap(regions, ob.get("priority", "later_wins"), float(ob.get("base_height_mm", 0.0)))
    else:
        _kw(ob, ("meshes", "uncertainty_mm", "base_height_mm", "cell_mm"), "obstacles")
        meshes, poses, names = _meshes(ob, base_dir)
        unc = float(ob.get("uncertainty_mm", 0.0))
        base = float(ob.get("base_height_mm", 0.0))
        source = regions_from_meshes(meshes, poses, inflate_mm=probe.radius_mm + probe.lateral_margin_mm,
                                     uncertainty_mm=unc, base_height_mm=base, names=names)
        raster = height_grid_from_meshes(meshes, poses, cell_mm=float(ob.get("cell_mm", 1.0)),
                                         uncertainty_mm=unc, base_height_mm=base)
        hulls = regions_from_meshes(meshes, poses, uncertainty_mm=unc, base_height_mm=base, names=names)
        grid = LowestOf((raster, hulls))
        scene = Scene(meshes, poses, names)
    if method == "reference":
        ro = ReferenceOptions(**{k: v for k, v in opts.items() if k not in ("step_mm", "detours")})
        path: PlannedPath = plan_path_reference(points, source, probe, ro)
    else:
        po = ProfileOptions(step_mm=float(opts.get("step_mm", 1.0)), speeds=speeds if opts.get("detours", True) else None)
        path = plan_path_profile(points, grid, probe, po)
    out = path.to_dict()
    out["length_mm"] = path_length_mm(path)
    out["time_s"] = path_time_s(path, speeds)
    if scene is not None:
        report = check_path(path, scene, ProbeBody.from_probe(probe), speeds)
        out["collision"] = {"ok": report.ok, "reason": report.reason(),
                            "hits": [{"segment": h.segment_index, "obstacle": h.obstacle} for h in report.hits]}
    return out

