"""The rooms' import rules, read from the source (an ``ast`` scan of every import, including those inside
functions): the maths rooms import no service room; the web layer (``app.api``) is imported by no room
below it; routes reach the store and the vision only through the services; the viewer reads through
the services and is reached from the web only through its relay (``app/api/routes/viewer.py``)."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

APP = Path(__file__).resolve().parents[1] / "app"


def _parse(path: Path) -> ast.Module:
    """``ast.parse`` of the file. Python 3.11 keeps the AST builder's recursion count per interpreter,
    not per thread: a thread left by an earlier test of the same worker building an AST at the same
    moment makes the parse fail with "SystemError: AST constructor recursion depth mismatch"
    (CPython gh-106905; seen once in a full run on two workers). Not the file's fault: parse it again."""
    source = path.read_text(encoding="utf-8")
    for _ in range(2):
        try:
            return ast.parse(source)
        except SystemError:
            pass
    return ast.parse(source)


def _imports(path: Path) -> set[str]:
    """Every module ``path`` imports (absolute names; ``from a import b`` counts as ``a`` and ``a.b``)."""
    out = set()
    for node in ast.walk(_parse(path)):
        if isinstance(node, ast.Import):
            out.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            out.add(node.module)
            out.update(f"{node.module}.{a.name}" for a in node.names)
    return out


def _room(room: str) -> list[Path]:
    return sorted((APP / room).rglob("*.py")) if (APP / room).is_dir() else [APP / f"{room}.py"]


def _offences(rooms: list[str], forbidden: tuple[str, ...]) -> list[str]:
    bad = []
    for room in rooms:
        for path in _room(room):
            for mod in sorted(_imports(path)):
                if any(mod == f or mod.startswith(f + ".") for f in forbidden):
                    bad.append(f"{path.relative_to(APP.parent)} imports {mod}")
    return bad


def test_the_rooms_exist():
    for room in ("vision", "geometry", "planning", "api", "services", "store", "viewer", "machine"):
        assert _room(room), room


@pytest.mark.parametrize("rooms, forbidden", [
    # pure maths: no database, no web, no use cases, no viewer, no command line
    (["vision", "geometry", "planning"], ("app.api", "app.store", "app.services", "app.viewer", "app.cli",
                                          "app.main", "fastapi")),
    # nothing below the web layer reaches up into it
    (["services", "store", "viewer", "machine", "sources", "vision", "geometry", "planning"], ("app.api", "app.main")),
    # the viewer reads through the services, never the store; it serves no web routes of its own
    (["viewer"], ("app.store", "fastapi")),
    # routes reach the store and the vision through the services
    (["api/routes"], ("app.store", "app.vision")),
    # the store knows nothing of the rooms that use it
    (["store"], ("app.services", "app.viewer", "app.vision", "app.planning")),
])
def test_imports_point_one_way(rooms, forbidden):
    assert _offences(rooms, forbidden) == []


def test_only_the_web_layer_imports_fastapi():
    users = {str(p.relative_to(APP.parent)) for p in APP.rglob("*.py")
             if any(m == "fastapi" or m.startswith("fastapi.") for m in _imports(p))}
    assert users and all(u.startswith("app/api/") or u == "app/main.py" for u in users), sorted(users)


def test_services_and_viewer_import_at_module_top():
    """Imports inside functions hide a module's dependencies (and import cycles); the CLI may keep them
    for a fast ``--help``."""
    inner = []
    for room in ("services", "viewer"):
        for path in _room(room):
            for fn in ast.walk(_parse(path)):
                if isinstance(fn, (ast.FunctionDef, ast.AsyncFunctionDef)):
                    inner += [f"{path.relative_to(APP.parent)}:{n.lineno}" for n in ast.walk(fn)
                              if isinstance(n, (ast.Import, ast.ImportFrom))]
    assert inner == []


def test_the_scan_sees_a_forbidden_import(tmp_path):
    """The rule can fail: an import inside a function is seen like one at the top."""
    p = tmp_path / "m.py"
    p.write_text("def f():\n    from app.store.db import session_scope\n")
    assert "app.store.db" in _imports(p)
