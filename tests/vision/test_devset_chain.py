"""The support chain on scenes from the independent devset (another renderer than ours): a part in
the vise on hidden parallels, a part on parallels not in the library, a small part on a big table. Read from
../shared/data/devset (never copied into the repository)."""

from __future__ import annotations

import json
import re
from pathlib import Path

import cv2
import numpy as np
import pytest
import trimesh

from app.synth.devset import devset_scene
from app.vision.localize import Candidate, localize
from app.vision.object_pose import locate as locate_module
from app.vision.object_pose import refine as refine_module
from app.vision.pose_errors import pose_error_6dof
from tests.support.devset_setup import within_3_sigma as _within_3_sigma

pytestmark = pytest.mark.slow
DEVSET = Path(__file__).resolve().parents[3] / "shared" / "data" / "devset"
if not (DEVSET / "manifest.json").exists():
    pytest.skip(f"the devset is not beside the repository ({DEVSET})", allow_module_level=True)


# prepared models by (mesh file, kind, name), kept for the module as the service keeps them per model revision
# (services/setups.py): the devset's vise alone took 1.1 s to prepare in every test
_PREPARED: dict = {}


def _prepared(cand: Candidate, mesh_file: str) -> Candidate:
    key = (mesh_file, cand.kind, cand.name)
    if key not in _PREPARED:
        _PREPARED[key] = (cand.mesh, cand.prepare())
    cand.mesh, cand.prepared = _PREPARED[key]
    return cand


def _scene(scene_id: str, family: str = "setup"):
    """The devset scene, its image and its workpiece as a candidate, every model prepared."""
    entry = next(e for e in json.loads((DEVSET / "manifest.json").read_text())["families"][family]
                 if e["scene_id"] == scene_id)
    sc = devset_scene(DEVSET, entry)
    for c in sc.fixture_candidates + [sc.table_candidate]:
        _prepared(c, f"{c.name}.stl")
    image = cv2.imread(str(DEVSET / entry["image"]), cv2.IMREAD_UNCHANGED)
    mesh_file = sc.workpiece["mesh"]
    wp = Candidate(sc.workpiece["name"], trimesh.load(DEVSET / mesh_file, force="mesh"))
    return sc, image, _prepared(wp, mesh_file)


def _run(scene_id: str, recode=None, K=None, layout=None, **kw):
    """The scene through the chain (``K``: the intrinsics the engine is told, else the true ones;
    ``layout``: the markers it is told, else all)."""
    sc, image, wp = _scene(scene_id)
    image = image if recode is None else recode(image)
    res = localize(image, sc.K if K is None else K, sc.dist, sc.layout if layout is None else layout,
                   [wp] + sc.fixture_candidates,
                   table_model=sc.table_candidate,
                   chain=True, **kw)
    obj = next(o for o in res.objects if o["kind"] == "workpiece")
    # the operator picks among the poses the result lists as the same look (a plate turned over shows
    # the same outline: which face is up is a datum question, asked on the page)
    listed = [obj["T_table_obj"], *obj["equivalent_poses"]]
    errs = [pose_error_6dof(np.asarray(T), np.asarray(sc.workpiece["T_table_object"]), wp.prepare()) for T in listed]
    k = int(np.argmin([np.linalg.norm(e[:3]) + 10 * np.linalg.norm(np.nan_to_num(e[3:])) for e in errs]))
    assert k == 0 or obj["datum_ambiguous"], "the truth is listed but the datum was called decided"
    return res, obj, errs[k]




def test_part_in_the_vise_on_hidden_parallels():
    res, obj, err = _run("setup_019")          # block_pocket in the vise, on 20 mm parallels, mono camera
    assert res.ok, res.reason
    assert "vise_body seat" in obj["chain"] and obj["chain"][-1] == "table", obj["chain"]
    assert np.linalg.norm(err[:3]) < 0.3 and np.nanmax(np.abs(err[3:])) < 0.1, err
    assert _within_3_sigma(obj, err), (err, obj["sigma"])


def test_part_on_parallels_that_are_not_in_the_library():
    res, obj, err = _run("setup_012")          # plate_slots on 30 mm parallels
    assert res.ok, res.reason
    riser = re.fullmatch(r"an unknown support ([0-9.]+) mm high", obj["chain"][0])
    assert riser and abs(float(riser[1]) - 30.0) < 0.5 and obj["chain"][-1] == "table", obj["chain"]
    assert np.linalg.norm(err[:3]) < 0.3 and np.nanmax(np.abs(err[3:])) < 0.1, err
    assert _within_3_sigma(obj, err), (err, obj["sigma"])
    # the table pose's own error is part of the stated sigma (shared by every object in the picture)
    C, C_table = np.asarray(obj["cov6"]), np.asarray(obj["cov6_table"])
    assert np.all(np.diag(C_table)[:3] > 0) and np.all(np.diag(C_table) <= np.diag(C) + 1e-12)


# the heights of the devset shop's parallels (its meshes' parallel_*.stl)
SHOP_PARALLELS = (20.0, 25.0, 27.062, 30.0)


def test_part_on_a_declared_parallel_stands_on_it():
    """A part in the vise on 20 mm parallels hidden by it: its freely fitted height, 19.5 mm (0.56 mm
    off along the line of sight), says clearly which of the shop's parallels it stands on; refitted
    on it the part is where it is."""
    res, obj, err = _run("setup_024", riser_heights_mm=SHOP_PARALLELS)
    assert res.ok, res.reason
    assert obj["chain"][:2] == ["a declared riser 20 mm high", "vise_body seat"], obj["chain"]
    assert obj["riser_mm"] == 20.0
    assert np.linalg.norm(err[:3]) < 0.15 and np.nanmax(np.abs(err[3:])) < 0.1, err
    assert _within_3_sigma(obj, err), (err, obj["sigma"])


