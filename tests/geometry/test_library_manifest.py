import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from app.geometry.library_manifest import LibraryManifestError, load_library_manifest
from app.geometry.mesh import load_mesh, mesh_summary

LIBRARY = Path(__file__).resolve().parents[2] / "models_library"


def test_manifest_loads_and_every_file_is_a_valid_mesh():
    entries = load_library_manifest(LIBRARY)
    kinds = [e.kind for e in entries]
    assert kinds.count("table") == 1 and kinds.count("clamp") >= 3 and kinds.count("workpiece") >= 3
    sizes = []
    for e in entries:
        m = load_mesh(e.path.read_bytes(), e.file, e.units)
        s = mesh_summary(m)
        assert s["watertight"], e.key
        if e.kind == "workpiece":
            assert e.T_obj_datum is not None
            sizes.append(max(s["extents_mm"]))
            # the datum lies on the part's bounding box top face
            assert e.T_obj_datum[2, 3] == pytest.approx(s["bbox_max_mm"][2])
    assert min(sizes) <= 35 and max(sizes) >= 280  # ~30 mm to ~300 mm
    assert sum(p.stat().st_size for p in LIBRARY.iterdir()) < 2_000_000  # small committed files


def test_table_entry_extents_and_layout():
    (table,) = [e for e in load_library_manifest(LIBRARY) if e.kind == "table"]
    m = load_mesh(table.path.read_bytes(), table.file, table.units)
    assert np.allclose(m.bounds[:, :2], [[0, 0], [800, 400]])
    assert m.bounds[1, 2] == pytest.approx(0.0) and 60 <= m.extents[2] <= 80
    assert table.layout is not None and table.layout.dictionary == "DICT_5X5_100"
    assert 10 <= len(table.layout.markers) <= 14


def test_committed_files_match_the_generator():
    """The committed library is what build_library.py makes from app/geometry/parts.py today."""
    from app.geometry.parts import example_library

    entries = {e.key: e for e in load_library_manifest(LIBRARY)}
    models = example_library()
    assert [m.key for m in models] == list(entries)
    for model in models:
        e = entries[model.key]
        stale = f"{model.key} is stale: rerun models_library/build_library.py"
        assert e.kind == model.kind and e.name == model.name, stale
        # compare geometry, not bytes: another manifold3d version may order triangles differently
        committed = load_mesh(e.path.read_bytes(), e.file, e.units)
        assert np.allclose(committed.bounds, model.mesh.bounds, atol=1e-4), stale
        assert committed.volume == pytest.approx(model.mesh.volume, rel=1e-6), stale
        assert committed.area == pytest.approx(model.mesh.area, rel=1e-6), stale
        if model.T_obj_datum is None:
            assert e.T_obj_datum is None, stale
        else:
            assert np.allclose(e.T_obj_datum, model.T_obj_datum, atol=1e-6), stale
        if model.layout is None:
            assert e.layout is None, stale
        else:
            assert json.loads(e.fiducials_path.read_text()) == json.loads(json.dumps(model.layout)), stale
        assert e.support_surfaces == model.support_surfaces, stale


def _copy_library(tmp_path: Path) -> tuple[Path, dict]:
    d = tmp_path / "lib"
    shutil.copytree(LIBRARY, d, ignore=shutil.ignore_patterns("*.py", "*.pdf", "*.svg"))
    return d, json.loads((d / "library.json").read_text())


def _guide(carrier: str, **changes) -> dict:
    return {"carrier": carrier, "T_carrier_obj": [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 70], [0, 0, 0, 1]],
            "axis": [1, 0, 0], "travel_mm": [0, 80], **changes}


