#!/usr/bin/env bash
# Installs LinuxCNC 2.9 (Debian 12's linuxcnc-uspace, no recommends: ≈ 100 s, ≈ 300 MB) for the tests
# that use a real controller as the outside judge: `rs274` reads rewritten NC programs, COMP_FILE loads
# exported tables, and a headless LinuxCNC with mb2hal + external offsets runs the closed loop
# (docs/linuxcnc.md). Idempotent; never removes or downgrades a host package (scripts/apt-install-safe.sh).
set -euo pipefail
SUDO=""
if [ "$(id -u)" -ne 0 ]; then SUDO="sudo"; fi
if dpkg -s linuxcnc-uspace >/dev/null 2>&1 && command -v rs274 >/dev/null; then
  echo "setup-linuxcnc: linuxcnc-uspace already present ($(dpkg-query -W -f='${Version}' linuxcnc-uspace))"
  exit 0
fi
if ! apt-cache show linuxcnc-uspace >/dev/null 2>&1; then
  $SUDO apt-get -o DPkg::Lock::Timeout=600 update -qq
fi
echo "setup-linuxcnc: apt-get install linuxcnc-uspace (no recommends)"
# apt-install-safe.sh: simulated first, refused if anything would be removed or downgraded.
bash "$(dirname "$0")/apt-install-safe.sh" linuxcnc-uspace
command -v rs274 >/dev/null || { echo "setup-linuxcnc: rs274 missing after install" >&2; exit 1; }
echo "setup-linuxcnc: done ($(dpkg-query -W -f='${Version}' linuxcnc-uspace))"
