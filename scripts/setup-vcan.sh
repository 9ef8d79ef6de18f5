#!/bin/sh
# Host peers for the real-kernel vcan test (tests/vcan_qemu.rs, docs/vcan.md): QEMU (TCG, no KVM
# needed), busybox-static and can-utils for the guest, cpio/gzip/xz for the initramfs, and a warm
# kernel cache. Debian/Ubuntu; run as root (or via sudo). Idempotent.
# To be joined into scripts/setup-peers.sh (the python part belongs to helper "bus").
set -eu

SUDO=""
if [ "$(id -u)" -ne 0 ]; then SUDO="sudo"; fi

$SUDO apt-get update -qq
# --no-install-recommends: qemu-system-x86's recommends pull in a GUI stack (~300 MB) we never use.
DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends \
    qemu-system-x86 busybox-static can-utils cpio gzip xz-utils binutils

# Download and unpack Debian's linux-image-amd64 kernel into the cache now, so the first test run
# does not pay for it (~70 MB download, ~10 MB kept).
here=$(cd "$(dirname "$0")" && pwd)
sh "$here/vcan-qemu/fetch-kernel.sh"
