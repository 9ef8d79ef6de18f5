#!/usr/bin/env bash
# Builds the Debian packages from the binaries of the test profile and checks them (docs/install.md,
# "Building the package"):
#   1. amd64: `cargo deb --no-build --profile deb-test`: the test profile's target/debug/retrocomp
#      (the binary the test suite just built) hard-linked as target/deb-test/ (cargo-deb reads
#      `target/release/` in the assets as the profile's directory). The shipped package is
#      `cargo deb --profile dist`; building that here would compile the whole dependency tree a
#      second time with fat LTO (≈ 9 min of CPU on 2 cores).
#   2. arm64: the same binary cross-built (deploy/cross-build.sh --profile test: the Debian cross
#      linker, rustup's aarch64 std; the host's build scripts and proc macros of step 1 are reused)
#      into target/aarch64-unknown-linux-gnu/debug/, hard-linked as …/deb-test/ and packaged with
#      `cargo deb --no-build --profile deb-test --target aarch64-unknown-linux-gnu`.
#   Each package: lintian reports no error (warnings are printed, not fatal); it is unpacked into a
#   scratch root (`dpkg -x`, no maintainer script runs): the files the unit and the docs promise are
#   there, /etc/retrocomp/* is 0640 in the package, the unit's Documentation= files exist, and the
#   unpacked binary runs `--version`, `check-config` on the unpacked model and `check-config
#   --field` on the unpacked field file: arm64's under qemu-aarch64 (scripts/fetch-qemu-user.sh:
#   Debian's qemu-user-static unpacked into a cache, never installed) with `-L /usr/aarch64-linux-gnu`
#   (the loader and libc of libc6-arm64-cross), as the dynamically linked binary the package ships.
#   The arm64 build tree is removed afterwards (RETROCOMP_KEEP_CROSS=1 keeps it); both .deb stay.
# Prints `deb-check: N passed, N failed` and exits non-zero on any failure; a missing tool or Rust
# target is a failure that says how to install it.
set -uo pipefail
cd "$(dirname "$0")/.."
TARGET_DIR="${CARGO_TARGET_DIR:-target}"
passed=0
failed=0
ok() { echo "deb-check: ok: $*"; passed=$((passed + 1)); }
bad() { echo "deb-check: FAILED: $*" >&2; failed=$((failed + 1)); }
finish() {
    echo "deb-check: $passed passed, $failed failed"
    [ "$failed" -eq 0 ]
    exit $?
}
need() {
    command -v "$1" >/dev/null 2>&1 || { bad "$1 missing: $2"; finish; }
}
need cargo-deb "cargo install --locked cargo-deb (scripts/setup-peers.sh does)"
need lintian "apt-get install lintian (scripts/setup-peers.sh does)"
need dpkg-deb "a Debian host"

# package ARCH DIR [--target TRIPLE]: packages DIR/debug/retrocomp (hard-linked as DIR/deb-test/:
# cargo-deb strips into a file of its own and never writes its source, and a copy was ≈ 60 MB) into
# $TARGET_DIR/debian-test/; sets `deb` to the .deb's path (not printed: the counters of ok/bad
# would be lost in a command substitution's subshell).
package() {
    deb=""
    local arch="$1" dir="$2"
    shift 2
    mkdir -p "$dir/deb-test"
    ln -f "$dir/debug/retrocomp" "$dir/deb-test/retrocomp"
    local out="$TARGET_DIR/debian-test"
    mkdir -p "$out"
    rm -f "$out"/retrocomp_*_"$arch".deb
    if cargo deb --no-build --profile deb-test --locked -p retrocomp "$@" -o "$out/" \
        >"$out.$arch.log" 2>&1; then
        ok "cargo deb ($arch)"
        # cargo-deb's stripped scratch copy of the binary (≈ 40 MB), in the .deb now.
        rm -f "$dir"/retrocomp/retrocomp.stripped-*.tmp
    else
        cat "$out.$arch.log" >&2
        bad "cargo deb ($arch)"
        return 1
    fi
    deb=$(ls "$out"/retrocomp_*_"$arch".deb 2>/dev/null | head -n 1)
    [ -n "$deb" ] || { bad "no retrocomp_*_$arch.deb in $out"; return 1; }
    echo "deb-check: $deb"
}

# lint DEB: no error (lintian's exit status is 0 with warnings only, 1 on an error, 2 when it could
# not check the file).
lint() {
    local lint rc
    lint=$(lintian --tag-display-limit 0 "$1" 2>&1)
    rc=$?
    echo "$lint" | sed 's/^/deb-check: lintian: /'
    if [ "$rc" -ne 0 ] || echo "$lint" | grep -q '^E: '; then
        bad "lintian reports errors in $(basename "$1")"
    else
        ok "lintian: no error in $(basename "$1")"
    fi
}