def test_the_sharper_of_readings_along_the_line_of_sight_is_taken():
    """A bracket in the vise on 20 mm parallels that the jaws hide: standing on the shop's 25 or 30 mm
    parallels instead, slid along the line of sight, it fits its outline as well at 1.5 px (75 % each),
    and fitted with its height free it slides away to a floating pose. Searched on each declared top
    and judged by the edges that match within 0.5 px, it stands on its own parallel (before: located
    135 mm away, turned over, or refused as ambiguous)."""
    res, obj, err = _run("setup_001", riser_heights_mm=SHOP_PARALLELS)
    assert res.ok, res.reason
    assert obj["chain"][:2] == ["a declared riser 20 mm high", "vise_body seat"], obj["chain"]
    assert np.linalg.norm(err[:3]) < 0.15 and np.nanmax(np.abs(err[3:])) < 0.1, err
    assert _within_3_sigma(obj, err), (err, obj["sigma"])


def test_a_reading_on_the_next_parallel_that_the_6dof_fit_brings_back_is_no_rival():
    """A stepped block on 20 mm parallels: its reading on the shop's 25 mm parallel supports as many
    edges (65 % against 66 %) and nearly as sharply, but fitted in 6 DoF it comes back to 20 mm: one
    reading, not two (else the part is refused as ambiguous)."""
    res, obj, err = _run("setup_022", riser_heights_mm=SHOP_PARALLELS)
    assert res.ok, res.reason
    assert obj["chain"][:2] == ["a declared riser 20 mm high", "table"], obj["chain"]
    assert np.linalg.norm(err[:3]) < 0.1 and np.nanmax(np.abs(err[3:])) < 0.1, err
    assert _within_3_sigma(obj, err), (err, obj["sigma"])


def test_a_height_that_names_its_parallel_though_the_image_fixes_it_loosely_stands_on_it():
    """An idler riser on 20 mm parallels on the table: fitted with its height free it slides 1.3 mm
    down the line of sight (18.7 mm, sigma 1.2 mm at the decision scale) and is 1.8 mm off, wrong.
    Its height still names one declared top (25 mm is 5 sigma away): stood on it, the part is right."""
    res, obj, err = _run("setup_017", riser_heights_mm=SHOP_PARALLELS)
    assert obj["chain"] == ["a declared riser 20 mm high", "table"], obj["chain"]
    assert np.linalg.norm(err[:3]) < 0.5 and np.nanmax(np.abs(err[3:])) < 0.5, err


def _over_exposed(image):
    """One stop over-exposed: linear light doubled and clipped (every face brighter than mid-grey reads
    255 at its edges)."""
    linear = np.minimum(2.0 * (image.astype(np.float64) / 255.0) ** 2.2, 1.0)
    return np.clip(np.rint(255.0 * linear ** (1.0 / 2.2)), 0, 255).astype(np.uint8)


def test_a_declared_parallel_is_fitted_where_the_free_fit_put_the_part():
    """setup_022 one stop over-exposed: the best flat start is a reading on the 25 mm parallel, 5 mm
    off along the line of sight, that the free 6-DoF fit slides down to 20.5 mm and to the part. Stood
    on the 20 mm top from that start, straight down, the part was 8.8 mm off; from where the free fit
    put it, it is where it sits."""
    res, obj, err = _run("setup_022", recode=_over_exposed, riser_heights_mm=SHOP_PARALLELS)
    assert obj["chain"][0] == "a declared riser 20 mm high", obj["chain"]
    assert np.linalg.norm(err[:3]) < 0.25 and np.nanmax(np.abs(err[3:])) < 0.1, err
    assert _within_3_sigma(obj, err), (err, obj["sigma"])


@pytest.mark.parametrize("declared", [(25.0, 30.0), (19.0, 20.0)])
def test_a_parallel_is_not_taken_unless_the_height_says_which(declared):
    """The same part with only 25 and 30 mm parallels declared (its own is not among them), or with
    19 and 20 mm (its fitted 19.5 mm lies between two tops, within 4 sigma of both): its height stays
    the image's own, over a support of unknown height, with the broad sigma that goes with it."""
    res, obj, err = _run("setup_024", riser_heights_mm=declared)
    assert obj["riser_mm"] is None
    assert obj["chain"][0].startswith("an unknown support"), obj["chain"]
    assert _within_3_sigma(obj, err), (err, obj["sigma"])


def test_part_held_between_the_located_jaws():
    """A flange on hidden parallels between the vise's jaws: one view sees it only up to a slide along
    the line of sight; both located jaws' faces hold it (0.66 mm off before they did)."""
    res, obj, err = _run("setup_039")
    assert res.ok, res.reason
    assert set(obj["held_by"]) == {"vise_body", "vise_jaw"}, obj["held_by"]
    assert np.linalg.norm(err[:3]) < 0.2 and np.nanmax(np.abs(err[3:])) < 0.2, err
    assert _within_3_sigma(obj, err), (err, obj["sigma"])


