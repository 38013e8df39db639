"""One setup image -> table pose -> object poses on the table: the stages in order.

``localize`` runs the stages (table markers, then each object), hands each finished stage to an
optional ``on_stage`` callback (numbers, time, picture) and returns a :class:`LocalizeResult` whose
objects carry ``T_table_obj = inv(T_cam_table) @ T_cam_obj``. It has no database or web state, so the
CLI, the service's worker and the tests call the same function.

Clamps and vises are located before workpieces so that their fitted meshes can hide the workpiece
edges they cover (occluders), as in a real vise setup.
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass, field
from typing import Any, Callable, NamedTuple

import cv2
import numpy as np
import trimesh

from app.geometry.guides import (
    GUIDE_CAPTURE_DEG,
    GUIDE_CAPTURE_MM,
    OFF_GUIDE_DEG,
    OFF_GUIDE_MM,
    guide_deviation,
    guide_start_poses,
)
from app.geometry.model_edges import PreparedModel, prepare_model
from app.geometry.solid_overlap import interior_points, share_inside
from app.geometry.transforms import make_pose, transform_points
from app.geometry.support_surfaces import CARRYING_KINDS
from app.vision import object_pose
from app.vision.blas_threads import one_blas_thread
from app.vision.fiducials import draw_table, locate_table
from app.vision.intrinsics import DEFAULT_INTRINSICS_SIGMA
from app.vision.object_pose.search import SEARCH_THREADS
from app.vision.overlay_text import put_banner, put_label, style_for
from app.vision.photo_model import PhotoModel, View, decide_lookalikes, known_edge_mask
from app.vision.photo_model import locate as locate_photo

FIXTURE_KINDS = CARRYING_KINDS                 # clamps and supports: they carry parts
# Fixtures are often half hidden by the part they hold (jaws, parallels under it): they are accepted
# at a lower share of supported edges than a workpiece, with the same margin and distinctiveness.
FIXTURE_MIN_SCORE = 0.35
# A fixture stands on a ground base, bolted down: its contact is much tighter than a part's. Its
# starts are searched once more around themselves before the fine fit (settle_starts): the plane
# search leaves a vise as big as a third of the table a coarse cell and a few degrees off, too far
# for the fine fit (devset vise bodies located 8 -> 10 of 16, about 2-4 s more per fixture). Its plane
# search is denser too (cells of at most 8 mm, 120 re-scored, 10 starts): a half-hidden vise's true
# cell ranked 57th-376th on the 16 mm grid and never reached the fine stage (9 -> 13 of 16, ~1 s more).
# At least 64 maxima of every turn go on to the image, whose scores leave out what the fixture hides
# behind its own body (self_occlusion): a vise seen from high in front ranked 64th in its turn, and
# counted its base and the lower steps of its ways, under its body, as misses (devset setup_029).
# A fixture's outline holds the part it carries (the devset's vise bodies leave 40-69 % of the edges
# inside theirs unexplained, a moving jaw more than 70 %): the unexplained-edge limit is a part's test.
NOT_A_PART = {"max_unexplained": 1.0}
# Two located objects cannot fill the same space: a real contact (a part on a parallel, between a vise's
# jaws, under a strap) interpenetrates by the fits' errors only; a fixture fitted to a part's edges lies
# in the part (a 150 x 32 mm parallel found along a bracket's front edge on the table: 45-94 % of it
# inside the bracket). Share of either solid's volume inside the other (app.geometry.solid_overlap).
OVERLAP_MAX = 0.2
FIXTURE_OPTIONS = {"contact_sigma_mm": 0.05, "contact_sigma_deg": 0.05, "free_contact_sigma_deg": 0.05,
                   "settle_starts": True, "n_coarse": 120, "coarse_step_max_mm": 8.0, "n_starts": 10,
                   "turn_maxima": 64, "self_occlusion": True, **NOT_A_PART}


def kind_options(kind: str) -> dict:
    """Locate options that follow from a library model's kind (:data:`NOT_A_PART` for all but a
    workpiece); the support chain's fixtures get :data:`FIXTURE_OPTIONS`, which include them."""
    return {} if kind == "workpiece" else NOT_A_PART

# BGR colours per object, in order (workpiece first): distinct on grey metal.
COLOURS = [(0, 220, 0), (255, 160, 0), (0, 200, 255), (255, 0, 255), (255, 255, 0), (80, 80, 255)]


@dataclass(eq=False)
class Candidate:
    """A library model that may be on the table (mesh in its own CAD frame, mm)."""

    name: str
    mesh: trimesh.Trimesh
    kind: str = "workpiece"                  # workpiece | clamp | support | table
    model_id: int | None = None
    revision: int | None = None
    T_obj_datum: np.ndarray | None = None
    prepared: PreparedModel | None = None    # filled lazily (prepare_model costs ~1 s; callers cache)
    # fixtures: the plane patches a part can rest on, in the model frame ({"name", "z_mm",
    # "outline_xy"}); None: derived from the mesh's upward faces
    support_surfaces: list[dict] | None = None
    # a model taught from pictures (app/vision/photo_model/): located by its edge template in the
    # table plane instead of the CAD search; ``mesh`` is then its outline extruded to its height
    photo: PhotoModel | None = None
    # fixtures: what carries it and how it moves there ({"carrier", "T_carrier_obj", "axis",
    # "travel_mm"}, carrier frame, mm: app/geometry/guides.py), ``carrier`` being the carrier
    # candidate's name; in the support chain it is searched only along the guide. None: stands free
    guide: dict | None = None

    def prepare(self) -> PreparedModel:
        if self.prepared is None:
            # a table is never searched for, only masked out: its symmetry does not matter
            # fixtures are modelled standing as they are used (CAD z up) and never lie otherwise
            self.prepared = prepare_model(self.mesh, self.name, detect_symmetry=self.kind != "table",
                                          upright_only=self.kind in FIXTURE_KINDS)
        return self.prepared


@dataclass
class Stage:
    """One finished stage: its numbers, its time and its picture."""

    name: str
    ok: bool
    ms: float
    message: str
    data: dict = field(default_factory=dict)
    image: np.ndarray | None = None


@dataclass
class LocalizeResult:
    ok: bool
    reason: str
    table: dict | None
    objects: list[dict]
    not_found: list[dict]
    stages: list[Stage]
    overlay: np.ndarray
    timings_ms: dict

    def to_dict(self) -> dict:
        return {"ok": self.ok, "reason": self.reason, "table": self.table, "objects": self.objects,
                "not_found": self.not_found, "timings_ms": self.timings_ms,
                "stages": [{"name": s.name, "ok": s.ok, "ms": round(s.ms, 1), "message": s.message}
                           for s in self.stages]}


def object_entry(cand: Candidate, pose: object_pose.ObjectPose, colour) -> dict:
    d = pose.to_dict()
    d.update(name=cand.name, kind=cand.kind, model_id=cand.model_id, revision=cand.revision,
             colour_bgr=list(colour),
             T_obj_datum=None if cand.T_obj_datum is None else np.asarray(cand.T_obj_datum).tolist())
    return d


