"""Where the obstacles are: the four sources of obstacle heights and the queries the planners use.

All heights are z of an obstacle's top in mm, in the planning frame (table frame, z up); all xy in mm.

Sources (the reference method's (a)-(d), plus a raster for the profile planner):

* :class:`PerMoveHeights` - (a) one obstacle height typed in per move.
* :class:`PartTop`        - (b) one height for every move: the part's highest point
  (:func:`part_top_from_meshes` reads it from located meshes).
* :class:`RegionMap`      - (c) regions (rectangles / polygons) each with a height. Where regions
  overlap a priority rule decides which height holds: ``"later_wins"`` (the region entered later),
  ``"narrower_wins"`` (a region contained in another, or else the narrower one, wins; see
  :func:`priority_order`) or ``"highest"`` (the maximum; used for regions made from meshes).
  (d) :func:`regions_from_meshes` builds such a map from the located scene's meshes, each
  footprint inflated sideways and its top raised by the given margins.
* :class:`HeightGrid`     - a raster upper bound of the scene's height, made from meshes by
  :func:`height_grid_from_meshes`; used by the profile planner.

Every source answers two questions (the :class:`ObstacleSource` protocol):

* ``box_max_mm(i, a_xy, b_xy, margin_mm)`` - highest point in the axis-aligned box spanned by the
  xy of start ``a`` and target ``b`` of move ``i``, the box grown by ``margin_mm`` on every side
  (the reference's obstacle height; margin 0 is the reference exactly).
* ``profile_mm(i, a_xy, b_xy, radius_mm, n_steps)`` - (n_steps,) highest point within
  ``radius_mm`` of the straight xy segment, per equal step along it: value k bounds every point of
  the capsule around the k-th step (the profile planner's input).

Sources with geometry (RegionMap, HeightGrid, LowestOf) also answer ``blocked_xy(level_mm,
radius_mm)``: a shapely geometry that contains every xy position where something higher than
``level_mm`` lies within ``radius_mm`` (the profile planner's detours go around it).
:class:`LowestOf` combines upper bounds (e.g. a raster and hull regions of the same meshes): the
lower of two upper bounds is still an upper bound, and tighter than either.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property
from typing import Literal, Protocol, Sequence

import cv2
import numpy as np
import shapely
import trimesh
from numpy.typing import ArrayLike
from shapely.geometry import MultiPoint, Polygon
from shapely.geometry import box as shapely_box

from app.geometry.transforms import check_pose, transform_points

PriorityRule = Literal["later_wins", "narrower_wins", "highest"]
PRIORITY_RULES = ("later_wins", "narrower_wins", "highest")


class ObstacleSource(Protocol):
    def box_max_mm(self, move_index: int, a_xy: ArrayLike, b_xy: ArrayLike, margin_mm: float = 0.0) -> float: ...

    def profile_mm(
        self, move_index: int, a_xy: ArrayLike, b_xy: ArrayLike, radius_mm: float, n_steps: int
    ) -> np.ndarray: ...


def step_centers(a_xy: ArrayLike, b_xy: ArrayLike, n_steps: int) -> tuple[np.ndarray, float]:
    """Centres (n_steps, 2) of n equal steps along segment a->b and the step length in mm."""
    a = np.asarray(a_xy, dtype=float)[:2]
    b = np.asarray(b_xy, dtype=float)[:2]
    t = (np.arange(n_steps) + 0.5) / n_steps
    return a + t[:, None] * (b - a), float(np.linalg.norm(b - a)) / n_steps


def _box(a_xy: ArrayLike, b_xy: ArrayLike, margin_mm: float):
    """Shapely geometry of the xy box spanned by a and b (a point or line when degenerate), grown."""
    a = np.asarray(a_xy, dtype=float)[:2]
    b = np.asarray(b_xy, dtype=float)[:2]
    g = MultiPoint([tuple(a), tuple(b)]).envelope
    if margin_mm > 0:
        lo, hi = np.minimum(a, b) - margin_mm, np.maximum(a, b) + margin_mm
        g = shapely_box(lo[0], lo[1], hi[0], hi[1])
    return g


# ---------------------------------------------------------------------------------------- (a), (b)


@dataclass(frozen=True)
class PerMoveHeights:
    """(a) One obstacle height per move (mm), typed in by the user; move i goes from point i to i+1."""

    heights_mm: tuple[float, ...]

    def _h(self, i: int) -> float:
        if not 0 <= i < len(self.heights_mm):
            raise ValueError(
                f"no obstacle height for move {i}: {len(self.heights_mm)} heights given; "
                "give one height per move (number of points - 1)"
            )
        return float(self.heights_mm[i])

    def box_max_mm(self, move_index, a_xy, b_xy, margin_mm=0.0) -> float:
        return self._h(move_index)

    def profile_mm(self, move_index, a_xy, b_xy, radius_mm, n_steps) -> np.ndarray:
        return np.full(n_steps, self._h(move_index))


@dataclass(frozen=True)
class PartTop:
    """(b) The part's highest point (mm) as the obstacle height of every move."""

    height_mm: float

    def box_max_mm(self, move_index, a_xy, b_xy, margin_mm=0.0) -> float:
        return float(self.height_mm)

    def profile_mm(self, move_index, a_xy, b_xy, radius_mm, n_steps) -> np.ndarray:
        return np.full(n_steps, float(self.height_mm))