def test_a_part_whose_top_is_over_the_sensors_top_is_fitted_without_the_edges_beside_it(monkeypatch):
    """setup_006: a white part in the vise, lit over the sensor's top (two thirds of its edges beside
    pixels at 255). Their 50 % crossings sit 0.37 px toward the dark side, so the part looked bigger,
    so nearer, and tilted: 0.8 mm and 0.29 deg off. The final fit without them is 0.6 mm and 0.02 deg
    off, its height now told by the side faces alone (a sigma of 2 mm along the line of sight, no
    longer matched to the 20 mm parallel). The shop's parallels are declared, as its library declares
    them; without, its height is not told at all (3-4 mm off either way, and refused). Held flush
    against its located jaws since the twentieth stop: 0.40 mm, and turned 0.07 deg (a quarter of its
    sigma). Since the twenty-first its moving jaw keeps its body's turn (it was 0.19 deg off it): the
    part 0.53 mm off (0.51 of it in height, 0.4 of its sigma there) and turned 0.01 deg; with the edges
    beside clipped pixels, 0.60 mm and 0.15 deg. Pressed by its jaws it now tilts by 0.1 deg at most
    (held_contact_sigma_deg), its prior weighed against the fit's own edge noise: with the edges beside
    clipped pixels 0.63 mm and 0.05 deg off, without them as before.

    Since the twenty-seventh stop the markers' corners are read with their clipped whites
    corrected for (marker 90 joins the table, the others move by hundredths of a pixel). The part was
    then refused as ambiguous: 68-69 % at its place against 65-67 % 8 mm along the line of sight, on
    a taller parallel, under the 10 % margin, because the sharpness that tells such readings apart
    counted the edges beside clipped pixels too (``LocateContext.sharp`` now leaves them out, and it
    is located: asserted first). The final fit is then judged with a 2 % margin, as it was while the
    part was refused: 0.62 mm off (0.6 of it in y, within its 0.44 mm sigma) and turned 0.01 deg; with
    the edges beside clipped pixels 0.68 mm and 0.05 deg."""
    sc, image, wp = _scene("setup_006")
    full = localize(image, sc.K, sc.dist, sc.layout, [wp] + sc.fixture_candidates, table_model=sc.table_candidate,
                    chain=True, riser_heights_mm=SHOP_PARALLELS)
    got = next((o for o in full.objects if o["kind"] == "workpiece"), None)
    assert got is not None, full.not_found
    e = pose_error_6dof(np.asarray(got["T_table_obj"]), np.asarray(sc.workpiece["T_table_object"]), wp.prepare())
    assert np.linalg.norm(e[:3]) < 0.7 and _within_3_sigma(got, e), (e, got["sigma"])
    res, obj, err = _run("setup_006", riser_heights_mm=SHOP_PARALLELS, min_margin=0.02)
    assert res.ok, res.reason
    assert np.linalg.norm(err[:3]) < 0.7 and np.nanmax(np.abs(err[3:])) < 0.05, err
    assert _within_3_sigma(obj, err), (err, obj["sigma"])
    monkeypatch.setattr(refine_module, "near_clipped", lambda clipped, uv, *a, **k: np.zeros(len(uv), bool))
    _, _, with_clipped = _run("setup_006", riser_heights_mm=SHOP_PARALLELS, min_margin=0.02)
    # with them it is further off and turned several times as much (0.72 mm and 0.19 deg before its jaw
    # kept the body's turn, 0.60 mm and 0.15 deg before the held tilt)
    assert np.linalg.norm(with_clipped[:3]) > np.linalg.norm(err[:3]), (with_clipped, err)
    assert np.nanmax(np.abs(with_clipped[3:])) > 3 * np.nanmax(np.abs(err[3:])), (with_clipped, err)


def test_a_small_part_deep_between_the_jaws_is_found_where_the_jaws_hold_it(monkeypatch):
    """setup_034: a 34 mm angle block on parallels deep in the vise, its sides partly hidden by the
    jaws. The plane search does not rank its place (the nearest start it keeps is 4 mm and 10 deg
    off); the poses the jaws allow, scored directly, find it."""
    res, obj, err = _run("setup_034")
    assert res.ok, res.reason
    assert obj["chain"][1:] == ["vise_body seat", "table"], obj["chain"]
    assert np.linalg.norm(err[:3]) < 0.1 and np.nanmax(np.abs(err[3:])) < 0.05, err
    assert _within_3_sigma(obj, err), (err, obj["sigma"])
    # without the jaws' starts it is not found
    monkeypatch.setattr(locate_module, "clamped_starts", lambda *a, **k: [])
    res, = _run_refused("setup_034")
    assert "angle_block not found" in res


def test_a_part_against_the_fixed_jaw_is_found_when_the_moving_jaw_is_not():
    """moved_001_a: the vise's moving jaw is not located, so no jaw opening; the fixed jaw alone holds
    the l-bracket's turn and place across it (it was refused before, 34 % of its edges)."""
    sc, image, wp = _scene("moved_001_a", family="moved")
    res = localize(image, sc.K, sc.dist, sc.layout, [wp] + sc.fixture_candidates, table_model=sc.table_candidate,
                   chain=True)
    assert "vise_jaw" not in [o["name"] for o in res.objects]
    obj = next(o for o in res.objects if o["kind"] == "workpiece")
    err = pose_error_6dof(np.asarray(obj["T_table_obj"]), np.asarray(sc.workpiece["T_table_object"]), wp.prepare())
    assert np.linalg.norm(err[:3]) < 0.2 and np.nanmax(np.abs(err[3:])) < 0.1, err
    assert _within_3_sigma(obj, err), (err, obj["sigma"])


def _run_refused(scene_id: str) -> tuple[str]:
    """The workpiece's refusal reason for the scene through the chain."""
    sc, image, wp = _scene(scene_id)
    res = localize(image, sc.K, sc.dist, sc.layout, [wp] + sc.fixture_candidates, table_model=sc.table_candidate,
                   chain=True)
    assert not any(o["kind"] == "workpiece" for o in res.objects)
    return (next(n["reason"] for n in res.not_found if n.get("name") == wp.name),)


def _layout_off(layout: dict, seed: int, mm: float, deg: float) -> dict:
    """``layout`` as a shop may hold it: every marker ``mm`` off (x, y, z) and turned ``deg`` (normal
    draws) from where it really sits."""
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(seed)
    markers = []
    for m in layout["markers"]:
        T = np.array(m["T_table_marker"], float)
        T[:3, :3] = T[:3, :3] @ Rotation.from_euler("z", deg * rng.standard_normal(), degrees=True).as_matrix()
        T[:3, 3] += mm * rng.standard_normal(3)
        markers.append({**m, "T_table_marker": T.tolist()})
    return {**layout, "markers": markers}


