"""Probing program for a located workpiece (issue 8, item 3): touch points, LinuxCNC G-code, results,
least-squares refinement of the offset.

Frames: the mesh is in its ``obj`` frame; ``T_table_obj`` is its located pose, ``T_obj_datum`` the NC
program zero on the model, so ``T_table_datum = T_table_obj @ T_obj_datum``. The program is written
in the *program frame* ``prog`` with ``T_prog_table`` (default identity: the active work offset,
G54 by default, has its zero and axes on the table frame; it must not tilt). mm and degrees.

The probe: a touch probe with a ball of ``ball_radius_mm``; the controlled point (tool length offset)
is the ball's lowest point, the "tip". Touching a face with outward unit normal ``n`` at point ``c``
puts the ball centre at ``c + r n`` and so the tip at ``c + r n - r e_z``.

Touch points (``choose_touch_points``) on the datum faces: the face whose plane passes nearest the
datum origin among the model faces perpendicular to datum x, the one perpendicular to datum y, and
the upward face nearest the datum's z = 0 plane (usually the top). The longer of the two side faces
gets two touches (15 % and 85 % along its usable length: rotation C), the other one touch at its
middle, both ``depth_mm`` below the face's upper edge; the top face one touch at its pole of
inaccessibility. Every touch is checked by casting a ray into the part: the first surface met must
be the datum face at the touch point.

Program (``probing_gcode``): header comment lines (frame, obstacles; see probing_safety), the title,
``G21 G90 G17 G94 G40`` and the work offset slot (from a closed set), ``G0 Z`` to the retract height,
travel with ``G1`` at the fastest feed the axes allow (the linking path from the profile planner,
which is collision-free for the given obstacles), ``G38.2`` towards each face (from ``approach_mm``
outside, to ``overtravel_mm`` inside), retract along the normal, ``G0 Z`` retract, ``M2``. No tool
change, no offsets written, no machine-coordinate (G53) moves. Results are logged
with ``(PROBEOPEN file)`` / ``(PROBECLOSE)``: LinuxCNC writes one line per successful probe with the
program-frame X Y Z A B C U V W (older versions X Y Z). The dry-run variant replaces every
``G38.2`` by a ``G1`` to the nominal contact and opens no log.

Refinement (``refine_offset``): the measured tips give ball centres ``c_i = tip_i + r e_z``, each
at distance r from its face (exact for planar faces, whatever the part's true rotation). The datum
pose is corrected by a translation (dx, dy, dz) and a rotation dC about the table z axis through the
datum origin, minimising ``sum_i (n_i^d . (T_table_datum'^-1 c_i) - o_i - r)^2`` where each face is
the plane ``n^d . p = o`` in the datum frame (scipy.optimize.least_squares).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np
import trimesh
from numpy.typing import ArrayLike
from scipy.optimize import least_squares
from shapely.geometry import LineString, Polygon
from shapely.geometry import Point as ShapelyPoint
from shapely.ops import polylabel, unary_union

from app.geometry.transforms import check_pose, inv, tilt_deg, transform_points
from app.planning.obstacles import ObstacleSource
from app.planning.path import AxisSpeeds, PlannedPath, ProbeParams, pt, segment_feed_mm_min
from app.planning.profile import ProfileOptions, plan_path_profile

COS_PARALLEL = np.cos(np.radians(2.0))


@dataclass(frozen=True)
class TouchPoint:
    """One touch. Points in the table frame, mm; ``normal`` is the face's outward unit normal (table).

    name           : "x", "y1", "y2", "z" (datum axis it measures; two for the rotation face).
    face_normal_datum / face_offset_mm : the face plane ``n . p = o`` in the datum frame.
    contact        : expected contact point on the face.
    approach_tip   : tip position before and after the touch (``approach_mm`` outside the face).
    contact_tip    : tip position at the expected contact (the dry run stops here).
    probe_end_tip  : G38.2 target, ``overtravel_mm`` beyond the face.
    """

    name: str
    face_normal_datum: tuple[float, float, float]
    face_offset_mm: float
    normal: tuple[float, float, float]
    contact: tuple[float, float, float]
    approach_tip: tuple[float, float, float]
    contact_tip: tuple[float, float, float]
    probe_end_tip: tuple[float, float, float]


@dataclass(frozen=True)
class ProbingParams:
    """The touch probe and the touch cycle (mm, mm/min). The probe: a ball of ``ball_radius_mm`` on a
    stylus (vertical cylinder of ``stylus_radius_mm`` from the ball centre up to ``stylus_length_mm``
    above the tip), then the body (``body_radius_mm``, ``body_length_mm`` above the stylus)."""

    ball_radius_mm: float = 1.5
    stylus_length_mm: float = 30.0
    approach_mm: float = 5.0
    overtravel_mm: float = 3.0
    depth_mm: float = 5.0
    edge_margin_mm: float = 2.0
    probe_feed_mm_min: float = 100.0
    stylus_radius_mm: float = 1.0
    body_radius_mm: float = 15.0
    body_length_mm: float = 80.0


@dataclass(frozen=True)
class ProbingProgram:
    touches: tuple[TouchPoint, ...]
    travel: tuple[PlannedPath, ...]  # travel[i] links the approach point before touch i
    gcode: str
    dry_run: bool
    obstacles: tuple = ()  # probing_safety.KnownObstacle: what the program was planned around
    frame: str = ""  # the frame sentence whole (the header's comment may be cut to fit a line)


def _face_clusters(mesh_datum: trimesh.Trimesh, axis: np.ndarray, upward_only: bool):
    """Faces with normal parallel to ``axis`` grouped by plane offset: {(sign, offset): [face ids]}."""
    n = mesh_datum.face_normals
    d = n @ axis
    sel = np.flatnonzero(d > COS_PARALLEL) if upward_only else np.flatnonzero(np.abs(d) > COS_PARALLEL)
    groups: dict[tuple[int, float], list[int]] = {}
    for f in sel:
        sign = 1 if d[f] > 0 else -1
        off = round(float(mesh_datum.vertices[mesh_datum.faces[f][0]] @ axis), 2)
        groups.setdefault((sign, off), []).append(int(f))
    return groups


def _pick_datum_face(mesh_datum, axis, upward_only, name):
    groups = _face_clusters(mesh_datum, axis, upward_only)
    if not groups:
        raise ValueError(f"no planar face perpendicular to datum {name} found on the workpiece; "
                         "probing needs flat datum faces (check T_obj_datum)")

    def area(ids):
        return float(mesh_datum.area_faces[ids].sum())

    (sign, off), ids = min(groups.items(), key=lambda kv: (abs(kv[0][1]), -area(kv[1])))
    return sign, off, ids


def _face_region(mesh_datum, ids, plane_axes):
    """Union of the faces projected on the two in-plane datum axes (indices), a shapely geometry."""
    tris = mesh_datum.vertices[mesh_datum.faces[ids]][:, :, plane_axes]
    polys = [Polygon(t) for t in tris if Polygon(t).area > 1e-9]
    return unary_union(polys)


def _usable_line(region, z: float, trim_mm: float, where: str) -> LineString:
    """The longest piece of the horizontal line at height ``z`` inside ``region`` (a face in its
    (along, z) plane), ``trim_mm`` shorter at both ends; ValueError naming ``where`` when none is left."""
    x0, _, x1, _ = region.bounds if not region.is_empty else (0.0, 0.0, 0.0, 0.0)
    line = LineString([(x0 - 1, z), (x1 + 1, z)]).intersection(region)
    pieces = [g for g in getattr(line, "geoms", [line]) if g.length > 2 * trim_mm]
    if not pieces:
        raise ValueError(f"no usable line {where}")
    seg = max(pieces, key=lambda g: g.length)
    (ax, az), (bx, _) = seg.coords[0], seg.coords[-1]
    lo, hi = min(ax, bx) + trim_mm, max(ax, bx) - trim_mm
    return LineString([(lo, az), (hi, az)]) if hi > lo else LineString([(lo, az), (lo + 1e-9, az)])


def _first_hit_ok(mesh_datum, point, normal, tol_mm=0.05) -> bool:
    origin = np.asarray(point) + 50.0 * np.asarray(normal)
    loc, _, _ = mesh_datum.ray.intersects_location([origin], [-np.asarray(normal)])
    if len(loc) == 0:
        return False
    first = loc[np.argmin(np.linalg.norm(loc - origin, axis=1))]
    return bool(np.linalg.norm(first - point) < tol_mm)


@dataclass(frozen=True)
class TouchPlacement:
    """Where on the datum faces the touches go: ``rot_fracs`` the two touches on the longer side face
    and ``single_frac`` the one on the other (fractions along the usable line), ``top_frac`` the top
    touch as fractions (u, v) of the usable top region's xy bounds (None: its pole of inaccessibility).
    ``rot_depth_mm`` / ``single_depth_mm``: the contact's depth below the face's upper edge (datum z, mm;
    None: ``params.depth_mm``, kept ``ball_radius_mm + edge_margin_mm`` from the edge); a given depth
    only has to keep ``edge_margin_mm`` from the edge (the ball's centre is beside the face, not on
    it), so a touch can move up a face held by vise jaws into the band above them.
    The default is the module doc's choice; a planner may try others to keep clear of clamps."""

    rot_fracs: tuple[float, float] = (0.15, 0.85)
    single_frac: float = 0.5
    top_frac: tuple[float, float] | None = None
    rot_depth_mm: float | None = None
    single_depth_mm: float | None = None


