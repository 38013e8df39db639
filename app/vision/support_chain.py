"""Where a workpiece can rest: the table and the support surfaces of located fixtures.

An object's pose is known relative to what carries it: a part lies on the table, on parallels, or
on parallels on the seat of a vise. Fixtures (vises, parallels, fixture plates) are located first;
their upward faces are the planes on which the workpiece is then searched. What carries the part is
not always in the library (a pair of parallels nobody modelled, a block under the part): above every
surface the search also tries risers of unknown height, on a grid fine enough for the plane search to
catch the part and the fit (height free) to settle it.

All geometry in the table frame (mm, z up, the table top at z = 0).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import trimesh
from scipy.spatial import ConvexHull

from app.geometry.support_surfaces import polygon_area_mm2
from app.geometry.transforms import transform_points


@dataclass(frozen=True)
class SupportSurface:
    """A horizontal upward face of a located object (or the table): height (table z, mm), outline in
    the table plane ((N, 2) convex hull, mm) and the object that carries it."""

    carrier: str
    height_mm: float
    outline_xy: np.ndarray
    area_mm2: float

    def extent(self, margin_mm: float) -> tuple[float, float, float, float]:
        lo = self.outline_xy.min(axis=0) - margin_mm
        hi = self.outline_xy.max(axis=0) + margin_mm
        return float(lo[0]), float(hi[0]), float(lo[1]), float(hi[1])


def support_surfaces(mesh: trimesh.Trimesh, T_table_obj: np.ndarray, carrier: str, *,
                     min_area_mm2: float = 200.0, max_normal_tilt_deg: float = 2.0,
                     merge_mm: float = 0.5) -> list[SupportSurface]:
    """Upward faces of ``mesh`` placed at ``T_table_obj``, grouped by height (within ``merge_mm``),
    each group with at least ``min_area_mm2`` of face area, highest first."""
    R, t = np.asarray(T_table_obj, float)[:3, :3], np.asarray(T_table_obj, float)[:3, 3]
    n = mesh.face_normals @ R.T
    up = n[:, 2] >= np.cos(np.radians(max_normal_tilt_deg))
    if not np.any(up):
        return []
    tri = mesh.triangles[up] @ R.T + t
    z = tri[:, :, 2].mean(axis=1)
    area = mesh.area_faces[up]
    order = np.argsort(z)
    groups: list[list[int]] = []
    for i in order:
        if groups and z[i] - z[groups[-1][-1]] <= merge_mm:
            groups[-1].append(i)
        else:
            groups.append([i])
    out = []
    for g in groups:
        a = float(area[g].sum())
        if a < min_area_mm2:
            continue
        pts = tri[g][:, :, :2].reshape(-1, 2)
        try:
            hull = pts[ConvexHull(pts).vertices]
        except Exception:  # noqa: BLE001 - degenerate (collinear) outline: keep its points
            hull = pts
        out.append(SupportSurface(carrier, float(np.average(z[g], weights=area[g])), hull, a))
    return sorted(out, key=lambda s: -s.height_mm)


def declared_surfaces(declared: list[dict], T_table_obj: np.ndarray, carrier: str) -> list[SupportSurface]:
    """Support surfaces declared with a library model (its manifest or REST entry): each a plane
    patch ``{"name", "z_mm", "outline_xy": [[x, y], ...]}`` in the model frame, placed at
    ``T_table_obj`` (a fixture stands upright, so the patch stays horizontal)."""
    out = []
    for d in declared:
        xy = np.asarray(d["outline_xy"], float).reshape(-1, 2)
        pts = transform_points(np.asarray(T_table_obj, float), np.column_stack([xy, np.full(len(xy), float(d["z_mm"]))]))
        a = polygon_area_mm2(xy)
        name = f"{carrier} {d['name']}" if d.get("name") else carrier
        out.append(SupportSurface(name, float(pts[:, 2].mean()), pts[:, :2], a))
    return sorted(out, key=lambda s: -s.height_mm)


def table_surface(extent_xy: tuple[float, float, float, float] | None = None) -> SupportSurface:
    """The table top itself (z = 0); its outline is the given extent or unbounded."""
    if extent_xy is None:
        return SupportSurface("table", 0.0, np.zeros((0, 2)), np.inf)
    x0, x1, y0, y1 = extent_xy
    return SupportSurface("table", 0.0, np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]], float),
                          (x1 - x0) * (y1 - y0))


# Risers of unknown height (parallels, blocks, a vise not in the library) under the part: 0 to 120 mm, every
# 7.5 mm on the table (the plane search catches a part up to ~5 mm off its true height, the fit
# with the height free settles it), every 5 mm on a fixture's smaller surfaces.
TABLE_RISERS_MM = tuple(np.arange(0.0, 120.0 + 1e-9, 7.5))
FIXTURE_RISERS_MM = tuple(np.arange(0.0, 40.0 + 1e-9, 5.0))


def search_planes(surfaces: list[SupportSurface], part_radius_mm: float, *,
                  table_risers=TABLE_RISERS_MM, fixture_risers=FIXTURE_RISERS_MM):
    """Heights (table z, mm) at which to search the part's resting plane, each with the table-plane
    extent to search there (None: the whole view), as ``(height, extent)`` pairs without repeats.
    A fixture's surface is searched only within its outline grown by the part's radius."""
    out: list[tuple[float, tuple | None]] = []
    seen: set = set()
    for s in surfaces:
        risers = table_risers if s.carrier == "table" else fixture_risers
        ext = None if not len(s.outline_xy) else s.extent(part_radius_mm)
        for r in risers:
            h = round(float(s.height_mm + r), 1)
            key = (h, ext if ext is None else tuple(round(v) for v in ext))
            if key in seen:
                continue
            seen.add(key)
            out.append((h, ext))
    return out


def part_search_planes(surfaces: list[SupportSurface], part_radius_mm: float, risers_mm=()) -> list:
    """Where a workpiece is searched (:func:`search_planes`): on every surface and over risers of any
    height on it (the stepped grids), the shop's declared risers' tops among them."""
    return search_planes(surfaces, part_radius_mm, table_risers=tuple(sorted({*TABLE_RISERS_MM, *risers_mm})),
                         fixture_risers=tuple(sorted({*FIXTURE_RISERS_MM, *risers_mm})))


def placed_height_above(surfaces: list[SupportSurface], T_table_obj: np.ndarray, vertices_obj: np.ndarray,
                        tol_mm: float = 1.0) -> SupportSurface | None:
    """The surface the placed part rests on: the highest one at or below the part's lowest point
    (within ``tol_mm``) whose outline holds the part's footprint centre; None if none does.
    ``vertices_obj``: the part's vertices that can rest on a surface (obj frame, mm;
    :attr:`app.geometry.model_edges.PreparedModel.support_vertices`)."""
    V = transform_points(T_table_obj, np.asarray(vertices_obj, dtype=float))
    zmin = float(V[:, 2].min())
    c = V[:, :2].mean(axis=0)
    best = None
    for s in surfaces:
        if s.height_mm > zmin + tol_mm:
            continue
        if len(s.outline_xy) >= 3:
            lo, hi = s.outline_xy.min(axis=0), s.outline_xy.max(axis=0)
            if not (np.all(c >= lo - 1.0) and np.all(c <= hi + 1.0)):
                continue
        if best is None or s.height_mm > best.height_mm:
            best = s
    return best


def share_of_base_within(extent_xy: tuple[float, float, float, float], T_table_obj: np.ndarray,
                         vertices_obj: np.ndarray, n_grid: int = 41) -> float:
    """Share (0..1) of the placed part's base (the convex hull of its vertices within 0.5 mm of its
    lowest point, seen from above) that lies within ``extent_xy`` (x_lo, x_hi, y_lo, y_hi, mm, table
    frame): measured on an ``n_grid`` x ``n_grid`` grid over the base's box. A base without area (a
    point, an edge) counts as its points: 1.0 if they all lie within. ``vertices_obj``: as in
    :func:`placed_height_above`."""
    V = transform_points(T_table_obj, np.asarray(vertices_obj, dtype=float))
    base = V[V[:, 2] <= V[:, 2].min() + 0.5, :2]
    x0, x1, y0, y1 = extent_xy
    lo, hi = base.min(axis=0), base.max(axis=0)
    try:
        hull = ConvexHull(base)
    except Exception:   # noqa: BLE001 - flat or too few points: no area to share
        inside = (base[:, 0] >= x0) & (base[:, 0] <= x1) & (base[:, 1] >= y0) & (base[:, 1] <= y1)
        return float(inside.all())
    gx, gy = np.meshgrid(np.linspace(lo[0], hi[0], n_grid), np.linspace(lo[1], hi[1], n_grid))
    G = np.column_stack([gx.ravel(), gy.ravel()])
    G = G[np.all(G @ hull.equations[:, :2].T + hull.equations[:, 2] <= 1e-6, axis=1)]
    if not len(G):
        return 1.0
    return float(np.mean((G[:, 0] >= x0) & (G[:, 0] <= x1) & (G[:, 1] >= y0) & (G[:, 1] <= y1)))
