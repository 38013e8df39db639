"""Parametric models of the example library: a T-slot table with its fiducial layout, machine vises,
strap clamps, parallels and sample workpieces. Pure geometry (trimesh + shapely + manifold3d booleans), mm.

Every function returns a watertight ``trimesh.Trimesh`` in its own ``obj`` frame (stated in its
docstring; z up, resting on z = 0 unless said otherwise), so ``models_library/build_library.py``,
the scene generator and tests can build the same models in memory.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import shapely.geometry as sg
import trimesh
from shapely.ops import unary_union

from app.geometry.transforms import make_pose

HOLE_SECTIONS = 40  # facets on a drilled hole's circumference


# --------------------------------------------------------------------------- helpers

def _box(lo, hi) -> trimesh.Trimesh:
    return trimesh.creation.box(bounds=np.array([lo, hi], dtype=float))


def _prism(poly: sg.Polygon, z0: float, z1: float) -> trimesh.Trimesh:
    """Extrude a polygon in the xy-plane from z0 to z1."""
    return trimesh.creation.extrude_polygon(poly, height=z1 - z0, transform=make_pose(t=(0, 0, z0)))


def _rounded_rect(x0: float, y0: float, x1: float, y1: float, r: float) -> sg.Polygon:
    """Rectangle [x0, x1] x [y0, y1] with corner radius r (a milled pocket outline)."""
    return sg.box(x0 + r, y0 + r, x1 - r, y1 - r).buffer(r, quad_segs=8)


def _cyl_z(x: float, y: float, d: float, z0: float, z1: float, sections: int = HOLE_SECTIONS) -> trimesh.Trimesh:
    """Cylinder along z with diameter d from z0 to z1 at (x, y)."""
    return trimesh.creation.cylinder(radius=d / 2.0, segment=[[x, y, z0], [x, y, z1]], sections=sections)


def _cyl_x(y: float, z: float, d: float, x0: float, x1: float, sections: int = HOLE_SECTIONS) -> trimesh.Trimesh:
    return trimesh.creation.cylinder(radius=d / 2.0, segment=[[x0, y, z], [x1, y, z]], sections=sections)


def _hex_z(x: float, y: float, across_flats: float, z0: float, z1: float) -> trimesh.Trimesh:
    """Hexagonal prism (a nut) along z."""
    r = across_flats / np.sqrt(3.0)  # circumradius
    return trimesh.creation.cylinder(radius=r, segment=[[x, y, z0], [x, y, z1]], sections=6)


def _difference(base: trimesh.Trimesh, cutters: list[trimesh.Trimesh]) -> trimesh.Trimesh:
    if not cutters:
        return base
    return trimesh.boolean.difference([base, *cutters], engine="manifold")


def _union(parts: list[trimesh.Trimesh]) -> trimesh.Trimesh:
    return trimesh.boolean.union(parts, engine="manifold")


def _clean(m: trimesh.Trimesh) -> trimesh.Trimesh:
    m.merge_vertices()
    m.update_faces(m.nondegenerate_faces())
    m.remove_unreferenced_vertices()
    m.fix_normals()
    return m


# --------------------------------------------------------------------------- T-slot table

@dataclass(frozen=True)
class TSlotTableSpec:
    """A T-slot machine table top (DIN 650 style slots running along x).

    Table frame: origin at the front-left corner of the top face, x along the length, y along the
    width (away from the operator), z up; the top face is z = 0 and the body spans z in
    [-thickness, 0]. Slot cross-section: a neck of ``slot_width_mm`` from the top face down to
    ``slot_depth_mm - head_height_mm``, then the head of ``head_width_mm`` x ``head_height_mm``.
    Slot centres lie at ``first_slot_y_mm + k * slot_pitch_mm``.
    """

    length_mm: float = 800.0
    width_mm: float = 400.0
    thickness_mm: float = 70.0
    slot_count: int = 5
    slot_pitch_mm: float = 70.0
    first_slot_y_mm: float = 60.0
    slot_width_mm: float = 14.0     # DIN 650 size 14
    head_width_mm: float = 24.0
    head_height_mm: float = 11.0
    slot_depth_mm: float = 28.0

    def slot_centres_y_mm(self) -> list[float]:
        return [self.first_slot_y_mm + k * self.slot_pitch_mm for k in range(self.slot_count)]

    def lands_y_mm(self) -> list[tuple[float, float]]:
        """The flat strips of the top face between slots (and at the front/back edges), (y0, y1)."""
        edges = [0.0]
        for yc in self.slot_centres_y_mm():
            edges += [yc - self.slot_width_mm / 2, yc + self.slot_width_mm / 2]
        edges.append(self.width_mm)
        return [(edges[i], edges[i + 1]) for i in range(0, len(edges), 2)]

    def cross_section(self) -> sg.Polygon:
        """The table's cross-section in the (y, z) plane as a shapely polygon."""
        body = sg.box(0.0, -self.thickness_mm, self.width_mm, 0.0)
        cuts = []
        neck_bottom = -(self.slot_depth_mm - self.head_height_mm)
        for yc in self.slot_centres_y_mm():
            a, b = self.slot_width_mm / 2, self.head_width_mm / 2
            cuts.append(sg.box(yc - a, neck_bottom - 0.01, yc + a, 1.0))  # overlap: one clean T
            cuts.append(sg.box(yc - b, -self.slot_depth_mm, yc + b, neck_bottom))
        poly = body.difference(unary_union(cuts))
        if not isinstance(poly, sg.Polygon):
            raise ValueError("T-slot table cross-section fell apart: slots overlap or cut through the body; "
                             "check slot pitch, head width and depth against the table size")
        return poly