def choose_touch_points(
    mesh: trimesh.Trimesh, T_table_obj: ArrayLike, T_obj_datum: ArrayLike, params: ProbingParams = ProbingParams(),
    placement: TouchPlacement = TouchPlacement(),
) -> tuple[TouchPoint, ...]:
    """Touch points on the datum faces (see the module doc); raises ValueError with a reason when a
    face is missing or too small for the ball (or the top point of ``placement`` is off the face)."""
    T_table_datum = check_pose(T_table_obj, "T_table_obj") @ check_pose(T_obj_datum, "T_obj_datum")
    T_datum_obj = inv(check_pose(T_obj_datum, "T_obj_datum"))
    md = trimesh.Trimesh(transform_points(T_datum_obj, mesh.vertices), mesh.faces, process=False)
    r = params.ball_radius_mm
    inset = r + params.edge_margin_mm
    E = np.eye(3)
    sides = []
    for a, name in ((0, "x"), (1, "y")):
        sign, off, ids = _pick_datum_face(md, E[a], False, name)
        face = _face_region(md, ids, [1 - a, 2])
        region = face.buffer(-inset)
        if region.is_empty:
            raise ValueError(f"datum face {name} is too small for a {r:.1f} mm ball with {params.edge_margin_mm} mm margin")
        top = region.bounds[3]
        z = max(top - max(params.depth_mm - inset, 0.0), region.bounds[1])
        seg = _usable_line(region, z, 0.0, f"{params.depth_mm} mm below the edge of datum face {name}")
        sides.append((a, name, sign, off, seg, z, face))
    rot = max(sides, key=lambda s: s[4].length)
    touches_d: list[tuple[str, np.ndarray, float, np.ndarray]] = []  # (name, n_datum, offset, point_datum)
    for a, name, sign, off, seg, z, face in sides:
        depth = placement.rot_depth_mm if a == rot[0] else placement.single_depth_mm
        if depth is not None:  # an explicit depth: the contact keeps the edge margin from the upper edge
            if not np.isfinite(depth) or depth < params.edge_margin_mm:
                raise ValueError(f"a touch {depth} mm below the edge of datum face {name} is closer to it than the "
                                 f"edge margin {params.edge_margin_mm} mm")
            z = face.bounds[3] - float(depth)
            seg = _usable_line(face.buffer(-params.edge_margin_mm), z, r, f"{depth:.2f} mm below the edge of datum "
                               f"face {name}")
        fracs = tuple(placement.rot_fracs) if (a == rot[0]) else (placement.single_frac,)
        for k, f in enumerate(fracs):
            u = seg.interpolate(f, normalized=True).x
            p = np.zeros(3)
            p[a], p[1 - a], p[2] = off, u, z
            n = sign * E[a]
            label = f"{name}{k + 1}" if len(fracs) > 1 else name
            touches_d.append((label, n, float(n @ p), p))
    sign, off, ids = _pick_datum_face(md, E[2], True, "z (upward)")
    region = _face_region(md, ids, [0, 1]).buffer(-inset)
    if region.is_empty:
        raise ValueError(f"top datum face is too small for a {r:.1f} mm ball")
    if region.geom_type == "MultiPolygon":
        region = max(region.geoms, key=lambda g: g.area)
    if placement.top_frac is None:
        c = polylabel(region, tolerance=0.5)
        cx, cy = c.x, c.y
    else:
        x0, y0, x1, y1 = region.bounds
        cx, cy = x0 + placement.top_frac[0] * (x1 - x0), y0 + placement.top_frac[1] * (y1 - y0)
        if not region.contains(ShapelyPoint(cx, cy)):
            raise ValueError(f"top touch at ({cx:.2f}, {cy:.2f}) (datum frame) is off the usable top face")
    touches_d.append(("z", E[2], off, np.array([cx, cy, off])))

    out = []
    R = T_table_datum[:3, :3]
    for label, n_d, o, p_d in touches_d:
        if not _first_hit_ok(md, p_d, n_d):
            raise ValueError(f"touch {label} at {np.round(p_d, 2).tolist()} (datum frame) is hidden behind other "
                             "material of the part; choose another datum or depth_mm")
        n = R @ n_d
        c_t = transform_points(T_table_datum, p_d)[0]
        ez = np.array([0, 0, 1.0])
        tip = lambda centre: centre - r * ez  # noqa: E731
        out.append(TouchPoint(
            label, pt(n_d), float(o), pt(n), pt(c_t),
            pt(tip(c_t + (r + params.approach_mm) * n)),
            pt(tip(c_t + r * n)),
            pt(tip(c_t + (r - params.overtravel_mm) * n)),
        ))
    return tuple(out)


