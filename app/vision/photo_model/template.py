"""Teaching (:func:`teach`): a :class:`~app.vision.photo_model.model.PhotoModel` from pictures of the
object lying on the table.

The first picture is rectified onto the top face's plane; the object is the largest area its edges
close (:func:`_object_blob`), its edges inside the outline are the template (one point per
``TEMPLATE_SPACING_MM``). Further pictures keep only the edges most of them show (:func:`_agree`),
the template keeps the edges that border the top face (:func:`_face`: outline, hole rims), its
symmetries are found (:func:`_with_symmetry`), and the template is fitted to its first picture for
``teach_cov`` and ``teach_table_cov`` (:mod:`app.vision.photo_model.uncertainty`).
"""

from __future__ import annotations

import cv2
import numpy as np

from app.geometry.transforms import make_pose
from app.vision.object_pose.uncertainty import SIGMA_SCALE
from app.vision.photo_model.edges import PlaneEdges, plane_edges
from app.vision.photo_model.fit import refine, refine_fixed, supported
from app.vision.photo_model.locating import locate
from app.vision.photo_model.model import (
    CLUSTER_MM,
    TEMPLATE_SPACING_MM,
    PhotoModel,
    rot,
    table_xyt,
    thin,
    transform,
)
from app.vision.photo_model.plane import (
    FINE_MM_PER_PX,
    PlaneGrid,
    camera_mm_per_px,
    point_distance,
    point_grid,
    rectify,
)
from app.vision.photo_model.uncertainty import fit_cov, table_term
from app.vision.photo_model.view import View


class TeachError(ValueError):
    """Teaching failed; the message says why in words for the admin."""


def _object_blob(edges: PlaneEdges, grid: PlaneGrid, join_mm: float = 3.0) -> np.ndarray:
    """The object in a rectification: the largest area enclosed by edges (gaps up to ``join_mm``
    closed), so that open lines (the table's machining marks, a slot's remains) do not count.
    Returns its filled mask (uint8), grown by ``join_mm``."""
    r = max(1, round(join_mm / grid.mm_per_px))
    sil, outers, _ = _silhouette(edges.canny, r)
    if not outers:
        raise TeachError("no object found on the table: no closed outline besides the table's edges "
                         "(is the whole object in view, and the table's markers?)")
    # the largest body: areas narrower than 10 mm (a strip between two lines) do not count
    k = max(1, round(5.0 / grid.mm_per_px))
    body = cv2.morphologyEx(sil, cv2.MORPH_OPEN, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * k + 1, 2 * k + 1)))
    areas = []
    for c in outers:
        m = np.zeros(sil.shape, np.uint8)
        cv2.fillPoly(m, [np.rint(c).astype(np.int32)], 255)
        areas.append(int(np.count_nonzero(body[m > 0])))
    best = outers[int(np.argmax(areas))]
    if max(areas) * grid.mm_per_px ** 2 < 100.0:
        raise TeachError("no object found on the table: the largest closed outline is under 1 cm² "
                         "(or narrower than 10 mm)")
    blob = np.zeros(edges.canny.shape, np.uint8)
    cv2.fillPoly(blob, [np.rint(best).astype(np.int32)], 255)
    return cv2.dilate(blob, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1)))