def tslot_table(spec: TSlotTableSpec = TSlotTableSpec()) -> trimesh.Trimesh:
    """The T-slot table top as a mesh in the table frame (see :class:`TSlotTableSpec`).

    Built by extruding the (y, z) cross-section along x, so the slots are exact and the mesh small.
    """
    m = trimesh.creation.extrude_polygon(spec.cross_section(), height=spec.length_mm)
    # extrusion frame (u, v, w) = (y, z, x): x = w, y = u, z = v (a proper rotation, det = +1)
    P = np.array([[0, 0, 1, 0], [1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 0, 1]], dtype=float)
    m.apply_transform(P)
    return _clean(m)


def tslot_table_layout(
    spec: TSlotTableSpec = TSlotTableSpec(),
    marker_size_mm: float = 40.0,
    dictionary: str = "DICT_5X5_100",
    end_margin_mm: float = 20.0,
    min_clearance_mm: float = 5.0,
) -> dict:
    """Fiducial layout (DESIGN format) for the T-slot table: markers flat on the top face (z = 0),
    marker x along table x, centred on the lands between slots and never over a slot.

    Placement: on the front and back lands at the left end, middle and right end; on the second and
    second-to-last lands at both ends; on the middle lands at about 1/4 and 3/4 of the length (so
    that any camera view of one end still sees at least two non-collinear markers). Ids 0.. in that
    order. Raises ValueError when a land is too narrow for the marker plus ``min_clearance_mm``.
    """
    lands = spec.lands_y_mm()
    need = marker_size_mm + 2 * min_clearance_mm
    narrow = [(round(y0, 3), round(y1, 3)) for y0, y1 in lands if y1 - y0 < need]
    if narrow:
        raise ValueError(f"lands {narrow} are narrower than marker {marker_size_mm} mm + 2 x "
                         f"{min_clearance_mm} mm clearance; use smaller markers or a wider slot pitch")
    L = spec.length_mm
    x_lo = end_margin_mm + marker_size_mm / 2
    x_hi = L - x_lo
    yc = [(y0 + y1) / 2 for y0, y1 in lands]
    positions = [(x_lo, yc[0]), (L / 2, yc[0]), (x_hi, yc[0]),
                 (x_lo, yc[-1]), (L / 2, yc[-1]), (x_hi, yc[-1])]
    if len(lands) >= 4:
        positions += [(x_lo, yc[1]), (x_hi, yc[1]), (x_lo, yc[-2]), (x_hi, yc[-2])]
    if len(lands) >= 6:
        positions += [(round(L * 0.275, 3), yc[2]), (round(L * 0.725, 3), yc[-3])]
    markers = [{"id": i, "size_mm": float(marker_size_mm),
                "T_table_marker": make_pose(np.eye(3), (x, y, 0.0)).tolist()}
               for i, (x, y) in enumerate(positions)]
    return {"dictionary": dictionary, "markers": markers}