def _fmt(v: float) -> str:
    s = f"{v:.4f}"
    return "0.0000" if s == "-0.0000" else s


def _xyz(p) -> str:
    return f"X{_fmt(p[0])} Y{_fmt(p[1])} Z{_fmt(p[2])}"


def probing_gcode(
    touches: Sequence[TouchPoint],
    obstacles: ObstacleSource,
    travel_probe: ProbeParams,
    start_table: ArrayLike,
    *,
    params: ProbingParams = ProbingParams(),
    speeds: AxisSpeeds = AxisSpeeds(),
    T_prog_table: ArrayLike | None = None,
    wcs: str = "G54",
    dry_run: bool = False,
    results_file: str = "setupcam_probe.txt",
    title: str = "setupcam probing",
    header: Sequence[str] = (),
    retract_z_mm: float | None = None,
    method: str = "profile",
    axis_at: tuple[str, float] | None = None,
) -> ProbingProgram:
    """LinuxCNC program that visits ``touches`` in order from ``start_table`` and back to it.

    ``obstacles`` / ``travel_probe``: what the linking moves must clear (e.g. a :class:`HeightGrid`
    of the workpiece and clamps, the probe's tip as working distance 0 and its widest radius).
    Positions in the program are the tip in the program frame (``T_prog_table @ p_table``).
    ``wcs``: the work-offset slot the program runs in (one of G54..G59.3, written as given in that
    closed set, never pasted). ``header``: comment lines (see app.planning.probing_safety.header_lines)
    written first. ``retract_z_mm``: table z of the tip for the first and last move (straight up or
    down at the unknown start position; default: the start's z). ``method``: travel planner,
    "profile" (default) or "reference" (the reference method, for comparison). ``axis_at``: (name,
    degrees) of a rotary table's axis (A, B or C) at which the table frame was placed in the machine:
    the program aborts before any move unless the axis stands there (:func:`rotary_guard_lines`).
    """
    from app.machine.base import SLOT_P_NUMBERS
    from app.planning.probing_safety import comment
    from app.planning.reference import ReferenceOptions, plan_path_reference

    slot = str(wcs).upper()
    if slot not in SLOT_P_NUMBERS:
        raise ValueError(f"unknown work offset slot {wcs!r}; use one of {', '.join(SLOT_P_NUMBERS)}")
    if method not in ("profile", "reference"):
        raise ValueError(f"unknown travel method {method!r}; use 'profile' or 'reference'")
    if any(not ln.startswith("(") or not ln.endswith(")") or "\n" in ln or ln.count("(") != 1 or ln.count(")") != 1
           for ln in header):
        raise ValueError("header lines must be single comments; build them with probing_safety.comment")
    T = np.eye(4) if T_prog_table is None else check_pose(T_prog_table, "T_prog_table")
    if tilt_deg(T) > 1e-6:
        raise ValueError("T_prog_table must not tilt: the program frame's z has to be the table's z")
    if params.stylus_length_mm < params.depth_mm + travel_probe.clearance_mm + params.ball_radius_mm:
        raise ValueError(f"stylus of {params.stylus_length_mm} mm is too short to touch {params.depth_mm} mm "
                         f"below an edge with {travel_probe.clearance_mm} mm clearance for the probe body; "
                         "reduce depth_mm or use a longer stylus")
    start = np.asarray(start_table, dtype=float).reshape(3)
    retract = float(start[2] if retract_z_mm is None else retract_z_mm)
    if not np.all(np.isfinite(start)) or not np.isfinite(retract):
        raise ValueError("start and retract height must be finite numbers")
    if retract < start[2]:
        raise ValueError(f"retract height {retract:.3f} mm is below the start height {start[2]:.3f} mm")
    stops = [start] + [np.asarray(t.approach_tip) for t in touches] + [start]
    travel = []
    lines = [
        "%",
        *header,
        comment(f"{title}{' - DRY RUN: probe moves as G1 to the nominal contact' if dry_run else ''}"),
        "(units mm; positions are the probe tip = ball bottom; probe tool and its length offset must be active)",
        f"G21 G90 G17 G94 G40 {slot}",
        *([] if axis_at is None else rotary_guard_lines(axis_at[0], axis_at[1], slot)),
    ]

    def prog(p_table):
        p = transform_points(T, p_table)[0]
        if not np.all(np.isfinite(p)):
            raise ValueError("a program position is not a finite number")
        return p

    z_retract = prog([start[0], start[1], retract])[2]  # no tilt: one z for every xy
    lines.append(f"G0 Z{_fmt(z_retract)} (retract: above every obstacle by the clearance, inside the travel)")
    if not dry_run:
        lines.append(f"(PROBEOPEN {results_file})")

    def move(p_table, feed):
        return f"G1 {_xyz(prog(p_table))} F{feed:.0f}"

    p0 = prog(start)
    lines += [f"G0 X{_fmt(p0[0])} Y{_fmt(p0[1])}", f"G1 Z{_fmt(p0[2])} F{speeds.z_mm_min:.0f}"]
    for i in range(len(stops) - 1):
        if method == "profile":
            path = plan_path_profile([stops[i], stops[i + 1]], obstacles, travel_probe, ProfileOptions(speeds=speeds))
        else:
            margin = travel_probe.radius_mm + travel_probe.lateral_margin_mm
            path = plan_path_reference([stops[i], stops[i + 1]], obstacles, travel_probe,
                                       ReferenceOptions(box_margin_mm=margin))
        travel.append(path)
        lines.append(f"(travel to {'touch ' + touches[i].name if i < len(touches) else 'start'})")
        W = np.asarray(path.waypoints)
        for a, b in zip(W[:-1], W[1:]):
            lines.append(move(b, segment_feed_mm_min(a, b, speeds)))
        if i < len(touches):
            t = touches[i]
            lines.append(comment(f"touch {t.name}: face normal {np.round(t.normal, 4).tolist()}"))
            if dry_run:
                lines.append(move(t.contact_tip, params.probe_feed_mm_min))
            else:
                lines.append(f"G38.2 {_xyz(prog(t.probe_end_tip))} F{params.probe_feed_mm_min:.0f}")
            lines.append(move(t.approach_tip, params.probe_feed_mm_min * 5))
    if not dry_run:
        lines.append("(PROBECLOSE)")
    lines += [f"G0 Z{_fmt(z_retract)}", "M2", "%"]
    return ProbingProgram(tuple(touches), tuple(travel), "\n".join(lines) + "\n", dry_run)


