"""``setupcam plan``: JSON in, path JSON out, reasoned errors."""

from __future__ import annotations

import json

import trimesh

from app.cli import main

EXAMPLE = {
    "points": [[20.0 * k, 0.0, z] for k, z in enumerate([0, -6, -23, -33, -23, -6, 0])],
    "probe": {"working_distance_mm": 30, "clearance_mm": 5},
    "obstacles": {"part_top_mm": 6},
}


def _run(tmp_path, capsys, req, *extra):
    f = tmp_path / "req.json"
    f.write_text(json.dumps(req))
    code = main(["plan", str(f), *extra])
    out = capsys.readouterr()
    return code, out.out, out.err


def test_worked_example_via_cli(tmp_path, capsys):
    code, out, _ = _run(tmp_path, capsys, EXAMPLE)
    assert code == 0
    ans = json.loads(out)
    assert [m["pattern"] for m in ans["moves"]] == [
        "straight", "over_then_down", "up_over_down", "up_over_down", "up_then_over", "straight"]
    assert {m["safe_height_mm"] for m in ans["moves"]} == {-19.0}
    assert ans["waypoints_mm"][:4] == [[0, 0, 0], [20, 0, -6], [40, 0, -6], [40, 0, -23]]
    code, out, _ = _run(tmp_path, capsys, {**EXAMPLE, "options": {"diagonal_down": True, "up_diagonal": True}})
    assert json.loads(out)["moves"][1]["pattern"] == "diagonal_then_down"
    code, out, _ = _run(tmp_path, capsys, EXAMPLE, "--method", "profile")
    prof = json.loads(out)
    assert code == 0 and prof["method"] == "profile" and prof["length_mm"] <= ans["length_mm"]


def test_regions_and_meshes(tmp_path, capsys):
    req = {
        "points": [[10, 50, 20], [90, 50, 20]],
        "probe": {"working_distance_mm": 0, "clearance_mm": 2},
        "obstacles": {"regions": [{"rect_mm": [0, 0, 100, 100], "height_mm": 20},
                                  {"rect_mm": [40, 0, 60, 100], "height_mm": 35}], "priority": "narrower_wins"},
    }
    code, out, _ = _run(tmp_path, capsys, req)
    assert code == 0 and json.loads(out)["moves"][0]["obstacle_height_mm"] == 35
    box = trimesh.creation.box(extents=(20, 100, 35))
    box.export(tmp_path / "wall.stl")
    T = [[1, 0, 0, 50], [0, 1, 0, 50], [0, 0, 1, 17.5], [0, 0, 0, 1]]
    req["obstacles"] = {"meshes": [{"path": "wall.stl", "T_table_obj": T, "name": "wall"}], "uncertainty_mm": 0.5}
    req["probe"]["radius_mm"] = 3
    for method in ("reference", "profile"):
        code, out, _ = _run(tmp_path, capsys, {**req, "method": method})
        ans = json.loads(out)
        assert code == 0 and ans["collision"]["ok"], ans["collision"]
        assert max(p[2] for p in ans["waypoints_mm"]) >= 37.5


def test_bad_requests_say_why(tmp_path, capsys):
    code, _, err = _run(tmp_path, capsys, {**EXAMPLE, "obstacles": {"per_move_mm": [6, 6]}})
    assert code == 2 and "2 heights for 6 moves" in err
    code, _, err = _run(tmp_path, capsys, {**EXAMPLE, "probe": {"clearance_mm": 5}})
    assert code == 2 and "working_distance_mm is required" in err
    code, _, err = _run(tmp_path, capsys, {**EXAMPLE, "obstacles": {"regions": [{"rect_mm": [0, 0, 1, 1], "height_mm": 1}],
                                                                    "priority": "biggest"}})
    assert code == 2 and "unknown priority rule 'biggest'" in err