# --------------------------------------------------------------------------- vise and clamps

def machine_vise(jaw_width_mm: float = 150.0, opening_mm: float = 80.0, jaw_height_mm: float = 50.0) -> trimesh.Trimesh:
    """A machine vise with fixed jaw, moving jaw, body with tie-down flanges and spindle handle.

    Obj frame: origin on the fixed jaw's clamping face, at mid jaw width, on the bottom of the body
    (the plane the vise stands on); x from the fixed jaw towards the moving jaw and spindle, y along
    the jaws, z up. The clamping faces are at x = 0 and x = ``opening_mm``; the jaw tops at
    z = body height (70) + ``jaw_height_mm``.
    """
    w2 = jaw_width_mm / 2
    body_h = 70.0
    top = body_h + jaw_height_mm
    x_end = opening_mm + 230.0
    parts = [
        _box((-110, -w2 - 5, 0), (x_end, w2 + 5, body_h - 20)),                # lower body
        _box((-110, -w2 + 20, body_h - 20), (x_end, w2 - 20, body_h)),         # guide ways
        _box((-70, -w2 - 45, 0), (10, w2 + 45, 18)),                            # tie-down flanges
        _box((-60, -w2, body_h - 20), (0, w2, top)),                            # fixed jaw
        _box((opening_mm, -w2, body_h - 20), (opening_mm + 65, w2, top)),       # moving jaw
        _box((x_end - 30, -45, 10), (x_end, 45, body_h)),                        # spindle bearing
        _cyl_x(0, 42, 26, x_end - 1, x_end + 45),                               # spindle
        _box((x_end + 45, -18, 24), (x_end + 75, 18, 60)),                      # handle square
    ]
    body = _union(parts)
    cutters = [
        _box((-40, -w2 - 36, -1), (-20, -w2 - 22, 19)),                          # tie-down slots
        _box((-40, w2 + 22, -1), (-20, w2 + 36, 19)),
        _box((-6, -w2 - 1, top - 3), (0.5, w2 + 1, top + 1)),                   # jaw plate steps
        _box((opening_mm - 0.5, -w2 - 1, top - 3), (opening_mm + 6, w2 + 1, top + 1)),
    ]
    return _clean(_difference(body, cutters))


def simple_vise(jaw_width_mm: float = 125.0, opening_mm: float = 60.0, jaw_height_mm: float = 40.0,
                base_height_mm: float = 55.0) -> trimesh.Trimesh:
    """A simple machine vise: a flat base with tie-down flanges, fixed jaw, moving jaw, spindle block,
    spindle and handle square, as one mesh.

    Obj frame as :func:`machine_vise`: origin on the fixed jaw's clamping face, at mid jaw width, on
    the bottom of the base (the plane the vise stands on); x from the fixed jaw towards the moving jaw
    and spindle, y along the jaws, z up. The clamping faces are at x = 0 and x = ``opening_mm``; the
    seat (the top of the base between the jaws, where parts or parallels stand) at z =
    ``base_height_mm``; the jaw tops at z = ``base_height_mm + jaw_height_mm``. See :func:`vise_seat`.
    """
    w2, hb = jaw_width_mm / 2, base_height_mm
    top = hb + jaw_height_mm
    x_end = opening_mm + 150.0
    b2 = w2 + 7.5                                                                # base half width
    parts = [
        _box((-70, -b2, 0), (x_end, b2, hb)),                                   # base
        _box((-50, -b2 - 28, 0), (10, b2 + 28, 14)),                            # tie-down flanges
        _box((-45, -w2, hb), (0, w2, top)),                                     # fixed jaw
        _box((opening_mm, -w2, hb), (opening_mm + 50, w2, top)),                # moving jaw
        _box((x_end - 25, -35, hb), (x_end, 35, hb + 25)),                       # spindle block
        _cyl_x(0, hb + 12, 22, x_end - 1, x_end + 35),                          # spindle
        _box((x_end + 35, -15, hb), (x_end + 60, 15, hb + 24)),                 # handle square
    ]
    body = _union(parts)
    cutters = [
        _box((-30, -b2 - 22, -1), (-10, -b2 - 8, 15)),                          # tie-down slots
        _box((-30, b2 + 8, -1), (-10, b2 + 22, 15)),
        _box((-5, -w2 - 1, top - 3), (0.5, w2 + 1, top + 1)),                   # jaw plate steps
        _box((opening_mm - 0.5, -w2 - 1, top - 3), (opening_mm + 5, w2 + 1, top + 1)),
    ]
    return _clean(_difference(body, cutters))