#: how far (degrees) a rotary table may stand from the angle a probing program was planned for
ROTARY_GUARD_TOL_DEG = 0.01


def rotary_guard_lines(axis: str, angle_deg: float, slot: str) -> list[str]:
    """LinuxCNC lines that abort a program (before it moves) unless rotary ``axis`` stands at ``angle_deg``
    (machine coordinates, within ROTARY_GUARD_TOL_DEG): its position in the active frame (#5423-#5425 for
    A, B, C) plus the slot's offset of that axis and the G92 offset when active is the machine position."""
    from app.machine.base import SLOT_P_NUMBERS
    from app.planning.probing_safety import comment

    k = {"A": 3, "B": 4, "C": 5}.get(axis)
    if k is None or not np.isfinite(angle_deg):
        raise ValueError(f"rotary guard: axis must be A, B or C and the angle finite, got {axis!r} {angle_deg!r}")
    g5x = 5201 + 20 * SLOT_P_NUMBERS[slot] + k
    return [
        comment(f"the table's {axis} axis must stand at {angle_deg:.3f} deg, where this program's frame was planned"),
        f"#<setupcam_axis> = [#{5420 + k} + #{g5x} + #5210 * #{5211 + k}]",
        f"o9001 if [ABS[#<setupcam_axis> - {angle_deg:.6f}] GT {ROTARY_GUARD_TOL_DEG:.6f}]",
        f"(abort, the rotary table {axis} is not at {angle_deg:.3f} deg: turn it there, then start again)",
        "o9001 endif",
    ]


