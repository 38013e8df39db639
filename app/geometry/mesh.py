"""Mesh loading and normalisation for the model library: CAD bytes in, one mm triangle mesh out.

Formats: STL (ASCII and binary), OBJ, PLY, GLB / GLTF (embedded buffers only), STEP / STP (B-rep,
tessellated by OpenCASCADE through ``cascadio``). Scenes (several bodies, instances) are flattened
into one mesh with the scene graph's transforms applied. The frame of the file is kept as it is:
the CAD frame IS the ``obj`` frame, nothing is recentred.

Units: STEP files declare their unit and are read in it (cascadio converts to metres, we scale to
mm); every other format carries no trustworthy unit, so the caller's ``units`` ("mm" | "inch")
applies. The result is always in mm.

Also here: a summary of the mesh (bounding box, counts, volume), the normalised GLB export and the
stable resting poses of the mesh on a plane (``T_plane_obj``, z up, object on z = 0).
"""

from __future__ import annotations

import io
import json
import os
import struct
import tempfile
from dataclasses import dataclass, field
from pathlib import PurePath

import numpy as np
import trimesh
from scipy.spatial import ConvexHull

from app.geometry.transforms import check_pose

UNIT_SCALE_TO_MM = {"mm": 1.0, "inch": 25.4}

# file suffix -> (trimesh file_type, name used in messages)
_FORMATS = {
    ".stl": ("stl", "STL"),
    ".obj": ("obj", "OBJ"),
    ".ply": ("ply", "PLY"),
    ".glb": ("glb", "GLB"),
    ".gltf": ("gltf", "GLTF"),
    ".step": ("step", "STEP"),
    ".stp": ("step", "STEP"),
}
SUPPORTED_SUFFIXES = tuple(_FORMATS)

# Smallest extent (mm) below which a mesh counts as flat (a sheet with no thickness).
FLAT_EXTENT_MM = 1e-3
# A part whose largest extent is below this is a unit mistake (metres read as mm), not a CNC part.
MIN_SIZE_MM = 1.0


class MeshError(ValueError):
    """A CAD file that cannot become a library mesh. ``status`` is the HTTP status to answer with:
    422 for unreadable / empty / degenerate / unknown input, 413 for a mesh over the face limit."""

    def __init__(self, message: str, status: int = 422):
        super().__init__(message)
        self.status = status


def _fmt_mm(v: float) -> str:
    """Short readable number for messages: 100 -> '100', 34.925 -> '34.925', 1e-9 -> '0'."""
    r = round(float(v), 3)
    return f"{r:g}" if r != 0 else "0"


def _empty_stl(data: bytes) -> bool:
    """True when ``data`` is a well-formed STL that simply holds no triangles."""
    if len(data) >= 84:
        n = struct.unpack("<I", data[80:84])[0]
        if len(data) == 84 + 50 * n:  # a binary STL (its header may still start with "solid")
            return n == 0
    head = data[:2000].lstrip().lower()
    return head.startswith(b"solid") and b"facet" not in data.lower()