def marker_labels_table(layout: dict, scale: float = 1.4) -> list[np.ndarray]:
    """The printed marker labels on the table (table frame, mm, (4, 3) each): the black square grown
    by ``scale`` about its centre to take in the white quiet zone (one cell of a 5x5 code is 1.29)."""
    from app.vision.fiducials import marker_corners_table_mm

    out = []
    for m in layout.get("markers", []):
        c = marker_corners_table_mm(m)
        centre = c.mean(axis=0)
        out.append(centre + scale * (c - centre))
    return out


def draw_overlay(image: np.ndarray, K, dist, table_result, located: list[tuple[Candidate, Any]]) -> np.ndarray:
    """The operator's picture: markers (used green, rejected red) and each object's fitted edges with its
    name, score and position; a failure as its best candidate in red with the reason. Text and dots are
    sized to the picture (overlay_text), so they read at full HD too."""
    out = draw_table(image, table_result) if table_result is not None else (
        image.copy() if image.ndim == 3 else cv2.cvtColor(image, cv2.COLOR_GRAY2BGR))
    T_cam_table = getattr(table_result, "T_cam_table", None)
    banner = 1  # line 0 holds the table's summary
    for i, (cand, pose) in enumerate(located):
        if isinstance(pose, object_pose.ObjectPose):
            T = pose.T_table_obj
            label = (f"{pose.model_name} {pose.score:.0%} x{T[0, 3]:.1f} y{T[1, 3]:.1f} "
                     f"C{np.degrees(np.arctan2(T[1, 0], T[0, 0])):.2f}")
            out = draw_model_edges(out, K, dist, pose.T_cam_obj, cand.prepare(), COLOURS[i % len(COLOURS)], label)
        elif pose.candidates and T_cam_table is not None:
            T_cam_obj = np.asarray(T_cam_table) @ np.asarray(pose.candidates[0]["T_table_obj"])
            out = draw_model_edges(out, K, dist, T_cam_obj, cand.prepare(), (0, 0, 255), pose.reason[:120])
        else:
            put_banner(out, pose.reason, (0, 0, 255), line=banner)
            banner += 1
    return out


#: recognition that accepts no part on the surfaces and declared risers searches this many of its best
#: ranked models again over risers of any height
RECOGNISE_AGAIN = 8