def parse_probe_results(text: str) -> np.ndarray:
    """(N, 3) probed positions (program frame, mm) from a LinuxCNC PROBEOPEN log (lines of 9 or 3
    numbers: X Y Z [A B C U V W]) or from JSON ``[[x, y, z], ...]``."""
    s = text.strip()
    if s.startswith("["):
        import json

        arr = np.asarray(json.loads(s), dtype=float)
    else:
        rows = []
        for k, line in enumerate(s.splitlines(), 1):
            if not line.strip():
                continue
            try:
                vals = [float(v) for v in line.split()]
            except ValueError:
                raise ValueError(f"probe results line {k}: {line!r} is not a list of numbers") from None
            if len(vals) not in (3, 9):
                raise ValueError(f"probe results line {k}: expected 3 or 9 numbers (X Y Z [A B C U V W]), got {len(vals)}")
            rows.append(vals[:3])
        arr = np.asarray(rows, dtype=float)
    if arr.ndim != 2 or arr.shape[1] < 3 or len(arr) == 0:
        raise ValueError(f"probe results: expected rows of x, y, z; got shape {arr.shape}")
    return arr[:, :3]


@dataclass(frozen=True)
class OffsetRefinement:
    """Correction of the located datum from probe results.

    dx_mm, dy_mm, dz_mm, dc_deg : correction in the table frame (rotation about table z through the
    datum origin). T_table_datum : the refined datum pose (4, 4). residuals_mm : per touch, distance of
    the measured contact from its refined face plane. reason : empty when usable.
    """

    dx_mm: float
    dy_mm: float
    dz_mm: float
    dc_deg: float
    T_table_datum: np.ndarray
    residuals_mm: tuple[float, ...]
    reason: str = ""

    @property
    def ok(self) -> bool:
        return not self.reason


