"""How much of one placed solid lies inside another: two located objects cannot fill the same space.

A fixture fitted to a part's edges (a parallel along a bracket's front edge, both "on the table")
is found where the part is; a real contact (a part on a parallel, between a vise's jaws, under a
strap) only touches, and interpenetrates by no more than the fits' errors. Pure: meshes and poses
in, a share out (mm, table frame).
"""

from __future__ import annotations

import numpy as np
import trimesh

from app.geometry.transforms import transform_points

# points spread through a solid's bounding box; those inside it stand for its volume (a parallel
# fills its box: all are kept; a vise about half). 400: a share to about 2 % (1 sigma) in ~25 ms a pair
N_POINTS = 400


def interior_points(mesh: trimesh.Trimesh, n: int = N_POINTS, seed: int = 0) -> np.ndarray:
    """(m, 3) points inside ``mesh`` (its own frame, mm), m <= ``n``, the same for the same mesh and
    seed; empty for a mesh that is not closed (its inside is undefined)."""
    if not mesh.is_watertight or mesh.volume <= 0:
        return np.zeros((0, 3))
    lo, hi = mesh.bounds
    p = np.random.default_rng(seed).uniform(lo, hi, (n, 3))
    return p[_contains(mesh, p)]


def share_inside(mesh_a: trimesh.Trimesh, T_table_a: np.ndarray, mesh_b: trimesh.Trimesh,
                 T_table_b: np.ndarray, points_a: np.ndarray | None = None) -> float:
    """Share (0..1) of solid ``a``'s volume that lies inside solid ``b``, both placed on the table
    (``T_table_a``, ``T_table_b``: 4x4, mm). 0.0 when either is not closed (nothing claimed).
    ``points_a``: :func:`interior_points` of ``mesh_a`` when already taken."""
    pa = interior_points(mesh_a) if points_a is None else points_a
    if not len(pa) or not mesh_b.is_watertight:
        return 0.0
    in_b = transform_points(np.linalg.inv(np.asarray(T_table_b, float)) @ np.asarray(T_table_a, float), pa)
    lo, hi = mesh_b.bounds
    near = np.all((in_b >= lo) & (in_b <= hi), axis=1)      # ray tests only where b could hold them
    if not near.any():
        return 0.0
    return float(np.count_nonzero(_contains(mesh_b, in_b[near]))) / len(pa)


def _contains(mesh: trimesh.Trimesh, points: np.ndarray) -> np.ndarray:
    # trimesh's ray test divides by its rays' direction components, some of them 0 (axis-parallel rays):
    # the infinities it gets there are handled, the warnings they raise are noise in the service's log
    with np.errstate(divide="ignore", over="ignore", invalid="ignore"):
        return mesh.contains(points)