@one_blas_thread
def localize(image: np.ndarray, K: np.ndarray, dist: np.ndarray, table_layout: dict,
             candidates: list[Candidate], *, recognise: bool = False,
             on_stage: Callable[[Stage], None] | None = None,
             on_progress: Callable[[object_pose.Progress], None] | None = None, min_score: float = 0.5,
             min_margin: float = 0.1, height_offsets_mm=(0.0,), table_model: Candidate | None = None,
             chain: bool = False, free_height: bool = False,
             riser_heights_mm: tuple | None = None,
             intrinsics_sigma: tuple | None = DEFAULT_INTRINSICS_SIGMA,
             search_threads: int = SEARCH_THREADS) -> LocalizeResult:
    """Locate the table and the candidates in one image.

    Parameters
    ----------
    image : (H, W, 3) BGR or (H, W) grey uint8, as taken (distorted)
    K : (3, 3) camera matrix, px; dist : (5,) OpenCV distortion
    table_layout : fiducial layout of the table (DESIGN format)
    candidates : models to locate (``recognise=False``: each is expected) or to choose from
        (``recognise=True``: the fixtures among them are located first, as in the chain, and kept where
        found; the workpieces are then looked for on the table, on the located fixtures' surfaces and
        on the declared risers' tops, and those recognised with a margin are accepted; when none is,
        the best :data:`RECOGNISE_AGAIN` are searched again over risers of any height)
    on_stage : called with each finished :class:`Stage`
    on_progress : called while recognition runs (30-60 s over a 20-model library), with how many of
        its models are searched and fitted (:class:`app.vision.object_pose.Progress`); what it raises
        ends the call (the service's job stopped)
    table_model : the table's own model (its frame is the table frame): its border, slots and steps are
        removed from the image's edges before objects are searched (they are not the part)
    chain : the support chain (fixtures first, parts on their surfaces or over risers)
    riser_heights_mm : the shop's declared risers (its parallels' heights, mm), which a part over a
        riser of unknown height is tested against (support chain only), besides the heights of the
        candidates of kind ``support`` (:func:`riser_heights`), hidden under the part or not
    intrinsics_sigma : how well ``K`` is known (focal length relative, cx px, cy px; 1 sigma): it
        enters every object's sigma (:func:`app.vision.fiducials.locate_table`); None: ``K`` exact
    search_threads : threads of each plane search (its resting states at once): the cores this
        call may have (the service gives each job its share); the result does not depend on it
    """
    K = np.asarray(K, float)
    dist = np.asarray(dist, float).ravel()
    stages: list[Stage] = []
    t_all = time.perf_counter()

    def done(stage: Stage) -> None:
        stages.append(stage)
        if on_stage is not None:
            on_stage(stage)

    # --- table
    t = time.perf_counter()
    table = locate_table(image, K, dist, table_layout, intrinsics_sigma=intrinsics_sigma)
    table_ms = (time.perf_counter() - t) * 1e3
    table_pic = draw_table(image, table)
    if not table:
        done(Stage("table markers", False, table_ms, table.reason, table.to_dict(), table_pic))
        return LocalizeResult(False, table.reason, table.to_dict(), [], [], stages, table_pic,
                              {"table": table_ms, "total": (time.perf_counter() - t_all) * 1e3})
    tdict = table.to_dict()
    read = table.gamma_reading
    gamma_note = f"; {read.reason}" if read is not None and read.changed else ""
    done(Stage("table markers", True, table_ms,
               f"table located from markers {', '.join(map(str, table.ids_used))}; RMS {table.rms_px:.2f} px"
               f"{gamma_note}", tdict, table_pic))
    known = ((table_model.prepare(), np.eye(4)),) if table_model is not None else ()
    table_top = _table_top(known)
    labels = marker_labels_table(table_layout)
    table_xy = _table_xy(table_top, table_layout)
    edges = _edges_once(image, table.gamma)
    if chain or recognise:
        table, levelled = _levelled(image, K, dist, table, candidates, known, labels, edges, table_top, table_xy,
                                    min_margin=min_margin, search_threads=search_threads)
        if levelled is not None:
            done(levelled)
            tdict = table.to_dict()
    T_cam_table = table.T_cam_table
    table_cov = table.frame_error()     # its error (and the intrinsics') enters every object's sigma
    photo_view = None
    if any(c.photo is not None for c in candidates):   # the picture as photo models see it
        photo_view = View.of(image, K, dist, table, known_edge_mask(image.shape[:2], K, dist, T_cam_table,
                                                                    list(known), labels))
    # --- objects: clamps first (they occlude the workpiece), then workpieces
    ordered = sorted(candidates, key=lambda c: 0 if c.kind == "clamp" else 1)
    located: list[tuple[Candidate, Any]] = []
    objects, not_found = [], []
    if recognise and ordered:
        risers = riser_heights(candidates, riser_heights_mm or ())
        # the library's fixtures first, as the chain does: the parts are then looked for on their faces
        # (and the declared risers' tops), their edges are not a part's (a 32 mm block "recognised" on
        # a vise's jaw), and they hide what lies behind them; a fixture not there is no failure here.
        # Every workpiece is searched on all those planes: ranked on the surfaces alone (the risers'
        # planes left to the best four), the devset's parts on parallels ranked too low (13 of 40
        # right instead of 21)
        held = Chain([], [], [], [])
        fixtures = [c for c in ordered if c.kind in FIXTURE_KINDS]
        if fixtures:
            held = _locate_chain(image, K, dist, T_cam_table, fixtures, known, labels, table, done,
                                 min_score=min_score, min_margin=min_margin, photo_view=photo_view,
                                 photo_xy=table_xy, edges=edges, table_cov=table_cov, search_threads=search_threads)
            located += held.located
        t = time.perf_counter()
        cad = [c for c in ordered if c.photo is None and c.kind not in FIXTURE_KINDS]
        rec = None
        searched_again = False
        by_name = {c.name: c for c in ordered}
        accepted, ranked, reasons = [], [], []
        if cad:
            from app.vision.support_chain import part_search_planes, search_planes, table_surface

            models = [c.prepare() for c in cad]
            surfaces = held.surfaces or [table_surface()]
            placed = _placed(held.located)
            # what the scene says beside the planes: the surfaces' heights, the declared risers, the jaws
            # and the located fixtures' bodies
            scene = {"known_heights_mm": tuple(s.height_mm for s in surfaces), "riser_heights_mm": risers,
                     "clamp_faces": tuple(held.jaw_faces), "occluder_models": placed}
            where = {"height_offsets_mm": height_offsets_mm, "free_height": free_height}
            if held.located or risers:
                radius = max(0.5 * m.diameter_mm for m in models)
                where = {"height_offsets_mm": tuple(search_planes(surfaces, radius, table_risers=(0.0, *risers),
                                                                  fixture_risers=(0.0, *risers))), **scene}
            rec_kw = dict(min_score=max(min_score, 0.6), min_margin=min_margin,
                          known_models=tuple(known) + tuple(placed), known_regions=labels,
                          table_covariance=table_cov, gamma=table.gamma, search_threads=search_threads,
                          table_extent_xy=table_top)
            rec = object_pose.recognise(image, K, dist, T_cam_table, models, **rec_kw, **where,
                                        on_progress=on_progress)
            if not rec and not free_height:
                # nothing on those planes: the best few there are searched again where the chain searches
                # a named part, over risers of any height with their height fitted (a part on parallels
                # in a vise that it hides: devset setup_036). Only then and only those: every model
                # searched so always cost 2-3x the time and fitted other parts to a vise's or a tool's
                # edges at odd heights (setup_021, 026)
                again = {r["model"] for r in rec.ranked[:RECOGNISE_AGAIN]}
                best = [m for m in models if m.name in again]
                radius = max(0.5 * m.diameter_mm for m in best)
                anywhere = {"height_offsets_mm": tuple(part_search_planes(surfaces, radius, risers)),
                            "free_height": True, **scene}
                first = rec

                def again_told(p: object_pose.Progress) -> None:
                    if on_progress is not None:
                        on_progress(dataclasses.replace(p, message=f"none found on the table or the fixtures; the best "
                                                                   f"{len(best)} again over risers of any height: "
                                                                   f"{p.message}"))

                rec = object_pose.recognise(image, K, dist, T_cam_table, best, **rec_kw, **anywhere,
                                            on_progress=again_told)
                rec = dataclasses.replace(rec, timings_ms={**{f"first_{k}": v for k, v in first.timings_ms.items()},
                                                           **rec.timings_ms})
                searched_again = True
            # what each recognised part rests on, as the chain states it for a named one
            accepted += [dataclasses.replace(p, chain=_carrier(surfaces, p, by_name[p.model_name]))
                         for p in rec.accepted]
            ranked += list(rec.ranked)
            if not rec:
                reasons.append(rec.reason)
        photo = [c for c in ordered if c.photo is not None and c.kind not in FIXTURE_KINDS]
        if photo:
            got, why = _recognise_photo(photo_view, photo, table_xy, max(min_score, 0.6), min_margin, ranked)
            accepted, lost = _merge_by_place(accepted, got, by_name, min_margin)
            ranked += lost
            reasons += why
        # the part set up is the one that explains most of the picture, and the first workpiece's datum is
        # the offset the page proposes: by score, devset setup_003 proposed a 26 mm pin block fitted to
        # clutter (70.5 %, 262 px of edges) before the plate (67.3 %, 2180 px)
        accepted.sort(key=lambda p: -p.supported_edge_px)
        for pose in accepted:
            located.append((by_name[pose.model_name], pose))
        reason = "" if accepted else "not recognised: " + "; ".join(r.removeprefix("not recognised: ")
                                                                      for r in reasons if r)
        msg = ("recognised " + ", ".join(f"{p.model_name} ({r})" if (r := _rests_on(p)) else p.model_name
                                         for p in accepted)) if accepted else reason
        data = {"ok": bool(accepted), "accepted": [a.to_dict() for a in accepted], "ranked": ranked,
                "reason": reason, "searched_any_height": searched_again,
                "timings_ms": dict(rec.timings_ms) if rec is not None else {}}
        done(Stage("recognition", bool(accepted), (time.perf_counter() - t) * 1e3, msg, data,
                   draw_overlay(image, K, dist, table, located)))
        if not accepted:
            not_found.append({"name": None, "reason": reason, "ranked": ranked})
    elif chain:
        chain_kw = dict(min_score=min_score, min_margin=min_margin, photo_view=photo_view, photo_xy=table_xy,
                        edges=edges, table_cov=table_cov, risers=riser_heights(candidates, riser_heights_mm or ()),
                        search_threads=search_threads)
        found = _locate_chain(image, K, dist, T_cam_table, ordered, known, labels, table, done, **chain_kw)
        found = _looked_under(found, image, K, dist, T_cam_table, ordered, known, labels, table, done, chain_kw)
        located, not_found = found.located, found.not_found
    else:
        for cand in ordered:
            t = time.perf_counter()
            if cand.photo is not None:
                pose = locate_photo(photo_view, cand.photo, cand.name, search_xy=table_xy, min_score=min_score,
                                    min_margin=min_margin)
            else:
                occluders = [(c.prepare(), p.T_table_obj) for c, p in located
                             if isinstance(p, object_pose.ObjectPose)]
                pose = object_pose.locate_object(image, K, dist, T_cam_table, cand.prepare(), edge_image=edges(),
                                                 table_covariance=table_cov,
                                                 occluder_models=occluders, min_score=min_score,
                                                 min_margin=min_margin, height_offsets_mm=height_offsets_mm,
                                                 known_models=known, free_height=free_height, known_regions=labels,
                                                 table_extent_xy=table_top, search_threads=search_threads,
                                                 **kind_options(cand.kind))
            _report(cand, pose, (time.perf_counter() - t) * 1e3, located, not_found, done, image, K, dist, table)
    located = _drop_overlapping(located, not_found, done, fixtures_asked=not recognise)
    for i, (cand, pose) in enumerate(located):
        objects.append(object_entry(cand, pose, COLOURS[i % len(COLOURS)]))
    overlay = draw_overlay(image, K, dist, table, located)

    workpieces = [o for o in objects if o["kind"] == "workpiece"]
    if not objects:
        reason = not_found[0]["reason"] if not_found else "no candidate models to look for"
        ok = False
    elif not workpieces and any(c.kind == "workpiece" for c in candidates):
        # fixtures alone are no setup: the part looked for (or recognition's choice) is missing
        reason = "; ".join(n["reason"] if n.get("name") is None else f"{n['name']}: {n['reason']}" for n in not_found)
        ok = False
    else:
        ok = True
        reason = ""
        if not_found:
            names = ", ".join(str(n["name"]) for n in not_found if n.get("name"))
            reason = f"{len(objects)} of {len(objects) + len(not_found)} objects located; {names} not found"
    return LocalizeResult(ok, reason, tdict, objects, not_found, stages, overlay,
                          {"table": table_ms, "total": (time.perf_counter() - t_all) * 1e3})


