"""Starts for the fine fit (app.vision.object_pose.search): a start a few mm and degrees off is
settled back onto the part."""

from __future__ import annotations

import cv2
import numpy as np

from app.geometry import parts
from app.geometry.model_edges import prepare_model
from app.geometry.transforms import make_pose
from app.synth.scene import SceneObject, place_on_table
from app.vision.object_pose import prepare_image
from app.vision.object_pose.planar_fit import planar_fit, sample_subset
from app.vision.object_pose.search import Hyp, _state_of, settle_start
from tests.vision.object_pose.test_locate import DIST, K, _errors, _render


def test_a_start_off_by_a_coarse_cell_is_settled_onto_the_part():
    model = prepare_model(parts.bracket_140(), "bracket_140")
    T_true = place_on_table(model.mesh, 400.0, 200.0, 25.0)
    scene, r = _render([SceneObject("bracket_140", model.mesh, T_true, albedo=0.65)],
                       [150.0, -250.0, 600.0], [400.0, 200.0, 0.0])
    eimg = prepare_image(r.image, gamma=scene.gamma)
    c = T_true[:3, 3]
    turn = make_pose(np.array([[np.cos(0.12), -np.sin(0.12), 0], [np.sin(0.12), np.cos(0.12), 0], [0, 0, 1]]))
    T0 = make_pose(None, [13.0, -9.0, 0.0]) @ make_pose(None, c) @ turn @ make_pose(None, -c) @ T_true  # 15.8 mm, 6.9 deg
    state = _state_of(model, T_true)
    start = Hyp(state=state, T_table_obj=T0)
    px_per_mm = K[0, 0] / 700.0
    aligned = planar_fit(eimg, model, Hyp(state=state, T_table_obj=T0.copy()), scene.T_cam_table, K, DIST,
                         sample_subset(model, px_per_mm, 4.0, 400))
    settled = settle_start(model, start, scene.T_cam_table, K, DIST, eimg, capture_mm=20.0, capture_deg=8.0)
    dxy, _, drz = _errors(settled.T_table_obj, T_true)
    assert dxy < 1.5 and drz < 0.5, (dxy, drz)
    assert settled.score > aligned.score         # the aligned start alone stays further off
    # a start that is already right is kept (nothing better around it)
    right = planar_fit(eimg, model, Hyp(state=state, T_table_obj=T_true.copy()), scene.T_cam_table, K, DIST,
                       sample_subset(model, px_per_mm, 4.0, 400))
    again = settle_start(model, right, scene.T_cam_table, K, DIST, eimg, capture_mm=20.0, capture_deg=8.0)
    assert _errors(again.T_table_obj, T_true)[0] < 1.0


def test_a_bores_facets_count_only_where_they_are_its_silhouette():
    """A small block with a cross bore (a finely faceted horizontal cylinder: most of its template
    samples, all horizontal) scored at its true pose by the search's image scorer: with the smooth
    facets counted only as silhouettes the true pose scores as a part, counting every facet whose face
    turns to the camera (the old rule) buries it under edges that are not in the image."""
    from app.geometry.parts import _box, _clean, _cyl_x, _difference
    from app.vision.object_pose.search import _image_scorer, edge_faces_of

    mesh = _clean(_difference(_box((0, 0, 0), (34, 25, 34)), [_cyl_x(12.5, 17.0, 12.0, -1, 35, sections=96)]))
    model = prepare_model(mesh, "cross_bored_block")
    T_true = place_on_table(model.mesh, 400.0, 200.0, 30.0)
    scene, r = _render([SceneObject("cross_bored_block", model.mesh, T_true, albedo=0.7)],
                       [150.0, -150.0, 330.0], [400.0, 200.0, 0.0])
    eimg = prepare_image(r.image, gamma=scene.gamma)
    state = _state_of(model, T_true)
    T_rest = model.resting_states[state].T_rest_obj
    M = T_true @ np.linalg.inv(T_rest)
    P = (model.samples_obj @ T_rest[:3, :3].T + T_rest[:3, 3]) + np.array([0.0, 0.0, M[2, 3]])
    D = model.sample_dir_obj @ T_rest[:3, :3].T
    sel = np.nonzero(np.abs(D[:, 2]) < 0.3)[0]          # the plane search's template: horizontal edges
    smooth = ~model.edge_feature[model.sample_edge[sel]]
    assert smooth.mean() > 0.4                           # the bore's facets are a large share of it
    scorer = _image_scorer(eimg, K, DIST, scene.T_cam_table)
    x, y, th = np.array([M[0, 3]]), np.array([M[1, 3]]), np.array([np.arctan2(M[1, 0], M[0, 0])])
    N0, N1, sm = edge_faces_of(model, T_rest, sel)
    now = float(scorer(x, y, th, P[sel], D[sel], np.ones(len(sel)), normals=(N0, N1, sm))[0])
    old = float(scorer(x, y, th, P[sel], D[sel], np.ones(len(sel)), normals=(N0, N1, np.zeros_like(sm)))[0])
    assert now > 0.4 and now > 3 * old, (now, old)     # measured: 0.47 and 0.07