def _posed_vertices(meshes: Sequence[trimesh.Trimesh], poses: Sequence[ArrayLike]) -> list[np.ndarray]:
    if len(meshes) != len(poses):
        raise ValueError(f"{len(meshes)} meshes but {len(poses)} poses T_table_obj; give one pose per mesh")
    return [
        transform_points(check_pose(T, f"T_table_obj of mesh {k}"), m.vertices)
        for k, (m, T) in enumerate(zip(meshes, poses))
    ]


def part_top_from_meshes(
    meshes: Sequence[trimesh.Trimesh], poses: Sequence[ArrayLike], uncertainty_mm: float = 0.0
) -> PartTop:
    """(b) from located meshes: the highest vertex of all meshes at their poses T_table_obj, plus the
    position uncertainty (mm)."""
    V = _posed_vertices(meshes, poses)
    return PartTop(float(max(v[:, 2].max() for v in V)) + float(uncertainty_mm))


# ---------------------------------------------------------------------------------------- (c), (d)


@dataclass(frozen=True)
class Region:
    """A region of the height map: a simple polygon in xy (mm, table frame) and its top height (mm)."""

    polygon_xy_mm: tuple[tuple[float, float], ...]
    height_mm: float
    name: str = ""

    @staticmethod
    def rectangle(x0_mm: float, y0_mm: float, x1_mm: float, y1_mm: float, height_mm: float, name: str = "") -> Region:
        xa, xb = sorted((float(x0_mm), float(x1_mm)))
        ya, yb = sorted((float(y0_mm), float(y1_mm)))
        return Region(((xa, ya), (xb, ya), (xb, yb), (xa, yb)), float(height_mm), name)

    def geometry(self) -> Polygon:
        poly = Polygon(self.polygon_xy_mm)
        if not poly.is_valid:
            poly = shapely.make_valid(poly)
        if poly.area <= 0:
            label = self.name or str(self.polygon_xy_mm[:3])
            raise ValueError(f"region {label}: polygon has no area; give at least 3 corners that are not on one line")
        return poly


def min_width_mm(geom) -> float:
    """Smallest width of a shape (mm): min over directions of its extent, found on the convex hull's
    edge directions (rotating calipers)."""
    hull = np.asarray(geom.convex_hull.exterior.coords)[:-1]
    best = np.inf
    for k in range(len(hull)):
        e = hull[(k + 1) % len(hull)] - hull[k]
        n = np.linalg.norm(e)
        if n == 0:
            continue
        normal = np.array([-e[1], e[0]]) / n
        proj = hull @ normal
        best = min(best, float(proj.max() - proj.min()))
    return best