def test_three_markers_off_their_layout_are_covered_by_the_declared_placement_sigma(monkeypatch):
    """setup_027 shows 3 markers: no jackknife can show their placement error, and markers 0.1 mm off
    move the table's distance (which rests on their spread) by several times what the points' scatter
    admits. The layout's declared ``placement_sigma`` covers it, in the table's and in the part's sigma;
    the points' scatter alone (the layout taken as exact, no side shared error) does not."""
    from app.vision import fiducials
    from app.vision.fiducials import locate_table

    sc, image, wp = _scene("setup_027")
    T_true = np.asarray(sc.gt["T_cam_table"])
    covered, plain = 0, 0
    for seed in range(6):
        told = _layout_off(sc.layout, seed, 0.1, 0.1)
        declared = locate_table(image, sc.K, sc.dist, {**told, "placement_sigma": {"position_mm": 0.1,
                                                                                   "rotation_deg": 0.1}})
        with monkeypatch.context() as m:
            m.setattr(fiducials, "SIDE_OFFSET_PX", 0.0)
            exact = locate_table(image, sc.K, sc.dist, told, markers_placed=(0, 0, 0))
        assert len(declared.ids_used) == 3 and declared.placement_sigma[:2] == (0.1, 0.1)
        c = declared.centroid_table_mm
        d = (np.linalg.inv(T_true) @ declared.T_cam_table @ np.append(c, 1))[:3] - c
        covered += bool(np.all(np.abs(d) <= 3 * declared.sigma_xyz_mm))
        plain += bool(np.all(np.abs(d) <= 3 * exact.sigma_xyz_mm))
    assert covered == 6 and plain <= 2, (covered, plain)
    # and the part's sigma carries it
    told = _layout_off(sc.layout, 1, 0.1, 0.1)
    res = localize(image, sc.K, sc.dist, {**told, "placement_sigma": {"position_mm": 0.1, "rotation_deg": 0.1}},
                   [wp] + sc.fixture_candidates, table_model=sc.table_candidate, chain=True)
    obj = next(o for o in res.objects if o["kind"] == "workpiece")
    err = pose_error_6dof(np.asarray(obj["T_table_obj"]), np.asarray(sc.workpiece["T_table_object"]), wp.prepare())
    assert _within_3_sigma(obj, err), (err, obj["sigma"])


def _fixtures(scene_id: str):
    """The vise alone (body, then its moving jaw along the devset's declared guide)."""
    sc, image, _ = _scene(scene_id)
    res = localize(image, sc.K, sc.dist, sc.layout, sc.fixture_candidates, table_model=sc.table_candidate, chain=True)
    truth = {o["name"]: np.asarray(o["T_table_object"]) for o in sc.gt["objects"]}
    return sc, res, truth


def _assert_fixture_at_its_place(sc, res, truth: dict, name: str) -> None:
    """The fixture ``name`` is among the located objects within 0.5 mm and 0.1 deg of its truth."""
    obj = next((o for o in res.objects if o["name"] == name), None)
    assert obj is not None, res.not_found
    model = next(c for c in sc.fixture_candidates if c.name == name).prepare()
    err = pose_error_6dof(np.asarray(obj["T_table_obj"]), truth[name], model)
    assert np.linalg.norm(err[:3]) < 0.5 and np.nanmax(np.abs(err[3:])) < 0.1, (name, err)


@pytest.mark.parametrize("scene_id", ["setup_009", "setup_014"])
def test_vise_found_where_a_coarse_grid_missed_it(scene_id):
    """A vise is a third of the table, half hidden by its jaw and its part: on a 16 mm / 7 deg coarse
    grid its true cell ranked 57th-376th and never reached the fine stage. Fixtures are searched on a
    grid of at most 8 mm with more cells re-scored (``localize.FIXTURE_OPTIONS``)."""
    _assert_fixture_at_its_place(*_fixtures(scene_id), "vise_body")


def test_vise_found_where_its_own_body_hides_its_lower_edges():
    """Devset setup_029: the vise seen from high in front, a bracket on parallels between its jaws.
    The coarse correlation ranked the vise's true cell 64th among the local maxima of its turn, of
    which 4 were re-scored in the image: every start lay 46 mm across the vise (best fit 32 %,
    refused). Fixtures now have 64 maxima of every turn re-scored, and the image scores leave out
    the edges the vise hides behind its own body (``search._self_hidden``): it is found. Either
    alone does not find it."""
    _assert_fixture_at_its_place(*_fixtures("setup_029"), "vise_body")


def test_a_vise_a_plate_hides_is_found_under_the_plate():
    """Devset setup_021: a plate on 25 mm parallels in the vise, seen from above, hides most of the
    vise (41 % of it in view); searched over the whole table its best fit supports 25 % of its edges
    and the plate is located on "an unknown support 94.9 mm high" (0.25 mm off, 2 sigma in ry).
    Looked for under the plate, with the plate hiding it, the vise and its jaw are found, and the
    plate stands on its declared parallel on the seat, held by both jaws."""
    res, obj, err = _run("setup_021", riser_heights_mm=SHOP_PARALLELS)
    look = next(s for s in res.stages if s.name == "look under the parts")
    assert look.ok and "vise_body found under plate_slots" in look.message, look.message
    sc, _, _ = _scene("setup_021")
    truth = {o["name"]: np.asarray(o["T_table_object"]) for o in sc.gt["objects"]}
    for name in ("vise_body", "vise_jaw"):
        _assert_fixture_at_its_place(sc, res, truth, name)
    assert obj["chain"] == ["a declared riser 25 mm high", "vise_body seat", "table"], obj["chain"]
    assert set(obj["held_by"]) == {"vise_body", "vise_jaw"}, obj["held_by"]
    assert np.linalg.norm(err[:3]) < 0.2 and np.nanmax(np.abs(err[3:])) < 0.1, err
    assert _within_3_sigma(obj, err), (err, obj["sigma"])


def test_a_part_on_an_unknown_support_with_no_fixture_under_it_stays_as_it_was():
    """Devset setup_036: the vise under the plate is not found even there (the close view shows a
    sliver of it): the stage says so and the plate stays as the first pass located it."""
    res, obj, err = _run("setup_036", riser_heights_mm=SHOP_PARALLELS)
    look = next(s for s in res.stages if s.name == "look under the parts")
    assert not look.ok and "not found under octagonal_pocket either" in look.message, look.message
    assert [s.name for s in res.stages].count("locate octagonal_pocket") == 1
    assert obj["chain"][0].startswith("an unknown support") and np.linalg.norm(err[:3]) < 0.2, (obj["chain"], err)


