import numpy as np
import pytest
from shapely.geometry import box as sbox

from app.geometry import parts
from app.geometry.fiducial_layout import parse_layout


def test_tslot_table_frame_extents_and_slot_cross_section():
    spec = parts.TSlotTableSpec()
    m = parts.tslot_table(spec)
    assert m.is_watertight
    assert np.allclose(m.bounds, [[0, 0, -spec.thickness_mm], [800, 400, 0]])
    # volume = body minus 5 T-profiles x length
    neck = spec.slot_width_mm * (spec.slot_depth_mm - spec.head_height_mm)
    head = spec.head_width_mm * spec.head_height_mm
    expected = 800 * (400 * spec.thickness_mm - spec.slot_count * (neck + head))
    assert m.volume == pytest.approx(expected, rel=1e-9)
    # probe the slot: a point in the neck and in the head is outside the solid, beside it inside
    yc = spec.slot_centres_y_mm()[2]
    probes = np.array([
        [400, yc, -5.0],                                   # neck: air
        [400, yc + spec.head_width_mm / 2 - 1, -spec.slot_depth_mm + 2],  # head undercut: air
        [400, yc + spec.slot_width_mm / 2 + 1, -5.0],      # beside the neck: steel
        [400, yc, -spec.slot_depth_mm - 2],                # below the slot: steel
    ])
    assert m.contains(probes).tolist() == [False, False, True, True]


def test_table_layout_markers_on_top_face_clear_of_slots_and_each_other():
    spec = parts.TSlotTableSpec()
    layout = parse_layout(parts.tslot_table_layout(spec))
    assert layout.dictionary == "DICT_5X5_100"
    assert 10 <= len(layout.markers) <= 14
    cells = 7  # 5x5 bits + border; the printed white quiet zone is one cell wide
    slots = [sbox(0, yc - spec.slot_width_mm / 2, 800, yc + spec.slot_width_mm / 2)
             for yc in spec.slot_centres_y_mm()]
    labels = []
    for m in layout.markers:
        T = np.asarray(m.T_table_marker)
        assert np.allclose(T[:3, :3], np.eye(3))  # flat, x along table x
        c = m.corners_table_mm()
        assert np.allclose(c[:, 2], 0.0)  # on the top face z = 0
        assert c[:, 0].min() >= 0 and c[:, 0].max() <= 800 and c[:, 1].min() >= 0 and c[:, 1].max() <= 400
        q = m.size_mm / cells
        label = sbox(c[:, 0].min() - q, c[:, 1].min() - q, c[:, 0].max() + q, c[:, 1].max() + q)
        assert label.bounds[0] >= 0 and label.bounds[1] >= 0 and label.bounds[2] <= 800 and label.bounds[3] <= 400
        for s in slots:
            assert label.intersection(s).area == 0, f"marker {m.id} (with quiet zone) covers a slot"
        labels.append(label)
    for i in range(len(labels)):
        for j in range(i + 1, len(labels)):
            assert labels[i].intersection(labels[j]).area == 0
    # markers in both halves of the table, not collinear
    xy = np.array([np.asarray(m.T_table_marker)[:2, 3] for m in layout.markers])
    assert np.linalg.matrix_rank(xy - xy.mean(axis=0), tol=1.0) == 2
    # marker corners sit on solid material: the table mesh is below each corner
    table = parts.tslot_table(spec)
    corners = np.vstack([m.corners_table_mm() for m in layout.markers]) - [0, 0, 0.5]
    assert table.contains(corners).all()


def test_table_layout_refuses_too_narrow_lands():
    spec = parts.TSlotTableSpec(slot_pitch_mm=50.0, first_slot_y_mm=100.0)
    with pytest.raises(ValueError, match="narrower than marker 40"):
        parts.tslot_table_layout(spec)


def test_vise_frame_and_jaws():
    v = parts.machine_vise(jaw_width_mm=150.0, opening_mm=80.0)
    assert v.is_watertight
    assert v.bounds[0][2] == pytest.approx(0.0)
    assert v.bounds[1][2] == pytest.approx(120.0)  # jaw tops at body 70 + jaw 50
    # between the jaws (above the body) is air; inside the jaws is steel
    probe = np.array([[40, 0, 100], [-30, 0, 100], [110, 0, 100]])
    assert v.contains(probe).tolist() == [False, True, True]
    jaw_y = v.vertices[(v.vertices[:, 2] > 110)][:, 1]
    assert np.ptp(jaw_y) == pytest.approx(150.0)


def test_strap_clamp_stands_on_z0_and_scales():
    a = parts.strap_clamp(length_mm=125, clamp_height_mm=30)
    b = parts.strap_clamp(length_mm=175, clamp_height_mm=50)
    for m, L in ((a, 125), (b, 175)):
        assert m.is_watertight
        assert m.bounds[0][2] == pytest.approx(0.0)
        assert np.ptp(m.vertices[:, 0]) == pytest.approx(L)
    assert b.bounds[1][2] > a.bounds[1][2] + 15


@pytest.mark.parametrize("fn, extents", [
    (parts.pin_block_32, (32, 24, 16)),
    (parts.flange_plate_80, (80, 80, 20)),
    (parts.bracket_140, (140, 90, 35)),
    (parts.base_plate_300, (300, 180, 25)),
])
def test_workpieces_are_solid_with_features(fn, extents):
    m = fn()
    assert m.is_watertight and m.volume > 0
    assert np.allclose(m.extents, extents, atol=1e-6)
    assert m.bounds[0][2] == pytest.approx(0.0)
    box_volume = float(np.prod(extents))
    assert 0.5 * box_volume < m.volume < 0.99 * box_volume  # pockets and holes removed material
    assert m.euler_number < 2  # through holes make genus > 0


def test_flange_is_nearly_symmetric_and_the_pin_hole_breaks_it():
    m = parts.flange_plate_80()
    R90 = np.array([[0, -1, 0, 0], [1, 0, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]], float)
    rotated = m.copy().apply_transform(R90)
    assert rotated.volume == pytest.approx(m.volume)
    # the pin hole at (0, -30) is air in the part but steel after the 90 degree turn
    probe = np.array([[0.0, -30.0, 18.0]])
    assert not m.contains(probe)[0]
    assert rotated.contains(probe)[0]


def test_top_datum():
    m = parts.bracket_140()
    assert np.allclose(parts.top_datum(m, "min")[:3, 3], [0, 0, 35])
    assert np.allclose(parts.top_datum(parts.flange_plate_80(), "centre")[:3, 3], [0, 0, 20])
    with pytest.raises(ValueError, match="unknown datum corner"):
        parts.top_datum(m, "max")
