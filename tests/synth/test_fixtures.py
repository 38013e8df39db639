"""Generated setups are physically possible: the part stands on the parallels, the parallels on the
vise's seat or the table, and nothing passes through anything else."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from app.geometry import parts
from app.geometry.transforms import transform_points
from app.synth.fixtures import (
    CLAMPS_FROM,
    SHOP_FROM,
    VISE_SHADE_N,
    in_vise,
    on_parallels,
    shop_conditions,
    synth_entry,
    under_strap_clamps,
    vise_shade_entry,
    vise_shade_objects,
    vise_shade_scene,
)
from app.synth.scene import SceneObject, place_on_table


@pytest.fixture(scope="module")
def lib():
    return {m.key: m for m in parts.example_library()}


def _zrange(obj):
    z = transform_points(obj.T_table_obj, obj.mesh.vertices)[:, 2]
    return float(z.min()), float(z.max())


def _overlap_volume(a, b) -> float:
    ma, mb = a.mesh.copy(), b.mesh.copy()
    ma.apply_transform(a.T_table_obj)
    mb.apply_transform(b.T_table_obj)
    try:
        inter = trimesh.boolean.intersection([ma, mb], engine="manifold")
    except Exception:  # noqa: BLE001 - no overlap can also come back as an error
        return 0.0
    return float(abs(inter.volume)) if len(inter.faces) else 0.0


def test_part_on_parallels_rests_on_their_tops(lib):
    rng = np.random.default_rng(1)
    wp, par = lib["bracket_140"], lib["parallel_150x25x8"]
    objs = on_parallels(rng, wp.key, wp.mesh, par.mesh, par.key, 400.0, 200.0)
    part, p0, p1 = objs
    assert _zrange(part)[0] == pytest.approx(25.0, abs=1e-6)
    for p in (p0, p1):
        assert _zrange(p) == pytest.approx((0.0, 25.0), abs=1e-6)
        assert _overlap_volume(part, p) < 1.0


def test_part_in_the_vise_stands_on_parallels_on_the_seat_between_the_jaws(lib):
    rng = np.random.default_rng(2)
    wp, v, par = lib["pin_block_32"], lib["vise_150"], lib["parallel_150x25x8"]
    seat = v.support_surfaces[0]
    objs = in_vise(rng, wp.key, wp.mesh, v.mesh, v.key, seat, par.mesh, par.key, 400.0, 200.0)
    part, vise, *pars = objs
    assert _zrange(part)[0] == pytest.approx(seat["z_mm"] + 25.0, abs=1e-6)
    for p in pars:
        assert _zrange(p)[0] == pytest.approx(seat["z_mm"], abs=1e-6)
        assert _overlap_volume(p, vise) < 1.0
    assert _overlap_volume(part, vise) < 1.0


def test_a_part_wider_than_the_opening_does_not_go_into_the_vise(lib):
    rng = np.random.default_rng(3)
    wp, v, par = lib["base_plate_300"], lib["vise_150"], lib["parallel_150x25x8"]
    assert in_vise(rng, wp.key, wp.mesh, v.mesh, v.key, v.support_surfaces[0], par.mesh, par.key, 400, 200) is None


def test_the_generated_set_cycles_modes_and_parts():
    modes = [synth_entry(k)["fixture_mode"] for k in range(6)]
    assert modes == ["table", "vise", "parallels"] * 2
    assert len({synth_entry(k)["workpiece"] for k in range(12)}) == 4


def test_shop_scenes_add_a_spindle_dark_parts_and_vignetting_and_leave_the_older_ones():
    box = trimesh.creation.box(bounds=[[0, 0, 0], [60, 40, 30]])
    objs = [SceneObject("part", box, place_on_table(box, 300.0, 200.0, 0.0), albedo=0.6)]
    even, odd = shop_conditions(SHOP_FROM, objs), shop_conditions(SHOP_FROM + 1, objs)
    for sc in (even, odd):
        names = [o.name for o in sc["objects"]]
        assert names == ["part", "spindle"] and 0.3 <= sc["vignetting"] <= 0.6
        spindle = sc["objects"][1]
        low = float(transform_points(spindle.T_table_obj, spindle.mesh.vertices)[:, 2].min())
        assert low >= 30.0 + 60.0 - 1e-6              # the tool's tip stays above the part's top
    assert even["objects"][0].albedo < 0.3 and even["table_albedo"] < 0.3     # dark part, dark table
    assert odd["objects"][0].albedo == 0.6 and odd["table_albedo"] == 0.42
    assert objs[0].albedo == 0.6                      # the caller's objects are not changed


@pytest.mark.parametrize("key", ["flange_plate_80", "base_plate_300", "bracket_140"])
def test_strap_clamps_press_the_part_from_their_heel_blocks_on_the_table(lib, key):
    """Each set's nose rests on the part's top (within 0.01 mm), its heel block stands on the table, and
    neither passes through the part; a bracket's flange is not crossed."""
    wp = lib[key]
    part = SceneObject(wp.key, wp.mesh, place_on_table(wp.mesh, 400.0, 200.0, 30.0), albedo=0.6)
    clamps = under_strap_clamps(np.random.default_rng(4), part)
    assert 1 <= len(clamps) <= 2
    for c in clamps:
        assert _zrange(c)[0] == pytest.approx(0.0, abs=1e-6)          # on the table (its stud from z = 0)
        assert _overlap_volume(c, part) < 1.0
        # the set touches the part: moved 0.5 mm down, it passes into it
        T = c.T_table_obj.copy()
        T[2, 3] -= 0.5
        lowered = SceneObject(c.name, c.mesh, T, albedo=c.albedo)
        assert _overlap_volume(lowered, part) > 1.0