@pytest.mark.parametrize("scene_id", ["setup_006", "setup_016"])
def test_the_moving_jaw_is_found_along_its_guide(scene_id):
    """A plain box: searched anywhere in any rotation it was "ambiguous: two different poses fit almost
    equally well" in both scenes (73 % against 67 %, 80 % against 74 %); searched only along its
    guide on the located body it is found, on the guide, within half a millimetre. The ways hold its
    turn (``clamping.guide_hold``): fitted freely it was turned 0.19 and 0.04 deg about the table
    normal (its body 0.02 and 0.01 deg); held, 0.006 and 0.006 deg. The hold is not in its ``held_by``."""
    sc, res, truth = _fixtures(scene_id)
    jaw = next((o for o in res.objects if o["name"] == "vise_jaw"), None)
    assert jaw is not None, res.not_found
    assert jaw["guided_by"] == "vise_body" and jaw["chain"][-1] == "table" and "vise_body" in jaw["chain"][0]
    (stage,) = [s for s in res.stages if s.name == "locate vise_jaw"]
    assert "guided by vise_body" in stage.message, stage.message
    model = next(c for c in sc.fixture_candidates if c.name == "vise_jaw").prepare()
    err = pose_error_6dof(np.asarray(jaw["T_table_obj"]), truth["vise_jaw"], model)
    assert np.linalg.norm(err[:3]) < 0.5 and np.linalg.norm(err[3:]) < 0.3, err
    assert abs(err[5]) < 0.03, err
    assert jaw["held_by"] == [], jaw["held_by"]


def test_a_jaw_whose_vise_was_not_found_is_not_searched():
    """setup_021: the body is not found; searched freely the jaw was "located" 556 mm from where it is
    (a plain box fits many places) and then hid the part's edges. Now it is reported, not guessed."""
    _, res, _ = _fixtures("setup_021")
    assert [o["name"] for o in res.objects if o["name"] == "vise_jaw"] == []
    jaw = next(n for n in res.not_found if n["name"] == "vise_jaw")
    assert jaw["kind"] == "not_found"
    assert jaw["reason"] == "vise_jaw not searched: it rides on vise_body, which was not found"


def _through_markers(scene_id: str, ids: tuple[int, ...], monkeypatch=None, level: bool = True):
    """The scene through the chain with only the markers ``ids`` in the layout it is told."""
    sc, image, wp = _scene(scene_id)
    if not level:
        from app.vision import table_levelling

        monkeypatch.setattr(table_levelling, "LEVEL_MIN_TILT_DEG", 90.0)
    few = {**sc.layout, "markers": [m for m in sc.layout["markers"] if m["id"] in ids]}
    res = localize(image, sc.K, sc.dist, few, [wp] + sc.fixture_candidates, table_model=sc.table_candidate,
                   chain=True, riser_heights_mm=SHOP_PARALLELS)
    return sc, wp, res


def test_a_table_seen_through_two_markers_is_levelled_by_its_vise(monkeypatch):
    """setup_039 through markers 88 and 90: the located table is tilted 0.1 deg about x (1.4 of its
    sigmas; 0.34 mm of height under the vise). On it the flange is fitted on an unknown support
    19.8 mm high, not on its declared 20 mm parallel. The vise, searched over the heights the table's
    error allows with its tilt free, reads that tilt; levelled by it, the table is within 0.05 deg,
    and the flange stands on its declared parallel within 0.3 mm and 3 sigma. (Before the markers'
    corners were read profile by profile and corrected for clipping, marker 90 read 0.54 px off, the
    table was tilted 0.42 deg and the flange fitted 1.4 mm off.)"""
    from app.vision.fiducials import _frame_step

    sc, wp, res = _through_markers("setup_039", (88, 90), monkeypatch, level=False)
    assert not any(s.name == "table levelled" for s in res.stages)
    obj = next(o for o in res.objects if o["kind"] == "workpiece")
    assert obj["chain"][0].startswith("an unknown support"), obj["chain"]
    monkeypatch.undo()
    sc, wp, res = _through_markers("setup_039", (88, 90))
    stage = next(s for s in res.stages if s.name == "table levelled")
    assert stage.ok and stage.data["levelled_by"] == "vise_body", stage.message
    assert stage.data["correction"][0] > 0.03 and stage.data["correction"][2] < -0.2, stage.data["correction"]
    assert res.table["T_cam_table"] == stage.data["T_cam_table"]
    T_levelled = np.asarray(res.table["T_cam_table"])
    tilt = _frame_step(np.asarray(sc.gt["T_cam_table"]), T_levelled, np.asarray(res.table["centroid_table_mm"]))[:2]
    assert np.degrees(np.abs(tilt)).max() < 0.05, np.degrees(tilt)
    assert {"vise_body", "vise_jaw"} <= {o["name"] for o in res.objects}
    obj = next(o for o in res.objects if o["kind"] == "workpiece")
    assert obj["chain"][:2] == ["a declared riser 20 mm high", "vise_body seat"], obj["chain"]
    err = pose_error_6dof(np.asarray(obj["T_table_obj"]), np.asarray(sc.workpiece["T_table_object"]), wp.prepare())
    assert np.linalg.norm(err[:3]) < 0.3 and np.abs(err[3:]).max() < 0.2, err
    assert _within_3_sigma(obj, err), (err, obj["sigma"])


