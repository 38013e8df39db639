"""Upload pipeline of a library model: load + summary + resting poses + thumbnail + GLB.

    .venv/bin/python benchmarks/mesh_pipeline.py

Ours: app.geometry.mesh (one vertex merge, tetra-sum volume/centroid, stable poses on a bounded
convex hull) and app.geometry.thumbnail (vectorised z-buffer).
Baseline: plain trimesh defaults (``trimesh.load`` with processing, ``mesh.volume`` /
``mesh.center_mass``, ``trimesh.poses.compute_stable_poses(mesh)`` on the full mesh) and a
painter's-algorithm thumbnail (one ``cv2.fillConvexPoly`` per triangle, far to near).
Also reported: whether both find the same most probable resting height, and the painter's
image's pixel disagreement with the z-buffer image (visibility errors of the painter's order).
"""

from __future__ import annotations

import io
import sys
import time
from pathlib import Path

import cv2
import numpy as np
import trimesh

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from app.geometry import parts  # noqa: E402
from app.geometry.mesh import load_mesh, mesh_summary, resting_poses, to_glb  # noqa: E402
from app.geometry.thumbnail import _zbuffer, project_triangles  # noqa: E402

EXTERNAL = Path(__file__).resolve().parent.parent.parent / "shared" / "data" / "external" / "trimesh_models"


def painter_index(mesh: trimesh.Trimesh, S: int = 512) -> tuple[np.ndarray, np.ndarray]:
    """Baseline: painter's algorithm (one cv2.fillConvexPoly per triangle, far to near) drawing
    triangle indices; returns (index map, normals)."""
    tri, n, uv = project_triangles(mesh, S)
    pts = np.round(uv * 16).astype(np.int32)
    img = np.full((S, S), -1, np.int32)
    for i in np.argsort(tri[:, :, 2].mean(axis=1)):
        cv2.fillConvexPoly(img, pts[i], int(i), lineType=cv2.LINE_8, shift=4)
    return img, n


def zbuffer_index(mesh: trimesh.Trimesh, S: int = 512) -> tuple[np.ndarray, np.ndarray]:
    tri, n, uv = project_triangles(mesh, S)
    return _zbuffer(uv, tri[:, :, 2], S), n


def visibility_errors(mesh: trimesh.Trimesh) -> tuple[float, float, float]:
    """(painter s, z-buffer s, % of covered pixels where the painter shows a differently oriented face)."""
    t = time.perf_counter()
    pi, n = painter_index(mesh)
    tp = time.perf_counter() - t
    t = time.perf_counter()
    zi, _ = zbuffer_index(mesh)
    tz = time.perf_counter() - t
    both = (pi >= 0) & (zi >= 0)
    wrong = both & (np.einsum("ij,ij->i", n[np.maximum(pi, 0)].reshape(-1, 3),
                              n[np.maximum(zi, 0)].reshape(-1, 3)).reshape(pi.shape) < 0.99)
    return tp, tz, 100.0 * wrong.sum() / max(both.sum(), 1)


def cases() -> list[tuple[str, bytes, str, str]]:
    out = []
    if (EXTERNAL / "featuretype.STEP").exists():
        out.append(("featuretype.STEP (real, inch)", (EXTERNAL / "featuretype.STEP").read_bytes(), "f.step", "mm"))
        out.append(("featuretype.STL (real, inch)", (EXTERNAL / "featuretype.STL").read_bytes(), "f.stl", "inch"))
    out.append(("library vise_150", parts.machine_vise().export(file_type="stl"), "v.stl", "mm"))
    out.append(("library base_plate_300", parts.base_plate_300().export(file_type="stl"), "p.stl", "mm"))
    ball = trimesh.creation.icosphere(subdivisions=5, radius=50)  # 20480 faces
    out.append(("sphere 20k faces", ball.export(file_type="stl"), "s.stl", "mm"))
    big = trimesh.util.concatenate([
        trimesh.creation.icosphere(subdivisions=6, radius=50),
        trimesh.creation.annulus(r_min=20, r_max=60, height=30, sections=15000).apply_translation([150, 0, 0]),
    ])
    out.append(("sphere + ring 200k faces", big.export(file_type="stl"), "b.stl", "mm"))
    return out


def ours(data: bytes, name: str, units: str):
    t = time.perf_counter()
    m = load_mesh(data, name, units)
    mesh_summary(m)
    poses = resting_poses(m)
    to_glb(m)
    return m, poses, time.perf_counter() - t


def baseline(m: trimesh.Trimesh, data: bytes, name: str, max_faces: int):
    """Plain trimesh defaults; None when the mesh is too big to finish in reasonable time."""
    if len(m.faces) > max_faces:
        return None, None
    t = time.perf_counter()
    if name.endswith(".step"):
        bm = m.copy()  # trimesh would call the same cascadio; reuse the tessellation
    else:
        bm = trimesh.load(io.BytesIO(data), file_type=name.rsplit(".", 1)[1], force="mesh")
    _ = bm.volume, bm.center_mass, bm.is_watertight
    T, p = trimesh.poses.compute_stable_poses(bm)
    dt = time.perf_counter() - t
    T0 = np.asarray(T[int(np.argmax(p))])
    z = m.vertices @ T0[2, :3]
    return dt, float(z.max() - z.min())


def main() -> int:
    rows = ["| mesh | faces | ours: load+summary+poses+GLB s | baseline trimesh defaults s | same top pose "
            "| thumbnail z-buffer s | painter s | painter wrong-face px % |",
            "| --- | ---: | ---: | ---: | --- | ---: | ---: | ---: |"]
    for label, data, name, units in cases():
        m, poses, tg = ours(data, name, units)
        bg, bh = baseline(m, data, name, max_faces=60_000)
        tp, tz, wrong = visibility_errors(m)
        if bg is None:
            base, same = "skipped (> 60k faces)", "-"
        else:
            base = f"{bg:.2f}"
            same = f"{'yes' if abs(bh - poses[0].height_mm) < 0.5 else 'no'} ({poses[0].height_mm:.1f} / {bh:.1f} mm)"
        rows.append(f"| {label} | {len(m.faces)} | {tg:.2f} | {base} | {same} | {tz:.2f} | {tp:.2f} | {wrong:.2f} |")
        print(rows[-1], flush=True)
    print()
    print("\n".join(rows))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
