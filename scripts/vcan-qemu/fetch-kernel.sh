#!/bin/sh
# Fetch Debian's stock kernel for the vcan QEMU guest, without installing it.
#
# `apt-get download` + `dpkg -x` into a cache directory avoids the slow initramfs-tools trigger and
# leaves the host's /boot alone. Reruns are free: an unpacked kernel in the cache is reused.
#
# Usage: fetch-kernel.sh [CACHE_DIR]      (default: $RETROCOMP_VCAN_CACHE or ~/.cache/retrocomp-vcan)
# Prints one line on stdout: the unpacked tree (it holds boot/vmlinuz-<abi> and lib/modules/<abi>/).
# Needs: apt-get, apt-cache, dpkg (any Debian/Ubuntu host). Install peers: scripts/setup-peers.sh
set -eu

cache="${1:-${RETROCOMP_VCAN_CACHE:-$HOME/.cache/retrocomp-vcan}}"
mkdir -p "$cache"

# The metapackage linux-image-amd64 depends on exactly one ABI package, e.g. linux-image-6.1.0-56-amd64.
# RETROCOMP_VCAN_KPKG pins it (for hosts whose apt lists are stale or not Debian).
kpkg="${RETROCOMP_VCAN_KPKG:-}"
if [ -z "$kpkg" ]; then
    if ! command -v apt-cache >/dev/null 2>&1; then
        echo "fetch-kernel.sh: apt-cache not found; this needs a Debian-like host (see docs/vcan.md)" >&2
        exit 2
    fi
    kpkg=$(apt-cache depends linux-image-amd64 2>/dev/null |
        sed -n 's/^ *Depends: \(linux-image-[0-9][^ ]*-amd64\)$/\1/p' | head -n 1)
fi
if [ -z "$kpkg" ]; then
    # A cached unpack is still usable when apt lists are missing (offline rerun).
    cached=$(ls -d "$cache"/linux-image-*-amd64 2>/dev/null | tail -n 1 || true)
    if [ -n "$cached" ] && [ -f "$cached/.unpacked" ]; then
        echo "$cached"
        exit 0
    fi
    echo "fetch-kernel.sh: cannot resolve the kernel ABI package: 'apt-cache depends linux-image-amd64' gave nothing." >&2
    echo "  run 'apt-get update' (or scripts/setup-peers.sh), or set RETROCOMP_VCAN_KPKG=linux-image-<abi>-amd64" >&2
    exit 2
fi

tree="$cache/$kpkg"
# A complete tree is reused; else, alone under the cache's lock, unpack into a private directory
# that is renamed into place only when complete.
. "$(dirname "$0")/../apt-unpack.sh"
apt_unpack_ready "$cache" "$tree" && exit 0
work=$(mktemp -d "$cache/.unpack.XXXXXX")
trap 'rm -rf "$work"' EXIT
# apt-get download writes into the current directory; as root it warns about the _apt sandbox.
if ! (cd "$work" && apt-get download "$kpkg" >&2); then
    # Stale apt lists name a version the mirror has dropped (Debian security keeps only the newest),
    # or we are offline: an earlier cached kernel still does the job.
    cached=$(ls -d "$cache"/linux-image-*-amd64 2>/dev/null | tail -n 1 || true)
    if [ -n "$cached" ] && [ -f "$cached/.unpacked" ]; then
        echo "fetch-kernel.sh: 'apt-get download $kpkg' failed; using the cached $(basename "$cached")" >&2
        echo "$cached"
        exit 0
    fi
    echo "fetch-kernel.sh: 'apt-get download $kpkg' failed (network? stale apt lists? run 'apt-get update')" >&2
    exit 2
fi
deb=$(ls "$work/${kpkg}_"*.deb | tail -n 1)
dpkg -x "$deb" "$work/root"
abi=${kpkg#linux-image-}
if [ ! -f "$work/root/boot/vmlinuz-$abi" ] || [ ! -d "$work/root/lib/modules/$abi" ]; then
    echo "fetch-kernel.sh: $deb does not hold boot/vmlinuz-$abi and lib/modules/$abi" >&2
    exit 2
fi
# Keep only what the guest needs (vmlinuz and the CAN modules): ~400 MB unpacked → ~10 MB.
keep="$work/keep"
mkdir -p "$keep/boot" "$keep/lib/modules/$abi/kernel/net" "$keep/lib/modules/$abi/kernel/drivers/net"
cp "$work/root/boot/vmlinuz-$abi" "$keep/boot/"
cp -r "$work/root/lib/modules/$abi/kernel/net/can" "$keep/lib/modules/$abi/kernel/net/"
cp -r "$work/root/lib/modules/$abi/kernel/drivers/net/can" "$keep/lib/modules/$abi/kernel/drivers/net/"
echo "$kpkg" >"$keep/.unpacked"
rm -rf "$tree"
mv "$keep" "$tree"
# Kernels of earlier ABIs (the metapackage moved on after an apt-get update) are dead weight.
for old in "$cache"/linux-image-*-amd64; do
    [ "$old" = "$tree" ] || rm -rf "$old"
done
echo "$tree"