def test_a_bigger_fixture_the_picture_does_not_show_does_not_stop_the_levelling():
    """The shop's library holds a bigger vise that is not on the table (a 460 x 220 x 130 block): it
    is tried first and not found, and the vise that is there levels the table. Searched with 64
    maxima of every turn, the block fits 76 % of its visible edges along the table's slots and its
    end, with 44 % of its base off the table, and the vise was then not found: a fixture
    standing on the table has most of its base over its top (``localize.BASE_ON_TABLE_MIN``)."""
    sc, image, wp = _scene("setup_039")
    absent = trimesh.creation.box(extents=(460.0, 220.0, 130.0))
    absent.apply_translation([0.0, 0.0, 65.0])
    few = {**sc.layout, "markers": [m for m in sc.layout["markers"] if m["id"] in (88, 90)]}
    res = localize(image, sc.K, sc.dist, few, [wp, *sc.fixture_candidates, Candidate("big_vise", absent, kind="clamp")],
                   table_model=sc.table_candidate, chain=True, riser_heights_mm=SHOP_PARALLELS)
    stage = next(s for s in res.stages if s.name == "table levelled")
    assert stage.ok and stage.data["levelled_by"] == "vise_body", stage.message
    assert "big_vise" not in {o["name"] for o in res.objects}


def test_a_table_seen_through_many_markers_is_not_levelled():
    """All its markers fix the table's tilt better than a vise stands (0.014 deg): nothing is re-read."""
    sc, image, wp = _scene("setup_019")
    res = localize(image, sc.K, sc.dist, sc.layout, [wp] + sc.fixture_candidates, table_model=sc.table_candidate,
                   chain=True)
    assert not any(s.name == "table levelled" for s in res.stages)
    assert max(res.table["sigma_rot_deg"][:2]) < 0.05


def test_small_part_on_parallels_gets_a_start_at_its_place(monkeypatch):
    """setup_007: the angle block on 30 mm parallels (not in the library: searched over free height
    on the whole table). Its place's coarse cell ranked 1364th of 1.3 million and 7th to 9th among
    the local maxima of its turn, of which 4 went on to the image scorer: no start of the plane
    search came near it. (What then outscored it: :func:`test_a_fit_under_the_table_is_no_reading`.)"""
    sc, image, wp = _scene("setup_007")
    starts = []
    real = locate_module.find_starts

    def spy(*args, **kwargs):
        out = real(*args, **kwargs)
        if args[4] is wp.prepared and not isinstance(out, str):
            starts.extend(out[0])
        return out

    monkeypatch.setattr(locate_module, "find_starts", spy)
    localize(image, sc.K, sc.dist, sc.layout, [wp] + sc.fixture_candidates, table_model=sc.table_candidate,
             chain=True)
    assert starts
    T_true = np.asarray(sc.workpiece["T_table_object"], float)
    errs = [pose_error_6dof(h.T_table_obj, T_true, wp.prepared) for h in starts]
    near = [e for e in errs if np.linalg.norm(e[:3]) < 5.0 and np.nanmax(np.abs(e[3:])) < 5.0]
    assert near, min(errs, key=lambda e: np.linalg.norm(e[:3]))


def test_a_fit_under_the_table_is_no_reading():
    """setup_007: the angle block on 30 mm parallels. Fitted with its height free, one reading slid
    along the line of sight to 62 mm under the table top, 226 mm from the part, and matched 67 % of
    its edges against the true pose's 61 %: it won, and was refused as not distinct. No part can be
    under the table; without that reading the true pose is located."""
    res, obj, err = _run("setup_007", riser_heights_mm=SHOP_PARALLELS)
    assert np.linalg.norm(err[:3]) < 0.5 and np.nanmax(np.abs(err[3:])) < 0.5, err
    assert obj["chain"][-1] == "table", obj["chain"]
    assert _within_3_sigma(obj, err), (err, obj["sigma"])


def _with_strap_clamps(scene_id: str):
    """The scene located with its strap clamp sets in the library; (result, clamps, their truth)."""
    sc, image, wp = _scene(scene_id)
    strap = {o["name"]: o for o in sc.gt["objects"] if o.get("subtype") == "strap_clamp"}
    clamps = [Candidate(n, trimesh.load(DEVSET / o["mesh"], force="mesh"), kind="clamp") for n, o in strap.items()]
    res = localize(image, sc.K, sc.dist, sc.layout, [wp] + sc.fixture_candidates + clamps,
                   table_model=sc.table_candidate, chain=True, riser_heights_mm=SHOP_PARALLELS)
    return res, {c.name: c for c in clamps}, strap


def _clamp_error(res, clamp, truth):
    got = next(o for o in res.objects if o["name"] == clamp.name)
    err = pose_error_6dof(np.asarray(got["T_table_obj"]), np.asarray(truth["T_table_object"]), clamp.prepare())
    return got, err


def test_a_strap_clamp_stands_on_its_heel_block():
    """setup_003: a part under a strap clamp set whose stud reaches 16 mm down into the T-slot. Standing
    on its lowest point (the stud's end) every devset set was searched 16 mm too high (setup_013: one
    ambiguous, one 27 mm off). Standing on its heel block it is located."""
    res, clamps, truth = _with_strap_clamps("setup_003")
    got, err = _clamp_error(res, clamps["strap_clamp_0"], truth["strap_clamp_0"])
    assert np.linalg.norm(err[:3]) < 0.3 and np.nanmax(np.abs(err[3:])) < 0.1, err
    assert _within_3_sigma(got, err), (err, got["sigma"])
    assert got["chain"] == ["table"]


def test_a_clamp_that_another_clamp_fits_as_well_is_refused():
    """setup_000: two strap clamp sets that differ in their straps' length. The longer one was located at
    the shorter one's place (151 mm from its own), and passed by its sigma; the shorter then took the
    longer one's place. Started there, the shorter set fits it clearly better (65 % against 50 %): the
    longer one is refused as ambiguous and the shorter one is found at its own place."""
    res, clamps, truth = _with_strap_clamps("setup_000")
    (refused,) = [n for n in res.not_found if n["name"] == "strap_clamp_1"]
    assert refused["kind"] == "ambiguous" and "strap_clamp_0 fits its place as well" in refused["reason"]
    got, err = _clamp_error(res, clamps["strap_clamp_0"], truth["strap_clamp_0"])
    assert np.linalg.norm(err[:3]) < 0.3 and np.nanmax(np.abs(err[3:])) < 0.1, err