def vise_seat(opening_mm: float, half_width_mm: float, seat_z_mm: float) -> dict:
    """The declared support surface of a vise in its obj frame (see :func:`machine_vise` and
    :func:`simple_vise`): the seat between the clamping faces (x 0 to ``opening_mm``), y within
    +-``half_width_mm``, at height ``seat_z_mm``. :func:`machine_vise`: the guide ways' top, half width
    jaw width / 2 - 20, z 70; :func:`simple_vise`: the base top, half the jaw width, z = base height."""
    w2 = float(half_width_mm)
    return {"name": "seat", "z_mm": float(seat_z_mm),
            "outline_xy": [[0.0, -w2], [float(opening_mm), -w2], [float(opening_mm), w2], [0.0, w2]]}


def parallel(length_mm: float = 150.0, height_mm: float = 25.0, thickness_mm: float = 8.0) -> trimesh.Trimesh:
    """One precision parallel (a ground steel bar; they come in pairs): ``length_mm`` along x,
    ``thickness_mm`` along y, ``height_mm`` along z.

    Obj frame: origin at the centre of the base face, x along the length, z up. Its support surface
    (:func:`top_face`) is the top face at z = ``height_mm``.
    """
    return _clean(_box((-length_mm / 2, -thickness_mm / 2, 0), (length_mm / 2, thickness_mm / 2, height_mm)))


def top_face(mesh: trimesh.Trimesh, name: str = "top") -> dict:
    """The declared support surface of a block-shaped fixture: its bounding box's top face."""
    (x0, y0, _), (x1, y1, z1) = np.round(mesh.bounds, 6).tolist()
    return {"name": name, "z_mm": float(z1), "outline_xy": [[x0, y0], [x1, y0], [x1, y1], [x0, y1]]}


def strap_clamp(length_mm: float = 150.0, clamp_height_mm: float = 40.0, width_mm: float = 30.0,
                thickness_mm: float = 18.0, stud_diameter_mm: float = 12.0) -> trimesh.Trimesh:
    """A strap clamp set: strap with a stud slot, heel (step) block, stud, washer and nut.

    Obj frame: origin on the stud axis in the plane the clamp stands on (the table top), x along the
    strap towards its nose (the end pressing on the workpiece), z up. The strap's underside is at
    ``clamp_height_mm``; the heel block stands under the back end, the stud rises from z = 0 (in a
    real setup it continues into the T-slot, which is not modelled).
    """
    L, h, t, d = length_mm, clamp_height_mm, thickness_mm, stud_diameter_mm
    x_back, x_nose = -0.45 * L, 0.55 * L
    strap = _box((x_back, -width_mm / 2, h), (x_nose, width_mm / 2, h + t))
    slot = _prism(_rounded_rect(-0.12 * L, -(d + 2) / 2, 0.12 * L, (d + 2) / 2, (d + 2) / 2 - 0.01), h - 1, h + t + 1)
    strap = _difference(strap, [slot])
    nose = _box((x_nose - 12, -width_mm / 2, h - 3), (x_nose, width_mm / 2, h + 1))
    heel = _box((x_back, -width_mm / 2 - 3, 0), (x_back + 32, width_mm / 2 + 3, h + 0.5))
    z_top = h + t
    washer = _cyl_z(0, 0, 2.2 * d, z_top, z_top + 3, sections=48)
    nut = _hex_z(0, 0, 1.6 * d, z_top + 3, z_top + 3 + 0.8 * d)
    stud = _cyl_z(0, 0, d, 0, z_top + 3 + 0.8 * d + 12, sections=32)
    return _clean(_union([strap, nose, heel, washer, nut, stud]))


