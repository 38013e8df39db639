#!/usr/bin/env bash
# Install Debian packages WITHOUT upgrading any package already on the machine.
#
#   scripts/apt-install.sh PKG...             install the missing PKGs that need no upgrade of others
#   scripts/apt-install.sh --simulate PKG...  only say what each PKG would upgrade (no root, no change)
#
# Why: `apt-get install` upgrades an installed package whenever a new one needs an exact newer build of
# it (a new udev wants libudev1 and systemd of its own version, libgl1-mesa-dev the same mesa build as
# libgbm1, ...). The archive keeps only the newest builds, so such a package cannot come in without
# those upgrades. Each PKG is first simulated (`apt-get -s install`, counting "Inst name [old] (new"
# lines: upgrades of installed packages); one that would upgrade anything is left out with the list, and
# the tests that need it skip with their reason. BOOTSTRAP_APT_UPGRADES=allow installs it anyway (a
# throw-away machine such as CI). --no-install-recommends keeps the set small; --no-upgrade keeps a PKG
# that is already installed as it is. APT_STATUS_FILE (simulation only) reads another dpkg status file,
# e.g. a copy describing the machine before anything was installed, to measure the effect.
set -euo pipefail

simulate_only=0
if [ "${1:-}" = --simulate ]; then simulate_only=1; shift; fi
[ $# -gt 0 ] || { echo "usage: $0 [--simulate] PKG..." >&2; exit 2; }
APT_FLAGS=(--no-install-recommends --no-upgrade)
sim_flags=()
[ -n "${APT_STATUS_FILE:-}" ] && sim_flags=(-o "Dir::State::status=$APT_STATUS_FILE")

# upgrades PKG...: the installed packages `apt-get install PKG...` would upgrade, one per line
upgrades() {
  local out
  if ! out=$(apt-get -s "${sim_flags[@]}" install "${APT_FLAGS[@]}" "$@" 2>&1); then
    echo "apt-install: apt cannot install $*:" >&2
    echo "$out" | grep -E '^( |E:)' >&2 || true
    return 1
  fi
  echo "$out" | sed -nE 's/^Inst ([^ ]+) \[([^]]+)\] \(([^ ]+).*/\1 \2 -> \3/p'
}

if [ "$simulate_only" = 1 ]; then
  total=0
  for pkg in "$@"; do
    list=$(upgrades "$pkg") || continue
    n=$(printf '%s' "$list" | grep -c . || true)
    total=$((total + n))
    echo "$pkg: would upgrade $n installed package(s)${list:+: $(echo "$list" | cut -d' ' -f1 | tr '\n' ' ')}"
  done
  together=$(upgrades "$@" | grep -c . || true)
  echo "all together: would upgrade $together installed package(s)"
  exit 0
fi

SUDO=""; [ "$(id -u)" -ne 0 ] && SUDO=sudo
$SUDO apt-get update -qq
take=() left=()
for pkg in "$@"; do
  list=$(upgrades "$pkg") || { left+=("$pkg"); continue; }
  if [ -z "$list" ]; then
    take+=("$pkg")
  elif [ "${BOOTSTRAP_APT_UPGRADES:-}" = allow ]; then
    echo "apt-install: $pkg upgrades $(echo "$list" | wc -l) installed package(s) (BOOTSTRAP_APT_UPGRADES=allow)"
    take+=("$pkg")
  else
    echo "apt-install: NOT installing $pkg: it would upgrade these installed packages:" >&2
    echo "$list" | sed 's/^/    /' >&2
    echo "  (the archive only has builds of $pkg that need them; install it yourself, or rerun with" \
         "BOOTSTRAP_APT_UPGRADES=allow on a machine where upgrades do not matter)" >&2
    left+=("$pkg")
  fi
done
if [ ${#take[@]} -gt 0 ]; then
  # together they may need what none needs alone: check once more before touching anything
  list=$(upgrades "${take[@]}")
  if [ -n "$list" ] && [ "${BOOTSTRAP_APT_UPGRADES:-}" != allow ]; then
    echo "apt-install: NOT installing ${take[*]}: together they would upgrade:" >&2
    echo "$list" | sed 's/^/    /' >&2
    exit 1
  fi
  echo "apt-install: installing ${take[*]}"
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq "${APT_FLAGS[@]}" "${take[@]}"
fi
[ ${#left[@]} -eq 0 ] || echo "apt-install: left out: ${left[*]}" >&2