def test_small_part_on_the_table_is_located():
    """setup_025: the angle block alone on the table (no clamp), 530 mm from the camera."""
    sc, image, wp = _scene("setup_025")
    res = localize(image, sc.K, sc.dist, sc.layout, [wp] + sc.fixture_candidates, table_model=sc.table_candidate,
                   chain=True)
    obj = next((o for o in res.objects if o["kind"] == "workpiece"), None)
    assert obj is not None, [n["reason"] for n in res.not_found]
    err = pose_error_6dof(np.asarray(obj["T_table_obj"]), np.asarray(sc.workpiece["T_table_object"]), wp.prepare())
    assert np.linalg.norm(err[:3]) < 0.3 and np.nanmax(np.abs(err[3:])) < 0.5, err


def test_a_part_lying_free_on_the_table_may_tilt():
    """A pocketed block lying on the table, tilted 0.5 deg by something under one edge: held to the
    0.3 deg tilt of a clamped part its pose was 0.40 mm off; lying free, 0.5 deg, 0.23 mm, fitted
    with 0.31 deg of its tilt while the prior counted several times what its covariance gives it.
    Weighed against the edge noise the fit shows, it keeps its tilt: 0.05 mm, 0.05 deg."""
    res, obj, err = _run("setup_000")
    assert res.ok, res.reason
    assert obj["chain"] == ["table"], obj["chain"]
    assert np.linalg.norm(err[:3]) < 0.12 and np.nanmax(np.abs(err[3:])) < 0.1, err
    assert _within_3_sigma(obj, err), (err, obj["sigma"])


def _without_gamma(image):
    """The image as a camera that outputs linear light (gamma 1, many machine-vision cameras' default)
    would have taken it: the devset renders with gamma 2.2."""
    return np.clip(np.rint(255 * (image.astype(np.float64) / 255) ** 2.2), 0, 255).astype(np.uint8)


def test_a_camera_without_gamma_is_read_as_one():
    """setup_036, a part in the vise, taken without gamma. Decoded as 2.2 every edge sits up to half a
    pixel towards its bright side: the part was not found (and 13 of 40 devset parts were wrong, their
    sigma over-confident). The markers' cells say which gamma the image has; with it the part is found
    where it sits, as in the image as rendered."""
    res, obj, err = _run("setup_036", recode=_without_gamma)
    assert res.ok, res.reason
    assert res.table["gamma"] == pytest.approx(1.0, abs=0.1), res.table["gamma_reading"]
    assert "read from the markers" in res.stages[0].message
    assert np.linalg.norm(err[:3]) < 0.3 and np.nanmax(np.abs(err[3:])) < 0.1, err
    assert _within_3_sigma(obj, err), (err, obj["sigma"])


def _dark_and_noisy(image):
    """Under-exposed (every grey level x 0.45) with 4 grey levels of read noise: a dim machine room."""
    noisy = image.astype(np.float64) * 0.45 + np.random.default_rng(36).normal(0.0, 4.0, image.shape)
    return np.clip(np.rint(noisy), 0, 255).astype(np.uint8)


def test_a_dark_noisy_picture_of_the_vise_is_read():
    """setup_036 under-exposed and noisy. Each subpixel edge must stand out of the noise; the noise was
    judged at mid-grey, where decoding is about 3 times steeper than at these dark levels, and the part
    was not found (17 % of its true pose's edges passed the floor). Judged at their own grey level, the
    part is found where it sits."""
    res, obj, err = _run("setup_036", recode=_dark_and_noisy)
    assert res.ok, res.reason
    assert np.linalg.norm(err[:3]) < 0.3 and np.nanmax(np.abs(err[3:])) < 0.1, err
    assert _within_3_sigma(obj, err), (err, obj["sigma"])


def test_intrinsics_off_by_a_calibration_error_stay_within_the_stated_sigma():
    """Told a focal length 0.6 % short and a principal point 1.5 px off (two careful calibrations of one
    camera differ by 0.1-1 % in f), the L bracket on the table (setup_010) is found a few tenths of a
    millimetre away: the stated sigma covers it because the intrinsics' own sigma is in it. Taken as
    exact, the same intrinsics give a sigma that the error exceeds 3-fold."""
    from app.vision.intrinsics import moved_intrinsics

    sc, _, _ = _scene("setup_010")
    K = moved_intrinsics(moved_intrinsics(moved_intrinsics(sc.K, 0, -0.006), 1, 1.5), 2, -0.7)
    res, obj, err = _run("setup_010", K=K)
    assert res.ok and np.linalg.norm(err[:3]) > 0.1, err           # the intrinsics do move the part
    assert _within_3_sigma(obj, err), (err, obj["sigma"])
    # its share is in the result apart (the gate's reason names it when it is most of a sigma)
    C_k, C_frame = np.diag(obj["cov6_intrinsics"]), np.diag(obj["cov6_table"])
    assert np.all(C_k[:3] > 0) and np.all(C_k <= C_frame + 1e-12)
    _, exact, err_exact = _run("setup_010", K=K, intrinsics_sigma=None)
    np.testing.assert_allclose(err_exact, err, atol=1e-9)            # the same fit, another sigma
    assert not _within_3_sigma(exact, err_exact), (err_exact, exact["sigma"])
    assert np.all(np.asarray(exact["cov6_intrinsics"]) == 0)


def test_recognition_locates_the_fixtures_first_and_finds_the_part_in_the_vise():
    """Recognition (no model named) on a vise scene: the library's vise is located first, as in the
    chain; the part is then recognised on its seat, and a 32 mm block does not take the vise's edges."""
    from app.geometry import parts

    sc, image, wp = _scene("setup_011")         # the flange in the vise, on parallels
    block = Candidate("pin_block_32", parts.pin_block_32())
    res = localize(image, sc.K, sc.dist, sc.layout, [wp, block] + sc.fixture_candidates,
                   table_model=sc.table_candidate, recognise=True, riser_heights_mm=SHOP_PARALLELS)
    assert res.ok, res.reason
    names = [o["name"] for o in res.objects]
    assert "vise_body" in names and wp.name in names and block.name not in names, names
    obj = next(o for o in res.objects if o["name"] == wp.name)
    err = pose_error_6dof(np.asarray(obj["T_table_obj"]), np.asarray(sc.workpiece["T_table_object"]), wp.prepare())
    assert np.linalg.norm(err[:3]) < 1.0 and np.nanmax(np.abs(err[3:])) < 0.5, err
    assert [s.name for s in res.stages][:3] == ["table markers", "locate vise_body", "locate vise_jaw"]