def _rz(c_rad: float) -> np.ndarray:
    c, s = np.cos(c_rad), np.sin(c_rad)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def refine_offset(
    touches: Sequence[TouchPoint],
    measured_tips: ArrayLike,
    T_table_datum: ArrayLike,
    *,
    ball_radius_mm: float,
    T_prog_table: ArrayLike | None = None,
    max_residual_mm: float = 0.05,
) -> OffsetRefinement:
    """Least-squares correction (dx, dy, dz, dC) of the located datum from measured tip positions
    (N, 3) in the program frame, one per touch in order (see the module doc)."""
    T0 = check_pose(T_table_datum, "T_table_datum")
    T = np.eye(4) if T_prog_table is None else check_pose(T_prog_table, "T_prog_table")
    tips = transform_points(inv(T), np.asarray(measured_tips, dtype=float).reshape(-1, 3))
    if len(tips) != len(touches):
        raise ValueError(f"{len(tips)} probe results for {len(touches)} touches; the log must hold one line per touch")
    centres = tips + np.array([0, 0, ball_radius_mm])  # ball centres
    n_d = np.array([t.face_normal_datum for t in touches])
    o = np.array([t.face_offset_mm for t in touches])
    R0, t0 = T0[:3, :3], T0[:3, 3]

    def pose(x):
        R = _rz(np.radians(x[3])) @ R0
        return R, t0 + x[:3]

    def residuals(x):
        R, t = pose(x)
        p_d = (centres - t) @ R  # R^T (c - t) per row
        return np.sum(n_d * p_d, axis=1) - o - ball_radius_mm  # the centre is r from the face plane

    if len(touches) < 4:
        return OffsetRefinement(0.0, 0.0, 0.0, 0.0, T0, (), f"{len(touches)} touches cannot fix X, Y, Z and C; "
                                "probe at least one point on the x and z datum faces and two on the y face")
    sol = least_squares(residuals, np.zeros(4), x_scale=np.array([1.0, 1.0, 1.0, 0.1]))
    if np.linalg.matrix_rank(sol.jac, tol=1e-6) < 4:
        return OffsetRefinement(0.0, 0.0, 0.0, 0.0, T0, (), "the touches do not fix X, Y, Z and C (faces parallel "
                                "or both rotation touches at one place); choose touches on three perpendicular faces")
    R, t = pose(sol.x)
    T1 = np.eye(4)
    T1[:3, :3], T1[:3, 3] = R, t
    res = residuals(sol.x)
    reason = ""
    if np.max(np.abs(res)) > max_residual_mm:
        reason = (f"largest probe residual {np.max(np.abs(res)):.3f} mm exceeds {max_residual_mm} mm: the part "
                  "does not fit the model here (burr, wrong face, probe not calibrated); check and probe again")
    return OffsetRefinement(float(sol.x[0]), float(sol.x[1]), float(sol.x[2]), float(sol.x[3]), T1,
                            tuple(float(v) for v in res), reason)


