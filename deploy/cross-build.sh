#!/usr/bin/env bash
# Cross-build retrocomp for an aarch64 Linux box (Raspberry Pi 4/5, industrial ARM PCs).
# Needs: rustup, and the Debian cross linker: sudo apt-get install gcc-aarch64-linux-gnu libc6-dev-arm64-cross
# Usage: deploy/cross-build.sh [extra cargo args]   → target/aarch64-unknown-linux-gnu/dist/retrocomp
# (the dist profile: fat LTO, as shipped; pass --profile release for a lighter build, or
# --profile test (opt-level 1, no LTO) for the binary scripts/deb-check.sh packages and runs
# under qemu-aarch64).
set -euo pipefail
cd "$(dirname "$0")/.."
TARGET=aarch64-unknown-linux-gnu
if ! command -v aarch64-linux-gnu-gcc >/dev/null; then
    echo "error: aarch64-linux-gnu-gcc not found. Install the Debian cross linker:" >&2
    echo "  sudo apt-get install gcc-aarch64-linux-gnu libc6-dev-arm64-cross" >&2
    exit 1
fi
if ! rustup target list --installed | grep -qx "$TARGET"; then
    rustup target add "$TARGET"
fi
export CARGO_TARGET_AARCH64_UNKNOWN_LINUX_GNU_LINKER=aarch64-linux-gnu-gcc
export CC_aarch64_unknown_linux_gnu=aarch64-linux-gnu-gcc
# The profile the caller chose (--release, --profile P, --profile=P), else dist.
PROFILE=""
prev=""
for a in "$@"; do
    case "$a" in --release) PROFILE=release ;; --profile=*) PROFILE="${a#--profile=}" ;; esac
    [ "$prev" = "--profile" ] && PROFILE="$a"
    prev="$a"
done
if [ -z "$PROFILE" ]; then PROFILE=dist; set -- --profile dist "$@"; fi
cargo build --locked --target "$TARGET" -p retrocomp "$@"
# cargo's directory of a profile: dev and test build into debug/, bench into release/, any other
# profile into its own name.
case "$PROFILE" in dev | test) DIR=debug ;; bench) DIR=release ;; *) DIR="$PROFILE" ;; esac
BIN="${CARGO_TARGET_DIR:-target}/$TARGET/$DIR/retrocomp"
file "$BIN" 2>/dev/null || true
echo "built $BIN"