def _silhouette(canny: np.ndarray, close_px: int) -> tuple[np.ndarray, list[np.ndarray], list[np.ndarray]]:
    """Areas closed by edge loops with gaps up to ``2 close_px``: (filled mask, outer contours,
    enclosed regions) in grid px. The edges are thickened by ``close_px`` (which bridges the gaps),
    the outside flooded, and the filled area thinned back by ``close_px``."""
    k = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * close_px + 1, 2 * close_px + 1))
    thick = cv2.dilate(canny, k)
    H, W = thick.shape
    outside = np.pad(thick, 1)
    cv2.floodFill(outside, np.zeros((H + 4, W + 4), np.uint8), (0, 0), 128)
    sil = cv2.erode(np.where(outside[1:-1, 1:-1] == 128, 0, 255).astype(np.uint8), k)
    outer, _ = cv2.findContours(sil, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
    free = np.where((sil > 0) & (thick == 0), 255, 0).astype(np.uint8)
    n, lab, stats, _ = cv2.connectedComponentsWithStats(free, connectivity=4)
    holes = []
    if n > 2:
        face = 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))
        for i in range(1, n):
            if i == face or stats[i, cv2.CC_STAT_AREA] < 4:
                continue
            region = cv2.dilate(np.where(lab == i, 255, 0).astype(np.uint8), k)
            cs, _ = cv2.findContours(region, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
            holes += [c[:, 0, :].astype(float) for c in cs if len(c) >= 3]
    return sil, [c[:, 0, :].astype(float) for c in outer if len(c) >= 3], holes


def teach(views: list[View], height_mm: float, *, region_mm: tuple[float, float, float, float] | None = None,
          table_xy_mm: tuple[float, float, float, float] = (0.0, 800.0, 0.0, 400.0),
          min_agree: float = 0.5) -> tuple[PhotoModel, np.ndarray]:
    """A photo model from pictures of the object lying on the table (all of one placement).

    views : the pictures; the first shows where the obj frame is. The others may show the object moved
        or turned (better: turned, so that side walls and shadow fall elsewhere) and the camera anywhere
    height_mm : height of the object's top face above the table
    region_mm : (x_lo, x_hi, y_lo, y_hi) table box that holds the object; None: found as the largest
        group of edges on the table (``table_xy_mm``) besides those the views' ``ignore`` masks explain
    min_agree : share of the other views that must show a template edge for it to be kept
    Returns (model, the first view rectified onto the top face (uint8, the teach picture; its grid is
    ``model.teach_grid``)). Raises :class:`TeachError` with the reason.
    """
    if not views:
        raise TeachError("no picture to teach from")
    if not (0.5 <= float(height_mm) <= 1000.0):
        raise TeachError(f"height {height_mm} mm is not plausible: give the top face's height above the table, "
                         "0.5 to 1000 mm")
    h = float(height_mm)
    v0 = views[0]
    if region_mm is not None:
        x_lo, x_hi, y_lo, y_hi = (float(v) for v in region_mm)
        if not (x_hi - x_lo >= 5 and y_hi - y_lo >= 5 and (x_hi - x_lo) * (y_hi - y_lo) <= 1.0e6
                and max(abs(x_lo), abs(x_hi), abs(y_lo), abs(y_hi)) <= 10_000):
            raise TeachError(f"region {list(region_mm)} mm: give [x_lo, x_hi, y_lo, y_hi] on the table, each side "
                             "5 mm or more, at most 1 m², within 10 m of the table origin")
    # the outline on a 1 mm grid: the largest area closed by edges (gaps up to 6 mm: where the
    # table's own edges, masked out, cross the object's)
    box = region_mm if region_mm is not None else table_xy_mm
    g = PlaneGrid.around(box[0], box[1], box[2], box[3], 1.0, h)
    rect, valid, ign = rectify(v0.image, v0.K, v0.dist, v0.T_cam_table, g, v0.ignore)
    blob = _object_blob(plane_edges(rect, valid, ign, smooth_px=0.8), g, join_mm=6.0)
    outers, _ = cv2.findContours(cv2.erode(blob, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (13, 13))),
                                 cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
    outer = max(outers, key=cv2.contourArea)[:, 0, :].astype(float)
    m = cv2.moments(outer.astype(np.float32))
    c_mm = g.to_mm(np.array([[m["m10"] / m["m00"], m["m01"] / m["m00"]]]))[0]
    outline_table = g.to_mm(outer)
    lo, hi = outline_table.min(axis=0) - 6.0, outline_table.max(axis=0) + 6.0
    x_lo, x_hi, y_lo, y_hi = lo[0], hi[0], lo[1], hi[1]
    if (x_hi - x_lo) * (y_hi - y_lo) > 1.0e6:
        raise TeachError(f"the object found is {x_hi - x_lo:.0f} x {y_hi - y_lo:.0f} mm: larger than 1 m²; "
                         "give the region that holds it")
    grid = PlaneGrid.around(x_lo, x_hi, y_lo, y_hi, FINE_MM_PER_PX, h)
    rect0, valid, ign = rectify(v0.image, v0.K, v0.dist, v0.T_cam_table, grid, v0.ignore)
    if np.mean(valid > 0) < 0.9:
        raise TeachError("the object is not wholly in the picture")
    e0 = plane_edges(rect0, valid, ign, smooth_px=1.5)
    # the template: the edges inside the outline grown by 2 mm; holes: areas they enclose
    sil = np.zeros((grid.height, grid.width), np.uint8)
    cv2.fillPoly(sil, [np.rint(grid.to_px(outline_table) * 4).astype(np.int32)], 255, shift=2)
    r2 = round(2.0 / FINE_MM_PER_PX)
    grown = cv2.dilate(sil, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r2 + 1, 2 * r2 + 1)))
    inner = cv2.erode(sil, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r2 + 1, 2 * r2 + 1)))
    _, _, holes = _silhouette(np.where(inner > 0, e0.canny, 0).astype(np.uint8), round(1.0 / FINE_MM_PER_PX))
    iu = np.clip(np.rint(e0.uv).astype(int), 0, [grid.width - 1, grid.height - 1])
    keep = grown[iu[:, 1], iu[:, 0]] > 0
    uv, ang = e0.uv[keep], e0.angle[keep]
    pts = grid.to_mm(uv) - c_mm
    sel = thin(pts, TEMPLATE_SPACING_MM)
    pts, ang = pts[sel], ang[sel]
    if len(pts) < 40:
        raise TeachError(f"only {len(pts) * TEMPLATE_SPACING_MM:.0f} mm of edges on the object: too few to locate it")
    outline = outline_table - c_mm
    model = PhotoModel(points_mm=pts, normal_rad=ang, cluster=_clusters(pts), height_mm=h, outline_mm=outline,
                       holes_mm=tuple(grid.to_mm(hh) - c_mm for hh in holes),
                       T_table_obj_teach=make_pose(t=[c_mm[0], c_mm[1], 0.0]), teach_grid=grid, n_views=1)
    if len(views) > 1:
        model = _agree(model, views[1:], table_xy_mm, min_agree)
    model = _face(model)
    fit = refine(v0, model, (float(c_mm[0]), float(c_mm[1]), 0.0))
    model = PhotoModel(**{**model.__dict__, "teach_cov": SIGMA_SCALE ** 2 * fit_cov(fit, model),
                          "teach_table_cov": table_term(fit, model, v0),
                          "teach_mm_per_px": camera_mm_per_px(v0.K, v0.T_cam_table, c_mm, h)})
    teach_pic = np.clip(rect0, 0, 255).astype(np.uint8)
    return _with_symmetry(model), teach_pic


