"""Creases from a part's features, not from its tessellation: clean CAD keeps its creases, coarse
facets of round surfaces and the noise of scans do not make creases."""

from __future__ import annotations

import itertools
from pathlib import Path

import numpy as np
import pytest
import trimesh
from scipy.spatial import cKDTree
from skimage.measure import marching_cubes

from app.geometry.feature_edges import feature_edges, normal_noise_deg
from app.geometry.mesh import load_mesh
from app.geometry.model_edges import prepare_model

REPO = Path(__file__).resolve().parents[2]
LIBRARY = sorted((REPO / "models_library").glob("*.stl"))


def _crease_set(edge_vertices, feature) -> set[tuple[int, int]]:
    return {tuple(sorted(map(int, e))) for e in edge_vertices[feature]}


def _dihedral_creases(mesh: trimesh.Trimesh, feature_angle_deg: float = 30.0) -> set[tuple[int, int]]:
    """The rule before feature edges: every face adjacency above the feature angle is a crease."""
    crease = np.degrees(mesh.face_adjacency_angles) > feature_angle_deg
    return _crease_set(mesh.face_adjacency_edges, crease)


# --------------------------------------------------------------------------------------------------
# clean CAD: nothing changes
# --------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("path", LIBRARY, ids=lambda p: p.stem)
def test_library_models_keep_their_creases(path):
    mesh = load_mesh(path.read_bytes(), path.name, "mm")
    fe = feature_edges(mesh)
    assert not fe.info["noisy"] and fe.face_normals is None
    assert _crease_set(fe.edge_vertices, fe.edge_feature) == _dihedral_creases(mesh)
    assert not fe.fitted.any()


def test_step_part_keeps_the_creases_of_its_stl(external_data):
    folder = external_data / "trimesh_models"
    step = load_mesh((folder / "featuretype.STEP").read_bytes(), "featuretype.STEP", "mm")
    stl = load_mesh((folder / "featuretype.STL").read_bytes(), "featuretype.STL", "inch")
    fe = feature_edges(step)
    assert not fe.info["noisy"]
    assert _crease_set(fe.edge_vertices, fe.edge_feature) == _dihedral_creases(step)
    # the B-rep's tessellation and the STL's are different meshes of one part: same crease lines
    fe_stl = feature_edges(stl)
    p_step = _crease_points(fe.edge_ends[fe.edge_feature], step=0.05)
    p_stl = _crease_points(fe_stl.edge_ends[fe_stl.edge_feature], step=0.05)
    assert np.mean(cKDTree(p_stl).query(p_step)[0] < 0.06) > 0.99
    assert np.mean(cKDTree(p_step).query(p_stl)[0] < 0.06) > 0.99


# --------------------------------------------------------------------------------------------------
# coarse tessellation
# --------------------------------------------------------------------------------------------------


def boss_and_hole(sections: int) -> trimesh.Trimesh:
    """80 x 50 x 20 block with a boss (R 12, on top) and a through hole (R 6), both in ``sections``
    facets: 360 / sections degrees between neighbouring facets."""
    box = trimesh.creation.box(bounds=[[0, 0, 0], [80, 50, 20]])
    boss = trimesh.creation.cylinder(radius=12, height=30, sections=sections,
                                     transform=trimesh.transformations.translation_matrix([25, 25, 25]))
    hole = trimesh.creation.cylinder(radius=6, height=40, sections=sections,
                                     transform=trimesh.transformations.translation_matrix([60, 25, 10]))
    return trimesh.boolean.difference([trimesh.boolean.union([box, boss], engine="manifold"), hole],
                                      engine="manifold")


@pytest.mark.parametrize("sections", [8, 10])
def test_coarse_cylinder_facets_are_not_creases(sections):
    mesh = boss_and_hole(sections)
    fe = feature_edges(mesh)
    V = mesh.vertices
    crease = fe.edge_vertices[fe.edge_feature]
    d = V[crease[:, 1]] - V[crease[:, 0]]
    vertical = np.abs(d[:, 2]) > 0.99 * np.linalg.norm(d, axis=1)
    mid = 0.5 * (V[crease[:, 0]] + V[crease[:, 1]])
    on_round = (np.hypot(mid[:, 0] - 25, mid[:, 1] - 25) < 12.5) | (np.hypot(mid[:, 0] - 60, mid[:, 1] - 25) < 6.5)
    assert not np.any(vertical & on_round), "a facet edge along a cylinder's side is drawn as a crease"
    # the facet edges stay as silhouette edges, and the rims and the block's edges stay creases
    side = fe.edge_vertices[~fe.edge_feature]
    ds = V[side[:, 1]] - V[side[:, 0]]
    assert np.sum(np.abs(ds[:, 2]) > 0.99 * np.linalg.norm(ds, axis=1)) >= 2 * sections
    rim_len = np.linalg.norm(d, axis=1)[on_round & ~vertical].sum()
    chord = 2 * np.sin(np.pi / sections)
    assert rim_len == pytest.approx(sections * chord * (12 * 2 + 6 * 2), rel=0.03)   # boss: 2 rims, hole: 2
    assert np.sum(vertical & ~on_round) == 4                                         # the block's corners
    # the rule before: every facet edge of these coarse cylinders was a crease
    old = _dihedral_creases(mesh) - _crease_set(fe.edge_vertices, fe.edge_feature)
    assert len(old) == 2 * sections