def gcode_positions(gcode: str) -> list[tuple[str, np.ndarray]]:
    """Visited tip positions (program frame) of a program written by :func:`probing_gcode`: a list of
    (word, (3,) target) for every G0/G1/G38.x line, absolute mode (for tests and the collision check).
    Coordinates not known in the program frame (after a G53 move) are NaN."""
    out = []
    pos = None
    for line in gcode.splitlines():
        s = line.split("(")[0].strip()
        if not s:
            continue
        words = s.split()
        if "G53" in words:  # machine coordinates: position unknown in the program frame
            pos = np.full(3, np.nan)
            continue
        g = next((w for w in words if w in ("G0", "G1", "G38.2", "G38.3")), None)
        if g is None:
            continue
        vals = {w[0]: float(w[1:]) for w in words if w[0] in "XYZ"}
        base = pos if pos is not None else np.full(3, np.nan)
        p = np.array([vals.get("X", base[0]), vals.get("Y", base[1]), vals.get("Z", base[2])])
        out.append((g, p))
        pos = p
    return out


def refined_work_offset(
    refinement: OffsetRefinement, T_machine_table: ArrayLike, T_obj_datum: ArrayLike, *, max_tilt_deg: float
):
    """The work offset (X, Y, Z, C in machine coordinates, app.geometry.work_offset.OffsetResult) of
    the refined datum: ``T_table_obj' = T_table_datum' @ inv(T_obj_datum)`` into
    ``work_offset_from_poses``. Export it like any offset (operator confirmation, read-back)."""
    from app.geometry.work_offset import work_offset_from_poses

    T_obj_datum = check_pose(T_obj_datum, "T_obj_datum")
    T_table_obj = refinement.T_table_datum @ inv(T_obj_datum)
    return work_offset_from_poses(T_machine_table, T_table_obj, T_obj_datum, max_tilt_deg=max_tilt_deg)


