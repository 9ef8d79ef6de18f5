#!/usr/bin/env bash
# apt-get install that never removes or downgrades a host package.
#   apt-install-safe.sh PACKAGE...
# Simulates first (apt-get -s): if the plan removes ("Remv") or downgrades ("Inst x [newer] (older")
# anything, it prints the plan and exits 3 without touching the system. The real install then runs
# with --no-remove (apt refuses any removal itself) and --no-install-recommends.
set -euo pipefail
[ "$#" -gt 0 ] || { echo "usage: $0 PACKAGE..." >&2; exit 2; }
SUDO=""
if [ "$(id -u)" -ne 0 ]; then SUDO="sudo"; fi
APT=(apt-get -o DPkg::Lock::Timeout=600 -y -qq --no-install-recommends --no-remove)
plan=$(LC_ALL=C $SUDO "${APT[@]}" -s install "$@" 2>&1) || {
  echo "apt-install-safe: the simulated install of $* fails (it would need to remove a package?):" >&2
  echo "$plan" >&2
  exit 3
}
# "Inst pkg [installed] (candidate …)": a downgrade when candidate < installed.
bad=$(echo "$plan" | awk '
  /^Remv / { print; next }
  /^Inst / && $3 ~ /^\[/ {
    old = substr($3, 2, length($3) - 2); new = substr($4, 2)
    cmd = "dpkg --compare-versions \"" new "\" lt \"" old "\""
    if (system(cmd) == 0) print
  }')
if [ -n "$bad" ]; then
  echo "apt-install-safe: refusing: installing $* would remove or downgrade host packages:" >&2
  echo "$bad" >&2
  exit 3
fi
DEBIAN_FRONTEND=noninteractive $SUDO "${APT[@]}" install "$@"