def test_a_chamfer_keeps_both_its_creases():
    # a 50 x 30 x 20 block whose vertical corner at (50, 30) is chamfered 2 mm x 45 deg: the chamfer is
    # a narrow strip between two wide faces, not a facet of a round
    poly = np.array([[0, 0], [50, 0], [50, 28], [48, 30], [0, 30.0]])
    from shapely.geometry import Polygon
    mesh = trimesh.creation.extrude_polygon(Polygon(poly), 20.0)
    fe = feature_edges(mesh)
    assert _crease_set(fe.edge_vertices, fe.edge_feature) == _dihedral_creases(mesh)
    assert fe.info["facet_edges"] == 0


# --------------------------------------------------------------------------------------------------
# scans
# --------------------------------------------------------------------------------------------------


def _box_sdf(p, lo, hi, r=0.0):
    """Signed distance (mm, < 0 inside) to the box [lo, hi] with its vertical edges rounded by r."""
    c = 0.5 * (np.asarray(lo) + np.asarray(hi))
    h = 0.5 * (np.asarray(hi) - np.asarray(lo))
    q = np.abs(p - c) - h
    qxy = q[:, :2] + r
    d2 = np.linalg.norm(np.maximum(qxy, 0), axis=1) + np.minimum(qxy.max(1), 0) - r
    w = np.stack([d2, q[:, 2]], 1)
    return np.linalg.norm(np.maximum(w, 0), axis=1) + np.minimum(w.max(1), 0)


def _part_sdf(p):
    """A 100 x 60 x 20 plate with R 10 fillets on its vertical edges and a sharp 40 x 30 x 15 block on top."""
    return np.minimum(_box_sdf(p, [0, 0, 0], [100, 60, 20], 10.0), _box_sdf(p, [20, 15, 19.9], [60, 45, 35]))


def _true_creases(step=0.25) -> np.ndarray:
    """Points every ``step`` mm on the part's true creases: the plate's top and bottom outlines
    (fillet rims included), the block's 12 edges less the 4 bottom ones, plus its 4 concave ones."""
    t = np.linspace(0, 1, int(np.ceil(np.pi / 2 * 10 / step)), endpoint=False)
    outline = []
    for (cx, cy), a0 in (((90, 10), -90), ((90, 50), 0), ((10, 50), 90), ((10, 10), 180)):
        a = np.radians(a0 + 90 * t)
        outline.append(np.c_[cx + 10 * np.cos(a), cy + 10 * np.sin(a)])
    outline = np.concatenate(outline)
    ring = np.r_[outline, outline[:1]]
    pts = []
    for z in (0.0, 20.0):
        for a, b in itertools.pairwise(ring):
            n = max(1, int(np.ceil(np.linalg.norm(b - a) / step)))
            pts.append(np.c_[np.linspace(a, b, n, endpoint=False), np.full(n, z)])
    corners = np.array([[20, 15], [60, 15], [60, 45], [20, 45], [20, 15.0]])
    for z in (20.0, 35.0):
        for a, b in itertools.pairwise(corners):
            n = int(np.linalg.norm(b - a) / step)
            pts.append(np.c_[a + (b - a) * (np.arange(n)[:, None] + 0.5) / n, np.full(n, z)])
    for x, y in corners[:4]:
        n = int(15 / step)
        pts.append(np.c_[np.full(n, x), np.full(n, y), 20 + 15 * (np.arange(n) + 0.5) / n])
    return np.concatenate(pts)