# check_unpacked DEB [RUNNER...]: the unpacked package's files, modes and the binary's answers (a
# RUNNER such as qemu-aarch64 runs a foreign binary).
check_unpacked() {
    local pkg="$1"
    shift
    local root
    root=$(mktemp -d "${TMPDIR:-/tmp}/retrocomp-deb.XXXXXX")
    dpkg -x "$pkg" "$root" || { bad "dpkg -x $pkg"; return; }
    local f
    for f in usr/bin/retrocomp usr/lib/systemd/system/retrocomp.service \
        etc/systemd/system/retrocomp.service.d/network.conf etc/retrocomp/field.toml \
        etc/retrocomp/vmc-machine.toml lib/udev/rules.d/60-retrocomp-gpio.rules \
        usr/share/doc/retrocomp/install.md usr/share/doc/retrocomp/copyright; do
        [ -e "$root/$f" ] || bad "$(basename "$pkg"): /$f missing"
    done
    local listing
    listing=$(dpkg-deb -c "$pkg")
    for f in field.toml vmc-machine.toml; do
        if echo "$listing" | grep -E "^-rw-r----- .* \./etc/retrocomp/$f\$" >/dev/null; then
            ok "/etc/retrocomp/$f is 0640 in the package"
        else
            bad "/etc/retrocomp/$f is not 0640: $(echo "$listing" | grep "etc/retrocomp/$f")"
        fi
    done
    local docs
    docs=$(sed -n 's|^Documentation=file://||p' "$root/usr/lib/systemd/system/retrocomp.service" 2>/dev/null)
    [ -n "$docs" ] || bad "the unit names no Documentation= file"
    for f in $docs; do
        if [ -f "$root$f" ]; then ok "Documentation= $f is in the package"; else bad "Documentation= $f is not in the package"; fi
    done
    local exe="$root/usr/bin/retrocomp"
    if "$@" "$exe" --version | grep -q '^retrocomp '; then ok "$* retrocomp --version"; else bad "$* retrocomp --version"; fi
    if "$@" "$exe" check-config "$root/etc/retrocomp/vmc-machine.toml" >"$root/model.out" 2>&1; then
        ok "$* check-config on the installed model"
    else
        bad "check-config on the installed model: $(cat "$root/model.out")"
    fi
    if "$@" "$exe" check-config --field "$root/etc/retrocomp/field.toml" >"$root/field.out" 2>&1 \
        && grep -q '^IPAddressAllow=192.168.10.20 192.168.10.30$' "$root/field.out"; then
        ok "$* check-config --field on the installed field file prints its IPAddressAllow= line"
    else
        bad "check-config --field on the installed field file: $(cat "$root/field.out")"
    fi
    rm -rf "$root"
}
bin="$TARGET_DIR/debug/retrocomp"
[ -x "$bin" ] || cargo build --locked --profile test --bin retrocomp || { bad "building $bin"; finish; }
if package amd64 "$TARGET_DIR"; then
    lint "$deb"
    check_unpacked "$deb"
fi

# arm64: every prerequisite is checked before the (long) cross build; a missing one fails with how
# to install it, never skips.
cross=aarch64-unknown-linux-gnu
sysroot=/usr/aarch64-linux-gnu
arm64() {
    command -v aarch64-linux-gnu-gcc >/dev/null 2>&1 && [ -e "$sysroot/lib/ld-linux-aarch64.so.1" ] || {
        bad "the Debian cross toolchain is missing: apt-get install gcc-aarch64-linux-gnu libc6-dev-arm64-cross (scripts/setup-peers.sh does)"
        return
    }
    rustup target list --installed 2>/dev/null | grep -qx "$cross" || {
        bad "the Rust standard library for $cross is missing: rustup target add $cross"
        return
    }
    local qemu
    qemu=$(sh scripts/fetch-qemu-user.sh) || {
        bad "no qemu-aarch64: scripts/fetch-qemu-user.sh failed (apt lists? run apt-get update)"
        return
    }
    bash deploy/cross-build.sh --profile test --bin retrocomp >"$TARGET_DIR/cross-build-test.log" 2>&1 || {
        tail -n 30 "$TARGET_DIR/cross-build-test.log" >&2
        bad "deploy/cross-build.sh --profile test --bin retrocomp (log: $TARGET_DIR/cross-build-test.log)"
        return
    }
    ok "cross-built $TARGET_DIR/$cross/debug/retrocomp"
    package arm64 "$TARGET_DIR/$cross" --target "$cross" || return
    lint "$deb"
    check_unpacked "$deb" "$qemu" -L "$sysroot"
}
arm64
# The arm64 tree (≈ 770 MB: its own dependency graph) is needed by nothing after its package is
# checked, and the .deb is kept in debian-test/; RETROCOMP_KEEP_CROSS=1 keeps it for a quicker
# second local run.
[ "${RETROCOMP_KEEP_CROSS:-0}" = 1 ] || rm -rf "${TARGET_DIR:?}/$cross"

finish