def priority_order(regions: Sequence[Region], rule: PriorityRule) -> list[int]:
    """Indices of the regions in painting order: a region painted later wins where regions overlap.

    ``later_wins``: the order of entry. ``narrower_wins``: widest first, i.e. sorted by (min width
    descending, area descending, entry order). A region contained in another is never wider nor larger,
    so it always wins over its container; two partly overlapping regions are decided by width, then
    area, then entry order.
    """
    if rule == "later_wins":
        return list(range(len(regions)))
    if rule == "narrower_wins":
        geoms = [r.geometry() for r in regions]
        keys = [(-round(min_width_mm(g), 9), -round(g.area, 9), k) for k, g in enumerate(geoms)]
        return [k for *_, k in sorted(keys)]
    raise ValueError(f"no painting order for rule {rule!r}; rules are {PRIORITY_RULES}")


@dataclass(frozen=True)
class RegionMap:
    """(c) Height map of regions with a priority rule; outside every region the height is ``base_height_mm``."""

    regions: tuple[Region, ...]
    rule: PriorityRule = "later_wins"
    base_height_mm: float = 0.0

    def __post_init__(self) -> None:
        if self.rule not in PRIORITY_RULES:
            raise ValueError(f"unknown priority rule {self.rule!r}; use one of {PRIORITY_RULES}")

    @cached_property
    def pieces(self) -> tuple[tuple[object, float, int], ...]:
        """(geometry, height_mm, region index) of the parts of regions where each one holds."""
        geoms = [r.geometry() for r in self.regions]
        if self.rule == "highest":
            return tuple((g, self.regions[k].height_mm, k) for k, g in enumerate(geoms))
        out = []
        covered = None
        for k in reversed(priority_order(self.regions, self.rule)):  # winners first
            g = geoms[k] if covered is None else geoms[k].difference(covered)
            covered = geoms[k] if covered is None else covered.union(geoms[k])
            if not g.is_empty and g.area > 0:
                out.append((g, self.regions[k].height_mm, k))
        return tuple(out)

    @cached_property
    def _union(self):
        return shapely.union_all([r.geometry() for r in self.regions]) if self.regions else None

    def height_at_mm(self, xy: ArrayLike) -> np.ndarray:
        """Effective height (N,) at points (N, 2) under the priority rule."""
        P = np.asarray(xy, dtype=float).reshape(-1, 2)
        pts = shapely.points(P)
        out = np.full(len(P), float(self.base_height_mm))
        hit = np.zeros(len(P), dtype=bool)
        for g, h, _ in self.pieces:
            inside = shapely.intersects(g, pts)
            if self.rule == "highest":
                out = np.where(inside & hit, np.maximum(out, h), np.where(inside, h, out))
            else:
                out = np.where(inside & ~hit, h, out)
            hit |= inside
        return out

    def box_max_mm(self, move_index, a_xy, b_xy, margin_mm=0.0) -> float:
        box = _box(a_xy, b_xy, margin_mm)
        heights = [h for g, h, _ in self.pieces if g.intersects(box)]
        if self._union is None or not box.difference(self._union).is_empty:
            heights.append(float(self.base_height_mm))
        return float(max(heights))

    def profile_mm(self, move_index, a_xy, b_xy, radius_mm, n_steps) -> np.ndarray:
        centers, ds = step_centers(a_xy, b_xy, n_steps)
        reach = float(radius_mm) + ds / 2.0 + 1e-9
        pts = shapely.points(centers)
        out = np.full(n_steps, -np.inf)
        for g, h, _ in self.pieces:
            near = shapely.distance(g, pts) <= reach
            out = np.where(near, np.maximum(out, h), out)
        if self._union is None:
            return np.full(n_steps, float(self.base_height_mm))
        if all(h >= self.base_height_mm for _, h, _ in self.pieces):
            return np.maximum(out, self.base_height_mm)  # the base can only matter where nothing is near
        lo = centers.min(axis=0) - reach - 1.0
        hi = centers.max(axis=0) + reach + 1.0
        free = shapely_box(lo[0], lo[1], hi[0], hi[1]).difference(self._union)
        if not free.is_empty:
            near = shapely.distance(free, pts) <= reach
            out = np.where(near, np.maximum(out, self.base_height_mm), out)
        return out

    def blocked_xy(self, level_mm: float, radius_mm: float):
        """Union of the winning pieces higher than ``level_mm``, grown by ``radius_mm``."""
        if self.base_height_mm > level_mm:
            raise ValueError("the base height is above the level: everything is blocked")
        geoms = [g for g, h, _ in self.pieces if h > level_mm]
        if not geoms:
            return Polygon()
        return shapely.union_all([g.buffer(float(radius_mm) + 1e-6, join_style="mitre") for g in geoms])


