"""localize's solid check (_drop_overlapping): of a fixture and a workpiece that would fill the same space,
the one whose fit explains fewer image edges is taken out and said in a stage; real contacts stay."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from app.geometry import parts
from app.geometry.transforms import pose_from_xyz_euler
from app.vision.localize import Candidate, _drop_overlapping

LIB = {m.key: m for m in parts.example_library()}
T_BRACKET = pose_from_xyz_euler(329.6, 123.8, 0.0, c_deg=20.0)


def _located(key: str, T, explained_px: float):
    m = LIB[key]
    return Candidate(m.name, m.mesh, kind=m.kind), SimpleNamespace(T_table_obj=T, supported_edge_px=explained_px)


def _run(located, fixtures_asked=True):
    not_found, stages = [], []
    kept = _drop_overlapping(located, not_found, stages.append, fixtures_asked=fixtures_asked)
    return [c.name for c, _ in kept], not_found, stages


def test_a_fixture_standing_in_the_part_is_taken_out_when_the_part_explains_more():
    bracket = _located("bracket_140", T_BRACKET, 2000.0)
    phantom = _located("parallel_150x32x8", T_BRACKET @ pose_from_xyz_euler(70.0, 4.0, 0.0), 300.0)
    kept, not_found, stages = _run([phantom, bracket], fixtures_asked=True)
    assert kept == [bracket[0].name]
    assert [n["name"] for n in not_found] == [phantom[0].name] and "same space as" in not_found[0]["reason"]
    assert [s.name for s in stages] == ["solid check"] and stages[0].message.startswith(phantom[0].name)
    # recognition looked for every fixture of the library: one taken out is said, not listed missing
    kept, not_found, stages = _run([phantom, bracket], fixtures_asked=False)
    assert kept == [bracket[0].name] and not_found == [] and stages[0].data["taken_out"][0]["name"] == phantom[0].name


def test_the_part_is_taken_out_when_the_fixture_explains_more():
    bracket = _located("bracket_140", T_BRACKET, 100.0)
    vise = _located("vise_150", T_BRACKET @ pose_from_xyz_euler(-20.0, 10.0, 0.0), 3000.0)
    kept, not_found, _ = _run([vise, bracket], fixtures_asked=False)
    assert kept == [vise[0].name] and [n["name"] for n in not_found] == [bracket[0].name]


def test_a_part_on_its_parallels_stays_with_them_and_nothing_is_said():
    from app.synth.fixtures import on_parallels

    par = LIB["parallel_150x25x8"]
    objs = on_parallels(np.random.default_rng(1), "bracket_140", LIB["bracket_140"].mesh, par.mesh, par.key, 400, 200)
    located = [_located("parallel_150x25x8", o.T_table_obj, 200.0) for o in objs[1:]]
    located.append(_located("bracket_140", objs[0].T_table_obj, 2000.0))
    kept, not_found, stages = _run(located)
    assert len(kept) == 3 and not_found == [] and stages == []
