#!/usr/bin/env bash
# Prepare a fresh Debian 12 machine (or an existing one) for setupcam: system packages, a virtualenv
# in .venv, and the project installed into it. Idempotent and quick when nothing changed.
#   scripts/bootstrap.sh          # what the service needs
#   scripts/bootstrap.sh test     # plus what the test suite needs (browser, controller sim, ...)
set -euo pipefail
cd "$(dirname "$0")/.."
mode=${1:-run}
PY=${PYTHON:-python3.11}

need_apt=()
have_pkg() { dpkg-query -W -f='${Status}' "$1" 2>/dev/null | grep -q "install ok installed"; }
if ! command -v "$PY" >/dev/null 2>&1; then need_apt+=(python3.11 python3.11-venv); fi
if ! "$PY" -c "import venv, ensurepip" >/dev/null 2>&1; then need_apt+=(python3.11-venv); fi
if [ "$mode" = test ]; then
  while read -r pkg; do
    pkg=${pkg%%#*}; pkg=$(echo "$pkg" | xargs)
    [ -n "$pkg" ] && ! have_pkg "$pkg" && need_apt+=("$pkg")
  done < scripts/apt-packages.txt
fi
if [ ${#need_apt[@]} -gt 0 ]; then
  # only what is missing, and nothing that would upgrade a package already installed (scripts/apt-install.sh)
  echo "bootstrap: missing system packages: ${need_apt[*]}"
  scripts/apt-install.sh "${need_apt[@]}"
fi
# its own checks (commands, Python module) once the package is in; without it the LinuxCNC tests skip
if [ "$mode" = test ] && have_pkg linuxcnc-uspace; then scripts/install-linuxcnc.sh; fi

if [ ! -x .venv/bin/python ]; then "$PY" -m venv .venv; fi
extras=""; [ "$mode" = test ] && extras="[test]"
stamp=".venv/.installed-$mode-$(sha256sum pyproject.toml | cut -c1-16)"
if [ ! -f "$stamp" ]; then
  .venv/bin/pip install -q --upgrade pip
  .venv/bin/pip install -q -e ".$extras"
  # the engine's numba loops compiled into numba's cache beside the sources (about 3 s), so that
  # neither the first job of a service nor the test suite's first processes compile them; later
  # starts find them there (a job runner makes them ready itself before its first claim)
  .venv/bin/python -c "from app.vision.compiled_kernels import warm_up; warm_up()"
  touch "$stamp"
fi