def regions_from_meshes(
    meshes: Sequence[trimesh.Trimesh],
    poses: Sequence[ArrayLike],
    inflate_mm: float = 0.0,
    uncertainty_mm: float = 0.0,
    base_height_mm: float = 0.0,
    names: Sequence[str] | None = None,
) -> RegionMap:
    """(d) A region map from the located scene: one region per mesh, its footprint the convex hull of
    the posed mesh's xy projection grown by ``uncertainty_mm + inflate_mm`` (pass the clearance and
    the sensor radius as ``inflate_mm``), its height the mesh's highest point plus ``uncertainty_mm``.
    Overlaps take the highest (rule ``"highest"``). The hull is conservative for concave parts.

    meshes : trimesh meshes in their ``obj`` frame (mm); poses : T_table_obj (4, 4) per mesh.
    """
    V = _posed_vertices(meshes, poses)
    grow = float(inflate_mm) + float(uncertainty_mm)
    regions = []
    for k, v in enumerate(V):
        hull = MultiPoint([tuple(p) for p in v[:, :2]]).convex_hull
        g = hull.buffer(grow, join_style="mitre") if grow > 0 else hull
        if g.geom_type != "Polygon" or g.area <= 0:
            g = hull.buffer(max(grow, 1e-3))
        coords = tuple((float(x), float(y)) for x, y in np.asarray(g.exterior.coords)[:-1])
        name = names[k] if names else f"mesh_{k}"
        regions.append(Region(coords, float(v[:, 2].max()) + float(uncertainty_mm), name))
    return RegionMap(tuple(regions), "highest", base_height_mm)


# ---------------------------------------------------------------------------------------- raster