def _pose_by_pose_score(eimg, T_cam_table, x, y, th, P, D, w, normals, tau_px=2.0, max_angle_deg=20.0):
    """The image scorer's rule written out for one pose: the reference the batched scorer must match."""
    from app.geometry.model_edges import project_points_px

    R, t = T_cam_table[:3, :3], T_cam_table[:3, 3]
    Rz = np.array([[np.cos(th), -np.sin(th), 0.0], [np.sin(th), np.cos(th), 0.0], [0.0, 0.0, 1.0]])
    X = P @ Rz.T + np.array([x, y, 0.0])
    cam = -R.T @ t
    N0, N1, smooth = normals
    f0, f1 = (np.einsum("ij,ij->i", N @ Rz.T, cam - X) > 0 for N in (N0, N1))     # faces towards the camera
    vis = np.where(smooth, f0 ^ f1, f0 | f1)
    uv = project_points_px(X @ R.T + t, K, DIST)
    tv = project_points_px((X + 0.5 * (D @ Rz.T)) @ R.T + t, K, DIST) - uv
    val = np.zeros(len(P))
    for i, ((u, v), (tu, tw)) in enumerate(zip(uv, tv)):
        if not (np.isfinite(u) and np.isfinite(v) and 0 <= u <= eimg.width - 1 and 0 <= v <= eimg.height - 1):
            continue
        iu, iv = int(u), int(v)
        a = eimg.edge_angle[eimg.nearest[iv, iu]]
        if abs(np.cos(a) * tw - np.sin(a) * tu) / (np.hypot(tu, tw) + 1e-12) >= np.cos(np.radians(max_angle_deg)):
            val[i] = np.clip(1.0 - eimg.dist_px[iv, iu] / tau_px, 0.0, 1.0)
    w_floor = 0.5 * float(w[~smooth].sum()) if (~smooth).any() else 0.5 * float(w.sum())
    return float((val * vis) @ w / max(float(vis @ w), w_floor + 1e-9))


def _bracket_scene():
    model = prepare_model(parts.bracket_140(), "bracket_140")
    T_true = place_on_table(model.mesh, 400.0, 200.0, 25.0)
    scene, r = _render([SceneObject("bracket_140", model.mesh, T_true, albedo=0.65)],
                       [150.0, -250.0, 600.0], [400.0, 200.0, 0.0])
    return model, T_true, scene, prepare_image(r.image, gamma=scene.gamma)


def _horizontal_template(model, T_true, stride: int):
    """The plane search's template at the part's true height (its horizontal edge samples, every
    ``stride``-th), the planar pose moving the resting frame onto the true pose, and the samples'
    face normals: (M, P, D, normals)."""
    from app.vision.object_pose.search import edge_faces_of

    T_rest = model.resting_states[_state_of(model, T_true)].T_rest_obj
    M = T_true @ np.linalg.inv(T_rest)
    P = (model.samples_obj @ T_rest[:3, :3].T + T_rest[:3, 3]) + np.array([0.0, 0.0, M[2, 3]])
    D = model.sample_dir_obj @ T_rest[:3, :3].T
    sel = np.nonzero(np.abs(D[:, 2]) < 0.3)[0][::stride]
    return M, P[sel], D[sel], edge_faces_of(model, T_rest, sel)


