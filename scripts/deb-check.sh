#!/usr/bin/env bash
# Builds the Debian package from the binary the test suite just built and checks it (docs/install.md,
# "Building the package"):
#   1. `cargo deb --no-build --profile deb-test`: the test profile's target/debug/retrocomp copied to
#      target/deb-test/ (cargo-deb reads `target/release/` in the assets as the profile's directory).
#      The shipped package is `cargo deb --profile dist`; building that here would compile the whole
#      dependency tree a second time (≈ 9 min of CPU on 2 cores).
#   2. lintian: no error (warnings are printed, not fatal);
#   3. the package unpacked into a scratch root (`dpkg -x`, no maintainer script runs): the files
#      the unit and the docs promise are there, /etc/retrocomp/* is 0640 in the package, the unit's
#      Documentation= files exist, and the unpacked binary runs `--version`, `check-config` on the
#      unpacked model and `check-config --field` on the unpacked field file;
# Prints `deb-check: N passed, N failed` and exits non-zero on any failure.
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

bin="$TARGET_DIR/debug/retrocomp"
[ -x "$bin" ] || cargo build --locked --profile test --bin retrocomp || { bad "building $bin"; finish; }
mkdir -p "$TARGET_DIR/deb-test"
cp -f "$bin" "$TARGET_DIR/deb-test/retrocomp"
out="$TARGET_DIR/debian-test"
rm -rf "$out"
if cargo deb --no-build --profile deb-test --locked -p retrocomp -o "$out/" >"$out.log" 2>&1; then
    ok "cargo deb"
else
    cat "$out.log" >&2
    bad "cargo deb"
    finish
fi
deb=$(ls "$out"/retrocomp_*_amd64.deb 2>/dev/null | head -n 1)
[ -n "$deb" ] || { bad "no retrocomp_*_amd64.deb in $out"; finish; }
echo "deb-check: $deb"

lint=$(lintian --tag-display-limit 0 "$deb" 2>&1)
echo "$lint" | sed 's/^/deb-check: lintian: /'
if echo "$lint" | grep -q '^E: '; then bad "lintian reports errors"; else ok "lintian: no error"; fi

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
check_unpacked "$deb"

finish