def test_clamp_scenes_follow_the_older_ones():
    assert not any(synth_entry(k).get("clamps") for k in range(CLAMPS_FROM))
    assert all(synth_entry(k)["clamps"] and synth_entry(k)["fixture_mode"] == "table"
               for k in range(CLAMPS_FROM, CLAMPS_FROM + 8))
    assert len({synth_entry(k)["workpiece"] for k in range(CLAMPS_FROM, CLAMPS_FROM + 8)}) == 4


def test_vise_shade_scenes_hold_the_part_in_the_jaws_under_a_shading_spindle(lib):
    """Each set of the vise-in-shade family: the part stands in the vise without passing through it
    (a tenon plate's plate above the jaw tops), and the spindle and the part shade at least
    MIN_TOP_SHADE of the vise's top faces not under the part (or the best of 8 spindle places).
    Scenes 0 and 3: a tenon plate in vise_150, the pin block in vise_125."""
    for k in (0, 3):
        e = vise_shade_entry(k)
        assert e["fixture_mode"] == "vise" and e["scene_id"] == f"vshade_{k:03d}"
        light = np.array([0.6, 0.3, 0.5]) / np.linalg.norm([0.6, 0.3, 0.5])
        objs = vise_shade_objects(np.random.default_rng(k), k, lib, e["vise"], e["workpiece"], light)
        part, vise = objs[0], objs[1]
        assert [o.name for o in objs][1] == e["vise"] and objs[-1].name == "spindle"
        assert _overlap_volume(part, vise) < 1.0
        if e["workpiece"] == "tenon_plate":
            assert _zrange(part)[1] > float(vise.mesh.bounds[1, 2])      # the plate over the jaws
        assert _zrange(objs[-1])[0] > max(_zrange(part)[1], _zrange(vise)[1])   # the tool above everything


@pytest.mark.slow
def test_vise_shade_scene_renders_the_same_twice_with_the_vise_seen_in_part_and_shaded():
    """A small render (480 x 300) of the family's scene 1: the same image twice (seeded per scene
    index), and the ground truth holds the vise, partly hidden and partly in cast shade."""
    a_sc, a = vise_shade_scene(vise_shade_entry(1), width=480, height=300)
    b_sc, b = vise_shade_scene(vise_shade_entry(1), width=480, height=300)
    assert np.array_equal(a, b)
    assert np.allclose(a_sc.gt["objects"][0]["T_table_object"], b_sc.gt["objects"][0]["T_table_object"])
    v = a_sc.gt["objects"][0]
    assert v["name"] == "vise_125" and v["subtype"] == "vise"
    assert 0.3 <= v["visible_fraction"] < 0.95
    assert v["shaded_fraction"] > 0.2
    assert len(a_sc.gt["visible_marker_ids"]) >= 3
    assert [c.name for c in a_sc.fixture_candidates] == ["vise_125", "parallel_150x25x8"]


def test_the_vise_shade_family_leaves_the_generated_set_alone():
    """The family has its own entries; synth_entry's scenes keep their ids and modes."""
    assert all(synth_entry(k)["scene_id"] == f"synth_{k:03d}" and "family" not in synth_entry(k) for k in range(44))
    assert len({vise_shade_entry(k)["vise"] for k in range(VISE_SHADE_N)}) == 2
