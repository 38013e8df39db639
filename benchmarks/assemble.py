"""Assemble BENCHMARKS.md from the per-topic result files benchmarks/<topic>.md.

Each topic's script writes its own .md (figures, command, date, machine); this only concatenates them
under a short index, so BENCHMARKS.md is never edited by hand in two places.
    .venv/bin/python benchmarks/assemble.py
"""

from pathlib import Path

HERE = Path(__file__).resolve().parent
ORDER = ["table_pose", "object_pose", "feature_edges", "calibration", "mesh_pipeline", "sheet", "rotary", "planning"]
#: topics measured by a test on the controller sim rather than a script of their own
SOURCES = {"rotary_table": "tests/e2e/test_rotary_table_sim.py` (LinuxCNC XYZC sim)",
           "detour_subroutine": "tests/planning/test_detour_sim.py` (the LinuxCNC sim)"}

HEADER = """# Benchmarks

Every figure below was produced by a script in `benchmarks/` that measures our method and a baseline
in the same run (command, date and machine under each heading). All ran on project machines of one
kind: 2 cores, 24 GiB, Debian 12 (the CPU model, Intel Xeon or AMD EPYC, is named per section), often
shared with test runs, so wall-clock times are pessimistic; the ratios against the baselines come
from the same runs.

Regenerate this file after re-running a benchmark: `.venv/bin/python benchmarks/assemble.py`.

"""


def main() -> None:
    files = [HERE / f"{k}.md" for k in ORDER if (HERE / f"{k}.md").exists()]
    files += sorted(p for p in HERE.glob("*.md") if p not in files)
    index = "\n".join(f"* [{p.stem}](#{p.stem.replace('_', '-')}) — `{SOURCES.get(p.stem, f'benchmarks/{p.stem}.py`')}"
                      for p in files)
    parts = [HEADER, "## Contents\n\n", index, "\n"]
    for p in files:
        body = p.read_text().strip()
        body = "\n".join(("#" + line) if line.startswith("#") else line for line in body.splitlines())
        parts.append(f"\n<a id=\"{p.stem.replace('_', '-')}\"></a>\n\n{body}\n")
    (HERE.parent / "BENCHMARKS.md").write_text("".join(parts))


if __name__ == "__main__":
    main()