# --------------------------------------------------------------------------- sample workpieces

def pin_block_32() -> trimesh.Trimesh:
    """Small block 32 x 24 x 16 mm: a through hole, a slot and a 45-degree corner chamfer (datum cue).

    Obj frame: origin at the front-left bottom corner, x along 32, y along 24, z up.
    """
    outline = sg.Polygon([(0, 0), (32, 0), (32, 18), (26, 24), (0, 24)])  # chamfer at back-right
    body = _prism(outline, 0, 16)
    cutters = [
        _cyl_z(9, 12, 8, -1, 17),
        _prism(_rounded_rect(17, 4, 23, 20, 2.99), 10, 17),                  # 6 mm slot, 6 deep
    ]
    return _clean(_difference(body, cutters))


def flange_plate_80() -> trimesh.Trimesh:
    """Nearly symmetric square plate 80 x 80 x 20 mm: a central round pocket and four corner
    holes (4-fold symmetric), broken only by one small 4 mm pin hole near the -y edge.

    Obj frame: origin at the centre of the bottom face, z up; the pin hole is at (0, -30).
    """
    body = _box((-40, -40, 0), (40, 40, 20))
    cutters = [_cyl_z(0, 0, 40, 10, 21, sections=64)]
    cutters += [_cyl_z(sx * 28, sy * 28, 9, -1, 21) for sx in (-1, 1) for sy in (-1, 1)]
    cutters.append(_cyl_z(0, -30, 4, 12, 21, sections=24))
    return _clean(_difference(body, cutters))


def bracket_140() -> trimesh.Trimesh:
    """Bracket block 140 x 90 x 35 mm with a rebate along the back edge, a rounded pocket, two
    through holes and a smaller hole: clearly asymmetric.

    Obj frame: origin at the front-left bottom corner, x along 140, y along 90, z up.
    """
    body = _box((0, 0, 0), (140, 90, 35))
    cutters = [
        _box((-1, 68, 20), (141, 91, 36)),                                    # rebate 22 x 15
        _prism(_rounded_rect(15, 14, 80, 54, 6), 20, 36),                     # pocket 65 x 40 x 15
        _cyl_z(105, 18, 10.5, -1, 36),
        _cyl_z(105, 50, 10.5, -1, 36),
        _cyl_z(125, 34, 6.8, -1, 36),
    ]
    return _clean(_difference(body, cutters))


def base_plate_300() -> trimesh.Trimesh:
    """Base plate 300 x 180 x 25 mm: a rectangular and a round pocket, a hole pattern along the edges
    and one chamfered corner (20 x 20) that marks the datum side.

    Obj frame: origin at the front-left bottom corner, x along 300, y along 180, z up; the chamfer
    is at the back-right corner (x = 300, y = 180).
    """
    outline = sg.Polygon([(0, 0), (300, 0), (300, 160), (280, 180), (0, 180)])
    body = _prism(outline, 0, 25)
    cutters = [
        _prism(_rounded_rect(30, 40, 150, 120, 8), 13, 26),                   # pocket 120 x 80 x 12
        _cyl_z(215, 80, 60, 17, 26, sections=64),                              # round pocket 60 x 8
    ]
    for x in (15, 100, 200, 285):
        cutters.append(_cyl_z(x, 15, 11, -1, 26))
    for x in (15, 150):
        cutters.append(_cyl_z(x, 165, 11, -1, 26))
    cutters.append(_cyl_z(215, 80, 12, -1, 26))                                # centre bore
    return _clean(_difference(body, cutters))