def _recognised_at_its_place(res, sc, wp, others) -> dict:
    """The workpiece recognised within 1 mm and 0.5 deg of the truth, none of ``others``; its entry."""
    assert res.ok, res.reason
    names = [o["name"] for o in res.objects]
    assert wp.name in names and not {c.name for c in others} & set(names), names
    obj = next(o for o in res.objects if o["name"] == wp.name)
    err = pose_error_6dof(np.asarray(obj["T_table_obj"]), np.asarray(sc.workpiece["T_table_object"]), wp.prepare())
    assert np.linalg.norm(err[:3]) < 1.0 and np.nanmax(np.abs(err[3:])) < 0.5, err
    return obj


def test_recognition_ranks_a_part_in_the_vise_by_the_poses_its_jaws_allow():
    """Devset setup_004: the stepped block held in the vise. A plane search alone ranks it behind a bar
    and blocks fitted to the vise's own edges, and recognition locates only the best few completely;
    ranked by the poses the located jaws allow (as it is then located), it is recognised at its place."""
    from app.geometry import parts

    sc, image, wp = _scene("setup_004")
    small = parts.pin_block_32()
    small.apply_scale(0.8)
    others = [Candidate("parallel_150x25x8", parts.parallel(150.0, 25.0, 8.0)),
              Candidate("pin_block_32", parts.pin_block_32()), Candidate("pin_block_32_x0.8", small),
              Candidate("angle_block", trimesh.load(DEVSET / "meshes" / "wp_angle_block.stl", force="mesh"))]
    res = localize(image, sc.K, sc.dist, sc.layout, [wp] + others + sc.fixture_candidates,
                   table_model=sc.table_candidate, recognise=True, riser_heights_mm=SHOP_PARALLELS)
    _recognised_at_its_place(res, sc, wp, others)


def _recognised_among_a_bar_and_a_block(scene_id: str):
    """Recognition over the scene's workpiece, a 150 mm bar and a 32 mm block (the scene's vise in the
    library, the shop's parallels declared) -> (result, recognition stage, scene, workpiece, others)."""
    from app.geometry import parts

    sc, image, wp = _scene(scene_id)
    others = [Candidate("parallel_150x25x8", parts.parallel(150.0, 25.0, 8.0)),
              Candidate("pin_block_32", parts.pin_block_32())]
    stages = []
    res = localize(image, sc.K, sc.dist, sc.layout, [wp] + others + sc.fixture_candidates,
                   table_model=sc.table_candidate, recognise=True, riser_heights_mm=SHOP_PARALLELS,
                   on_stage=stages.append)
    return res, next(st for st in stages if st.name == "recognition"), sc, wp, others


def test_of_two_parts_recognised_the_one_that_explains_most_of_the_picture_comes_first():
    """Devset setup_003: the slotted plate on the table, and clutter beside it that a 26 mm pin block fits
    (a higher score than the plate's, a tenth of its edges). The first workpiece's datum is the offset the
    page proposes: it is the plate's."""
    from app.geometry import parts

    small = parts.pin_block_32()
    small.apply_scale(0.8)
    sc, image, wp = _scene("setup_003")
    block = Candidate("pin_block_32_x0.8", small)
    stages = []
    res = localize(image, sc.K, sc.dist, sc.layout, [block, wp] + sc.fixture_candidates,
                   table_model=sc.table_candidate, recognise=True, riser_heights_mm=SHOP_PARALLELS,
                   on_stage=stages.append)
    parts_found = [o for o in res.objects if o["kind"] == "workpiece"]
    assert parts_found[0]["name"] == wp.name, [(o["name"], o["score"], o["supported_edge_px"]) for o in parts_found]
    explained = [o["supported_edge_px"] for o in parts_found]
    assert explained == sorted(explained, reverse=True)
    rec = next(st for st in stages if st.name == "recognition")
    assert rec.message.startswith(f"recognised {wp.name}"), rec.message


def test_recognition_searches_its_best_few_again_over_risers_of_any_height_when_it_finds_nothing():
    """Devset setup_036: a plate on parallels in the vise, which it mostly hides (the vise is not located).
    On the table and the declared risers' tops nothing fits well enough; searched again as a named part
    is, over risers of any height with its height fitted, the plate is recognised at its place. (Until
    the fixtures' search left out what they hide behind themselves this was setup_029, whose vise is
    now located and its bracket recognised on the first search.)"""
    res, rec, sc, wp, others = _recognised_among_a_bar_and_a_block("setup_036")
    assert rec.data["searched_any_height"] and any(k.startswith("first_") for k in rec.data["timings_ms"])
    obj = _recognised_at_its_place(res, sc, wp, others)
    assert "unknown support" in obj["chain"][0], obj["chain"]       # it says it floats on something unseen
    assert f"{wp.name} (rests on an unknown support" in rec.message, rec.message


def test_recognition_reads_a_part_as_a_named_locate_does():
    """Devset setup_001: the L bracket on 20 mm parallels in the vise. Located by name it is found; among
    other models recognition chose its readings with no margin, took the bracket slid along the line of
    sight and then refused it as "ambiguous" against the reading a named locate keeps. With the margin
    its readings are chosen as a named part's are, and it is recognised at its place, on the first search."""
    res, rec, sc, wp, others = _recognised_among_a_bar_and_a_block("setup_001")
    assert not rec.data["searched_any_height"]
    _recognised_at_its_place(res, sc, wp, others)
