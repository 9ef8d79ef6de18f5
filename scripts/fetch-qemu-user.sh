#!/bin/sh
# Provide qemu-aarch64 (user-mode emulation) for the arm64 package check (scripts/deb-check.sh)
# WITHOUT installing it: Debian's qemu-user-static is `apt-get download`ed and `dpkg -x`ed into a
# cache (scripts/apt-unpack.sh, as the vcan guest's qemu-system-x86). Installing it would run its
# maintainer scripts, which register binfmt handlers so that every aarch64 binary on the host runs
# under QEMU behind the user's back. The static build needs no shared library from the host.
#
# If the host already has qemu-aarch64-static or qemu-aarch64 on PATH, that one is used
# (RETROCOMP_QEMU_FORCE_CACHE=1: the cache's all the same).
#
# Usage: fetch-qemu-user.sh [CACHE_DIR]  (default: $RETROCOMP_QEMU_USER_CACHE or ~/.cache/retrocomp-qemu-user)
# Prints one line on stdout: the qemu-aarch64 to run. Run a dynamically linked aarch64 binary with
# `-L /usr/aarch64-linux-gnu` (the loader and libc of Debian's libc6-arm64-cross).
# Needs: apt-get, apt-cache, dpkg, dpkg-query; up-to-date apt lists (apt-get update).
set -eu

if [ -z "${RETROCOMP_QEMU_FORCE_CACHE:-}" ]; then
    for q in qemu-aarch64-static qemu-aarch64; do
        if host=$(command -v "$q" 2>/dev/null); then
            echo "$host"
            exit 0
        fi
    done
fi

cache="${1:-${RETROCOMP_QEMU_USER_CACHE:-$HOME/.cache/retrocomp-qemu-user}}"
. "$(dirname "$0")/apt-unpack.sh"
# The package holds a static QEMU for every architecture (≈ 370 MB unpacked): keep aarch64's.
keep_aarch64() {
    find "$1/root" -type f ! -path '*/usr/bin/qemu-aarch64-static' -delete
}
tree=$(APT_UNPACK_HOOK=keep_aarch64 apt_unpack "$cache" qemu-user-static qemu-user-static)
bin="$tree/root/usr/bin/qemu-aarch64-static"
[ -x "$bin" ] || apt_unpack_fail "the qemu-user-static package holds no usr/bin/qemu-aarch64-static"
"$bin" --version >&2 || apt_unpack_fail "$bin --version failed"
echo "$bin"