def plate_scan(pitch_mm=1.0, noise_mm=0.1, seed=0) -> trimesh.Trimesh:
    """A scan of the part: marching cubes of its distance field (fine, well-shaped triangles, the
    sharp edges cut across by a triangle or two as a scanner rounds them) plus Gaussian vertex noise."""
    lo = np.array([0.0, 0, 0]) - 2.37 * pitch_mm     # grid off the part's round coordinates
    n = np.ceil((np.array([100.0, 60, 35]) + 2 * pitch_mm - lo) / pitch_mm).astype(int) + 1
    axes = [lo[k] + pitch_mm * np.arange(n[k]) for k in range(3)]
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
    v, f, _, _ = marching_cubes(-_part_sdf(grid).reshape(n), 0.0, spacing=(pitch_mm,) * 3)
    mesh = trimesh.Trimesh(v + lo, f[:, ::-1], process=True)
    if mesh.volume < 0:
        mesh.invert()
    mesh.vertices = mesh.vertices + np.random.default_rng(seed).normal(0, noise_mm, mesh.vertices.shape)
    return mesh


def _crease_points(ends: np.ndarray, step: float = 0.25) -> np.ndarray:
    a, b = ends[:, 0], ends[:, 1]
    L = np.linalg.norm(b - a, axis=1)
    n = np.maximum(1, np.ceil(L / step).astype(int))
    rep = np.repeat(np.arange(len(L)), n)
    k = np.arange(int(n.sum())) - (np.cumsum(n) - n)[rep]
    return a[rep] + (b - a)[rep] * ((k + 0.5) / n[rep])[:, None]


def test_noise_level_tells_scans_from_cad():
    assert normal_noise_deg(trimesh.creation.box(extents=[40, 30, 20])) == 0.0
    assert normal_noise_deg(boss_and_hole(8)) == 0.0
    assert normal_noise_deg(plate_scan(1.0, 0.1)) > 2.0


@pytest.mark.slow
def test_scan_creases_are_the_parts_creases():
    truth = _true_creases()
    true_len = 0.25 * len(truth)
    scan = plate_scan(1.0, 0.1, seed=3)
    model = prepare_model(scan, "scan", detect_symmetry=False, sample_step_mm=0.5)
    crease = model.edge_feature[model.sample_edge]
    P = model.samples_obj[crease]
    length = model.sample_step_mm * len(P)
    d_false = cKDTree(truth).query(P)[0]
    covered = cKDTree(P).query(truth)[0] < 1.0
    assert length == pytest.approx(true_len, rel=0.10)
    assert np.mean(d_false > 1.0) < 0.02            # hardly a crease sample away from a true crease
    assert covered.mean() > 0.95                    # and every true crease found, in one line
    assert np.median(d_false) < 0.35                # drawn on the fitted line, not on the zigzag
    # each crease sample's direction follows its true line (not the triangle edge under it)
    D = model.sample_dir_obj[crease]
    axis = np.argmax(np.abs(D), axis=1)
    straight = ~((P[:, 2] < 1) | ((P[:, 2] > 19) & (P[:, 2] < 21) & ((P[:, 0] < 10) | (P[:, 0] > 90))))
    assert np.mean(np.max(np.abs(D), axis=1)[straight] > np.cos(np.radians(10))) > 0.9
    assert len(np.unique(axis)) == 3
    # corners are where the fitted lines turn, not every kink of the zigzag under them
    assert np.mean(model.sample_corner_mm[crease] > 3.0) > 0.8
    # the denoised normals stand in for the mesh's own: the scan's faces are within a few degrees
    # of the part's (its flat top: +z)
    c = scan.triangles_center
    top = (np.abs(c[:, 2] - 35) < 0.5) & (np.abs(c[:, 0] - 40) < 15) & (np.abs(c[:, 1] - 30) < 10)
    assert np.degrees(np.arccos(model.face_normals[top][:, 2])).max() < 6.0
    assert np.degrees(np.arccos(np.clip(scan.face_normals[top][:, 2], -1, 1))).max() > 10.0
    # the dihedral rule on the same scan: most of its "creases" are noise
    old = scan.vertices[np.array(sorted(_dihedral_creases(scan)))]
    assert np.mean(cKDTree(truth).query(_crease_points(old))[0] > 1.0) > 0.5


@pytest.mark.parametrize("subdivisions", [2, 4])
def test_a_ball_has_no_creases_and_prepares(subdivisions):
    # every face of a coarse sphere turns by more than a scan's noise, so the noisy branch cuts them
    # all into its crease zone: no patch was left, and the patch labelling failed on the empty set
    ball = trimesh.creation.icosphere(subdivisions, 20.0)
    fe = feature_edges(ball)
    assert fe.edge_feature.sum() == 0
    model = prepare_model(ball, "ball")
    assert model.edge_feature.sum() == 0 and model.continuous_axis_obj is not None