def _agree(model: PhotoModel, others: list[View], table_xy_mm, min_agree: float) -> PhotoModel:
    """Keep the template's edges that most other pictures show, at their mean position. Each other
    picture may show the object moved or turned (better: turned, so its side walls, shadow and
    reflections fall elsewhere): it is located with the first picture's template first."""
    votes = np.zeros(len(model.points_mm))
    acc = model.points_mm.copy()
    for k, v in enumerate(others, start=2):
        p = locate(v, model, "object", search_xy=table_xy_mm, min_score=0.35, min_margin=0.0,
                   max_unexplained_mm=1e9)
        if not p:
            raise TeachError(f"picture {k}: the object of the first picture is not found in it ({p.reason})")
        x, y, t = table_xyt(p.T_table_obj)
        fit = refine_fixed(v, model, (x, y, t))
        ok = supported(fit.found, fit.residual_mm)
        Q, N = transform(model, x, y, t)
        seen = Q + np.nan_to_num(fit.residual_mm)[:, None] * N
        votes += ok
        acc[ok] += ((seen - [x, y]) @ rot(t))[ok]           # back into the obj frame
    keep = votes >= max(1.0, min_agree * len(others))
    if keep.sum() < 40:
        raise TeachError(f"the {len(others) + 1} pictures agree on only {keep.sum() * TEMPLATE_SPACING_MM:.0f} mm of "
                         "edges: is the height right, and is it the same object?")
    pts = acc[keep] / (1 + votes[keep])[:, None]
    return PhotoModel(**{**model.__dict__, "points_mm": pts, "normal_rad": model.normal_rad[keep],
                         "cluster": _clusters(pts), "n_views": len(others) + 1})