def _drop_overlapping(located: list, not_found: list, done: Callable[[Stage], None], *,
                      fixtures_asked: bool = True) -> list:
    """``located`` without the objects that would fill the same space as another: of a fixture and a
    workpiece whose solids overlap by more than :data:`OVERLAP_MAX` of either, the one that explains
    fewer image edges is taken out, said in a stage and added to ``not_found`` with the reason: a
    workpiece always, a fixture where it was asked for (``fixtures_asked``; recognition looks for
    every fixture of the library, and one that is not there is no object missing)."""
    t = time.perf_counter()
    points: dict[int, np.ndarray] = {}

    def inside(a, b) -> float:
        (ca, pa), (cb, pb) = a, b
        if id(ca) not in points:
            points[id(ca)] = interior_points(ca.mesh)
        return share_inside(ca.mesh, pa.T_table_obj, cb.mesh, pb.T_table_obj, points[id(ca)])

    out, notes = list(located), []
    for f in [x for x in located if x[0].kind in FIXTURE_KINDS]:
        for w in [x for x in located if x[0].kind == "workpiece"]:
            if f not in out or w not in out or not _spheres_meet(f, w):
                continue
            share = max(inside(f, w), inside(w, f))
            if share <= OVERLAP_MAX:
                continue
            # image edges (px) each fit explains: CAD and photo poses both say
            keep, drop = (w, f) if w[1].supported_edge_px >= f[1].supported_edge_px else (f, w)
            out.remove(drop)
            reason = (f"taken out: it would fill the same space as {keep[0].name} ({share:.0%} of one of them "
                      f"inside the other), which explains more of the picture's edges")
            entry = {"name": drop[0].name, "model_id": drop[0].model_id, "reason": reason, "kind": "overlaps"}
            if fixtures_asked or drop[0].kind == "workpiece":
                not_found.append(entry)
            notes.append(entry)
    if notes:
        done(Stage("solid check", True, (time.perf_counter() - t) * 1e3,
                   "; ".join(f"{n['name']} {n['reason']}" for n in notes), {"taken_out": notes}))
    return out


def _spheres_meet(a, b) -> bool:
    """Whether two placed objects' bounding spheres meet (mm, table frame): else they cannot overlap."""
    (ca, pa), (cb, pb) = a, b
    centre = [transform_points(p.T_table_obj, c.mesh.bounding_sphere.primitive.center[None])[0]
              for c, p in ((ca, pa), (cb, pb))]
    radius = ca.mesh.bounding_sphere.primitive.radius + cb.mesh.bounding_sphere.primitive.radius
    return bool(np.linalg.norm(centre[0] - centre[1]) < radius)


def _report(cand, pose, ms, located, not_found, done, image, K, dist, table, chain_text: str = "") -> None:
    """Record one object's result (located or not) as a stage with its picture."""
    if pose:
        located.append((cand, pose))
        s = pose.sigma
        msg = (f"{cand.name}: score {pose.score:.0%}, x {pose.T_table_obj[0, 3]:.2f} ± {s.get('x_mm', float('nan')):.2f} mm, "
               f"y {pose.T_table_obj[1, 3]:.2f} ± {s.get('y_mm', float('nan')):.2f} mm")
        if chain_text:
            msg += f"; {chain_text}"
        if pose.datum_ambiguous:
            msg += f"; {pose.datum_note}"
    else:
        not_found.append({"name": cand.name, "model_id": cand.model_id, "reason": pose.reason, "kind": pose.kind})
        msg = f"{cand.name}: {pose.reason}"
    done(Stage(f"locate {cand.name}", bool(pose), ms, msg, pose.to_dict(),
               draw_overlay(image, K, dist, table, [(cand, pose)])))


def _levelled(image, K, dist, table, candidates: list[Candidate], known, labels, edges, table_top, table_xy, *,
              min_margin: float, search_threads: int):
    """The table levelled by its biggest free-standing fixture found (of the :data:`LEVEL_TRIES`
    biggest) where its markers leave its tilt more open than the fixture's stance is
    (:mod:`app.vision.table_levelling`): (table, the stage that says so, or None where it was not
    tried). ``table_top``: where the chain searches (None: anywhere), ``table_xy``: the table's
    extent, at whose corners its height is least sure."""
    from app.vision import table_levelling as tl

    fixtures = [c for c in candidates if c.kind in FIXTURE_KINDS and c.photo is None and c.guide is None]
    tilt = max(table.sigma_rot_deg[:2])
    if not fixtures or tilt <= tl.LEVEL_MIN_TILT_DEG:
        return table, None
    t = time.perf_counter()
    frame = table.frame_error()
    x0, x1, y0, y1 = table_xy
    heights = tl.search_heights(frame, [(x0, y0), (x0, y1), (x1, y0), (x1, y1)])
    missed = []
    # a library holds more fixtures than a picture shows (recognition looks for all of them)
    for cand in _biggest_first(fixtures)[:LEVEL_TRIES]:
        model = cand.prepare()
        # searched over the heights the table's error allows, height and tilt free by as much; on no
        # face of the located frame (known_heights_mm None): it is that frame's error being measured
        pose = object_pose.locate_object(
            image, K, dist, table.T_cam_table, model, table_extent_xy=table_top,
            table_covariance=frame, edge_image=edges(), min_score=FIXTURE_MIN_SCORE,
            min_margin=min_margin, height_offsets_mm=heights, free_height=True, known_models=known,
            known_regions=labels, search_threads=search_threads,
            **{**FIXTURE_OPTIONS, "table_tilt_sigmas": tl.SEARCH_SIGMAS})
        if pose:
            pose = _off_the_table(cand, pose, table_top)
        if pose:
            break
        missed.append(pose.reason)
    ms = (time.perf_counter() - t) * 1e3
    if not pose:
        return table, Stage("table levelled", False, ms, f"table not levelled (its markers leave its tilt open to "
                            f"{tilt:.2f} deg): {'; '.join(missed)}", {}, None)
    if "contact" in pose.flags or not all(np.isfinite(pose.sigma[k]) for k in ("z_mm", "rx_deg", "ry_deg")):
        return table, Stage("table levelled", False, ms, f"table not levelled: {cand.name}'s height and tilt "
                            f"could not be measured ({pose.score:.0%} of its edges)", {}, None)
    # its stance as the reported frame stands: the pose is given up to an exact symmetry of the model
    T_rest = model.resting_states[pose.resting_state].T_rest_obj
    up, base = max((tl.standing_base(T_rest @ S, model.support_vertices)
                    for S in [np.eye(4)] + [s.S for s in model.symmetries if s.exact]),
                   key=lambda ub: float((pose.T_table_obj[:3, :3] @ ub[0])[2]))
    lev = tl.level_table(table.T_cam_table, table.covariance, table.centroid_table_mm,
                         tl.stance(pose.T_table_obj, _own_covariance(pose), up, base))
    if not lev.chi2 <= tl.GATE_CHI2:
        return table, Stage("table levelled", False, ms, f"table not levelled: {cand.name} stands "
                            f"{lev.correction[0]:+.2f} / {lev.correction[1]:+.2f} deg and "
                            f"{lev.correction[2]:+.2f} mm off the markers' table, more than both their sigmas "
                            f"allow (chi-square {lev.chi2:.1f})", {}, None)
    sd = np.sqrt(np.clip(np.diag(lev.covariance), 0.0, None))
    msg = (f"table levelled by {cand.name} (its markers left its tilt open to {tilt:.2f} deg): their table "
           f"was off by {lev.correction[0]:+.2f} / {lev.correction[1]:+.2f} deg about x / y and "
           f"{lev.correction[2]:+.2f} mm in height under it; tilt sigma now {max(np.degrees(sd[:2])):.3f} deg")
    levelled = dataclasses.replace(table, T_cam_table=lev.T_cam_table, covariance=lev.covariance,
                                   sigma_rot_deg=np.degrees(sd[:3]), sigma_xyz_mm=sd[3:],
                                   warnings=table.warnings + (msg,))
    data = {**levelled.to_dict(), "levelled_by": cand.name, "chi2": round(lev.chi2, 2),
            "correction": [round(float(v), 4) for v in lev.correction]}
    return levelled, Stage("table levelled", True, ms, msg, data, draw_table(image, levelled))