@pytest.mark.parametrize("mutate, message", [
    (lambda doc: doc["models"][1].update(kind="fixture"),
     "kind 'fixture' unknown; use one of workpiece, clamp, support, table"),
    (lambda doc: doc["models"][1].update(units="m"), "units 'm' unknown"),
    (lambda doc: doc["models"][1].update(file="missing.stl"), "file 'missing.stl' not found"),
    (lambda doc: doc["models"][1].update(file="../../etc/passwd.stl"), "must be a path inside the library folder"),
    (lambda doc: doc["models"][1].update(file="vise_150.dxf"), "is not a supported mesh"),
    (lambda doc: doc["models"][4].update(T_obj_datum=np.diag([1.0, 1.0, -1.0, 1.0]).tolist()), "reflection"),
    (lambda doc: doc["models"][4].update(T_obj_datum=[[1, 0, 0]]), "T_obj_datum: expected shape (4, 4)"),
    (lambda doc: doc["models"][2].update(key=doc["models"][1]["key"]), "key 'vise_150' appears twice"),
    (lambda doc: doc["models"][0].update(fiducials=None), "a table needs a fiducial layout"),
    (lambda doc: doc["models"][2].update(key="Bad Key!"), "key must be"),
    (lambda doc: doc.pop("models"), 'expected an object {"models": [...]}'),
    (lambda doc: doc["models"][1].update(support_surfaces={"name": "seat"}),
     "('vise_150'): support_surfaces: expected a list of surfaces (or null), got dict"),
    (lambda doc: doc["models"][1]["support_surfaces"][0].update(outline_xy=[[0, 0], [80, 0]]),
     "support_surfaces[0].outline_xy: List should have at least 3 items"),
    (lambda doc: doc["models"][1]["support_surfaces"][0].update(z_mm="high"),
     "support_surfaces[0].z_mm: Input should be a valid number"),
    (lambda doc: doc["models"][1]["support_surfaces"][0].update(outline_xy=[[0, 0], [10, 0], [20, 0]]),
     "encloses 0 mm²"),
    (lambda doc: doc["models"][1].update(support_surfaces=[{"name": f"s{i}", "z_mm": 70,
                                                            "outline_xy": [[0, 0], [9, 0], [0, 9]]} for i in range(17)]),
     "support_surfaces: 17 surfaces; at most 16"),
    (lambda doc: doc["models"][4].update(support_surfaces=[{"name": "top", "z_mm": 16,
                                                            "outline_xy": [[0, 0], [32, 0], [0, 24]]}]),
     "pin_block_32'): support_surfaces: a workpiece carries no parts"),
    (lambda doc: doc["models"][4].update(guide=_guide("vise_150")),
     "('pin_block_32'): guide: a workpiece is not guided; only clamp and support models ride on a carrier"),
    (lambda doc: doc["models"][2].update(guide=_guide("vise_150", axis=[0, 0, 0])),
     "('strap_clamp_125'): guide.axis: axis is zero"),
    (lambda doc: doc["models"][2].update(guide=_guide("vise_150", travel_mm=[10, -10])),
     "('strap_clamp_125'): guide.travel_mm: [10, -10]: lo must be less than hi"),
    (lambda doc: doc["models"][2].update(guide=_guide("strap_clamp_125")),
     "('strap_clamp_125'): guide.carrier names the model itself"),
    (lambda doc: doc["models"][2].update(guide=_guide("no_such_vise")),
     "model 'strap_clamp_125': guide.carrier 'no_such_vise' is no key or name"),
])
def test_bad_manifest_is_refused_with_a_clear_sentence(tmp_path, mutate, message):
    d, doc = _copy_library(tmp_path)
    mutate(doc)
    (d / "library.json").write_text(json.dumps(doc))
    with pytest.raises(LibraryManifestError) as e:
        load_library_manifest(d)
    assert message in str(e.value)


