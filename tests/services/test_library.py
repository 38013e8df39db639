"""The example library loader and the support-surfaces migration, on a real database (SQLite; and
PostgreSQL when it answers)."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest
import sqlalchemy as sa
from alembic import command
from sqlmodel import Session, select

from app.services import library
from app.store.db import alembic_config, make_engine, migrate
from app.store.files import FolderStore
from app.store.models import LibraryModel
from tests.support.live_server import throwaway_database

LIBRARY = Path(__file__).resolve().parents[2] / "models_library"
FIXTURES = ("vise_150", "vise_125", "parallel_150x25x8", "parallel_150x32x8")


def _library_copy(tmp_path: Path, keys: tuple[str, ...], declared: bool) -> Path:
    """A copy of the example library with only ``keys`` (and the table), surfaces kept or removed."""
    d = tmp_path / ("lib-declared" if declared else "lib-plain")
    shutil.copytree(LIBRARY, d, ignore=shutil.ignore_patterns("*.py", "*.pdf", "*.svg", "*.md"))
    doc = json.loads((d / "library.json").read_text())
    doc["models"] = [m for m in doc["models"] if m["key"] in keys]
    if not declared:
        for m in doc["models"]:
            m.pop("support_surfaces", None)
    (d / "library.json").write_text(json.dumps(doc))
    return d


def _current(session: Session, key: str):
    m = session.exec(select(LibraryModel).where(LibraryModel.key == key)).one()
    return m, library.get_revision(session, m.id)


def test_loading_is_idempotent_and_older_loads_get_the_declared_surfaces(tmp_path):
    engine = make_engine(f"sqlite:///{tmp_path / 'lib.db'}")
    migrate(engine)
    files = FolderStore(tmp_path / "files")
    keys = ("tslot_table_800x400", "vise_150", "strap_clamp_125", "parallel_150x25x8")
    plain, declared = _library_copy(tmp_path, keys, False), _library_copy(tmp_path, keys, True)
    with Session(engine) as s:                      # an installation loaded before surfaces were declared
        assert library.load_example_library(s, files, plain) == list(keys)
        s.commit()
        assert _current(s, "vise_150")[1].support_surfaces is None
    with Session(engine) as s:                      # the next start: the declared surfaces arrive as revision 2
        assert library.load_example_library(s, files, declared) == []
        s.commit()
        model, rev = _current(s, "vise_150")
        assert model.current_revision == 2 and rev.support_surfaces[0]["name"] == "seat"
        assert rev.note == "support surfaces declared in the example library"
        assert library.get_revision(s, model.id, 1).support_surfaces is None
        assert _current(s, "parallel_150x25x8")[0].current_revision == 2
        assert _current(s, "strap_clamp_125")[0].current_revision == 1     # declares none
        assert _current(s, "tslot_table_800x400")[0].current_revision == 1
    with Session(engine) as s:                      # and then nothing changes any more
        assert library.load_example_library(s, files, declared) == []
        s.commit()
        assert _current(s, "vise_150")[0].current_revision == 2
        # an admin's choice stands: 'derive from the mesh' at revision 3 is not overwritten
        library.add_revision(s, files, _current(s, "vise_150")[0].id, support_surfaces=None, note="admin")
        s.commit()
    with Session(engine) as s:
        library.load_example_library(s, files, declared)
        s.commit()
        model, rev = _current(s, "vise_150")
        assert model.current_revision == 3 and rev.support_surfaces is None


BACKENDS = ["sqlite", "postgres"]


@pytest.mark.parametrize("backend", BACKENDS)
def test_migration_0006_adds_the_column_and_keeps_existing_revisions(tmp_path, backend):
    """A database at 0005 with a model in it: upgrading adds model_revision.support_surfaces (NULL for
    the old rows: derived from the mesh), downgrading removes it again, the rows stay."""
    with throwaway_database(backend, tmp_path) as url:
        cfg = alembic_config(url)
        command.upgrade(cfg, "0005")
        engine = make_engine(url)
        with engine.begin() as conn:
            conn.execute(sa.text("INSERT INTO storedfile (sha256, size_bytes, media_type, created_at) "
                                 "VALUES ('a', 1, 'x', CURRENT_TIMESTAMP)"))
            conn.execute(sa.text("INSERT INTO library_model (id, kind, name, description, current_revision, created_at) "
                                 "VALUES (1, 'clamp', 'old vise', '', 1, CURRENT_TIMESTAMP)"))
            conn.execute(sa.text(
                "INSERT INTO model_revision (model_id, revision, source_filename, source_sha256, glb_sha256, "
                "thumbnail_sha256, units, summary, resting_poses, note, created_at) "
                "VALUES (1, 1, 'v.stl', 'a', 'a', 'a', 'mm', '{}', '[]', '', CURRENT_TIMESTAMP)"))
        migrate(engine)
        cols = {c["name"] for c in sa.inspect(engine).get_columns("model_revision")}
        assert "support_surfaces" in cols
        with Session(engine) as s:
            rev = library.get_revision(s, 1)
            assert rev.support_surfaces is None and rev.source_filename == "v.stl"
            rev.support_surfaces = [{"name": "seat", "z_mm": 1.0, "outline_xy": [[0, 0], [1, 0], [0, 1]]}]
            s.add(rev)
            s.commit()
        with Session(engine) as s:
            assert library.get_revision(s, 1).support_surfaces[0]["name"] == "seat"
        engine.dispose()
        command.downgrade(cfg, "0005")
        engine = make_engine(url)
        assert "support_surfaces" not in {c["name"] for c in sa.inspect(engine).get_columns("model_revision")}
        with engine.connect() as conn:
            assert conn.execute(sa.text("SELECT count(*) FROM model_revision")).scalar() == 1
        engine.dispose()


def test_a_guide_loads_with_the_library_and_reaches_the_candidates_by_the_carriers_name(tmp_path):
    """A strap clamp declared riding on the vise (by its key) in the manifest: stored on its revision,
    and the setup's candidates name the carrier as the chain knows it (the vise model's name)."""
    from app.services.setups import library_candidates

    d = _library_copy(tmp_path, ("tslot_table_800x400", "vise_150", "strap_clamp_125"), True)
    doc = json.loads((d / "library.json").read_text())
    guide = {"carrier": "vise_150", "T_carrier_obj": [[1.0, 0, 0, 0], [0, 1.0, 0, 0], [0, 0, 1.0, 70.0], [0, 0, 0, 1.0]],
             "axis": [1.0, 0.0, 0.0], "travel_mm": [0.0, 80.0]}
    next(m for m in doc["models"] if m["key"] == "strap_clamp_125")["guide"] = guide
    (d / "library.json").write_text(json.dumps(doc))
    engine = make_engine(f"sqlite:///{tmp_path / 'lib.db'}")
    migrate(engine)
    files = FolderStore(tmp_path / "files")
    with Session(engine) as s:
        library.load_example_library(s, files, d)
        vise, vise_rev = _current(s, "vise_150")
        clamp, clamp_rev = _current(s, "strap_clamp_125")
        assert clamp_rev.guide == guide and vise_rev.guide is None
        refs = [{"model_id": m.id, "revision": m.current_revision} for m in (vise, clamp)]
        by_name = {c.name: c for c in library_candidates(s, files, refs)}
        assert by_name[clamp.name].guide == {**guide, "carrier": vise.name}
        assert by_name[vise.name].guide is None
        # a carrier not in the library stays as written: the chain reports the clamp as not searched
        library.add_revision(s, files, clamp.id, guide={**guide, "carrier": "gone"})
        (cand,) = library_candidates(s, files, [{"model_id": clamp.id, "revision": 2}])
        assert cand.guide["carrier"] == "gone"
