"""The photo model: a taught object's 2.5-D edge template in its own frame (mm), its serialisation,
and the template placed at a pose ``(x mm, y mm, theta rad)`` on the table.

The obj frame: origin at the outline's centroid on the table (z = 0), z up, axes as the table's when
the object was taught. A pose of the object on the table is its turn ``theta`` about table z and its
origin ``(x, y)``: ``T_table_obj`` of :func:`pose`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from app.geometry.transforms import make_pose
from app.vision.photo_model.plane import PlaneGrid

TEMPLATE_SPACING_MM = 0.5   # one template point per this square
CLUSTER_MM = 10.0           # template points in one such square share their errors (sigma's clusters)


@dataclass(frozen=True, eq=False)
class PhotoModel:
    """A taught object: the edges of its top face in its own frame (obj: origin at the outline's
    centroid on the table, z up; axes as the table's when it was taught), mm.

    points_mm (N, 2), normal_rad (N,) gradient direction of each edge point (mod 180 deg matters),
    cluster (N,) int: points in one ``CLUSTER_MM`` square (their errors are shared)
    height_mm : height of the top face above the table
    outline_mm : outer contour of the top face (M, 2); holes_mm : enclosed regions (holes, pockets)
    symmetry_deg : turns about z (other than 0) that map the template onto itself
    T_table_obj_teach : where the object lay when taught (4x4, mm); teach_grid : the stored teach
    picture's :class:`PlaneGrid` (so a click on it gives table, then obj coordinates)
    n_views : pictures that agreed on the edges
    teach_cov : 3x3 covariance (x mm, y mm, theta rad; obj axes) of the template's own placement, from
        the fit of the template to its first picture: every later pose inherits it
    teach_table_cov : 3x3 (obj axes, as ``teach_cov``) of where the obj frame lies on the object because
        of the first picture's table-pose error (the markers put the plane a little off, and the template
        with it): propagated from that picture's table covariance; every later pose inherits it. None
        (a model taught before it was kept): :func:`locate` takes the search picture's own table term
        in its stead
    teach_mm_per_px : size (mm) of one camera pixel of the first picture on the top face at the obj
        origin: the template's edge bias (:data:`EDGE_BIAS_PX`) is that many mm. None (an older model):
        the search picture's
    """

    points_mm: np.ndarray
    normal_rad: np.ndarray
    cluster: np.ndarray
    height_mm: float
    outline_mm: np.ndarray
    holes_mm: tuple = ()
    symmetry_deg: tuple = ()
    T_table_obj_teach: np.ndarray = field(default_factory=lambda: np.eye(4))
    teach_grid: PlaneGrid | None = None
    n_views: int = 1
    teach_cov: np.ndarray = field(default_factory=lambda: np.zeros((3, 3)))
    teach_table_cov: np.ndarray | None = None
    teach_mm_per_px: float | None = None

    @property
    def radius_mm(self) -> float:
        return float(np.max(np.linalg.norm(self.outline_mm, axis=1)))

    @property
    def edge_length_mm(self) -> float:
        """Length of the template's edges (its points are about ``spacing`` apart)."""
        return float(len(self.points_mm) * TEMPLATE_SPACING_MM)

    def to_dict(self) -> dict:
        return {"version": 1, "height_mm": self.height_mm,
                "points_mm": np.round(self.points_mm, 4).tolist(), "normal_rad": np.round(self.normal_rad, 5).tolist(),
                "cluster": self.cluster.astype(int).tolist(), "outline_mm": np.round(self.outline_mm, 3).tolist(),
                "holes_mm": [np.round(h, 3).tolist() for h in self.holes_mm], "symmetry_deg": list(self.symmetry_deg),
                "T_table_obj_teach": np.asarray(self.T_table_obj_teach).tolist(),
                "teach_grid": None if self.teach_grid is None else self.teach_grid.to_dict(), "n_views": self.n_views,
                "teach_cov": np.asarray(self.teach_cov).tolist(),
                "teach_table_cov": None if self.teach_table_cov is None else np.asarray(self.teach_table_cov).tolist(),
                "teach_mm_per_px": self.teach_mm_per_px}

    @staticmethod
    def from_dict(d: dict) -> PhotoModel:
        g = d.get("teach_grid")
        return PhotoModel(points_mm=np.asarray(d["points_mm"], float).reshape(-1, 2),
                          normal_rad=np.asarray(d["normal_rad"], float), cluster=np.asarray(d["cluster"], int),
                          height_mm=float(d["height_mm"]), outline_mm=np.asarray(d["outline_mm"], float).reshape(-1, 2),
                          holes_mm=tuple(np.asarray(h, float).reshape(-1, 2) for h in d.get("holes_mm", [])),
                          symmetry_deg=tuple(float(s) for s in d.get("symmetry_deg", [])),
                          T_table_obj_teach=np.asarray(d.get("T_table_obj_teach", np.eye(4).tolist()), float),
                          teach_grid=PlaneGrid(**g) if g else None, n_views=int(d.get("n_views", 1)),
                          teach_cov=np.asarray(d.get("teach_cov", np.zeros((3, 3)).tolist()), float),
                          teach_table_cov=(None if d.get("teach_table_cov") is None
                                           else np.asarray(d["teach_table_cov"], float).reshape(3, 3)),
                          teach_mm_per_px=None if d.get("teach_mm_per_px") is None else float(d["teach_mm_per_px"]))


def thin(uv_mm: np.ndarray, spacing: float) -> np.ndarray:
    """Indices keeping one point per ``spacing`` square (the strongest first is not needed: any)."""
    cells = np.floor(uv_mm / spacing).astype(np.int64)
    _, idx = np.unique(cells, axis=0, return_index=True)
    return np.sort(idx)


def rot(t: float) -> np.ndarray:
    """2x2 rotation by ``t`` rad (about table z)."""
    return np.array([[np.cos(t), -np.sin(t)], [np.sin(t), np.cos(t)]])


def angle_gap(a: float, b: float, model: PhotoModel) -> float:
    """Smallest turn (rad) between two angles, counting the model's symmetries as the same."""
    gaps = [abs((a - b - np.radians(s) + np.pi) % (2 * np.pi) - np.pi) for s in (0.0, *model.symmetry_deg)]
    return float(min(gaps))


def transform(model: PhotoModel, x: float, y: float, t: float) -> tuple[np.ndarray, np.ndarray]:
    """The template at (x mm, y mm, turn t rad) on the table: its points (N, 2), mm, and their unit
    normals (N, 2), table axes."""
    R = rot(t)
    Q = model.points_mm @ R.T + [x, y]
    a = model.normal_rad + t
    return Q, np.stack([np.cos(a), np.sin(a)], axis=1)


def pose(model: PhotoModel, x: float, y: float, t: float) -> np.ndarray:
    """``T_table_obj`` (4x4, mm) of the object at (x mm, y mm, turn t rad about table z) on the table."""
    c, s = np.cos(t), np.sin(t)
    return make_pose(np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]]), [x, y, 0.0])


def table_xyt(T_table_obj: np.ndarray) -> tuple[float, float, float]:
    """(x mm, y mm, turn rad about table z) of a pose on the table: the inverse of :func:`pose`."""
    T = T_table_obj
    return float(T[0, 3]), float(T[1, 3]), float(np.arctan2(T[1, 0], T[0, 0]))