def test_the_batched_image_scorer_gives_each_pose_its_own_score():
    """Many poses scored at once (the per-image edge maps, contiguous arrays) against the rule
    written out pose by pose: the same numbers."""
    from app.vision.object_pose.search import _image_scorer

    model, T_true, scene, eimg = _bracket_scene()
    M, P, D, normals = _horizontal_template(model, T_true, 7)
    w = np.where(np.arange(len(P)) % 3 == 0, 1.0, 0.5)
    rng = np.random.default_rng(3)
    x = M[0, 3] + rng.uniform(-20, 20, 40)
    y = M[1, 3] + rng.uniform(-20, 20, 40)
    th = np.arctan2(M[1, 0], M[0, 0]) + rng.uniform(-0.3, 0.3, 40)
    x[0], y[0], th[0] = M[0, 3], M[1, 3], np.arctan2(M[1, 0], M[0, 0])
    got = _image_scorer(eimg, K, DIST, scene.T_cam_table)(x, y, th, P, D, w, normals=normals)
    ref = [_pose_by_pose_score(eimg, scene.T_cam_table, *q, P, D, w, normals) for q in zip(x, y, th)]
    np.testing.assert_allclose(got, ref, rtol=0, atol=1e-9)
    assert got[0] > 0.3 and got[0] >= np.max(got) - 1e-9       # the true pose scores best (measured 0.49)


def test_planes_on_one_grid_reuse_the_template_spectra_and_find_the_same_starts(monkeypatch):
    """The coarse search's rotated-template spectra kept from one plane for the next on the same
    grid (the risers): the starts are those of a search that made its own."""
    from app.geometry.transforms import inv
    from app.vision.object_pose.search import _edge_rays_table, _image_scorer, _plane_search

    model, T_true, scene, eimg = _bracket_scene()
    T_table_cam = inv(scene.T_cam_table)
    rays = _edge_rays_table(eimg, K, DIST, T_table_cam, 60000, np.random.default_rng(0))
    C = T_table_cam[:3, 3]
    ext = (200.0, 600.0, 50.0, 350.0)
    scorer = _image_scorer(eimg, K, DIST, scene.T_cam_table)
    state = _state_of(model, T_true)

    def search(h, cache):
        return _plane_search(model, state, h, rays, C, ext, 6, px_mm=0.7, image_score=scorer, cache=cache)

    alone = search(7.5, {})
    cache: dict = {}
    search(0.0, cache)
    spectra = cache["coarse_kernels"][1]
    assert len(spectra) > 1
    shared = search(7.5, cache)
    assert cache["coarse_kernels"][1] is spectra                     # reused, not made again
    assert len(shared) == len(alone) > 0
    for a, b in zip(alone, shared):
        assert np.array_equal(a.T_table_obj, b.T_table_obj) and a.votes == b.votes
    # with room for the first turn's spectra only, the others are made per plane: the same starts
    monkeypatch.setattr("app.vision.object_pose.search.KERNEL_CACHE_BYTES", 1)
    cache = {}
    search(0.0, cache)
    assert len(cache["coarse_kernels"][1]) == 1
    capped = search(7.5, cache)
    for a, b in zip(alone, capped):
        assert np.array_equal(a.T_table_obj, b.T_table_obj) and a.votes == b.votes


def test_padded_template_spectra_are_rfft2s():
    """The coarse template's spectrum from its non-zero rows (:func:`_padded_rfft2`) is rfft2's."""
    from scipy import fft as sfft

    from app.vision.object_pose.search import _padded_rfft2

    rng = np.random.default_rng(0)
    for n, k, Py, Px in ((8, 23, 270, 180), (3, 9, 64, 50), (5, 23, 257, 199), (2, 31, 20, 40)):   # the last crops
        ker = np.zeros((n, k, k), np.float32)
        np.add.at(ker, (rng.integers(0, n, 300), rng.integers(0, k, 300), rng.integers(0, k, 300)),
                  rng.choice([0.5, 1.0], 300).astype(np.float32))
        want = sfft.rfft2(ker, s=(Py, Px))
        got = _padded_rfft2(ker, Py, Px)
        assert got.dtype == want.dtype and np.array_equal(got, want)


def test_top_k_is_the_k_best_largest_first_and_equal_ones_by_index():
    """The coarse scores' k best (:func:`_top_k`, from the values above a sampled threshold) against
    a full stable sort: the same indices in the same order, with and without equal values (a
    symmetric part's turns), whether the threshold lets enough through or not."""
    from app.vision.object_pose.search import _top_k

    rng = np.random.default_rng(5)
    for n, k in ((2_000_000, 800), (50_000, 800), (5_000, 800), (100_000, 40), (900, 900)):
        flat = rng.normal(size=n).astype(np.float32)
        assert np.array_equal(_top_k(flat, k), np.argsort(-flat, kind="stable")[:k])
        tied = np.round(flat, 1)                              # many equal values, at the k-th too
        assert np.array_equal(_top_k(tied, k), np.argsort(-tied, kind="stable")[:k])
    flat = np.zeros(100_000, np.float32)
    flat[::1000] = 1.0                                         # 100 above the threshold, k = 800
    assert np.array_equal(_top_k(flat, 800), np.argsort(-flat, kind="stable")[:800])