def _table_top(known) -> tuple[float, float, float, float] | None:
    """(x_lo, x_hi, y_lo, y_hi) of the table model's top (mm, table frame), the first of ``known``;
    None without a table model. Parts stand on it: the floor around it, or a tool seen beyond its
    back edge, is not searched."""
    if not known:
        return None
    b = known[0][0].mesh.bounds
    return float(b[0, 0]), float(b[1, 0]), float(b[0, 1]), float(b[1, 1])


def _table_xy(table_top, layout: dict) -> tuple[float, float, float, float]:
    """(x_lo, x_hi, y_lo, y_hi) of the table top (mm, table frame) where photo models are searched: the
    table model's extent (``table_top``), else the markers' (grown by 100 mm)."""
    if table_top is not None:
        return table_top
    from app.vision.fiducials import marker_corners_table_mm

    c = np.vstack([marker_corners_table_mm(m) for m in layout.get("markers", [])] or [np.zeros((1, 3))])
    return (float(c[:, 0].min() - 100), float(c[:, 0].max() + 100), float(c[:, 1].min() - 100),
            float(c[:, 1].max() + 100))


def _recognise_photo(view: View, cands: list[Candidate], table_xy, min_score: float, min_margin: float,
                     ranked: list) -> tuple[list, list[str]]:
    """Photo models in the picture: each located on its own (its checks refuse an object with edges it
    lacks or without its own inner edges), then look-alikes at one place decided by the edges in which
    they differ (:func:`app.vision.photo_model.decide_lookalikes`). Returns (accepted poses, reasons)."""
    found = []
    for c in cands:
        p = locate_photo(view, c.photo, c.name, search_xy=table_xy, min_score=min_score, min_margin=min_margin)
        ranked.append({"model": c.name, "score": float(p.score if p else p.best_score), "ok": bool(p),
                       "reason": "" if p else p.reason, "source": "photo"})
        if p:
            found.append((c.name, c.photo, p))
    if not found:
        return [], ["photo models: " + "; ".join(r["reason"] for r in ranked if r.get("source") == "photo")]
    keep, refused = decide_lookalikes(view, found, min_margin=min_margin)
    for i, why in refused.items():
        ranked.append({"model": found[i][0], "score": float(found[i][2].score), "ok": False, "reason": why,
                       "source": "photo"})
    return [found[i][2] for i in keep], list(dict.fromkeys(refused.values()))


def _merge_by_place(cad: list, photo: list, by_name: dict, min_margin: float) -> tuple[list, list]:
    """CAD and photo models accepted at the same place (centres closer than half the larger model's
    size): the better score stays when it leads by ``min_margin``, else neither (ambiguous)."""
    out, lost = list(cad), []
    for p in photo:
        size_p = float(np.linalg.norm(by_name[p.model_name].mesh.extents[:2]))
        clash = next((q for q in out if np.hypot(*(q.T_table_obj[:2, 3] - p.T_table_obj[:2, 3]))
                      < 0.25 * max(size_p, float(np.linalg.norm(by_name[q.model_name].mesh.extents[:2])))), None)
        if clash is None:
            out.append(p)
        elif p.score >= clash.score + min_margin:
            out.remove(clash)
            out.append(p)
            lost.append({"model": clash.model_name, "score": clash.score, "ok": False,
                         "reason": f"lost to the photo model {p.model_name} at the same place"})
        elif clash.score < p.score + min_margin:
            out.remove(clash)
            lost += [{"model": n, "score": s, "ok": False,
                      "reason": f"{p.model_name} and {clash.model_name} fit the same place about equally well"}
                     for n, s in ((p.model_name, p.score), (clash.model_name, clash.score))]
        else:
            lost.append({"model": p.model_name, "score": p.score, "ok": False,
                         "reason": f"lost to {clash.model_name} at the same place"})
    return out, lost


def _edges_once(image: np.ndarray, gamma: float) -> Callable[[], object_pose.EdgeImage]:
    """The image's edges (:func:`object_pose.prepare_image`, decoded with the ``gamma`` the table's
    markers were read with), made on the first call and shared by every object searched in it: each object's search
    then masks its own known geometry out of a copy, and the per-image caches (the table's mask, the
    scorers' maps) are kept in it for the next object."""
    held: list = []

    def get() -> object_pose.EdgeImage:
        if not held:
            held.append(object_pose.prepare_image(image, gamma=gamma))
        return held[0]

    return get


def _placed(located: list) -> list:
    """``(PreparedModel, T_table_obj)`` of each located ``(Candidate, ObjectPose)``: as occluders and
    known geometry for the objects searched after them."""
    return [(c.prepare(), p.T_table_obj) for c, p in located]


class Chain(NamedTuple):
    """What the support chain found: the objects located and not, the surfaces that carry parts (the
    table's and the located fixtures' faces, :class:`app.vision.support_chain.SupportSurface`) and
    the located fixtures' vertical faces that hold a part (:func:`.object_pose.clamping.fixture_faces`)."""

    located: list
    not_found: list
    surfaces: list
    jaw_faces: list


