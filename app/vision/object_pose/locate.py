"""One part located in one image: the engine's stages in order (see the package's docstring).

:func:`locate_object` reads as its stages; each stage is a function below it. What is shared between
the stages of one call (the image's edges, the table pose, the occluders, the options) is a
:class:`LocateContext`; a refined candidate pose is a :class:`Fit`.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace

import numpy as np

from app.geometry.model_edges import (
    PreparedModel,
    project_points_px,
    visible_edge_samples,
)
from app.geometry.transforms import check_pose, inv, make_pose, transform_points
from app.vision.blas_threads import one_blas_thread
from app.vision.object_pose.clamping import Flats, SideContact, part_flats, side_contacts
from app.vision.object_pose.datum import choose_datum
from app.vision.object_pose.edge_image import (
    EdgeImage,
    mask_known_edges,
    mask_table_regions,
    prepare_image,
)
from app.vision.object_pose.clamped_starts import clamped_starts
from app.vision.object_pose.options import LocateOptions
from app.vision.object_pose.planar_fit import sample_subset
from app.vision.object_pose.pose_params import FREE_6DOF, flat_at, perturb3
from app.vision.object_pose.refine import edge_support, near_clipped, refine_pose
from app.vision.object_pose.results import ObjectFailure, ObjectPose
from app.vision.object_pose.search import (
    Hyp,
    centre_extent,
    find_starts,
    search_planes,
    searched_states,
    settle_start,
    starts_from_poses,
    turned_over,
)
from app.vision.object_pose.uncertainty import (
    MAX_PRIOR_SIGMAS,
    RISER_APART_SIGMAS,
    RISER_MATCH_SIGMAS,
    RISER_MAX_SIGMA_MM,
    SNAP_MM,
    covariance,
    covariance_at,
    hull_points,
    origin_sigma,
    prior_offsets,
    frame_covariances,
    table_plane_sigma,
    unknown_height_covariance,
)
from app.vision.object_pose.verify import same_up_to_symmetry, unexplained_edges


@one_blas_thread
def locate_object(image, K, dist, T_cam_table, model: PreparedModel, *, options: LocateOptions | None = None,
                  occluder_models=(), known_models=(), known_regions=(), edge_image: EdgeImage | None = None,
                  start_poses=None, start_capture=None, known_heights_mm=None, table_extent_xy=None, clamp_faces=(),
                  keep_pose=None, table_covariance=None, guide_hold=None, **option_changes):
    """Locate one part on the table. Returns :class:`ObjectPose` or :class:`ObjectFailure`.

    Parameters
    ----------
    image : (H, W) uint8 grey (or BGR); ignored when ``edge_image`` (from :func:`prepare_image`) is given
    K : (3, 3), dist : OpenCV intrinsics of the image (4 to 14 coefficients)
    T_cam_table : (4, 4) pose of the table in the camera frame, mm
    model : prepared part
    options : :class:`LocateOptions`; single options may also be given by name (``min_score=0.6``)
    occluder_models : pairs ``(PreparedModel or trimesh.Trimesh, T_table_occ)`` of objects with known
        poses (vise, clamps) that may hide parts of the model's edges
    known_models : pairs ``(PreparedModel, T_table_model)`` of geometry whose edges are not the part,
        typically the table itself: its border, slots and steps are removed from the edge map
    known_regions : polygons (N, 3) on the table (table frame, mm) whose edges are not the part, e.g.
        the printed fiducial labels
    start_poses : ``T_table_obj`` starts (an operator's adjusted pose, "refine from here") that
        replace the search; refinement, verification and uncertainty are as usual
    start_capture : ``(capture_mm, capture_deg)``: how far around each start it is searched (None:
        30 mm and 8 deg, an operator's rough pose); starts that lie close together (along a guide)
        need less, and the search costs the square of it
    known_heights_mm : heights (table z) of surfaces known to carry parts (the table, located
        fixtures' faces); a start at another height (a riser of unknown height) has its height
        fitted with a broad prior. None: every searched height is known (unless ``free_height``).
    table_extent_xy : (x0, x1, y0, y1) of the table top (mm, table frame): the part's centre is
        searched within it, grown by half the part's size; None: wherever image edges meet the plane
    clamp_faces : vertical faces of located fixtures (:func:`.clamping.fixture_faces`: vise jaws, stops);
        a part face found against one is held there in the final fit, as the seat holds its height
    keep_pose : ``T_table_obj -> bool``: where the object can be at all (a vise's moving jaw on its
        guide); aligned starts and fine fits elsewhere are dropped before they compete (the local
        search around a start slides onto any edges within its reach)
    guide_hold : a guided fixture's turn on its located carrier (:func:`.clamping.guide_hold`: a vise's
        moving jaw in the body's ways), held in the final fit as a flat side against a jaw is
    table_covariance : ``(cov, centroid_table_mm[, intrinsics jacobian, intrinsics sigma])`` of the
        table pose (:meth:`app.vision.fiducials.TablePose.frame_error`): its error, and the
        intrinsics', enter the stated sigma (:func:`.uncertainty.table_covariance`); None:
        ``T_cam_table`` and ``K`` are taken as exact

    The pose is fitted lying flat (x, y, rotation about the table normal; height on unknown risers),
    then once more in 6 DoF with the contact prior (maximum a-posteriori): that is the pose returned,
    with its posterior sigma for all six axes.
    """
    opts = (options or LocateOptions()).with_(**option_changes)
    timings: dict[str, float] = {}
    t_all = time.perf_counter()

    def fail(kind, reason, best=0.0, cands=()):
        timings["total"] = (time.perf_counter() - t_all) * 1e3
        return ObjectFailure(model_name=model.name, kind=kind, reason=reason, best_score=float(best),
                             candidates=tuple(cands), timings_ms=dict(timings))

    ctx = _context(image, K, dist, T_cam_table, model, opts, occluder_models, known_models, known_regions,
                   edge_image, known_heights_mm, timings, tuple(clamp_faces), table_covariance, guide_hold)
    if isinstance(ctx, tuple):
        return fail(*ctx)
    found = _find(ctx, start_poses, table_extent_xy, start_capture)        # stages 1 and 2
    if isinstance(found, str):
        return fail("not_found", f"{model.name} not found: {found}")
    hyps, ctx.px_per_mm = found
    if keep_pose is not None:
        hyps = [h for h in hyps if keep_pose(h.T_table_obj)]
        if not hyps:
            return fail("not_found", f"{model.name} not found: no aligned start stayed where it can be (its guide)")
    t = time.perf_counter()
    fits = [ctx.refine_rest(s.T_table_obj, s.state, hyp=h)                   # stage 3
            for h in _distinct(ctx, hyps) for s in [_settle(ctx, h)]]
    if keep_pose is not None:
        fits = [f for f in fits if keep_pose(f.T)]
    refined = len(fits)
    fits = [f for f in fits if not ctx.under_table(f.T)]
    timings["refine"] = (time.perf_counter() - t) * 1e3
    if not fits:
        return fail("not_found", f"{model.name} not found: "
                    + ("every fit ended under the table top" if refined else "no start matched any image edges")
                    + (" where it can be (its guide)" if keep_pose is not None else ""))
    t = time.perf_counter()                                                # stage 4: verification
    best, fits, sym_scores = _choose(ctx, fits)
    # a fit too weak or not distinct is refused before its rivals are weighed: their 6-DoF fits are
    # most of the verification's time, and recognition fully fits several models that are neither
    refusal, distinct_drop = _weak_or_not_distinct(ctx, best)
    if refusal is None:
        rivals = _rivals(ctx, best, fits)
        refusal = _refusal(ctx, best, rivals)
    timings["verify"] = (time.perf_counter() - t) * 1e3
    if refusal is not None:
        return fail(*refusal, best.score, [{"T_table_obj": f.T.tolist(), "score": round(f.score, 4)} for f in fits])
    contact = _declared_riser(ctx, _contact_fit(ctx, best, fits))         # 6 DoF with the contact prior
    pose = _result(ctx, contact, rivals, sym_scores, distinct_drop)
    loose = _place_not_fixed(model, pose)
    if loose:
        return fail("not_found", loose, best.score)
    timings["verify"] = (time.perf_counter() - t) * 1e3
    timings["total"] = (time.perf_counter() - t_all) * 1e3
    return replace(pose, timings_ms=dict(timings))


# --------------------------------------------------------------------------------------------------
# what the stages share
# --------------------------------------------------------------------------------------------------


@dataclass(eq=False)
class Fit:
    """A candidate pose after the fine fit (stage 3): its verification score (share of the visible
    model edge samples with an image edge within 1.5 px), the supported edge length (px) and the
    least-squares state (``info``: empty or with ``failed`` when the fit did not converge)."""

    state: int
    T: np.ndarray
    info: dict
    score: float
    es: object
    sup: np.ndarray
    support_px: float
    hyp: Hyp | None = None

    @property
    def key(self) -> float:
        """Rank: share of the model's edges supported, weighted by how much image evidence that is
        (a simpler hypothesis, e.g. the part upside down with its pocket hidden, explains less)."""
        return self.score * np.sqrt(self.support_px)

    @property
    def converged(self) -> bool:
        return "sol" in self.info


@dataclass(eq=False)
class LocateContext:
    """Everything fixed during one :func:`locate_object` call (image, camera, table, model, options)."""

    eimg: EdgeImage
    K: np.ndarray
    dist: np.ndarray
    T_cam_table: np.ndarray
    model: PreparedModel
    opts: LocateOptions
    occluders_cam: tuple
    known_heights_mm: tuple | None
    timings: dict
    min_contrast: float
    hull_obj: np.ndarray
    clamp_faces: tuple = ()
    table_cov: tuple | None = None      # (6x6, centroid[, intrinsics jacobian, sigma]), see locate_object
    guide_hold: SideContact | None = None   # a guided fixture's turn on its carrier, see locate_object
    px_per_mm: float = 1.0
    _sub_fine: np.ndarray | None = field(default=None, repr=False)
    _unexplained: dict = field(default_factory=dict, repr=False)
    _sharp: dict = field(default_factory=dict, repr=False)
    _fit6: dict = field(default_factory=dict, repr=False)
    _flats: Flats | None = field(default=None, repr=False)

    @property
    def flats(self) -> Flats:
        """The part's plane sides that a jaw can hold flush (:func:`.clamping.part_flats`), once."""
        if self._flats is None:
            self._flats = part_flats(self.model.mesh)
        return self._flats

    @property
    def pos_tol(self) -> float:
        """Poses closer than this (mm, and 4 deg) are the same place."""
        return max(2.0, 0.04 * self.model.diameter_mm)

    @property
    def sub_fine(self) -> np.ndarray:
        if self._sub_fine is None:
            self._sub_fine = sample_subset(self.model, self.px_per_mm, 2.5, 1500)
        return self._sub_fine

    def lowest_z(self, T: np.ndarray) -> float:
        """Height (table z, mm) of the lowest point at ``T_table_obj`` that can rest on a surface."""
        return float(transform_points(T, self.model.support_vertices)[:, 2].min())

    def under_table(self, T: np.ndarray) -> bool:
        """Whether pose ``T``'s lowest point lies more than :data:`UNDER_TABLE_MM` under the table top
        (z = 0), where no part can be. A free height slides along the line of sight and can end there
        on the edges of whatever lies beyond (devset setup_007: the angle block 62 mm under the table,
        226 mm off, outscored its true pose, 67 % of its edges against 61 %)."""
        return self.lowest_z(T) < -UNDER_TABLE_MM

    def on_known_surface(self, T: np.ndarray) -> bool:
        if self.known_heights_mm is None:    # every searched height is a known surface, unless told to fit it
            return not self.opts.free_height
        z0 = self.lowest_z(T)
        return any(abs(z0 - h) < 0.5 for h in self.known_heights_mm)

    def table_plane(self, T: np.ndarray) -> tuple[float, float]:
        """The table top's 1-sigma (height mm, tilt rad) under the part's centre at ``T_table_obj``
        (:func:`.uncertainty.table_plane_sigma`); zeros without a finite table covariance."""
        if self.table_cov is None:
            return 0.0, 0.0
        sh, st = table_plane_sigma(self.table_cov, transform_points(T, self.model.center_obj[None])[0])
        return (sh, st) if np.isfinite(sh) and np.isfinite(st) else (0.0, 0.0)

    def stance_sigmas(self, T: np.ndarray, sigma_mm: float, sigma_rad: float) -> tuple[float, float]:
        """A contact prior's (height mm, tilt rad) sigmas at ``T_table_obj``, widened by
        ``opts.table_tilt_sigmas`` of the table's own (:meth:`table_plane`)."""
        k = self.opts.table_tilt_sigmas
        if k <= 0:
            return sigma_mm, sigma_rad
        sh, st = self.table_plane(T)
        return float(np.hypot(sigma_mm, k * sh)), float(np.hypot(sigma_rad, k * st))

    @property
    def declared_tops(self) -> dict[float, float]:
        """The declared risers' tops: table z (mm, to 0.01) of a known surface plus one of
        ``riser_heights_mm`` -> that riser's height (the first declared, where two tops coincide)."""
        tops: dict[float, float] = {}
        if self.known_heights_mm is not None:
            for h in self.known_heights_mm:
                for r in self.opts.riser_heights_mm:
                    if r > 0:
                        tops.setdefault(round(h + r, 2), r)
        return tops

    def declared_riser_top(self, T: np.ndarray) -> float | None:
        """The height (table z, mm, to 0.1) of the declared riser's top (:attr:`declared_tops`) that
        pose ``T``'s lowest point is on, within 0.5 mm; None if none."""
        tops = self.declared_tops
        if not tops:
            return None
        z0 = self.lowest_z(T)
        near = [t for t in tops if abs(z0 - t) < 0.5]
        return round(min(near, key=lambda t: abs(z0 - t)), 1) if near else None

    def refine(self, T0, free, radii, **kw):
        return refine_pose(self.eimg, self.model, T0, self.T_cam_table, self.K, self.dist, self.occluders_cam,
                           self.sub_fine, free=free, radii=radii, min_contrast=self.min_contrast, **kw)

    def unexplained(self, T: np.ndarray) -> float:
        """:func:`unexplained_edges` of the part at ``T_table_obj``, once per pose."""
        key = np.asarray(T, float).tobytes()
        if key not in self._unexplained:
            self._unexplained[key] = unexplained_edges(self.eimg, self.model, self.T_cam_table @ T, self.K, self.dist,
                                                       lines_across=self.opts.lines_across)
        return self._unexplained[key]

    def sharp(self, T: np.ndarray) -> float:
        """Share of the visible model edge samples at ``T_table_obj`` with an image edge within
        :data:`SHARP_PX`, once per pose (:func:`_sharper` and :func:`_rivals` both ask for the best's)."""
        key = np.asarray(T, float).tobytes()
        if key not in self._sharp:
            share, es, sup = self.support(T, support_px=SHARP_PX)
            if self.eimg.clipped is not None and len(sup):
                # beside a clipped face every crossing sits toward the dark side (refine.near_clipped):
                # the true reading of a white part looks no sharper than one slid along the line of sight
                clear = ~near_clipped(self.eimg.clipped, es.uv_px, es.normal_uv, np.zeros(len(sup)))
                if clear.sum() >= MIN_SHARP_SAMPLES:
                    share = float(sup[clear].mean())
            self._sharp[key] = share
        return self._sharp[key]

    def support(self, T, support_px: float = 1.5):
        return edge_support(self.eimg, self.model, T, self.T_cam_table, self.K, self.dist, self.occluders_cam,
                            self.sub_fine, min_contrast=self.min_contrast, support_px=support_px)

    def refine_rest(self, T0, state: int, radii=(5.0, 3.0, 2.0, 2.0), hyp: Hyp | None = None) -> Fit:
        """Fine fit of a start lying flat in resting state ``state`` (x, y, rotation about the table
        normal; the height too on a riser of unknown height), then verified."""
        model = self.model
        rs_axis = inv(model.resting_states[state].T_rest_obj)[:3, :3] @ np.array([0.0, 0.0, 1.0])
        # on a declared riser's top the height is held too (fitted free, the image slides the part
        # along the line of sight)
        free = ((0, 1, 2, 5) if self.opts.free_height and not self.on_known_surface(T0)
                and self.declared_riser_top(T0) is None else (0, 1, 5))
        if model.continuous_axis_obj is not None and abs(float(rs_axis @ model.continuous_axis_obj)) > 0.999:
            free = free[:-1]          # round part standing on its face: its spin is not observable
        T, info = self.refine(T0, free, radii)
        if 2 in free and self.known_heights_mm is not None:
            # a height fitted freely that ends near a known surface, or under it (impossible), is that
            # surface: the image alone slides the part along the line of sight
            z0 = self.lowest_z(T)
            near = [h for h in self.known_heights_mm
                    if z0 - SNAP_MM < h < z0 + SNAP_MM or (h > z0 and h - z0 < 3 * SNAP_MM)]
            if near:
                h = min(near, key=lambda h: abs(h - z0))
                T = make_pose(None, [0.0, 0.0, h - z0]) @ T
                T, info = self.refine(T, tuple(f for f in free if f != 2), radii[-2:])
        if self.opts.table_tilt_sigmas > 0 and "sol" in info:
            # scored as it stands on the true table, which the located frame tilts (LocateOptions)
            sz, st = self.stance_sigmas(T, self.opts.contact_sigma_mm, np.radians(self.opts.contact_sigma_deg))
            T6, info6 = self.refine(T, FREE_6DOF, radii[-2:], prior=(T, sz, st, self.hull_obj))
            if "sol" in info6:
                T, info = T6, info6
        score, es, sup = self.support(T)
        spacing = float(np.median(np.linalg.norm(np.diff(es.uv_px, axis=0), axis=1))) if len(es.index) > 2 else 0.0
        support_px = float(np.count_nonzero(sup)) * min(spacing, 10.0)
        return Fit(state=state, T=T, info=info, score=score, es=es, sup=sup, support_px=support_px, hyp=hyp)


def _context(image, K, dist, T_cam_table, model, opts, occluder_models, known_models, known_regions,
             edge_image, known_heights_mm, timings, clamp_faces=(), table_cov=None, guide_hold=None):
    """The image prepared (edges of known geometry removed) and the call's fixed inputs checked;
    or ``(kind, reason)`` of a failure."""
    K = np.asarray(K, dtype=float)
    dist = np.zeros(5) if dist is None else np.asarray(dist, dtype=float).ravel()
    T_cam_table = check_pose(T_cam_table, "T_cam_table")
    t = time.perf_counter()
    eimg = edge_image if edge_image is not None else prepare_image(image, gamma=opts.gamma)
    if known_models:
        eimg = mask_known_edges(eimg, [(m, T_cam_table @ np.asarray(T, float)) for m, T in known_models], K, dist)
    if len(known_regions):
        eimg = mask_table_regions(eimg, known_regions, T_cam_table, K, dist)
    timings["edges"] = (time.perf_counter() - t) * 1e3
    if len(eimg.edge_uv) < 20:
        return ("not_found", f"{model.name} not found: the image has almost no edges "
                             f"({len(eimg.edge_uv)} edge pixels); check exposure and focus")
    C = inv(T_cam_table)[:3, 3]
    if C[2] <= 0:
        return ("bad_input", "the camera is below the table plane according to T_cam_table "
                             f"(camera height {C[2]:.0f} mm); check the table pose")
    return LocateContext(
        eimg=eimg, K=K, dist=dist, T_cam_table=T_cam_table, model=model, opts=opts,
        occluders_cam=tuple((m, T_cam_table @ np.asarray(T, float)) for m, T in occluder_models),
        known_heights_mm=None if known_heights_mm is None else tuple(known_heights_mm), timings=timings,
        min_contrast=max(0.01, 6.0 * eimg.noise_linear), hull_obj=hull_points(model), clamp_faces=clamp_faces,
        table_cov=table_cov, guide_hold=guide_hold)


# --------------------------------------------------------------------------------------------------
# stages 1 to 3: starts, and the best distinct ones refined
# --------------------------------------------------------------------------------------------------


def coarse_starts(eimg: EdgeImage, K, dist, T_cam_table, model: PreparedModel, opts: LocateOptions,
                  table_extent_xy=None, clamp_faces=()):
    """Stages 1 and 2 of :func:`locate_object` alone, on a prepared image: the aligned starts, best
    first, and the image scale (px per mm); or the reason (str) why there are none. Recognition ranks
    the library's models by the best of these, so a part held between located jaws is ranked by the
    poses the jaws allow, as it is then located (a plane search alone ranked devset setup_004's
    stepped block fifth of 20, behind a parallel fitted to the jaws' edges)."""
    ctx = _context(None, K, dist, T_cam_table, model, opts, (), (), (), eimg, None, {}, tuple(clamp_faces))
    return ctx[1] if isinstance(ctx, tuple) else _find(ctx, None, table_extent_xy)


def _find(ctx: LocateContext, start_poses, table_extent_xy, start_capture=None):
    """Starts aligned in the table plane, best first, and the image scale (px per mm); or the reason."""
    if start_poses is not None:
        capture = {} if start_capture is None else dict(zip(("capture_mm", "capture_deg"), map(float, start_capture)))
        return starts_from_poses(ctx.model, start_poses, ctx.T_cam_table, ctx.K, ctx.dist, ctx.eimg, **capture)
    o = ctx.opts
    extent = centre_extent(table_extent_xy, ctx.model.diameter_mm)
    found = find_starts(ctx.eimg, ctx.K, ctx.dist, ctx.T_cam_table, ctx.model, height_offsets_mm=o.height_offsets_mm,
                        resting_states=o.resting_states, n_starts=o.n_starts, n_planar=o.n_planar,
                        n_coarse=o.n_coarse, coarse_step_max_mm=o.coarse_step_max_mm, turn_maxima=o.turn_maxima,
                        self_occlusion=o.self_occlusion,
                        max_edges=o.max_edges, rng=np.random.default_rng(o.seed), timings=ctx.timings,
                        table_extent_xy=extent, threads=o.search_threads)
    if isinstance(found, str) or not ctx.clamp_faces:
        return found
    # held between located jaws the part's stance follows them: those few poses, scored directly
    hyps, px_per_mm = found
    t = time.perf_counter()
    heights = sorted({h for h, _ in search_planes(o.height_offsets_mm)})
    held = clamped_starts(ctx.model, ctx.hull_obj, ctx.clamp_faces, heights,
                          searched_states(ctx.model, o.resting_states), ctx.eimg, ctx.K, ctx.dist,
                          ctx.T_cam_table, px_per_mm)
    ctx.timings["clamped_starts"] = (time.perf_counter() - t) * 1e3
    return sorted(hyps + held, key=lambda h: -h.score), px_per_mm


def _distinct(ctx: LocateContext, hyps: list[Hyp]) -> list[Hyp]:
    """The best ``n_refine`` starts that are different places (near-symmetric alternatives, e.g.
    the part upside down, count as different and compete), and besides them the best start of every
    resting state and the best one on a known surface, where those score at least
    :data:`RESERVE_SHARE` of the best start, and the jaws' start the image scores best. Aligned
    scores are not comparable between stances (a part on its side shows other edges than upright)
    nor between a known surface and a free height (a tool in the spindle fits a pin block lying on
    its side 100 mm above the table better than the block's own image fits it upright on its
    parallel): the fine fit, which sees all edges and their occlusion, decides between them."""
    distinct: list[Hyp] = []

    def add(h: Hyp) -> None:
        if h.score > 0 and not any(same_up_to_symmetry(ctx.model, h.T_table_obj, d.T_table_obj, ctx.pos_tol, 4.0,
                                                        exact_only=True) for d in distinct):
            distinct.append(h)

    for h in hyps:
        if len(distinct) >= ctx.opts.n_refine:
            break
        add(h)
    top = max((h.score for h in hyps), default=0.0)
    groups: dict = {}
    for h in hyps:                      # best first: the first of a group is its best
        if h.score >= RESERVE_SHARE * top:
            groups.setdefault(("state", h.state), h)
            if ctx.on_known_surface(h.T_table_obj):
                groups.setdefault(("known",), h)
            riser_top = ctx.declared_riser_top(h.T_table_obj)
            if riser_top is not None:   # standing on a declared parallel: that reading is refined too
                groups.setdefault(("riser", h.state, riser_top), h)
    # held by located jaws: the pose the image scores best among those the jaws allow is refined too,
    # whatever its aligned score (that alignment sees no occluder: deep between the jaws half the part
    # is hidden; moved_001_a: 0.27 aligned against a plane start's 0.44, 0.73 in the fine fit)
    held = [h for h in hyps if h.source == "clamped"]
    if held:
        groups.setdefault(("clamped",), max(held, key=lambda h: h.votes))
    for h in groups.values():
        if all(h is not d for d in distinct):
            add(h)
    return distinct


#: a pose whose lowest point lies further than this under the table top (mm) cannot be; a freely
#: fitted height that ends less far under a known surface is taken to rest on it (:data:`SNAP_MM`)
UNDER_TABLE_MM = 3 * SNAP_MM

#: a stance's (or a known surface's) best start is refined when its aligned score is at least this
#: share of the best start's (the true stance's start scored 0.82 of a floating side stance's)
RESERVE_SHARE = 0.75


def _settle(ctx: LocateContext, h: Hyp) -> Hyp:
    """The start searched once more around itself (x, y within 0.06 x the part's size, at least
    5 mm; rotation within 4 deg) and aligned. The plane search leaves a big part's start up to a
    coarse cell and a few degrees off, and from there the fine fit, which looks a few pixels along
    each edge normal, does not come back (a vise 6 mm and 2.7 deg off its true pose converged on its
    own jaw's edges instead)."""
    if not ctx.opts.settle_starts:
        return h
    return settle_start(ctx.model, h, ctx.T_cam_table, ctx.K, ctx.dist, ctx.eimg,
                        capture_mm=max(5.0, 0.06 * ctx.model.diameter_mm), capture_deg=4.0)


# --------------------------------------------------------------------------------------------------
# stage 4: which pose, is it distinct, does it rest where it says, how sure
# --------------------------------------------------------------------------------------------------


def _choose(ctx: LocateContext, fits: list[Fit]) -> tuple[Fit, list[Fit], list]:
    """The best fit after trying it turned over and turned by its near symmetries, polished.
    Returns (best, all fits with best first when turned-over poses joined, near-symmetry scores)."""
    model, min_score = ctx.model, ctx.opts.min_score
    fits = sorted(fits, key=lambda r: -r.key)
    best = fits[0]
    # the part turned over about one of its horizontal axes has the same outline when the outline is
    # symmetric (a plate with a pocket on top: upside down it is a plain rectangle that supports a high
    # share of its few edges); the search may offer only one of the two: refine the other as well
    # (the flip moves the part by a few mm when its outline is not centred on its mass: aligned in the
    # plane first). Explaining clearly more of the image (25 % more supported edge length) at an
    # acceptable score wins even at a lower share: the pocket's walls are rarely all supported.
    if best.converged and not model.stands_as_modelled:      # a fixture never lies upside down
        for T_alt in turned_over(model, best.T):
            found_alt = starts_from_poses(model, [T_alt], ctx.T_cam_table, ctx.K, ctx.dist, ctx.eimg,
                                          capture_mm=max(5.0, 0.06 * model.diameter_mm), capture_deg=2.0, n_peaks=1)
            if isinstance(found_alt, str):
                continue
            h = found_alt[0][0]
            alt = ctx.refine_rest(h.T_table_obj, h.state, hyp=h)
            if alt.converged and not ctx.under_table(alt.T):
                fits.append(alt)
                if alt.score >= min_score and alt.support_px >= STRONGER_BY * best.support_px:
                    best = alt
        fits.sort(key=lambda r: (r is not best, -r.key))
    if best.converged:
        best = _clearer_reading(ctx, best, fits)
        fits.sort(key=lambda r: (r is not best, -r.key))
    # near symmetries (outline maps, small features do not): try the turned poses, keep the best
    # (only turns about the table normal: a near-symmetric flip puts the part on another face, which
    # the search covers as its own resting state, at its own height)
    near = [s for s in model.symmetries if not s.exact and abs(float((best.T[:3, :3] @ s.axis_obj)[2])) > 0.99]
    sym_scores = []
    if near and best.converged:
        base = best
        for s in near:
            alt = ctx.refine_rest(base.T @ s.S, base.state, radii=(2.0, 2.0), hyp=base.hyp)
            sym_scores.append((s, alt.score))
            if alt.key > best.key:
                best = alt
    if best.converged:
        # of the fits at the same place that explain about as much, the one that leaves clearly fewer
        # image edges inside its outline unexplained is the reading (the block right side up: its
        # pocket's edges are its own; upside down it is a plain outline that supports a share as high;
        # within half the margin: devset setup_000, 0.88 against 0.90, not setup_001's 0.61 against 0.69)
        clearer = _clearer(ctx, best, fits, lambda r: r.score >= best.score - 0.5 * ctx.opts.min_margin
                           and r.support_px >= 0.8 * best.support_px)
        if clearer is not best:
            best = clearer
            fits.sort(key=lambda r: (r is not best, -r.key))
    if best.converged:
        sharper = _sharper(ctx, best, fits)
        if sharper is not best:
            best = sharper
            fits.sort(key=lambda r: (r is not best, -r.key))
    if best.converged:          # polish the chosen pose with a narrow search
        pol = ctx.refine_rest(best.T, best.state, radii=(2.0, 1.5, 1.5), hyp=best.hyp)
        if pol.converged and pol.key >= best.key * 0.98:
            fits = [pol if r is best else r for r in fits]
            best = pol
    return best, fits, sym_scores


#: a reading leaves "clearly fewer" of the image edges inside its outline unexplained when its share
#: is lower by this much (devset setup_000: the block right side up 0.1 below upside down)
CLEARER_BY = 0.1


def _clearer_reading(ctx: LocateContext, best: Fit, fits: list[Fit]) -> Fit:
    """Of the fits at the same place, the one that explains at least as much image edge length as
    ``best`` and leaves clearly fewer image edges inside its outline unexplained, else ``best``.

    A share of the model's own edges favours the simpler reading: our flange plate upside down is a
    plain square with four holes and supports 92 % of its edges, right side up its pocket's walls
    are half hidden and it supports 80 %; but right side up it explains 21 % more edge length and
    leaves 9 % of the edges inside its outline unexplained, against 33 % (generator synth_016)."""
    return _clearer(ctx, best, fits, lambda r: r.score >= ctx.opts.min_score and r.support_px >= best.support_px)


def _at_same_place(ctx: LocateContext, best: Fit, fits: list[Fit], admit) -> list[Fit]:
    """The converged fits other than ``best`` whose centres lie within a quarter of the part's size
    of its centre and that ``admit``, in the order of ``fits``."""
    model = ctx.model
    c_best = transform_points(best.T, model.center_obj[None])[0]
    return [r for r in fits if r is not best and r.converged and admit(r) and np.linalg.norm(
        transform_points(r.T, model.center_obj[None])[0] - c_best) < 0.25 * model.diameter_mm]


def _clearer(ctx: LocateContext, best: Fit, fits: list[Fit], admit) -> Fit:
    """Of the converged fits at ``best``'s place (centres within a quarter of the part's size) that
    ``admit``, the one that leaves the fewest image edges inside its outline unexplained, if that is
    clearly fewer (:data:`CLEARER_BY`) than ``best`` leaves; else ``best``. ``fits`` best first by
    key: the first of equals is taken."""
    cands = _at_same_place(ctx, best, fits, admit)
    if not cands:
        return best
    u_best = ctx.unexplained(best.T)
    u, clearer = min(((ctx.unexplained(r.T), r) for r in cands), key=lambda t: t[0])
    return clearer if u < u_best - CLEARER_BY else best


#: a rival that explains this many times the best's supported edge length (and clearly fewer
#: unexplained edges) makes the best ambiguous whatever its share (the 1.25 of the turned-over rule)
STRONGER_BY = 1.25

#: sharp support: an image edge within this of the model's edge (px); at the true pose the devset's
#: edges sit within 0.05-0.12 px (median), while a reading slid along the line of sight onto the
#: wrong riser matches the outline at 1.5 px but not at 0.5 px
SHARP_PX = 0.5
#: a reading is "clearly sharper" when its share of sharply supported edges is higher by this
SHARPER_BY = 0.1
#: the sharp share leaves out samples beside clipped pixels while at least this many remain
MIN_SHARP_SAMPLES = 20


def _sharper(ctx: LocateContext, best: Fit, fits: list[Fit]) -> Fit:
    """Of the converged fits at ``best``'s place that score within half the margin of it and explain
    about as much of the image (90 % of its supported edge length), the one whose edges match clearly
    more sharply (:data:`SHARPER_BY` at :data:`SHARP_PX`), else ``best``.

    Readings slid along the line of sight (a bracket in a vise on a 20, 25 or 30 mm parallel: devset
    setup_001) project to nearly the same outline and support 74-75 % of their edges at 1.5 px each
    (turned over, 72 %); at 0.5 px the true one supports 60 % against 48, 41 and 25 %. A simpler
    reading is not judged so: a housing turned over is a plain outline that matches sharply (devset
    moved_005_a: 97 % within 0.5 px against 79 %) but explains 30 % less edge length."""
    cands = _at_same_place(ctx, best, fits, lambda r: r.support_px >= 0.9 * best.support_px
                           and r.score >= best.score - 0.5 * ctx.opts.min_margin)
    if not cands:
        return best
    s_best = ctx.sharp(best.T)
    s, sharper = max(((ctx.sharp(r.T), r) for r in cands), key=lambda t: t[0])
    return sharper if s > s_best + SHARPER_BY else best


@dataclass
class Rivals:
    """How the best pose stands against the others: ``flips`` (the part turned over onto another face
    by a near symmetry: a datum question), ``rivals`` (different places that explain about as much),
    ``runner`` (best score of any different pose) and the margins."""

    flips: list
    flips_open: list
    rivals: list
    runner: float
    margin: float
    rival_margin: float
    flip_runner: float
    stronger: list = field(default_factory=list)   # rivals that explain clearly more of the image


def _rivals(ctx: LocateContext, best: Fit, fits: list[Fit]) -> Rivals:
    model, tol, min_margin = ctx.model, ctx.pos_tol, ctx.opts.min_margin
    # the part turned over onto another face by a near symmetry (same outline, e.g. a counterbore
    # underneath) is not a different place: it is a question of the datum
    flips = [r for r in fits if r is not best and
             not same_up_to_symmetry(model, r.T, best.T, tol, 4.0, exact_only=True) and
             same_up_to_symmetry(model, r.T, best.T, tol, 4.0)]
    # a different pose competes only if it explains about as much of the image (a part upside down
    # with its pocket hidden is a plain outline: a high share of fewer edges is not a rival)
    others = [r for r in fits if r is not best and all(r is not f for f in flips) and
              not same_up_to_symmetry(model, r.T, best.T, tol, 4.0, exact_only=True)]
    runner = max((r.score for r in others), default=float("nan"))
    rivals = [r for r in others if r.support_px >= 0.8 * best.support_px]
    flips_open = [r for r in flips if best.score - r.score < 2 * min_margin]
    if (rivals or flips_open) and best.converged:
        # nor is a pose that leaves clearly more of the image inside its outline unexplained (the
        # block upside down: same outline, its pocket's edges in the picture belong to nothing);
        # the same holds the face up decided
        u_best = ctx.unexplained(best.T)
        rivals = [r for r in rivals if ctx.unexplained(r.T) < u_best + CLEARER_BY]
        # nor one whose edges match clearly less sharply (the part slid along the line of sight; or
        # turned over, explaining no more edge length: setup_001's bracket, 23 % within 0.5 px against
        # 60 %), nor one that the 6-DoF fit brings back to the best's place (a 25 mm parallel's reading
        # of a part on its 20 mm one: the fitted height decides, devset setup_022)
        if rivals:
            s_best = ctx.sharp(best.T)
            rivals = [r for r in rivals if (r.state != best.state and r.support_px > best.support_px)
                      or ctx.sharp(r.T) > s_best - SHARPER_BY]
        if rivals:
            T6_best = _fit6(ctx, best).T6
            rivals = [r for r in rivals if not same_up_to_symmetry(model, _fit6(ctx, r).T6, T6_best, tol, 4.0,
                                                                    exact_only=True)]
        flips_open = [r for r in flips_open if ctx.unexplained(r.T) < u_best + CLEARER_BY]
    # a rival that explains clearly more edge length and leaves clearly fewer of the image's edges
    # inside its outline unexplained is not outscored by a higher share of fewer edges (our generator's
    # synth_047: a plate under two strap clamps not in the library, its true pose 50 % of 1850 px with
    # 64 % unexplained, against the plate on its side 301 mm away, 61 % of 1420 px with 82 %)
    stronger = [r for r in rivals if best.converged and r.support_px >= STRONGER_BY * best.support_px
                and ctx.unexplained(r.T) < ctx.unexplained(best.T) - CLEARER_BY]
    return Rivals(flips=flips, flips_open=flips_open,
                  rivals=rivals, runner=runner, margin=best.score - runner if others else float("nan"),
                  rival_margin=best.score - max((r.score for r in rivals), default=float("nan")),
                  flip_runner=max((r.score for r in flips), default=float("nan")), stronger=stronger)


def _weak_or_not_distinct(ctx: LocateContext, best: Fit) -> tuple[tuple[str, str] | None, float]:
    """``(kind, reason)`` when the best fit did not converge, supports less than ``min_score`` (or
    ``min_verified_score``) of its visible edges or is not distinct (:func:`_distinctiveness`), else
    None; and the pose's distinctiveness (NaN where not reached). Judged on the fit alone, before its
    rivals."""
    o, name = ctx.opts, ctx.model.name
    if not best.converged:
        return ("not_found", f"{name} not found: {best.info.get('failed', 'the fit did not converge')}"), float("nan")
    least = max(o.min_score, o.min_verified_score)
    if best.score < least:
        return ("not_found", f"{name} not found: the best fit supports only {best.score:.0%} of its visible "
                             f"edges (need {least:.0%}); the part may be hidden, outside the image or a "
                             f"different model"), float("nan")
    drop, weakest = _distinctiveness(ctx, best)
    if weakest:
        return ("not_found", f"{name} not found: the best fit ({best.score:.0%} of its visible edges) is not "
                             f"distinct: moved a few pixels in {weakest} it still fits {best.score - drop:.0%} "
                             f"(need a drop of {o.min_distinctiveness:.0%}); it lies on straight edges or "
                             f"texture, not on the part"), drop
    return None, drop


def _refusal(ctx: LocateContext, best: Fit, rv: Rivals) -> tuple[str, str] | None:
    """``(kind, reason)`` when a fit that passed :func:`_weak_or_not_distinct` is still not good enough
    to return (a stronger or an equal rival, too much of the image left unexplained), else None."""
    o, name = ctx.opts, ctx.model.name
    if rv.stronger:
        r = max(rv.stronger, key=lambda r: r.support_px)
        return ("ambiguous", f"{name} ambiguous: the best fit ({best.score:.0%} of its visible edges) leaves more of "
                             f"the image unexplained than another pose that fits {r.score:.0%} of its edges but "
                             f"explains {r.support_px / max(best.support_px, 1e-9):.1f} times the edge length; "
                             f"take another view or give the pose roughly")
    # a part hides what lies behind it: edges inside its outline that it does not explain are not
    # behind it (our generator's synth_042: a bracket read on clutter, 86 % unexplained)
    u = ctx.unexplained(best.T)
    if u > o.max_unexplained:
        return ("not_found", f"{name} not found: the best fit ({best.score:.0%} of its visible edges) leaves "
                             f"{u:.0%} of the image edges inside its outline unexplained (at most "
                             f"{o.max_unexplained:.0%}); a part would hide what made them, so it is not there; "
                             f"it may be hidden by something that is not in the library")
    if rv.rivals and rv.rival_margin < o.min_margin:
        return ("ambiguous", f"{name} ambiguous: two different poses fit almost equally well "
                             f"({best.score:.0%} and {best.score - rv.rival_margin:.0%} of the visible edges, margin "
                             f"{rv.rival_margin:.0%} < {o.min_margin:.0%}); take another view or give the pose roughly")
    return None


#: a located pose whose position is uncertain (1 sigma, any axis) by more than this share of the part's
#: size (its box diagonal) is not a place: right results stay under 0.05 (the devset and our
#: generator), our generator's synth_040 (a pin block under clamps read 300 mm away on a clamp's heel
#: block) came at 0.71, its rotation sigma 0.3 deg for an error of 68 deg
MAX_PLACE_SIGMA_SHARE = 0.25


def _place_not_fixed(model: PreparedModel, pose: ObjectPose) -> str:
    """The reason a located pose is no place at all (its position sigma more than
    :data:`MAX_PLACE_SIGMA_SHARE` of the part's size), else ""."""
    axis, s = max(((k, pose.sigma.get(k, float("nan"))) for k in ("x_mm", "y_mm", "z_mm")),
                  key=lambda t: t[1] if np.isfinite(t[1]) else -1.0)
    if not np.isfinite(s) or s <= MAX_PLACE_SIGMA_SHARE * model.diameter_mm:
        return ""
    return (f"{model.name} not found: the best fit ({pose.score:.0%} of its visible edges) does not fix its place: "
            f"1 sigma of {s:.0f} mm in {axis[0]}, more than {MAX_PLACE_SIGMA_SHARE:.0%} of its size "
            f"({model.diameter_mm:.0f} mm); from this view the image does not say where it is")


def _distinctiveness(ctx: LocateContext, best: Fit) -> tuple[float, str]:
    """Least drop of the support when the pose is moved by 4 px in x, y or turned as much (the
    better direction of each), and the first direction that does not drop enough ("" if none).
    A fit along one straight edge or onto texture does not drop."""
    model, o = ctx.model, ctx.opts
    shift_mm = 4.0 / ctx.px_per_mm
    c_tab = transform_points(best.T, model.center_obj[None])[0]
    # turned by as much as moves a typical edge point (mean distance from the centre) by those pixels
    r_mean = float(np.mean(np.linalg.norm(model.samples_obj - model.center_obj, axis=1)))
    dth = shift_mm / max(r_mean, 1.0)
    drops, owed = {}, {}
    es_b, sup_b = best.es, best.sup
    for key, q in (("x", (shift_mm, 0, 0)), ("-x", (-shift_mm, 0, 0)), ("y", (0, shift_mm, 0)),
                   ("-y", (0, -shift_mm, 0)), ("rz", (0, 0, dth)), ("-rz", (0, 0, -dth))):
        if model.continuous_axis_obj is not None and key.endswith("rz"):
            continue
        T_q = perturb3(best.T, c_tab, np.array(q, float))
        sc, _, _ = ctx.support(T_q)
        drops[key] = best.score - sc
        # the drop the part's own geometry owes: supported samples that the move carries off their
        # edge (a round outline turned, a long edge slid along itself, owe nothing)
        if len(es_b.index):
            uv_q = project_points_px(transform_points(ctx.T_cam_table @ T_q, es_b.points_obj), ctx.K, ctx.dist)
            moved = np.abs(np.einsum("ij,ij->i", uv_q - es_b.uv_px, es_b.normal_uv)) > 1.5
            owed[key] = float(np.count_nonzero(moved & sup_b)) / len(es_b.index)
    pairs, weakest = [], ""
    for (a, b), label in zip((("x", "-x"), ("y", "-y"), ("rz", "-rz")), ("x", "y", "rotation")):
        k = a if drops.get(a, 1.0) >= drops.get(b, 1.0) else b
        d = drops.get(k, 1.0)
        pairs.append(d)
        # distinct: a clear drop, or (where the geometry owes less than twice that) at least half
        # of what it owes: a flange's holes are all that turning it moves
        need = min(o.min_distinctiveness, 0.5 * owed.get(k, 1.0)) if k.endswith("rz") else o.min_distinctiveness
        if d < max(need, 0.02) and not weakest:
            weakest = label
    return float(min(pairs)), weakest


@dataclass
class ContactFit:
    """The chosen flat fit, its 6-DoF fit with the contact prior, and whether the two disagree;
    ``riser_mm``: the declared riser it was found standing on (None: a known surface, or a riser of
    unknown height)."""

    best: Fit
    T6: np.ndarray
    info6: dict
    prior: tuple
    conflict: bool
    riser_mm: float | None = None


def _fit6(ctx: LocateContext, r: Fit, sides: bool = True, rest_z: float | None = None,
          start: np.ndarray | None = None) -> ContactFit:
    """The 6-DoF fit of flat fit ``r`` with its contact prior: on a known surface (or, given
    ``rest_z``, with its lowest point on that height: a declared riser) within the contact's sigma,
    else over a riser of unknown height; held by the jaw faces it touches unless ``sides`` is False.
    ``start``: a flat pose (``T_table_obj``, lying in ``r``'s stance) to start from instead of ``r.T``.
    Fitted once per call and arguments (:func:`_rivals` and :func:`_contact_fit` both ask for the
    best's; the cached result holds ``r``, so its ``id`` stays unique)."""
    key = (id(r), sides, rest_z, None if start is None else start.tobytes())
    if key not in ctx._fit6:
        ctx._fit6[key] = _fit6_uncached(ctx, r, sides, rest_z, start)
    return ctx._fit6[key]


def _fit6_uncached(ctx: LocateContext, r: Fit, sides: bool, rest_z: float | None,
                   start: np.ndarray | None = None) -> ContactFit:
    o, model = ctx.opts, ctx.model
    T0 = r.T if start is None else start
    ra = None if model.continuous_axis_obj is None else T0[:3, :3] @ model.continuous_axis_obj
    T_rest = T0 if rest_z is None else make_pose(None, [0.0, 0.0, rest_z - ctx.lowest_z(T0)]) @ T0
    known = rest_z is not None or ctx.on_known_surface(T0)
    held = side_contacts(ctx.clamp_faces, ctx.hull_obj, T_rest, o.contact_sigma_mm,
                         flats=ctx.flats if ctx.clamp_faces else None) if sides else []
    if sides and ctx.guide_hold is not None:
        held.append(ctx.guide_hold)
    lying_free = known and not held and abs(ctx.lowest_z(T_rest)) < 0.5     # on the table itself (z = 0)
    pressed = any(c.holds_place for c in held)
    tilt_deg = o.held_contact_sigma_deg if pressed else o.free_contact_sigma_deg if lying_free else o.contact_sigma_deg
    sz, st = o.contact_sigma_mm if known else o.riser_sigma_mm, np.radians(tilt_deg)
    sz, st = ctx.stance_sigmas(T_rest, sz, st)
    pr = (T_rest, sz, st, ctx.hull_obj)
    if held:
        pr = pr + (tuple(held),)
    # the final fit places the part: without the edges beside clipped pixels (biased toward the dark
    # side); the flat fits that rank the starts keep them, for where most of a part's edges are clipped
    # (one stop over-exposed) they are what tells one place from another
    T6, info6 = ctx.refine(T_rest, FREE_6DOF, (2.0, 2.0), round_axis_table=ra, prior=pr, reweight=o.final_reweight,
                           drop_clipped=True, prior_noise_scale=o.sigma_scale)
    conflict = "sol" in info6 and np.max(np.abs(prior_offsets(T6, pr))) > MAX_PRIOR_SIGMAS
    if conflict and held:      # the image does not let it touch the face: judge it without
        return _fit6(ctx, r, sides=False, rest_z=rest_z, start=start)
    return ContactFit(best=r, T6=T6, info6=info6, prior=pr, conflict=bool(conflict))


def _contact_fit(ctx: LocateContext, best: Fit, fits: list[Fit]) -> ContactFit:
    """Residual tilt and height: the free 6-DoF fit from the flat result with the contact prior."""
    o = ctx.opts
    cf = _fit6(ctx, best)
    if cf.conflict:
        # the best flat fit does not rest where it says (e.g. on a vise's seat where the part in fact
        # stands 20 mm higher on parallels and, seen from afar, looks nearly the same): a rival of
        # about the same score that does rest as it says is the better reading
        # (the same stance only: a part turned over elsewhere that happens to rest is another part's
        # reading, devset setup_001's bracket 135 mm away with a 0.9 mm sigma)
        for r in sorted(fits, key=lambda r: -r.key):
            if r is best or not r.converged or r.score < best.score - o.min_margin or r.state != best.state:
                continue
            alt = _fit6(ctx, r)
            if "sol" in alt.info6 and not alt.conflict:
                return alt
    return cf


def _declared_riser(ctx: LocateContext, cf: ContactFit) -> ContactFit:
    """A part over a riser of unknown height whose fitted height says clearly which of the shop's
    declared risers (``riser_heights_mm``: its parallels) it stands on, refitted standing on it.

    Tested, not snapped: the lowest point's fitted height must lie within
    :data:`RISER_MATCH_SIGMAS` of its own sigma from one declared height above a known surface, every
    other declared height at least :data:`RISER_APART_SIGMAS` away, that sigma at most
    :data:`RISER_MAX_SIGMA_MM`, and the refit must not pull away from the riser (the contact
    prior's own test). Else the height stays the image's, with its broad sigma: a parallel that is
    not declared (27.06 mm among 20, 25 and 30) is not taken for its neighbour."""
    o = ctx.opts
    if (not o.riser_heights_mm or ctx.known_heights_mm is None or cf.conflict or "sol" not in cf.info6
            or ctx.on_known_surface(cf.best.T)):
        return cf
    cov = covariance(cf.info6, ctx.K, ctx.dist, ctx.T_cam_table, data_scale=o.sigma_scale)[0]
    P = transform_points(cf.T6, ctx.hull_obj)
    low = P[int(np.argmin(P[:, 2]))]
    sz = float(np.sqrt(max(covariance_at(cov, cf.info6["c_table"], low)[2, 2], 0.0)))
    if not np.isfinite(sz) or sz > RISER_MAX_SIGMA_MM:
        return cf
    heights = ctx.declared_tops
    z = np.array(sorted(heights))
    m = np.abs(z - low[2]) / max(sz, 1e-6)
    order = np.argsort(m)
    if m[order[0]] > RISER_MATCH_SIGMAS or (len(m) > 1 and m[order[1]] < RISER_APART_SIGMAS):
        return cf
    # refitted from where the free fit put the part, not from its flat start: that start can be a
    # reading on another top that the free fit slid down the line of sight (devset setup_022, one stop
    # over-exposed: the start on the 25 mm top, the free fit at 20.5 mm and 0.7 mm off; refitted on the
    # 20 mm top from the start, 8.8 mm off)
    on = _fit6(ctx, cf.best, rest_z=float(z[order[0]]), start=flat_at(cf.best.T, cf.T6, ctx.model.center_obj))
    if "sol" not in on.info6 or on.conflict:
        return cf
    return replace(on, riser_mm=float(heights[float(z[order[0]])]))


def _result(ctx: LocateContext, cf: ContactFit, rv: Rivals, sym_scores: list, distinct_drop: float) -> ObjectPose:
    """The located part: the 6-DoF pose (or the flat one where height and tilt are not known), its
    sigma, tilt, datum and flags."""
    model, o, K, dist = ctx.model, ctx.opts, ctx.K, ctx.dist
    best, T6, info6 = cf.best, cf.T6, cf.info6
    st = best.state
    n_rest = inv(model.resting_states[st].T_rest_obj)[:3, :3] @ np.array([0.0, 0.0, 1.0])
    up = T6[:3, :3] @ n_rest
    tilt = float(np.degrees(np.arccos(np.clip(up[2], -1.0, 1.0))))
    flags = []
    tilt_sigma = float("nan")
    if "sol" in info6:        # a decision: at the fit's own (wide) scale
        cov6 = covariance(info6, K, dist, ctx.T_cam_table, data_scale=o.sigma_scale)[0]
        tilt_sigma = float(np.degrees(np.sqrt(max(cov6[3, 3] + cov6[4, 4], 0.0))))
    if "sol" in info6 and tilt > o.max_tilt_deg and tilt > 3.0 * tilt_sigma:
        flags.append("tilt")          # the free fit says: not lying flat
    # The pose returned is the 6-DoF fit with the contact prior (maximum a-posteriori): where the
    # image cannot tell height and tilt, the contact holds them; where it can (a chip under an edge),
    # the image wins. Its covariance is the posterior, so the stated sigma covers all six axes.
    T_table_obj, info = (T6, info6) if "sol" in info6 else (best.T, best.info)
    if cf.conflict:
        # the image pulls the part far off the surface it should rest on (or tilts it by degrees):
        # either it does not rest as assumed or the fit is caught on other edges; keep the flat
        # pose and say that its height and tilt are not known
        flags.append("contact")
        T_table_obj, info = best.T, best.info
    # of the poses that look exactly the same, give the most upright one (the part's CAD z up, as a
    # 3-axis work offset needs it); which of them is meant stays the operator's choice
    S_up = max([np.eye(4)] + [s.S for s in model.symmetries if s.exact],
               key=lambda S: round(float((T_table_obj @ S)[2, 2]), 6))
    T_table_obj, T6 = T_table_obj @ S_up, T6 @ S_up
    # the stated covariance: of the fit as made (its prior weighed at sigma_scale), the image's noise
    # at its calibrated scale (uncertainty.STATED_SIGMA_SCALE); the frame's error moves the fit as made
    cov, inl, rms = covariance(info, K, dist, ctx.T_cam_table, data_scale=o.sigma_scale,
                               stated_scale=o.stated_sigma_scale)
    if info is info6:           # the tilt's sigma as stated (the flag above was decided at the fit's scale)
        tilt_sigma = float(np.degrees(np.sqrt(max(cov[3, 3] + cov[4, 4], 0.0))))
    if cf.conflict:
        cov = cov + unknown_height_covariance(T_table_obj, model, ctx.T_cam_table, o.riser_sigma_mm)
    cov_table, cov_k = np.zeros((6, 6)), np.zeros((6, 6))
    if ctx.table_cov is not None:           # the frame the pose is given in is itself measured
        cov_table, cov_k = frame_covariances(info, K, dist, ctx.T_cam_table, *ctx.table_cov, data_scale=o.sigma_scale)
        cov_table = cov_table + cov_k
    cov_o, sigma = origin_sigma(cov + cov_table, T_table_obj, model)
    if "sol" not in info6 or cf.conflict:     # height and tilt not measured, only assumed
        sigma.update(z_mm=float("nan"), rx_deg=float("nan"), ry_deg=float("nan"))
    # the spin of a round part about its own axis is not seen: undetermined, a datum question
    spin_free = set()
    if model.continuous_axis_obj is not None:
        ax = np.abs(T_table_obj[:3, :3] @ model.continuous_axis_obj)
        spin_free = {key for k, key in enumerate(("rx_deg", "ry_deg", "rz_deg")) if ax[k] > 0.9}
    for key in spin_free:
        sigma[key] = float("nan")
    datum = choose_datum(model, T_table_obj, best.score, sym_scores, rv.flips, rv.flips_open, rv.flip_runner,
                         o.min_margin)
    if datum.ambiguous:
        flags.append("datum_ambiguous")
    # an axis whose sigma is unknown fails (NaN compares false); only the spin of a round part about
    # its own axis is exempt: it is a datum question, not an uncertainty
    uncertainty_ok = bool(all(sigma[k] <= o.max_sigma_mm for k in ("x_mm", "y_mm", "z_mm")) and
                          all(sigma[k] <= o.max_sigma_deg for k in ("rx_deg", "ry_deg", "rz_deg") if k not in spin_free))
    if not uncertainty_ok:
        flags.append("uncertainty")
    n_vis = len(best.es.index)
    if n_vis < 60:
        flags.append("few_edges")
    vis_frac = 1.0
    W, H = ctx.eimg.width, ctx.eimg.height
    if ctx.occluders_cam:
        es_free = visible_edge_samples(model, ctx.T_cam_table @ T_table_obj, K, dist, W, H, occlusion_test=True,
                                       subset=ctx.sub_fine)
        vis_frac = n_vis / max(len(es_free.index), 1)
    height = float(transform_points(T_table_obj @ inv(model.resting_states[st].T_rest_obj), np.zeros((1, 3)))[0, 2])
    return ObjectPose(
        model_name=model.name, T_cam_obj=ctx.T_cam_table @ T_table_obj, T_table_obj=T_table_obj, resting_state=st,
        score=float(best.score), inlier_edge_fraction=min(1.0, float(inl.sum()) / max(n_vis, 1)), residual_px=rms,
        visible_fraction=float(vis_frac), n_edge_samples=int(info["n_used"]), sigma=sigma, tilt_deg=tilt,
        tilt_sigma_deg=tilt_sigma, T_table_obj_6dof=T6,
        unexplained_fraction=ctx.unexplained(T_table_obj),
        supported_edge_px=best.support_px, uncertainty_ok=uncertainty_ok, height_offset_mm=height,
        held_by=tuple(c.name for c in cf.prior[4] if c.holds_place) if len(cf.prior) > 4 and not cf.conflict else (),
        riser_mm=cf.riser_mm,
        margin=float(rv.margin), runner_up_score=float(rv.runner),
        distinctiveness=distinct_drop, covariance=cov_o,
        table_covariance=origin_sigma(cov_table, T_table_obj, model)[0],
        intrinsics_covariance=origin_sigma(cov_k, T_table_obj, model)[0],
        equivalent_poses=datum.equivalent, datum_ambiguous=datum.ambiguous, datum_note=datum.note,
        flags=tuple(flags), timings_ms=dict(ctx.timings))