def _face(model: PhotoModel) -> PhotoModel:
    """The top face from the template's own edges: the largest area they close (gaps to 4 mm) is the
    face; the template keeps the edges that border it (its outline, the rims of its holes and pockets,
    lines on it), and drops what lies beyond them (inside a hole: its wall and what shows through it;
    beyond the outline: a side wall's foot), which depends on the view. Outline and holes are redrawn
    from the face. Where the edges do not close a face, the model stays as it is."""
    P = model.points_mm
    g = point_grid(P, 4)
    img = np.zeros((g.height, g.width), np.uint8)
    ij = np.rint(g.to_px(P)).astype(int)
    img[ij[:, 1], ij[:, 0]] = 255

    def disk(r: int) -> np.ndarray:
        return cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1))

    thick = cv2.dilate(img, disk(8))
    outside = np.pad(thick, 1)
    cv2.floodFill(outside, np.zeros((g.height + 4, g.width + 4), np.uint8), (0, 0), 128)
    free = ((thick == 0) & (outside[1:-1, 1:-1] != 128)).astype(np.uint8)
    n, lab, stats, _ = cv2.connectedComponentsWithStats(free, connectivity=4)
    if n < 2:
        return model
    face_id = 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))
    face = np.where(lab == face_id, 255, 0).astype(np.uint8)
    area_mm2 = stats[face_id, cv2.CC_STAT_AREA] * g.mm_per_px ** 2
    if area_mm2 < 0.5 * cv2.contourArea(model.outline_mm.astype(np.float32)):
        return model      # the edges do not close the face: keep the outline seen in the picture
    keep = cv2.dilate(face, disk(10))[ij[:, 1], ij[:, 0]] > 0
    outers, _ = cv2.findContours(cv2.dilate(face, disk(8)), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
    outer = max(outers, key=cv2.contourArea)[:, 0, :].astype(float)
    body = np.zeros_like(face)
    cv2.fillPoly(body, [np.rint(outer).astype(np.int32)], 255)
    holes_px = cv2.subtract(body, cv2.dilate(face, disk(8)))
    hs, _ = cv2.findContours(cv2.morphologyEx(holes_px, cv2.MORPH_OPEN, disk(2)), cv2.RETR_EXTERNAL,
                             cv2.CHAIN_APPROX_SIMPLE)
    pts = P[keep]
    return PhotoModel(**{**model.__dict__, "points_mm": pts, "normal_rad": model.normal_rad[keep],
                         "cluster": _clusters(pts), "outline_mm": g.to_mm(outer),
                         "holes_mm": tuple(g.to_mm(h[:, 0, :].astype(float)) for h in hs if len(h) >= 3)})


def _clusters(pts: np.ndarray) -> np.ndarray:
    cells = np.floor(pts / CLUSTER_MM).astype(np.int64)
    _, inv_idx = np.unique(cells, axis=0, return_inverse=True)
    return inv_idx.ravel()


def _with_symmetry(model: PhotoModel) -> PhotoModel:
    """The model with the turns about z that map its template onto itself (within 0.5 mm for 95 %)."""
    P = model.points_mm
    g = point_grid(P, 5)
    dmap = point_distance(g, P)
    sym = []
    for deg in range(1, 360):
        q, ok = g.pixels(P @ rot(np.radians(deg)).T)
        if ok.mean() < 0.95:
            continue
        d = dmap[q[ok, 1], q[ok, 0]] * 0.25
        if np.mean(d < 0.5) > 0.95:
            sym.append(float(deg))
    # keep the centre of each run of neighbouring turns (a symmetry shows over a degree or two)
    out, run = [], []
    for s in sym + [1e9]:
        if run and s - run[-1] > 1.5:
            out.append(float(np.round(np.mean(run))))
            run = []
        run.append(s)
    return PhotoModel(**{**model.__dict__, "symmetry_deg": tuple(s for s in out if s < 1e8)})
