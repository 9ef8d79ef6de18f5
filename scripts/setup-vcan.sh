#!/usr/bin/env bash
# Host peers for the real-kernel vcan test (tests/vcan_qemu.rs, docs/vcan.md); idempotent.
#   apt: qemu-system-x86 (TCG: no KVM needed), busybox-static + can-utils (go into the guest),
#        cpio/gzip/xz-utils/binutils (initramfs assembly: cpio, gzip, xz -d for .ko.xz, strip)
#   kernel: warms ~/.cache/retrocomp-vcan with Debian's linux-image-amd64 (70 MB download, 10 MB kept)
# To be folded into scripts/setup-peers.sh: append APT_PACKAGES there and call the fetch at the end.
set -euo pipefail

REPO="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"

APT_PACKAGES=(
  qemu-system-x86
  busybox-static
  can-utils
  cpio
  gzip
  xz-utils
  binutils
)

SUDO=""
if [ "$(id -u)" -ne 0 ]; then SUDO="sudo"; fi

missing=()
for p in "${APT_PACKAGES[@]}"; do
  if ! dpkg -s "$p" >/dev/null 2>&1; then missing+=("$p"); fi
done
# fetch-kernel.sh resolves the kernel ABI from the apt lists, so they must exist even when every
# package is already installed (a fresh container has none).
if [ "${#missing[@]}" -gt 0 ] || ! apt-cache show linux-image-amd64 >/dev/null 2>&1; then
  $SUDO apt-get -o DPkg::Lock::Timeout=600 update -qq
fi
if [ "${#missing[@]}" -gt 0 ]; then
  echo "setup-vcan: apt-get install ${missing[*]}"
  # --no-install-recommends: qemu-system-x86's recommends pull a GUI stack (~300 MB) never used here.
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get -o DPkg::Lock::Timeout=600 install -y -qq \
    --no-install-recommends "${missing[@]}"
else
  echo "setup-vcan: apt packages already present: ${APT_PACKAGES[*]}"
fi

echo "setup-vcan: kernel cache $(sh "$REPO/scripts/vcan-qemu/fetch-kernel.sh")"
echo "setup-vcan: done"
