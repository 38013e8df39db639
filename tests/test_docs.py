"""The README names every setting and every command, and no document links outside the repository
(the docs must work on an offline shop-floor computer and in a copy of the repository)."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from app.cli import build_parser
from app.config import Settings

REPO = Path(__file__).resolve().parents[1]
README = (REPO / "README.md").read_text()
DOCUMENTS = [REPO / "README.md", REPO / "BENCHMARKS.md", REPO / "samples" / "README.md",
             REPO / "models_library" / "README.md", *sorted((REPO / "docs").glob("*.md"))]
LINK = re.compile(r"!?\[[^\]]*\]\(([^)\s]+)\)")


@pytest.mark.parametrize("variable", [f.validation_alias for f in Settings.model_fields.values()])
def test_readme_names_every_setting(variable):
    assert f"`{variable}`" in README, f"README.md does not explain {variable}"


def _commands() -> list[str]:
    out = []
    parser = build_parser()
    for name, sub in parser._subparsers._group_actions[0].choices.items():
        actions = [a for a in sub._actions if a.__class__.__name__ == "_SubParsersAction"]
        out += [f"setupcam {name} {action}" for a in actions for action in a.choices] or [f"setupcam {name}"]
    return out


@pytest.mark.parametrize("command", _commands())
def test_readme_names_every_command(command):
    assert command in README, f"README.md does not show `{command}`"


@pytest.mark.parametrize("doc", DOCUMENTS, ids=lambda p: str(p.relative_to(REPO)))
def test_links_stay_inside_the_repository(doc):
    for target in LINK.findall(doc.read_text()):
        path = target.split("#", 1)[0]
        assert "://" not in target and not target.startswith("//"), f"{doc.name} links outside: {target}"
        if path:
            resolved = (doc.parent / path).resolve()
            assert resolved.is_relative_to(REPO), f"{doc.name} links outside the repository: {target}"
            assert resolved.exists(), f"{doc.name} links to a missing file: {target}"


@pytest.mark.parametrize("limit, setting", [("max_tilt_deg", "SETUPCAM_MAX_TILT_DEG"),
                                            ("max_offset_change_mm", "SETUPCAM_MAX_OFFSET_CHANGE_MM"),
                                            ("max_offset_change_deg", "SETUPCAM_MAX_OFFSET_CHANGE_DEG")])
def test_readme_says_a_machine_limit_overrides_its_setting(limit, setting):
    row = next(line for line in README.splitlines() if line.startswith(f"| `{setting}`"))
    assert f"a machine's own `{limit}` overrides it" in row, row
    assert "**Per-machine limits.**" in README and "/api/v1/machines/default-limits" in README