def test_support_surfaces_declared_left_out_or_empty(tmp_path):
    """Declared surfaces are read as given (model frame, mm); left out or null means "derive them
    from the mesh" (None); [] means the model carries nothing."""
    entries = {e.key: e for e in load_library_manifest(LIBRARY)}
    assert entries["vise_150"].support_surfaces == [
        {"name": "seat", "z_mm": 70.0, "outline_xy": [[0.0, -55.0], [80.0, -55.0], [80.0, 55.0], [0.0, 55.0]]}]
    assert entries["vise_125"].support_surfaces[0]["name"] == "seat"
    assert entries["vise_125"].support_surfaces[0]["z_mm"] == 55.0
    for key, height in (("parallel_150x25x8", 25.0), ("parallel_150x32x8", 32.0)):
        e = entries[key]
        assert e.kind == "support"
        (top,) = e.support_surfaces
        m = load_mesh(e.path.read_bytes(), e.file, e.units)
        # the declared top face is the mesh's top face: 150 long (x), 8 thick (y), base centre at the origin
        assert top["z_mm"] == height == pytest.approx(m.bounds[1, 2])
        assert np.allclose(m.bounds, [[-75, -4, 0], [75, 4, height]])
        assert np.allclose(np.min(top["outline_xy"], axis=0), [-75, -4])
        assert np.allclose(np.max(top["outline_xy"], axis=0), [75, 4])
    assert entries["strap_clamp_125"].support_surfaces is None       # not declared: the field is left out
    assert entries["bracket_140"].support_surfaces is None

    d, doc = _copy_library(tmp_path)
    doc["models"][1]["support_surfaces"] = []                         # the vise carries nothing
    doc["models"][2]["support_surfaces"] = None                       # explicit null = left out
    doc["models"][3]["support_surfaces"] = [{"name": " pad ", "z_mm": 50, "outline_xy": [[0, 0], [20, 0], [20, 10]]}]
    doc["models"][4]["support_surfaces"] = []                         # a workpiece saying it carries nothing is fine
    (d / "library.json").write_text(json.dumps(doc))
    got = {e.key: e.support_surfaces for e in load_library_manifest(d)}
    assert got["vise_150"] == [] and got["strap_clamp_125"] is None and got["pin_block_32"] == []
    assert got["strap_clamp_175"] == [{"name": "pad", "z_mm": 50.0, "outline_xy": [[0.0, 0.0], [20.0, 0.0], [20.0, 10.0]]}]


def test_bad_fiducial_layout_names_the_marker(tmp_path):
    d, _ = _copy_library(tmp_path)
    fpath = d / "tslot_table_800x400.fiducials.json"
    layout = json.loads(fpath.read_text())
    layout["markers"][3]["id"] = layout["markers"][2]["id"]
    fpath.write_text(json.dumps(layout))
    with pytest.raises(LibraryManifestError, match=r"tslot_table_800x400.*marker id 2 appears twice"):
        load_library_manifest(d)


def test_missing_or_broken_manifest(tmp_path):
    with pytest.raises(LibraryManifestError, match="no library.json in"):
        load_library_manifest(tmp_path)
    (tmp_path / "library.json").write_text("{not json")
    with pytest.raises(LibraryManifestError, match="is not valid JSON"):
        load_library_manifest(tmp_path)


def test_a_guide_is_read_with_its_carrier_by_key_or_name(tmp_path):
    """A clamp riding on another model (a moving jaw on its vise): the guide is read as given, the axis
    made unit; the carrier may be named by key or by name; left out, a model stands free."""
    d, doc = _copy_library(tmp_path)
    doc["models"][2]["guide"] = _guide("vise_150", axis=[0, 0, 5])
    doc["models"][3]["guide"] = _guide(doc["models"][1]["name"])
    (d / "library.json").write_text(json.dumps(doc))
    got = {e.key: e for e in load_library_manifest(d)}
    assert got["strap_clamp_125"].guide == {**_guide("vise_150", axis=[0.0, 0.0, 1.0]), "travel_mm": [0.0, 80.0],
                                     "T_carrier_obj": [[float(x) for x in r] for r in _guide("")["T_carrier_obj"]]}
    assert got[doc["models"][3]["key"]].guide["carrier"] == doc["models"][1]["name"]
    assert got["vise_150"].guide is None and got["pin_block_32"].guide is None
    assert all(e.guide is None for e in load_library_manifest(LIBRARY))      # the example vises are one mesh