def test_best_per_row_takes_each_rows_k_best_of_the_masked_and_equal_ones_by_column():
    from app.vision.object_pose.search import _best_per_row

    rng = np.random.default_rng(2)
    values = np.round(rng.normal(size=(7, 300)), 1).astype(np.float32)
    mask = rng.random((7, 300)) < 0.05
    mask[3] = False                                            # a row with none
    rows, cols = _best_per_row(mask, values, 4)
    want_r, want_c = [], []
    for r in range(7):
        c = np.nonzero(mask[r])[0]
        c = c[np.argsort(-values[r, c], kind="stable")][:4]
        want_r += [r] * len(c)
        want_c += list(c)
    assert rows.tolist() == want_r and cols.tolist() == want_c


def test_an_edges_direction_on_a_plane_is_computed_once_per_image_and_is_the_cast_ones():
    """The edge directions and channels taken once per image (:class:`EdgeRays`) against the edges
    cast onto each plane and their direction measured there: the same channels, the same support
    maps, on planes below the camera at the table's and risers' heights (and for the rays that miss
    a plane: left out)."""
    from app.geometry.transforms import inv
    from app.vision.object_pose.search import _edge_rays_table, _plane_edges, _support_maps

    _model, _T, scene, eimg = _bracket_scene()
    T_table_cam = inv(scene.T_cam_table)
    rays = _edge_rays_table(eimg, K, DIST, T_table_cam, 60000, np.random.default_rng(0))
    C = T_table_cam[:3, 3]
    ext, b, nch = (150.0, 650.0, 0.0, 400.0), 2.0, 4
    ch_w = np.pi / nch
    for z in (0.0, 7.5, 25.0, 120.0):
        lam0 = (z - C[2]) / rays.r0[:, 2]
        lam1 = (z - C[2]) / rays.r1[:, 2]
        ok = (lam0 > 0) & (lam1 > 0)
        dd = lam1[ok, None] * rays.r1[ok, :2] - lam0[ok, None] * rays.r0[ok, :2]     # the cast edge
        phi = np.mod(np.arctan2(dd[:, 1], dd[:, 0]), np.pi)
        p0 = C[:2] + lam0[ok, None] * rays.r0[ok, :2]
        ix = np.floor((p0[:, 0] - ext[0]) / b + 0.5).astype(np.int64)
        iy = np.floor((p0[:, 1] - ext[2]) / b + 0.5).astype(np.int64)
        nx, ny, gx, gy, bits = _plane_edges(rays, C, z, ext, b)
        inside = (ix >= 0) & (ix < nx) & (iy >= 0) & (iy < ny)
        assert inside.sum() > 1000
        np.testing.assert_array_equal(gx, ix[inside])
        np.testing.assert_array_equal(gy, iy[inside])
        sup = _support_maps(rays, C, z, ext, b, 1.5)
        for k in range(nch):
            dphi = np.abs(np.mod(phi[inside] - (k + 0.5) * ch_w + np.pi / 2, np.pi) - np.pi / 2)
            np.testing.assert_array_equal((bits & (1 << k)) != 0, dphi <= ch_w)
            img = np.full((ny, nx), 255, np.uint8)
            img[iy[inside][dphi <= ch_w], ix[inside][dphi <= ch_w]] = 0
            ref = np.clip(1.0 - cv2.distanceTransform(img, cv2.DIST_L2, 3) / 1.5, 0.0, 1.0)
            np.testing.assert_array_equal(sup[k], ref.astype(np.float32))
    # a plane above the camera: its rays are the other ones, left out where they miss it
    _, _, gx, _, _ = _plane_edges(rays, C, C[2] + 100.0, ext, b)
    assert len(gx) == 0


