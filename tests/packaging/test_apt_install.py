"""scripts/apt-install.sh never upgrades an installed Debian package unless asked: driven with a stand-in
``apt-get`` on PATH that answers simulations (-s) from canned apt output and records real installs, so the
machine's own packages are never touched."""

from __future__ import annotations

import os
import subprocess
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
SCRIPT = REPO / "scripts" / "apt-install.sh"

FAKE_APT = """#!/usr/bin/env bash
# simulation: the canned lines of each package named; otherwise record the call
sim=0; pkgs=()
for a in "$@"; do case "$a" in -s) sim=1;; -*|install|update|-o|Dir::*) ;; *) pkgs+=("$a");; esac; done
if [ $sim = 1 ]; then
  echo "Reading package lists..."
  for p in "${pkgs[@]}"; do cat "$FAKE/$p.sim"; done
  exit 0
fi
echo "apt-get $*" >> "$FAKE/calls.log"
"""
# what apt prints: an upgrade has "[installed version]" after the name, a new package does not
SIMULATIONS = {
    "chromium": "Inst chromium-common (156.0 Debian:12.15/oldstable [amd64])\n"
                "Inst chromium (156.0 Debian:12.15/oldstable [amd64])\n",
    "linuxcnc-uspace": "Inst libudev1 [252.38-1~deb12u1] (252.39-1~deb12u2 Debian:12.15/oldstable [amd64])\n"
                       "Inst systemd [252.38-1~deb12u1] (252.39-1~deb12u2 Debian:12.15/oldstable [amd64])\n"
                       "Inst udev (252.39-1~deb12u2 Debian:12.15/oldstable [amd64])\n"
                       "Inst linuxcnc-uspace (2.9.0 Debian:12.15/oldstable [amd64])\n",
}


@pytest.fixture
def fake_apt(tmp_path):
    (tmp_path / "apt-get").write_text(FAKE_APT)
    (tmp_path / "sudo").write_text('#!/usr/bin/env bash\nexec "$@"\n')
    for name in ("apt-get", "sudo"):
        (tmp_path / name).chmod(0o755)
    for pkg, text in SIMULATIONS.items():
        (tmp_path / f"{pkg}.sim").write_text(text)
    return tmp_path


def _run(fake: Path, *args: str, **env: str) -> subprocess.CompletedProcess:
    full = {k: v for k, v in os.environ.items() if k != "BOOTSTRAP_APT_UPGRADES"}   # only what the test sets
    full.update(PATH=f"{fake}:{os.environ['PATH']}", FAKE=str(fake), **env)
    return subprocess.run(["bash", str(SCRIPT), *args], capture_output=True, text=True, env=full, timeout=60)


def _installs(fake: Path) -> list[str]:
    log = fake / "calls.log"
    return [line for line in log.read_text().splitlines() if " install " in f" {line} "] if log.exists() else []


def test_a_package_that_would_upgrade_others_is_left_out_with_the_list(fake_apt):
    r = _run(fake_apt, "chromium", "linuxcnc-uspace")
    assert r.returncode == 0, r.stderr
    assert _installs(fake_apt) == ["apt-get install -y -qq --no-install-recommends --no-upgrade chromium"]
    assert "NOT installing linuxcnc-uspace" in r.stderr
    assert "systemd 252.38-1~deb12u1 -> 252.39-1~deb12u2" in r.stderr and "libudev1" in r.stderr
    assert "udev " not in r.stderr.replace("libudev1", "")          # a new package is no upgrade
    assert "left out: linuxcnc-uspace" in r.stderr


def test_upgrades_only_when_asked(fake_apt):
    r = _run(fake_apt, "chromium", "linuxcnc-uspace", BOOTSTRAP_APT_UPGRADES="allow")
    assert r.returncode == 0, r.stderr
    assert _installs(fake_apt) == [
        "apt-get install -y -qq --no-install-recommends --no-upgrade chromium linuxcnc-uspace"]
    assert "linuxcnc-uspace upgrades 2 installed package(s)" in r.stdout


def test_simulate_counts_upgrades_per_package_and_changes_nothing(fake_apt):
    r = _run(fake_apt, "--simulate", "chromium", "linuxcnc-uspace")
    assert r.returncode == 0, r.stderr
    assert "chromium: would upgrade 0 installed package(s)" in r.stdout
    assert "linuxcnc-uspace: would upgrade 2 installed package(s): libudev1 systemd" in r.stdout
    assert "all together: would upgrade 2 installed package(s)" in r.stdout
    assert not (fake_apt / "calls.log").exists()                     # not even apt-get update