def _locate_chain(image, K, dist, T_cam_table, ordered, known, labels, table, done, *, min_score, min_margin,
                  photo_view: View | None = None, photo_xy=None, edges: Callable | None = None, table_cov=None,
                  risers: tuple = (), search_threads: int = SEARCH_THREADS, look_under=None) -> Chain:
    """The support chain: fixtures first (biggest first, each on the surfaces found so far, standing
    as modelled; a guided one after its carrier and only along its guide there), then every workpiece
    on all support surfaces and over risers of unknown height, with the located fixtures' edges
    removed from the image and their bodies as occluders. Without workpieces among ``ordered`` it is
    the fixtures' half (recognition runs it before it chooses among the workpieces). ``look_under``:
    ``(parts, names)``: the located ``parts`` (pairs of a candidate and its pose) hide every fixture
    and their edges are not the fixtures'; the free-standing fixtures ``names`` are searched only
    under them (:func:`_looked_under`)."""
    from app.vision.object_pose.clamping import fixture_faces
    from app.vision.support_chain import (
        declared_surfaces,
        part_search_planes,
        search_planes,
        support_surfaces,
        table_surface,
    )

    located: list[tuple[Candidate, Any]] = []
    not_found: list[dict] = []
    surfaces = [table_surface()]         # where workpieces may rest (declared surfaces where given)
    seats = [table_surface()]            # where fixtures may stand (every upward face: a jaw rides a rail)
    jaw_faces: list = []                 # vertical faces of the located fixtures (clamping.fixture_faces)
    # everything in the chain stands on the table: search its top, not the floor around it
    table_xy = _table_top(known)
    fixtures = _biggest_first([c for c in ordered if c.kind in FIXTURE_KINDS])
    parts = [c for c in ordered if c.kind not in FIXTURE_KINDS]
    for cand in fixtures + parts:
        t = time.perf_counter()
        fixture = cand.kind in FIXTURE_KINDS
        # a guided fixture (a vise's moving jaw) is searched only along its guide on its located carrier
        guide = cand.guide if fixture and cand.photo is None else None
        carrier_pose = None if guide is None else next(
            (p for c, p in located if c.name == guide["carrier"]), None)
        if guide is not None and carrier_pose is None:
            # without its carrier a guided fixture has no place to be searched: anywhere else a plain
            # box fits many edges (a jaw "located" 556 mm from its vise)
            why = "was not found" if any(c.name == guide["carrier"] for c in ordered) else \
                "is not among the models looked for"
            pose = object_pose.ObjectFailure(
                model_name=cand.name, kind="not_found",
                reason=f"{cand.name} not searched: it rides on {guide['carrier']}, which {why}",
                best_score=0.0, candidates=(), timings_ms={})
            _report(cand, pose, (time.perf_counter() - t) * 1e3, located, not_found, done, image, K, dist, table)
            continue
        model = cand.prepare()
        occ = _placed(located)
        search_xy = table_xy
        if look_under is not None and fixture:
            # the parts over the fixtures hide them, and their edges are not the fixtures' (a jaw under a
            # plate, searched without it, was fitted 6.5 mm along its guide with a 0.1 mm sigma)
            occ += _placed(look_under[0])
            if cand.name in look_under[1]:      # searched only around those parts
                c = np.array([transform_points(p.T_table_obj, c_.prepare().center_obj[None])[0, :2]
                              for c_, p in look_under[0]])
                search_xy = (float(c[:, 0].min()), float(c[:, 0].max()), float(c[:, 1].min()),
                             float(c[:, 1].max()))
        kn = tuple(known) + tuple(occ)
        radius = 0.5 * model.diameter_mm
        if fixture:     # a fixture stands directly on a face found so far
            planes = search_planes(seats, radius, table_risers=(0.0,), fixture_risers=(0.0,))
        else:
            # the declared risers' tops are searched too (a parallel's 25 mm falls between the 7.5 mm steps)
            planes = part_search_planes(surfaces, radius, risers)
        guided = {} if carrier_pose is None else {
            "start_poses": guide_start_poses(guide, carrier_pose.T_table_obj),
            "start_capture": (GUIDE_CAPTURE_MM, GUIDE_CAPTURE_DEG),
            "keep_pose": _on_guide(guide, carrier_pose.T_table_obj),
            "guide_hold": _guide_hold(guide, carrier_pose)}
        if cand.photo is not None:     # taught from pictures: it rests on the table where it was taught
            pose = locate_photo(photo_view, cand.photo, cand.name, search_xy=photo_xy or table_xy,
                                min_score=FIXTURE_MIN_SCORE if fixture else min_score, min_margin=min_margin)
        else:
            pose = object_pose.locate_object(
                image, K, dist, T_cam_table, model, occluder_models=occ, table_extent_xy=search_xy,
                table_covariance=table_cov,
                edge_image=None if edges is None else edges(),
                min_score=FIXTURE_MIN_SCORE if fixture else min_score, min_margin=min_margin,
                height_offsets_mm=tuple(planes), free_height=not fixture, known_models=kn, known_regions=labels,
                known_heights_mm=tuple(s.height_mm for s in (seats if fixture else surfaces)),
                clamp_faces=() if fixture else tuple(jaw_faces),    # a fixture stands on its own
                riser_heights_mm=() if fixture else risers, search_threads=search_threads,
                **guided, **(FIXTURE_OPTIONS if fixture else {}))
            if pose and carrier_pose is not None:
                pose = _kept_on_guide(cand, pose, guide, carrier_pose.T_table_obj)
            if pose and fixture and guide is None:
                pose = _unlike_the_others(cand, pose, [c for c in ordered if c is not cand], image, K, dist,
                                          T_cam_table, occ, kn, labels, table_xy, table_cov, min_margin,
                                          edge_image=None if edges is None else edges())
        chain_text = ""
        if pose and fixture:
            carrier = _carrier(seats, pose, cand)
            if carrier[0].startswith("an unknown support"):
                # a fixture stands on the table or on a located fixture, never on something unseen:
                # a fit that floats is a plain box matched to other edges (a jaw without its vise)
                pose = object_pose.ObjectFailure(
                    model_name=cand.name, kind="not_found",
                    reason=f"{cand.name} not found: the best fit ({pose.score:.0%} of its edges) would stand on "
                           f"{carrier[0]}, not on the table or a located fixture",
                    best_score=pose.score, candidates=(), timings_ms=dict(pose.timings_ms))
            elif carrier == ("table",):
                pose = _off_the_table(cand, pose, table_xy)
        if pose:
            carrier = _carrier(seats if fixture else surfaces, pose, cand)
            pose = dataclasses.replace(pose, chain=carrier, guided_by=None if guide is None else guide["carrier"])
            chain_text = _rests_on(pose)
            if pose.guided_by:
                chain_text += f", guided by {pose.guided_by}"
            if pose.held_by:
                chain_text += ", held by " + " and ".join(dict.fromkeys(pose.held_by))
            if fixture:
                derived = support_surfaces(cand.mesh, pose.T_table_obj, cand.name)
                seats += derived
                # a part between its jaws will be held by its faces
                # (the part and the jaw share the table's error: the face holds by the jaw's own sigma)
                jaw_faces += fixture_faces(cand.mesh, pose.T_table_obj, cand.name, _own_covariance(pose))
                surfaces += (derived if cand.support_surfaces is None
                             else declared_surfaces(cand.support_surfaces, pose.T_table_obj, cand.name))
        _report(cand, pose, (time.perf_counter() - t) * 1e3, located, not_found, done, image, K, dist, table,
                chain_text)
    return Chain(located, not_found, surfaces, jaw_faces)