def test_resting_states_searched_on_two_threads_give_the_starts_of_one():
    """The plane search with its resting states on two threads (SEARCH_THREADS) against one thread:
    the same starts in the same order, on two planes (each state's planes share its spectra)."""
    from app.vision.object_pose.search import find_starts, searched_states

    model, T_true, scene, _ = _bracket_scene()
    assert len(searched_states(model)) > 1
    image = _render([SceneObject("bracket_140", model.mesh, T_true, albedo=0.65)],
                    [150.0, -250.0, 600.0], [400.0, 200.0, 0.0])[1].image
    found = {}
    for threads in (1, 2):
        eimg = prepare_image(image, gamma=scene.gamma)          # its own cache: no memo of the other
        found[threads] = find_starts(eimg, K, DIST, scene.T_cam_table, model, height_offsets_mm=(0.0, 25.0),
                                     table_extent_xy=(150.0, 650.0, 0.0, 400.0), threads=threads)
    (one, px1), (two, px2) = found[1], found[2]
    assert px1 == px2 and len(one) == len(two) > 0
    assert len({h.state for h in one}) > 1
    for a, b in zip(one, two):
        assert (a.state, a.votes, a.score, a.height_mm) == (b.state, b.votes, b.score, b.height_mm)
        np.testing.assert_array_equal(a.T_table_obj, b.T_table_obj)


def test_the_correlations_rolled_crop_is_numpys_roll_and_crop():
    """The coarse correlation's turn, rolled by the template's radius and cropped to the grid, taken
    block by block: numpy's roll then crop, for a radius smaller and larger than the grid."""
    from app.vision.object_pose.search import _rolled_crop_into

    rng = np.random.default_rng(5)
    for (P, Q), (ny, nx), r in (((64, 50), (40, 30), 7), ((64, 50), (5, 40), 9), ((30, 30), (12, 3), 0),
                                ((48, 60), (20, 25), 22)):
        a = rng.normal(size=(P, Q))
        out = np.zeros((ny, nx), np.float32)
        _rolled_crop_into(out, a, r)
        ref = np.zeros((ny, nx), np.float32)
        ref[:] = np.roll(a, (r, r), axis=(0, 1))[:ny, :nx]
        np.testing.assert_array_equal(out, ref)


def test_a_models_own_body_hides_what_lies_behind_it_from_the_camera():
    """The self-occlusion masks of the plane search (``search._self_hidden``): an L-shaped block (a
    base 180 x 80 x 10 mm, a 30 mm wall 110 mm high at its +x end) seen from 45 deg above its +x side
    hides the base's top edges behind the wall and shows the wall's top and the base's far end
    beyond the wall's shadow; what turns away from the camera is left to the scorer's facing test.
    The bins of :func:`search._view_bins` follow the part's turn."""
    import trimesh
    from shapely.geometry import Polygon

    from app.vision.object_pose.search import VIEW_BIN_DEG, _self_hidden, _view_bins

    section = Polygon([(-120, 0), (60, 0), (60, 110), (30, 110), (30, 10), (-120, 10)])   # x, z
    mesh = trimesh.creation.extrude_polygon(section, 80.0)
    mesh.apply_transform(make_pose(np.array([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]]), [0.0, 40.0, 0.0]))   # section in x-z
    model = prepare_model(mesh, "ell", upright_only=True)
    T_rest = model.resting_states[0].T_rest_obj
    P = model.samples_obj @ T_rest[:3, :3].T + T_rest[:3, 3]
    P -= [0.0, 0.0, P[:, 2].min()]
    along_y = np.abs(model.sample_dir_obj @ T_rest[:3, :3].T)[:, 1] > 0.9
    base_top, wall_top = along_y & (np.abs(P[:, 2] - 10) < 0.5), along_y & (np.abs(P[:, 2] - 110) < 0.5)
    x0 = P[:, 0].min()
    # the camera 1 m from the block, 45 deg up, on its +x side; the block turned by 0 and 90 deg
    C = np.array([1000.0 / np.sqrt(2), 0.0, 1000.0 / np.sqrt(2)])
    bins, dist = _view_bins(model, T_rest, C, np.zeros(2), np.zeros(2), np.radians([0.0, 90.0]), 0.0)
    n_el = int(round(45.0 / VIEW_BIN_DEG))
    assert bins[0] == 500 + n_el and bins[1] == int(round(270.0 / VIEW_BIN_DEG)) * 1000 + 500 + n_el, bins
    assert abs(dist - 1000.0) < 60.0
    hidden = _self_hidden(model, T_rest, int(bins[0]), dist, np.arange(len(P)))
    behind_wall = base_top & (np.abs(P[:, 0] - (x0 + 150.0)) < 0.5)     # where the base meets the wall
    assert behind_wall.any() and hidden[behind_wall].all()
    assert not hidden[wall_top].any()
    assert not hidden[base_top & (np.abs(P[:, 0] - x0) < 0.5)].any()   # 150 mm before a wall 100 mm high: seen
