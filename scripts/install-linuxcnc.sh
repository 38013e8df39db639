#!/usr/bin/env bash
# Install the LinuxCNC simulator used by tests/machine (Debian 12 package linuxcnc-uspace) and check
# that what the tests need is there. Idempotent: a no-op (< 1 s) when already installed.
# Without --no-install-recommends apt would pull a realtime kernel, PyQt5, OpenCV, ... (459 packages).
set -euo pipefail
installed() { dpkg-query -W -f='${Status}' linuxcnc-uspace 2>/dev/null | grep -q "install ok installed"; }
if ! installed; then
  "$(dirname "$0")/apt-install.sh" linuxcnc-uspace   # never upgrades installed packages (see there)
  if ! installed; then
    echo "install-linuxcnc: linuxcnc-uspace is not installed (reason above); the LinuxCNC tests will skip" >&2
    exit 0
  fi
fi
for exe in linuxcnc linuxcncrsh; do
  command -v "$exe" >/dev/null || { echo "install-linuxcnc: $exe missing after installing linuxcnc-uspace" >&2; exit 1; }
done
# the tests read LinuxCNC's own status through Debian's module (built for CPython 3.11 only)
/usr/bin/python3 -c "import sys; sys.path.append('/usr/lib/python3/dist-packages'); import linuxcnc" \
  || { echo "install-linuxcnc: /usr/bin/python3 cannot import the linuxcnc module" >&2; exit 1; }