def top_datum(mesh: trimesh.Trimesh, corner: str = "min") -> np.ndarray:
    """``T_obj_datum`` at the top face: ``corner="min"`` puts the datum at (x_min, y_min, z_max) of the
    bounding box, ``"centre"`` at the centre of the top face; axes parallel to obj."""
    lo, hi = mesh.bounds
    if corner == "min":
        t = (lo[0], lo[1], hi[2])
    elif corner == "centre":
        t = ((lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, hi[2])
    else:
        raise ValueError(f"unknown datum corner {corner!r}; use 'min' or 'centre'")
    return make_pose(np.eye(3), np.round(np.asarray(t, float), 6))


# --------------------------------------------------------------------------- the example library

@dataclass(frozen=True)
class ExampleModel:
    """One model of the example library, built in memory (``models_library/`` holds the same as files)."""

    key: str
    kind: str  # "table" | "clamp" | "support" | "workpiece"
    name: str
    mesh: trimesh.Trimesh = field(repr=False)
    T_obj_datum: np.ndarray | None = field(repr=False)
    layout: dict | None = field(repr=False)  # fiducial layout (DESIGN format) for the table
    description: str
    # fixtures: declared support surfaces (model frame, mm; app/geometry/support_surfaces.py); None: not declared
    support_surfaces: list[dict] | None = field(default=None, repr=False, hash=False)


TABLE_KEY = "tslot_table_800x400"


def example_library() -> list[ExampleModel]:
    """The example library in manifest order: T-slot table (with its marker layout), vise, two strap
    clamps, four workpieces from 32 mm to 300 mm, a second (simpler) vise and two parallels (one of
    each pair). Deterministic; about 0.5 s."""
    spec = TSlotTableSpec()
    vise = machine_vise()
    vise_s = simple_vise(125.0, 60.0, 40.0, 55.0)
    par25, par32 = parallel(150.0, 25.0, 8.0), parallel(150.0, 32.0, 8.0)
    clamp_s = strap_clamp(length_mm=125.0, clamp_height_mm=30.0, width_mm=25.0, thickness_mm=16.0,
                          stud_diameter_mm=10.0)
    clamp_l = strap_clamp(length_mm=175.0, clamp_height_mm=50.0, width_mm=32.0, thickness_mm=20.0,
                          stud_diameter_mm=14.0)
    pin, flange, bracket, plate = pin_block_32(), flange_plate_80(), bracket_140(), base_plate_300()
    return [
        ExampleModel(
            TABLE_KEY, "table", "T-slot table 800 x 400", tslot_table(spec), None, tslot_table_layout(spec),
            f"Machine table top {spec.length_mm:g} x {spec.width_mm:g} x {spec.thickness_mm:g} mm with "
            f"{spec.slot_count} T-slots along x (DIN 650 size {spec.slot_width_mm:g}: head "
            f"{spec.head_width_mm:g} x {spec.head_height_mm:g}, depth {spec.slot_depth_mm:g}) at "
            f"y = {', '.join(f'{y:g}' for y in spec.slot_centres_y_mm())} mm. Frame: origin at the "
            "front-left corner of the top face, x along 800, y along 400, z up, top face z = 0. "
            "12 ArUco markers (DICT_5X5_100, 40 mm) on the lands between the slots."),
        ExampleModel(
            "vise_150", "clamp", "Machine vise 150 mm", vise, make_pose(np.eye(3), (0.0, 0.0, 120.0)), None,
            "Machine vise, jaw width 150 mm, opened 80 mm, jaw height 50 mm. Frame: origin on the fixed "
            "jaw's clamping face at mid width on the vise's bottom; x towards the moving jaw, z up. "
            "Datum: top edge of the fixed jaw face, mid width. Support surface: the seat between the jaws "
            "(top of the guide ways, z 70, x 0 to 80, y -55 to 55).",
            [vise_seat(80.0, 150.0 / 2 - 20.0, 70.0)]),
        ExampleModel(
            "strap_clamp_125", "clamp", "Strap clamp 125 mm", clamp_s, None, None,
            "Strap clamp set: strap 125 x 25 x 16 mm at 30 mm height, heel block, M10 stud, washer and "
            "nut. Frame: stud axis on the table plane, x towards the nose, z up."),
        ExampleModel(
            "strap_clamp_175", "clamp", "Strap clamp 175 mm", clamp_l, None, None,
            "Strap clamp set: strap 175 x 32 x 20 mm at 50 mm height, heel block, M14 stud, washer and "
            "nut. Frame: stud axis on the table plane, x towards the nose, z up."),
        ExampleModel(
            "pin_block_32", "workpiece", "Pin block 32 x 24 x 16", pin, top_datum(pin, "min"), None,
            "Small block with a through hole, a 6 mm slot and a chamfered back-right corner (the datum "
            "cue). Frame: front-left bottom corner. Datum: front-left corner of the top face."),
        ExampleModel(
            "flange_plate_80", "workpiece", "Flange plate 80 x 80 x 20", flange, top_datum(flange, "centre"), None,
            "Nearly 4-fold symmetric plate: central pocket d40 x 10 and four corner holes d9; only a 4 mm "
            "pin hole at (0, -30) breaks the symmetry. Frame: centre of the bottom face. Datum: centre of "
            "the top face."),
        ExampleModel(
            "bracket_140", "workpiece", "Bracket 140 x 90 x 35", bracket, top_datum(bracket, "min"), None,
            "Block with a 22 x 15 mm rebate along the back edge, a rounded pocket 65 x 40 x 15 and three "
            "holes. Frame: front-left bottom corner. Datum: front-left corner of the top face."),
        ExampleModel(
            "base_plate_300", "workpiece", "Base plate 300 x 180 x 25", plate, top_datum(plate, "min"), None,
            "Plate with a rectangular pocket 120 x 80 x 12, a round pocket d60 x 8 with a bore, six holes "
            "d11 and a 20 mm chamfer at the back-right corner. Frame: front-left bottom corner. Datum: "
            "front-left corner of the top face."),
        ExampleModel(
            "vise_125", "clamp", "Machine vise 125 mm", vise_s, make_pose(np.eye(3), (0.0, 0.0, 95.0)), None,
            "Simple machine vise, jaw width 125 mm, opened 60 mm, jaw height 40 mm on a base 55 mm high. "
            "Frame: origin on the fixed jaw's clamping face at mid width on the vise's bottom; x towards "
            "the moving jaw, z up. Datum: top edge of the fixed jaw face, mid width. Support surface: the "
            "seat between the jaws (top of the base, z 55, x 0 to 60, y -62.5 to 62.5).",
            [vise_seat(60.0, 125.0 / 2, 55.0)]),
        ExampleModel(
            "parallel_150x25x8", "support", "Parallel 150 x 25 x 8", par25, None, None,
            "Precision parallel (one of a pair) 150 long, 25 high, 8 thick. Frame: centre of the base face, "
            "x along the length, z up. Support surface: the top face (z 25).", [top_face(par25)]),
        ExampleModel(
            "parallel_150x32x8", "support", "Parallel 150 x 32 x 8", par32, None, None,
            "Precision parallel (one of a pair) 150 long, 32 high, 8 thick. Frame: centre of the base face, "
            "x along the length, z up. Support surface: the top face (z 32).", [top_face(par32)]),
    ]


def taught_prism(outline_xy: np.ndarray, holes_xy: list[np.ndarray], height_mm: float) -> trimesh.Trimesh:
    """The 2.5-D body of a photo model (app/vision/photo_model/): its top face's outline (N, 2) with
    its holes, in its obj frame (mm), extruded from the table (z = 0) to ``height_mm``. Holes that do
    not lie inside the outline are left out; an outline that does not close a valid area is made valid
    first (``buffer(0)``)."""
    outer = sg.Polygon(np.asarray(outline_xy, float)).buffer(0)
    if outer.geom_type == "MultiPolygon":
        outer = max(outer.geoms, key=lambda g: g.area)
    inner = [sg.Polygon(np.asarray(h, float)).buffer(0) for h in holes_xy if len(h) >= 3]
    body = outer
    for h in inner:
        if h.is_valid and not h.is_empty and outer.contains(h):
            body = body.difference(h)
    if body.geom_type == "MultiPolygon":
        body = max(body.geoms, key=lambda g: g.area)
    return _prism(body.simplify(0.05), 0.0, float(height_mm))