def _looked_under(found: Chain, image, K, dist, T_cam_table, ordered, known, labels, table, done,
                  chain_kw: dict) -> Chain:
    """The chain once more where a free-standing fixture was not found and a located workpiece rests
    on an unknown support: the fixture is searched under that part, within half its size of the
    part's centre, with the part hiding it and its edges not the fixture's. A plate lying over a vise
    hides most of it, and the plane search's scores over the whole table rank clutter above it (devset
    setup_021: 0.35 against 0.32) although the fit from its place supports 44 % of its edges. Taken
    where a missing fixture is found and every part of the first pass is located again; the stage
    "look under the parts" says which way it went."""
    got = {c.name for c, _ in found.located}
    missing = tuple(c.name for c in ordered if c.kind in FIXTURE_KINDS and c.guide is None and c.photo is None
                    and c.name not in got)
    floating = [(c, p) for c, p in found.located if c.kind not in FIXTURE_KINDS
                and getattr(p, "chain", ()) and p.chain[0].startswith("an unknown support")]
    if not missing or not floating:
        return found
    t = time.perf_counter()
    held: list[Stage] = []
    parts = " and ".join(c.name for c, _ in floating)
    # the fixtures first: where none turns up (a part on parallels with no vise there) the parts are
    # not searched again (devset setup_007: 20 -> 50 s CPU when they were)
    probe = _locate_chain(image, K, dist, T_cam_table, [c for c in ordered if c.kind in FIXTURE_KINDS], known,
                          labels, table, held.append, look_under=(floating, missing), **chain_kw)
    again = None
    if set(missing) & {c.name for c, _ in probe.located}:
        held = []
        again = _locate_chain(image, K, dist, T_cam_table, ordered, known, labels, table, held.append,
                              look_under=(floating, missing), **chain_kw)
    new = set() if again is None else {c.name for c, _ in again.located}
    ms = (time.perf_counter() - t) * 1e3
    if not (set(missing) & new) or not got <= new:
        msg = (f"{', '.join(missing)} not found under {parts} either" if not set(missing) & new else
               f"{', '.join(sorted(set(missing) & new))} found under {parts}, but {', '.join(sorted(got - new))} "
               "not located again: the first pass stands")
        done(Stage("look under the parts", False, ms, msg, {}, None))
        return found
    done(Stage("look under the parts", True, ms, f"{', '.join(sorted(set(missing) & new))} found under {parts}: "
               "the chain once more with it", {}, None))
    for st in held:
        done(st)
    return again


#: a fixture standing on the table has at least this share of its base over the table's top: bolted
#: into its slots it does not hang over its end (a 460 x 220 mm box that is not in the picture, fitted
#: to a table's slot edges and its end with 43 % of its base in the air, devset setup_039)
BASE_ON_TABLE_MIN = 0.8


def _off_the_table(cand: Candidate, pose, table_xy):
    """``pose``, or a failure where the fixture would hang over the table top ``table_xy`` (None: not
    known, not judged) by more than :data:`BASE_ON_TABLE_MIN` allows."""
    from app.vision.support_chain import share_of_base_within

    if table_xy is None:
        return pose
    on = share_of_base_within(table_xy, pose.T_table_obj, cand.prepare().support_vertices)
    if on >= BASE_ON_TABLE_MIN:
        return pose
    return object_pose.ObjectFailure(
        model_name=cand.name, kind="not_found",
        reason=f"{cand.name} not found: the best fit ({pose.score:.0%} of its visible edges) would stand with "
               f"{1 - on:.0%} of its base off the table top",
        best_score=pose.score, candidates=({"T_table_obj": pose.T_table_obj.tolist(), "score": pose.score},),
        timings_ms=dict(pose.timings_ms))


#: how many of the biggest free-standing fixtures are tried, biggest first, to level a table whose
#: markers leave its tilt open (each miss costs a search, 2-3 s)
LEVEL_TRIES = 2

#: two fixtures read at one place whose table-frame boxes differ by at most this (mm) fill the same space
LOOKALIKE_SAME_MM = 2.5


def _same_shape(a: trimesh.Trimesh, b: trimesh.Trimesh) -> bool:
    """Two meshes of the same part (two sets of one clamp in the library): interchangeable."""
    return (len(a.vertices) == len(b.vertices) and np.allclose(a.bounds, b.bounds, atol=0.01)
            and abs(float(a.area) - float(b.area)) <= 1e-3 * max(float(a.area), 1.0))


def _unlike_the_others(cand: Candidate, pose, others: list[Candidate], image, K, dist, T_cam_table, occ, kn,
                       labels, table_xy, table_cov, min_margin: float, edge_image=None):
    """``pose`` unless another fixture of the same kind and another shape, started where ``cand`` was
    found (its centre of mass there, turned as ``cand`` or half a turn), fits that place about as well
    (within ``min_margin``): then which of the two stands there is not told by the image, and the pose
    is refused as ambiguous. Devset setup_000: two strap clamp sets that differ only in their straps'
    length were each located at the other's place, one of them passed by its sigma."""
    model = cand.prepare()
    T = np.asarray(pose.T_table_obj, float)
    c = transform_points(T, model.center_obj[None])[0]
    z_low = float(transform_points(T, model.support_vertices)[:, 2].min())
    for other in others:
        if other.kind != cand.kind or other.photo is not None or other.guide is not None \
                or _same_shape(other.mesh, cand.mesh):
            continue
        om = other.prepare()
        starts = []
        for half_turn in (np.eye(3), np.diag([-1.0, -1.0, 1.0])):         # about its own z
            R = T[:3, :3] @ half_turn
            T0 = make_pose(R, c - R @ om.center_obj)
            T0[2, 3] += z_low - float(transform_points(T0, om.support_vertices)[:, 2].min())   # on the same face
            starts.append(T0)
        alt = object_pose.locate_object(
            image, K, dist, T_cam_table, om, occluder_models=occ, known_models=kn, known_regions=labels,
            edge_image=edge_image, table_extent_xy=table_xy, table_covariance=table_cov, start_poses=starts,
            min_score=FIXTURE_MIN_SCORE, min_margin=min_margin, free_height=False, **FIXTURE_OPTIONS)
        if not alt:
            continue
        T_alt = np.asarray(alt.T_table_obj, float)
        c_alt = transform_points(T_alt, om.center_obj[None])[0]
        near = np.linalg.norm((c_alt - c)[:2]) < 0.25 * max(model.diameter_mm, om.diameter_mm)
        # the two readings fill the same space (two sets whose straps differ by a millimetre or two,
        # devset setup_022 and 030): which one it is does not matter to what is planned around it
        V, V_alt = transform_points(T, cand.mesh.vertices), transform_points(T_alt, other.mesh.vertices)
        gap = max(float(np.abs(V.min(axis=0) - V_alt.min(axis=0)).max()),
                  float(np.abs(V.max(axis=0) - V_alt.max(axis=0)).max()))
        same_space = gap <= LOOKALIKE_SAME_MM
        if near and not same_space and alt.score >= pose.score - min_margin:
            return object_pose.ObjectFailure(
                model_name=cand.name, kind="ambiguous",
                reason=f"{cand.name} ambiguous: {other.name} fits its place as well ({alt.score:.0%} against "
                       f"{pose.score:.0%} of the visible edges); which of the two stands there is not seen: "
                       f"give its pose roughly",
                best_score=pose.score, candidates=(), timings_ms=dict(pose.timings_ms))
    return pose