def check_probing_program(
    program: ProbingProgram,
    scene,
    body,
    touching_body,
    T_prog_table: ArrayLike | None = None,
    tol_mm: float = 1e-4,
):
    """Collision check of every move of a program from :func:`probing_gcode` against the scene
    (app.planning.collision.Scene of the true/located meshes): travel moves with ``body``, moves that
    end at or start from an expected contact (the dry run's touches) with ``touching_body`` (the probe
    shrunk a little, since it touches there by design). G38 moves of a real program are checked up
    to the expected contact. Returns app.planning.collision.CollisionReport."""
    from app.planning.collision import CollisionHit, CollisionReport

    T = np.eye(4) if T_prog_table is None else check_pose(T_prog_table, "T_prog_table")
    Tinv = inv(T)
    pos = [(g, transform_points(Tinv, p)[0] if not np.isnan(p).any() else p) for g, p in gcode_positions(program.gcode)]
    contacts = [np.asarray(t.contact_tip) for t in program.touches]
    # a G38 move stops at the contact (beyond it the probe trips): the next move starts there too
    pos = [(g, min(contacts, key=lambda c: float(np.linalg.norm(c - p))) if g.startswith("G38") else p) for g, p in pos]
    hits, n = [], 0
    for k, ((_, a), (g, b)) in enumerate(zip(pos[:-1], pos[1:])):
        if np.isnan(a).any() or np.isnan(b).any():
            continue
        touching = any(np.linalg.norm(c - a) < tol_mm or np.linalg.norm(c - b) < tol_mm for c in contacts)
        report = scene.check_polyline([a, b], touching_body if touching else body)
        n += 1
        hits += [CollisionHit(k, pt(a), pt(b), h.obstacle) for h in report.hits]
    return CollisionReport(not hits, tuple(hits), n)


__all__ = [
    "ProbingParams",
    "ProbingProgram",
    "TouchPoint",
    "TouchPlacement",
    "OffsetRefinement",
    "choose_touch_points",
    "probing_gcode",
    "parse_probe_results",
    "refine_offset",
    "gcode_positions",
    "check_probing_program",
    "refined_work_offset",
]