@dataclass(frozen=True)
class HeightGrid:
    """Raster upper bound of the scene height: ``heights_mm[i, j]`` >= every obstacle point above the
    cell ``x in [x0 + j*c, x0 + (j+1)*c), y in [y0 + i*c, y0 + (i+1)*c)`` (c = cell_mm). Outside the
    grid the height is ``base_height_mm``. ``inflate_mm`` is added to every query radius (lateral
    uncertainty of the scene)."""

    origin_xy_mm: tuple[float, float]
    cell_mm: float
    heights_mm: np.ndarray
    base_height_mm: float = 0.0
    inflate_mm: float = 0.0
    _dilated: dict = field(default_factory=dict, compare=False, repr=False)

    def _cells(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        j = np.floor((xy[:, 0] - self.origin_xy_mm[0]) / self.cell_mm).astype(int)
        i = np.floor((xy[:, 1] - self.origin_xy_mm[1]) / self.cell_mm).astype(int)
        return i, j

    def dilated(self, radius_mm: float) -> np.ndarray:
        """Grid whose cell holds the max over all cells that a disc of ``radius_mm`` centred anywhere
        in it can touch (centre distance <= radius + sqrt(2) cells)."""
        quantum = self.cell_mm / 2.0  # round the radius up so that nearby radii share one dilation
        key = float(np.ceil(float(radius_mm) / quantum - 1e-9) * quantum)
        if key not in self._dilated:
            rc = key / self.cell_mm + np.sqrt(2.0)
            k = int(np.ceil(rc))
            padded = np.pad(self.heights_mm.astype(np.float32), k, constant_values=np.float32(self.base_height_mm))
            yy, xx = np.mgrid[-k : k + 1, -k : k + 1]
            kernel = ((xx**2 + yy**2) <= rc**2).astype(np.uint8)
            out = cv2.dilate(padded, kernel, borderType=cv2.BORDER_REPLICATE)
            self._dilated[key] = out
        return self._dilated[key]

    def _lookup(self, xy: np.ndarray, radius_mm: float) -> np.ndarray:
        r = float(radius_mm) + self.inflate_mm
        D = self.dilated(r)
        pad = (D.shape[0] - self.heights_mm.shape[0]) // 2
        i, j = self._cells(xy)
        i = i + pad
        j = j + pad
        ok = (i >= 0) & (j >= 0) & (i < D.shape[0]) & (j < D.shape[1])
        out = np.full(len(xy), float(self.base_height_mm))
        out[ok] = D[i[ok], j[ok]]
        return out

    def box_max_mm(self, move_index, a_xy, b_xy, margin_mm=0.0) -> float:
        a = np.asarray(a_xy, dtype=float)[:2]
        b = np.asarray(b_xy, dtype=float)[:2]
        m = float(margin_mm) + self.inflate_mm
        lo = np.minimum(a, b) - m
        hi = np.maximum(a, b) + m
        (i0, i1), (j0, j1) = self._cells(np.array([lo, hi]))
        H, W = self.heights_mm.shape
        sub = self.heights_mm[max(i0, 0) : min(i1, H - 1) + 1, max(j0, 0) : min(j1, W - 1) + 1]
        vals = [float(sub.max())] if sub.size else []
        x0, y0 = self.origin_xy_mm
        inside = lo[0] >= x0 and lo[1] >= y0 and hi[0] < x0 + W * self.cell_mm and hi[1] < y0 + H * self.cell_mm
        if not inside:
            vals.append(float(self.base_height_mm))
        return max(vals)

    def profile_mm(self, move_index, a_xy, b_xy, radius_mm, n_steps) -> np.ndarray:
        centers, ds = step_centers(a_xy, b_xy, n_steps)
        return self._lookup(centers, float(radius_mm) + ds / 2.0)

    def blocked_xy(self, level_mm: float, radius_mm: float):
        """Union of the cells (as squares, mm) whose dilated height exceeds ``level_mm``."""
        if self.base_height_mm > level_mm:
            raise ValueError("the base height is above the level: everything is blocked")
        D = self.dilated(float(radius_mm) + self.inflate_mm)
        pad = (D.shape[0] - self.heights_mm.shape[0]) // 2
        mask = (D > level_mm).astype(np.uint8)
        contours, hierarchy = cv2.findContours(mask, cv2.RETR_CCOMP, cv2.CHAIN_APPROX_SIMPLE)
        polys = []
        c = self.cell_mm
        x0 = self.origin_xy_mm[0] - pad * c
        y0 = self.origin_xy_mm[1] - pad * c
        for k, cnt in enumerate(contours):
            if hierarchy[0][k][3] != -1:  # holes are left filled (conservative)
                continue
            ij = cnt.reshape(-1, 2).astype(float)
            xy = np.column_stack([x0 + (ij[:, 0] + 0.5) * c, y0 + (ij[:, 1] + 0.5) * c])
            g = shapely.geometry.MultiPoint(xy).convex_hull if len(xy) < 3 else Polygon(xy)
            if not g.is_valid:
                g = shapely.make_valid(g)
            polys.append(g.buffer(c * 0.75, join_style="mitre"))  # centre line -> whole cells
        return shapely.union_all(polys) if polys else Polygon()


def height_grid_from_meshes(
    meshes: Sequence[trimesh.Trimesh],
    poses: Sequence[ArrayLike],
    bounds_xy_mm: tuple[float, float, float, float] | None = None,
    cell_mm: float = 1.0,
    uncertainty_mm: float = 0.0,
    base_height_mm: float = 0.0,
) -> HeightGrid:
    """Rasterise posed meshes into a :class:`HeightGrid` (conservative upper bound).

    Each triangle's xy footprint is filled with the triangle's highest z (triangles drawn in order of
    rising height, so a cell keeps the maximum), then every cell takes the max of its 3x3
    neighbourhood so that cells only grazed by a footprint are covered too. ``uncertainty_mm`` raises
    every cell a mesh covers (not the bare base) and is kept as the grid's lateral inflation.
    ``bounds_xy_mm`` = (xmin, ymin, xmax, ymax) to cover at least; the grid always covers the meshes'
    xy bounds plus 2 cells.
    """
    V = _posed_vertices(meshes, poses)
    allv = np.vstack(V)
    lo = allv[:, :2].min(axis=0) - 2 * cell_mm
    hi = allv[:, :2].max(axis=0) + 2 * cell_mm
    if bounds_xy_mm is not None:  # never smaller than the meshes: outside the grid counts as bare base
        lo = np.minimum(lo, np.array(bounds_xy_mm[:2], dtype=float))
        hi = np.maximum(hi, np.array(bounds_xy_mm[2:], dtype=float))
    W = int(np.ceil((hi[0] - lo[0]) / cell_mm))
    H = int(np.ceil((hi[1] - lo[1]) / cell_mm))
    if W <= 0 or H <= 0 or W * H > 50_000_000:
        raise ValueError(f"height grid of {W} x {H} cells is not possible; check the bounds or use a larger cell_mm")
    img = np.full((H, W), np.float32(base_height_mm), dtype=np.float32)
    tris = np.concatenate([v[m.faces] for v, m in zip(V, meshes)], axis=0)  # (T, 3, 3)
    tops = np.ceil(tris[:, :, 2].max(axis=1) * 100.0) / 100.0
    px = (tris[:, :, :2] - lo) / cell_mm - 0.5  # pixel centres at integers
    fixed = np.round(px * 16.0).astype(np.int32)  # shift=4 sub-pixel precision
    order = np.argsort(tops, kind="stable")
    uniq, start = np.unique(tops[order], return_index=True)
    for g, top in enumerate(uniq):
        idx = order[start[g] : start[g + 1] if g + 1 < len(start) else len(order)]
        if top <= base_height_mm:
            continue
        polys = [fixed[k] for k in idx]
        cv2.fillPoly(img, polys, float(top), lineType=cv2.LINE_8, shift=4)
        cv2.polylines(img, polys, True, float(top), lineType=cv2.LINE_8, shift=4)
    img = cv2.dilate(img, np.ones((3, 3), np.uint8), borderType=cv2.BORDER_REPLICATE)
    img = np.where(img > base_height_mm, img + np.float32(uncertainty_mm), img).astype(np.float32)
    return HeightGrid((float(lo[0]), float(lo[1])), float(cell_mm), img, float(base_height_mm), float(uncertainty_mm))


@dataclass(frozen=True)
class LowestOf:
    """The lower of several upper bounds of the same scene (e.g. a raster and hull regions of the
    same located meshes): every query takes the minimum, ``blocked_xy`` the intersection."""

    sources: tuple

    def box_max_mm(self, move_index, a_xy, b_xy, margin_mm=0.0) -> float:
        return min(s.box_max_mm(move_index, a_xy, b_xy, margin_mm) for s in self.sources)

    def profile_mm(self, move_index, a_xy, b_xy, radius_mm, n_steps) -> np.ndarray:
        return np.min([s.profile_mm(move_index, a_xy, b_xy, radius_mm, n_steps) for s in self.sources], axis=0)

    def blocked_xy(self, level_mm: float, radius_mm: float):
        out = None
        for s in self.sources:
            if not hasattr(s, "blocked_xy"):
                continue
            g = s.blocked_xy(level_mm, radius_mm)
            out = g if out is None else out.intersection(g)
        if out is None:
            raise ValueError("no source with geometry")
        return out