def riser_heights(candidates: list[Candidate], declared=()) -> tuple[float, ...]:
    """Heights (mm) of the supports among ``candidates`` (parallels, blocks) standing as modelled:
    each declared support surface's height above the mesh's lowest point, else the mesh's height;
    with the ``declared`` heights that are positive and finite, each once, ascending. A part over a
    riser of unknown height is tested against them (``LocateOptions.riser_heights_mm``)."""
    out: set[float] = {float(h) for h in declared if 0 < float(h) < 1e4}
    for c in candidates:
        if c.kind != "support" or c.photo is not None:
            continue
        z0 = float(c.mesh.bounds[0, 2])
        tops = [float(s["z_mm"]) for s in (c.support_surfaces or [])] or [float(c.mesh.bounds[1, 2])]
        out.update(round(z - z0, 3) for z in tops if z - z0 > 0.5)
    return tuple(sorted(out))


def _biggest_first(fixtures: list[Candidate]) -> list[Candidate]:
    """Fixtures in the order they are searched: biggest first (by their box's diagonal), each carrier
    before what rides on it (:func:`_carriers_first`)."""
    return _carriers_first(sorted(fixtures, key=lambda c: -float(np.linalg.norm(c.mesh.extents))))


def _carriers_first(fixtures: list[Candidate]) -> list[Candidate]:
    """``fixtures`` in their order, except that a guided one comes after its carrier (when that is
    among them): a jaw is searched on its located vise. A cycle of guides keeps the given order."""
    names = {c.name for c in fixtures}
    out: list[Candidate] = []
    pending = list(fixtures)
    while pending:
        placed = {c.name for c in out}
        ready = next((c for c in pending if c.guide is None or c.guide["carrier"] not in names
                      or c.guide["carrier"] in placed or c.guide["carrier"] == c.name), pending[0])
        pending.remove(ready)
        out.append(ready)
    return out


def _on_guide(guide: dict, T_table_carrier: np.ndarray) -> Callable[[np.ndarray], bool]:
    """``T_table_obj -> bool``: the pose is on the guide (within OFF_GUIDE_MM / OFF_GUIDE_DEG)."""
    return lambda T: guide_deviation(guide, T_table_carrier, T).on_guide()


def _own_covariance(pose) -> np.ndarray:
    """A located fixture's pose covariance without the table's share: what it adds to what it holds
    or carries, which share the table's error with it."""
    return pose.covariance if pose.table_covariance is None else pose.covariance - pose.table_covariance


def _guide_hold(guide: dict, carrier_pose):
    """The turn a guided fixture keeps on its located carrier (:func:`.object_pose.clamping.guide_hold`),
    with the carrier's own turn error."""
    from app.vision.object_pose.clamping import guide_hold

    R_table_carrier = np.asarray(carrier_pose.T_table_obj, float)[:3, :3]
    R = R_table_carrier @ np.asarray(guide["T_carrier_obj"], float)[:3, :3]
    return guide_hold(guide["carrier"], R, R_table_carrier @ np.asarray(guide["axis"], float),
                      _own_covariance(carrier_pose))


def _kept_on_guide(cand: Candidate, pose, guide: dict, T_table_carrier: np.ndarray):
    """The pose if it stayed on the guide; else a failure that says how far it left it (the local
    search around each start may slide onto other edges: a pose off the guide is not the fixture)."""
    dev = guide_deviation(guide, T_table_carrier, pose.T_table_obj)
    if dev.on_guide():
        return pose
    lo, hi = guide["travel_mm"]
    return object_pose.ObjectFailure(
        model_name=cand.name, kind="not_found",
        reason=(f"{cand.name} not found: the best fit ({pose.score:.0%} of its visible edges) left its guide on "
                f"{guide['carrier']}: {dev.across_mm:.1f} mm across it, at travel {dev.travel_mm:.1f} mm (range "
                f"{lo:g} to {hi:g}), turned {dev.angle_deg:.1f} deg (at most {OFF_GUIDE_MM:g} mm and "
                f"{OFF_GUIDE_DEG:g} deg)"),
        best_score=pose.score, candidates=({"T_table_obj": pose.T_table_obj.tolist(), "score": pose.score},),
        timings_ms=dict(pose.timings_ms))


def _rests_on(pose) -> str:
    """'rests on ... on table' for a pose that states its chain (a photo model's does not), else ''."""
    chain = getattr(pose, "chain", ())
    return "rests on " + " on ".join(chain) if chain else ""


def _carrier(surfaces, pose, cand) -> tuple[str, ...]:
    """What the located object rests on, down to the table: its names, nearest first. A gap of more
    than 1 mm to the highest surface below is an unknown support (parallels or a block not in the
    library) of that height."""
    from app.vision.support_chain import placed_height_above

    # a strap clamp's stud reaches down into the T-slot: it stands on its heel block's face
    V = cand.mesh.vertices if cand.prepared is None else cand.prepared.support_vertices
    zmin = float(transform_points(pose.T_table_obj, np.asarray(V))[:, 2].min())
    s = placed_height_above(surfaces, pose.T_table_obj, V, tol_mm=1.0)
    if s is None:
        return (f"an unknown support ({zmin:.1f} mm above the table)", "table")
    names = []
    riser = getattr(pose, "riser_mm", None)
    if riser is not None:
        names.append(f"a declared riser {riser:g} mm high")
    elif zmin - s.height_mm > 1.0:
        names.append(f"an unknown support {zmin - s.height_mm:.1f} mm high")
    names.append(s.carrier)
    if s.carrier != "table":
        names.append("table")
    return tuple(names)


def draw_model_edges(image: np.ndarray, K, dist, T_cam_obj: np.ndarray, model: PreparedModel, colour,
                     label: str = "") -> np.ndarray:
    """Draw a model's visible edges at ``T_cam_obj`` (hidden lines removed) with a label above them,
    dots and text sized to the picture."""
    from app.geometry.model_edges import visible_edge_samples

    out = image.copy() if image.ndim == 3 else cv2.cvtColor(image, cv2.COLOR_GRAY2BGR)
    H, W = out.shape[:2]
    style = style_for(out)
    es = visible_edge_samples(model, np.asarray(T_cam_obj, float), np.asarray(K, float),
                              np.zeros(5) if dist is None else np.asarray(dist, float), W, H, occlusion_test=True)
    for u, v in es.uv_px:
        cv2.circle(out, (int(round(u * 4)), int(round(v * 4))), 4 * style.dot_px, colour, -1,
                   lineType=cv2.LINE_AA, shift=2)
    if label and len(es.uv_px):
        u0, v0 = es.uv_px.min(axis=0)
        put_label(out, label, (int(u0), max(style.line_px, int(v0) - style.line_px // 3)), colour, style)
    return out


def draw_pose_overlay(base: np.ndarray, K, dist, result: dict, candidates: dict) -> np.ndarray:
    """Overlay of a (possibly operator-adjusted) result dict on ``base`` (e.g. the table-stage picture).

    candidates : {(model_id, revision): Candidate}
    """
    out = base
    for i, o in enumerate(result.get("objects", [])):
        cand = candidates.get((o.get("model_id"), o.get("revision")))
        if cand is None:
            continue
        T = np.asarray(o["T_table_obj"])
        label = f"{o['name']} x{T[0, 3]:.2f} y{T[1, 3]:.2f}" + (" (adjusted)" if o.get("adjusted") else "")
        out = draw_model_edges(out, K, dist, o["T_cam_obj"], cand.prepare(), tuple(o.get("colour_bgr") or COLOURS[i]),
                               label)
    return out