def _check_gltf_self_contained(data: bytes) -> None:
    """A .gltf upload is one file: its buffers and images must be embedded (data: URIs)."""
    try:
        doc = json.loads(data.decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise MeshError(f"could not read GLTF: not a JSON document ({exc})") from None
    if not isinstance(doc, dict):
        raise MeshError("could not read GLTF: not a glTF JSON object")
    external = [item.get("uri") for key in ("buffers", "images") for item in doc.get(key, [])
                if isinstance(item, dict) and isinstance(item.get("uri"), str)
                and not item["uri"].startswith("data:")]
    if external:
        raise MeshError(f"could not read GLTF: it references external files ({', '.join(external[:3])}); "
                        "upload a GLB, or a .gltf with embedded buffers")


def _load_step_scene(data: bytes, tol_linear_mm: float) -> trimesh.Scene:
    """Tessellate a STEP file with cascadio (OpenCASCADE) in a temp dir; returns a scene in metres."""
    import cascadio  # imported lazily: only STEP needs it

    with tempfile.TemporaryDirectory(prefix="setupcam_step_") as tmp:
        src, dst = os.path.join(tmp, "part.step"), os.path.join(tmp, "part.glb")
        with open(src, "wb") as f:
            f.write(data)
        # OpenCASCADE works in mm internally; tol_linear is an absolute chord deviation there.
        rc = cascadio.step_to_glb(src, dst, tol_linear=tol_linear_mm, tol_angular=0.5)
        if rc != 0 or not os.path.exists(dst):
            raise MeshError(
                "could not read STEP: OpenCASCADE failed to parse the file (is it an ISO-10303-21 "
                "STEP export?); re-export it from your CAD tool as STEP AP203/AP214 or as STL"
            )
        with open(dst, "rb") as f:
            glb = f.read()
    return trimesh.load(io.BytesIO(glb), file_type="glb", force="scene")


def _scene_to_mesh(scene: trimesh.Scene) -> trimesh.Trimesh | None:
    """Flatten a scene into one Trimesh (transforms applied); None when it holds no triangles."""
    parts = []
    for node in scene.graph.nodes_geometry:
        T, geom_name = scene.graph[node]
        g = scene.geometry.get(geom_name)
        if isinstance(g, trimesh.Trimesh) and len(g.faces):
            parts.append(g.copy().apply_transform(T))
    if not parts:
        return None
    return parts[0] if len(parts) == 1 else trimesh.util.concatenate(parts)


def load_mesh(
    data: bytes,
    filename: str,
    units: str = "mm",
    max_faces: int | None = 2_000_000,
    step_tolerance_mm: float = 0.05,
) -> trimesh.Trimesh:
    """Read a CAD file into one triangle mesh in mm, frame as in the file.

    Parameters
    ----------
    data : bytes
        The file content.
    filename : str
        Only its suffix is used to pick the reader (.stl .obj .ply .glb .gltf .step .stp).
    units : "mm" | "inch"
        Unit of the coordinates for formats without a declared unit (all but STEP).
    max_faces : int or None
        Largest accepted triangle count (413 above it); None for no limit.
    step_tolerance_mm : float
        Chordal deviation of the STEP tessellation, mm.

    Returns
    -------
    trimesh.Trimesh
        Vertices in mm, duplicate vertices merged, degenerate and duplicate faces removed.
        ``mesh.metadata["units_source"]`` says whether the unit came from the file or the caller.

    Raises
    ------
    MeshError
        status 422: unknown suffix, unknown unit, parser failure (with the parser's reason), no
        faces, non-finite coordinates, tiny mesh (largest extent < 1 mm: metres read as mm), flat
        mesh; status 413: more faces than ``max_faces``.
    """
    suffix = PurePath(filename).suffix.lower()
    if suffix not in _FORMATS:
        shown = suffix or "(none)"
        raise MeshError(f"unsupported file type {shown}; use STL, OBJ, PLY, GLB or STEP")
    if units not in UNIT_SCALE_TO_MM:
        raise MeshError(f"unknown units {units!r}; use 'mm' or 'inch'")
    file_type, fmt = _FORMATS[suffix]
    if not data:
        raise MeshError(f"could not read {fmt}: the file is empty (0 bytes)")

    if file_type == "step":
        scene = _load_step_scene(data, step_tolerance_mm)
        scale, units_source = 1000.0, "file"  # cascadio's GLB is in metres, whatever the STEP unit
    else:
        if file_type == "stl" and _empty_stl(data):
            raise MeshError("mesh has 0 faces")
        if file_type == "gltf":
            _check_gltf_self_contained(data)
        try:
            # geometry only: an embedded texture would be decoded by Pillow (a 109 KB PNG can be 900 MP)
            extra = {"skip_materials": True} if file_type in ("glb", "gltf") else {}
            scene = trimesh.load(io.BytesIO(data), file_type=file_type, force="scene", process=False, **extra)
        except MeshError:
            raise
        except Exception as exc:  # noqa: BLE001 - any parser failure becomes a 422 with its reason
            reason = str(exc).strip() or type(exc).__name__
            if isinstance(exc, (IndexError, KeyError, TypeError, AttributeError, struct.error)):
                # the parser tripped over the content: say so, keep its words for the expert
                reason = f"the file is malformed or truncated ({type(exc).__name__}: {reason})"
            raise MeshError(f"could not read {fmt}: {reason}") from None
        scale, units_source = UNIT_SCALE_TO_MM[units], "caller"

    mesh = _scene_to_mesh(scene)
    if mesh is None:
        if len(scene.geometry):
            raise MeshError("mesh has 0 faces")
        raise MeshError(f"could not read {fmt}: no triangles found in the file")

    if max_faces is not None and len(mesh.faces) > max_faces:
        raise MeshError(
            f"mesh has {len(mesh.faces)} faces; the limit is {max_faces}. Decimate it in your CAD "
            "tool (a coarser export tolerance) and upload again",
            status=413,
        )
    if not np.all(np.isfinite(mesh.vertices)):
        raise MeshError("mesh has NaN or infinite vertex coordinates")
    if scale != 1.0:
        mesh.apply_scale(scale)

    mesh.merge_vertices()
    keep = mesh.nondegenerate_faces(height=1e-9) & mesh.unique_faces()
    if not keep.all():
        mesh.update_faces(keep)
        mesh.remove_unreferenced_vertices()
    if len(mesh.faces) == 0:
        raise MeshError("mesh has 0 faces (all triangles are degenerate: zero area)")
    ext = mesh.extents
    if float(ext.max()) < MIN_SIZE_MM:
        shown = " x ".join(_fmt_mm(e) for e in ext)
        raise MeshError(f"mesh is tiny: extents {shown} mm (largest under {MIN_SIZE_MM:g} mm); the file is "
                        "probably in metres (glTF's convention, some STL exporters): convert it to mm or inch")
    if float(ext.min()) < FLAT_EXTENT_MM:
        shown = " x ".join(_fmt_mm(e) for e in ext)
        raise MeshError(f"mesh is flat: extents {shown} mm; a library model needs a solid body")
    mesh.metadata.update({"units": "mm", "units_source": units_source, "source_format": fmt})
    return mesh


def to_glb(mesh: trimesh.Trimesh) -> bytes:
    """The normalised GLB of a mesh: coordinates in mm, obj frame as in the CAD file (no recentring).

    glTF's nominal unit is the metre; our GLBs are mm by convention (the whole service is in mm),
    and ``load_mesh(glb, "x.glb", units="mm")`` reads them back unchanged.
    """
    m = trimesh.Trimesh(vertices=mesh.vertices, faces=mesh.faces, process=False)
    return trimesh.Scene(m).export(file_type="glb")


def volume_and_centroid(mesh: trimesh.Trimesh) -> tuple[float, np.ndarray]:
    """Signed volume (mm^3) and centre of mass (mm, uniform density) of a closed mesh, by summing
    signed tetrahedra from the origin (divergence theorem); much cheaper than trimesh's full
    mass properties (no inertia tensor) on big meshes."""
    tri = mesh.vertices[mesh.faces]
    det = np.einsum("ij,ij->i", tri[:, 0], np.cross(tri[:, 1], tri[:, 2]))
    vol6 = float(det.sum())
    if abs(vol6) < 1e-12:
        return 0.0, tri.reshape(-1, 3).mean(axis=0)
    centroid = (det[:, None] * tri.sum(axis=1)).sum(axis=0) / (4.0 * vol6)
    return vol6 / 6.0, centroid


def mesh_summary(mesh: trimesh.Trimesh) -> dict:
    """Numbers to store beside a library model (all mm).

    Returns ``{"bbox_min_mm": [x,y,z], "bbox_max_mm": [...], "extents_mm": [...], "faces": int,
    "vertices": int, "watertight": bool, "volume_mm3": float | None, "area_mm2": float}``;
    the volume is None when the mesh is not watertight (a volume would be meaningless).
    """
    lo, hi = mesh.bounds
    watertight = bool(mesh.is_watertight)
    return {
        "bbox_min_mm": [float(v) for v in lo],
        "bbox_max_mm": [float(v) for v in hi],
        "extents_mm": [float(v) for v in hi - lo],
        "faces": int(len(mesh.faces)),
        "vertices": int(len(mesh.vertices)),
        "watertight": watertight,
        "volume_mm3": abs(volume_and_centroid(mesh)[0]) if watertight else None,
        "area_mm2": float(mesh.area),
    }


@dataclass(frozen=True)
class RestingPose:
    """One stable way the object rests on a plane.

    ``T_plane_obj`` (4x4, mm): pose of the obj frame in a plane frame whose z is the plane normal (up)
    and whose z = 0 is the plane; the object touches z = 0 from above and its centre of mass lies
    above the plane origin (x = y = 0). The rotation about the plane normal is arbitrary: callers
    that place the object combine it with their own rotation about z. ``probability``: share of random drops ending in this pose (quasi-static
    estimate, sums to ~1 over all poses). ``height_mm``: height of the object in this pose.
    """

    T_plane_obj: np.ndarray = field(repr=False)
    probability: float
    height_mm: float

    def to_dict(self) -> dict:
        return {"T_plane_obj": self.T_plane_obj.tolist(), "probability": self.probability,
                "height_mm": self.height_mm}


def _center_mass(mesh: trimesh.Trimesh, hull: trimesh.Trimesh) -> np.ndarray:
    if mesh.is_watertight:
        vol, com = volume_and_centroid(mesh)
        if abs(vol) > 1e-9:
            return com
    return volume_and_centroid(hull)[1]  # open mesh: the hull is the best guess


def resting_poses(
    mesh: trimesh.Trimesh, max_poses: int = 8, max_hull_faces: int = 600, max_hull_points: int = 20000,
) -> list[RestingPose]:
    """Stable resting poses on a horizontal plane, most probable first.

    Uses ``trimesh.poses.compute_stable_poses`` (quasi-static drop probability per convex-hull
    facet) on the convex hull only, which is exact for resting (an object rests on its hull) and
    fast for big meshes; the centre of mass comes from the mesh when it is watertight, else from
    the hull. Meshes with more than ``max_hull_points`` vertices get the hull of a deterministic
    subsample (plus extreme points), hulls with more than ``max_hull_faces`` faces the hull of a
    subsample of their vertices: probabilities are then approximate, but every pose still puts
    the lowest vertex of the full mesh exactly on z = 0. The bounded hull size caps the time
    (about 0.1 s for the pose search, the hull of a 200k-face mesh about 0.3 s). When the
    probability computation fails, the fallback is the faces of the oriented bounding box
    (6 poses, probability by face area).

    Returns at most ``max_poses`` poses with probabilities renormalised over the ones returned.
    """
    pts = np.asarray(mesh.vertices)
    if len(pts) > max_hull_points:
        # Big mesh: hull of a deterministic subsample plus the extreme points along 13 directions
        # (the hull of ~all points costs seconds; resting probabilities barely change).
        rng = np.random.default_rng(0)
        dirs = np.array([[1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 0], [1, -1, 0], [1, 0, 1], [1, 0, -1],
                         [0, 1, 1], [0, 1, -1], [1, 1, 1], [1, 1, -1], [1, -1, 1], [-1, 1, 1]], float)
        proj = pts @ dirs.T
        extreme = np.unique(np.concatenate([proj.argmax(axis=0), proj.argmin(axis=0)]))
        pick = np.union1d(rng.choice(len(pts), size=max_hull_points, replace=False), extreme)
        pts = pts[pick]
    hull_pts = pts[ConvexHull(pts).vertices]  # plain qhull: only the hull's vertex set
    if len(hull_pts) > max_hull_faces // 2:  # a closed hull has ~2 faces per vertex
        rng = np.random.default_rng(0)
        hull_pts = hull_pts[rng.choice(len(hull_pts), size=max_hull_faces // 2, replace=False)]
    hull = trimesh.convex.convex_hull(hull_pts)
    com = _center_mass(mesh, hull)
    transforms: np.ndarray | None = None
    probs: np.ndarray | None = None
    try:
        transforms, probs = trimesh.poses.compute_stable_poses(hull, center_mass=com, sigma=0.0, n_samples=1)
    except Exception:  # noqa: BLE001 - fall back below
        transforms = None
    if transforms is None or len(transforms) == 0:
        transforms, probs = _obb_poses(mesh, com)
    out = []
    probs = np.asarray(probs, dtype=float)
    order = np.argsort(-probs)[:max_poses]
    total = float(probs[order].sum()) or 1.0
    for i in order:
        T = np.array(transforms[i], dtype=float)
        z = mesh.vertices @ T[2, :3] + T[2, 3]  # all vertices: exactly on z = 0, nothing below
        T[2, 3] -= float(z.min())
        T[:2, 3] -= (T[:3, :3] @ com + T[:3, 3])[:2]  # centre of mass above the plane origin
        check_pose(T, "T_plane_obj", tol=1e-6)
        out.append(RestingPose(T_plane_obj=T, probability=float(probs[i]) / total,
                               height_mm=float(z.max() - z.min())))
    return out


def _obb_poses(mesh: trimesh.Trimesh, com: np.ndarray) -> tuple[list[np.ndarray], np.ndarray]:
    """Fallback: rest on each face of the oriented bounding box, probability ~ face area."""
    T_obb = np.asarray(mesh.bounding_box_oriented.primitive.transform)  # T_obj_box
    ext = np.asarray(mesh.bounding_box_oriented.primitive.extents)
    transforms, weights = [], []
    for axis in range(3):
        for sign in (1.0, -1.0):
            n_box = np.zeros(3)
            n_box[axis] = sign  # outward normal in the box frame; rest on the face at -n (down)
            # rotation taking the box's -n_box to plane -z  (i.e. n_box to +z)
            R = trimesh.geometry.align_vectors(n_box, [0, 0, 1.0])[:3, :3]
            T = np.eye(4)
            T[:3, :3] = R @ T_obb[:3, :3].T
            c = T[:3, :3] @ com
            T[:3, 3] = -c
            transforms.append(T)
            others = [ext[i] for i in range(3) if i != axis]
            weights.append(others[0] * others[1])
    w = np.asarray(weights, dtype=float)
    return transforms, w / w.sum()
