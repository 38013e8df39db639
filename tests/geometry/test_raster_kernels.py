"""The z-buffer's compiled loops (app.geometry.raster_kernels, through model_edges.render_depth)
against the numpy rasteriser they replace (its pixel loops kept below as they were): depth and face ids the same bit
for bit on real parts from many views, several meshes in one buffer (ties between coplanar faces
included), faces behind the camera and off the buffer, and the same budget errors."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from app.geometry import parts
from app.geometry.model_edges import face_planes, render_depth
from app.geometry.transforms import pose_from_xyz_euler, transform_points


def numpy_render_depth(meshes_cam, K, width, height, max_pixel_tests=6_000_000, cull_back_faces=True):
    """render_depth as numpy drew it before the loops were compiled: each mesh's faces as
    :func:`face_planes` gives them, then every (face, row) pair and every (face, pixel) pair expanded
    into arrays and the nearest surface taken by a scattered minimum."""
    if width <= 0 or height <= 0:
        raise ValueError(f"z-buffer size must be positive, got {width} x {height}")
    depth = np.full(height * width, np.inf, dtype=np.float64)
    face_id = np.full(height * width, -1, dtype=np.int64)
    all_pix, all_z, all_id = [], [], []
    budget = max_pixel_tests
    for mi, (V, F) in enumerate(meshes_cam):
        planes = face_planes(V, F, K, width, height, cull_back_faces)
        if planes is None:
            continue
        fidx, A0, B0, C0, A1, B1, C1, zt, y0, nrow = planes
        A = np.stack([A0, A1, -A0 - A1], 1)
        B = np.stack([B0, B1, -B0 - B1], 1)
        C = np.stack([C0, C1, 1.0 - C0 - C1], 1)
        nr = int(nrow.sum())
        if nr > budget:
            raise ValueError(f"z-buffer needs {nr} rows, more than {budget}; render smaller")
        rf = np.repeat(np.arange(len(nrow)), nrow)
        py_r = y0[rf] + (np.arange(nr) - (np.cumsum(nrow) - nrow)[rf])
        rhs = -(B[rf] * py_r[:, None] + C[rf])           # A x >= rhs for every k
        Ar = A[rf]
        with np.errstate(divide="ignore", invalid="ignore"):
            bound = rhs / Ar
        lo = np.max(np.where(Ar > 1e-12, bound,
                             np.where(np.abs(Ar) <= 1e-12, np.where(rhs <= 1e-12, -np.inf, np.inf), -np.inf)), axis=1)
        hi = np.min(np.where(Ar < -1e-12, bound, np.inf), axis=1)
        x0 = np.clip(np.ceil(lo - 1e-9), 0, width).astype(np.int64)
        x1 = np.clip(np.floor(hi + 1e-9), -1, width - 1).astype(np.int64)
        cnt = np.maximum(x1 - x0 + 1, 0)
        total = int(cnt.sum())
        if total > budget:
            raise ValueError(f"z-buffer needs {total} pixel tests, more than {budget}; render smaller")
        budget -= total
        rep_r = np.repeat(np.arange(nr), cnt)
        px = x0[rep_r] + (np.arange(total) - (np.cumsum(cnt) - cnt)[rep_r])
        py = py_r[rep_r]
        rep = rf[rep_r]
        l0 = A0[rep] * px + B0[rep] * py + C0[rep]
        l1 = A1[rep] * px + B1[rep] * py + C1[rep]
        l2 = 1.0 - l0 - l1
        invz = l0 / zt[rep, 0] + l1 / zt[rep, 1] + l2 / zt[rep, 2]   # perspective-correct depth
        all_pix.append(py * width + px)
        all_z.append(1.0 / invz)
        all_id.append((np.int64(mi) << 32) + fidx[rep])
    if all_pix:
        pix = np.concatenate(all_pix)
        z = np.concatenate(all_z)
        ids = np.concatenate(all_id)
        np.minimum.at(depth, pix, z)
        win = z <= depth[pix]
        face_id[pix[win]] = ids[win]
    return depth.reshape(height, width).astype(np.float32), face_id.reshape(height, width)


K = np.array([[900.0, 0, 181.3], [0, 900.0, 120.7], [0, 0, 1]])
W, H = 360, 240


def _views(n: int, seed: int):
    """Camera-from-object poses 300-900 mm away, turned every way, some with the part beside the
    buffer or reaching behind the camera."""
    rng = np.random.default_rng(seed)
    for _ in range(n):
        T = pose_from_xyz_euler(*rng.uniform(-60, 60, 2), rng.uniform(300, 900), *rng.uniform(-180, 180, 3))
        yield T


def _same(a, b):
    (da, fa), (db, fb) = a, b
    np.testing.assert_array_equal(da, db)
    np.testing.assert_array_equal(fa, fb)


@pytest.mark.parametrize("make", [parts.bracket_140, parts.flange_plate_80, parts.pin_block_32,
                                  lambda: parts.machine_vise()])
def test_the_compiled_buffer_is_numpys_bit_for_bit(make):
    mesh = make()
    for T in _views(12, seed=len(mesh.faces)):
        V = transform_points(T, mesh.vertices)
        for cull in (True, False):
            _same(render_depth([(V, mesh.faces)], K, W, H, cull_back_faces=cull),
                  numpy_render_depth([(V, mesh.faces)], K, W, H, cull_back_faces=cull))


def test_several_meshes_ties_and_faces_behind_the_camera():
    # a plate and its copy in the same place (every depth a tie: the last mesh drawn keeps the id),
    # a block in front, and a box reaching behind the camera (its faces there are dropped)
    plate = trimesh.creation.box(extents=(200, 150, 10))
    block = trimesh.creation.box(extents=(40, 40, 40))
    near = trimesh.creation.box(extents=(100, 100, 600))
    T = pose_from_xyz_euler(5, -3, 700, 170, 8, 20)
    meshes = [(transform_points(T, plate.vertices), plate.faces), (transform_points(T, plate.vertices), plate.faces),
              (transform_points(pose_from_xyz_euler(0, 0, 500, 10, 20, 30), block.vertices), block.faces),
              (near.vertices + [250, 0, 100], near.faces)]
    got = render_depth(meshes, K, W, H)
    _same(got, numpy_render_depth(meshes, K, W, H))
    ids = got[1][got[1] >= 0] >> 32
    assert set(np.unique(ids)) >= {1, 2} and 0 not in ids       # the copy drawn last wins every tie


def test_a_buffer_too_large_fails_as_before():
    plate = trimesh.creation.box(extents=(200, 150, 10))
    V = transform_points(pose_from_xyz_euler(0, 0, 400, 180, 0, 0), plate.vertices)
    for budget in (100, 5000):
        with pytest.raises(ValueError) as new:
            render_depth([(V, plate.faces)], K, W, H, max_pixel_tests=budget)
        with pytest.raises(ValueError) as old:
            numpy_render_depth([(V, plate.faces)], K, W, H, max_pixel_tests=budget)
        assert str(new.value) == str(old.value)


@pytest.mark.parametrize("bad", [np.inf, -np.inf, np.nan, 1e300])
def test_vertices_that_are_not_finite_give_numpys_buffer(bad):
    # the compiled loops index the buffer unchecked: every face such a vertex spoils must be dropped
    # or clipped before them, as numpy dropped or clipped it
    box = trimesh.creation.box(extents=(50, 50, 50))
    V0 = transform_points(pose_from_xyz_euler(0, 0, 400, 170, 5, 0), box.vertices)
    for vertex, axis in ((0, 0), (0, 2), (3, 1)):
        V = V0.copy()
        V[vertex, axis] = bad
        with np.errstate(all="ignore"):
            _same(render_depth([(V, box.faces)], K, W, H), numpy_render_depth([(V, box.faces)], K, W, H))
