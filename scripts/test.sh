#!/usr/bin/env bash
# Runs every test of retrocomp on a fresh Debian machine, as CI does (.ci/run calls exactly this).
# 1. installs the third-party peers (scripts/setup-peers.sh: apt socat, mbpoll, can-utils…, never
#    removing or downgrading a host package; QEMU and the guest kernel downloaded into a cache, not
#    installed; LinuxCNC; a .venv with pinned python-can, pymodbus, pyserial) — quick when present;
# 2. `cargo fmt --check`, `cargo clippy --workspace --all-targets -- -D warnings` and
#    `cargo doc --workspace --no-deps` with warnings as errors (every intra-doc link resolves);
#    `cargo audit` (scripts/audit.sh) against the committed RustSec snapshot, or a newer clone;
# 3. the whole cargo test suite with --no-fail-fast (every test binary runs even after a failure),
#    including the real-peer integration tests and the QEMU guest that runs the socketcan backend
#    against real kernel vcan;
#    The `gpio` feature is a default one, so step 3 tests the quadrature injector on real Linux GPIO
#    character-device lines (no GPIO chip exists here: its test checks the clear error for a missing
#    chip). The build without the optional parts (opcua, mqtt, gpio) is compiled and linted in
#    step 2; its refusals of a field file naming them are tested in step 3 (the config check takes
#    the build's parts as a value), so no third dependency graph is built for a test run.
# 4. the Debian packages (scripts/deb-check.sh): amd64 of the binary step 3 built, arm64 of the same
#    code cross-built with the test profile (≈ 8 min of CPU more on a cold target/; its ≈ 0.8 GB
#    build tree is removed once its package is checked);
#    cargo deb, lintian, the unpacked package's files, modes and `check-config` answers (arm64's
#    under qemu-aarch64, unpacked into a cache, never installed).
# Ends with ONE line `N passed, N failed` (the sum of every `test result:` line) and exits non-zero
# if any test failed, a test binary did not build or run, or fmt/clippy/rustdoc complained.
# Needs root or sudo for apt (step 1). Takes ≈ 10 min on an idle 2-core VM, much more under load.
set -uo pipefail
cd "$(dirname "$0")/.."

bash scripts/setup-peers.sh || { echo "test.sh: scripts/setup-peers.sh failed" >&2; exit 1; }
export RETROCOMP_PYTHON="$PWD/.venv/bin/python"
# No incremental compilation state: a run on a fresh clone never reuses it, and it was ≈ 3 GB of
# target/ (a CI run ran out of disk writing it). Set CARGO_INCREMENTAL=1 to keep it between local runs.
export CARGO_INCREMENTAL="${CARGO_INCREMENTAL:-0}"

log=$(mktemp "${TMPDIR:-/tmp}/retrocomp-test.XXXXXX")
trap 'rm -f "$log"' EXIT
problems=()
cargo fmt --all -- --check || problems+=("cargo fmt --check")
cargo clippy --workspace --all-targets --locked -- -D warnings || problems+=("cargo clippy")
# The appliance gateway without its optional northbound servers (no OPC UA, MQTT or web crates).
cargo clippy -p retrocomp-gateway --no-default-features --all-targets --locked -- -D warnings ||
    problems+=("cargo clippy -p retrocomp-gateway --no-default-features")
# Every intra-doc link resolves (rustdoc's -D warnings); the rendered pages are only the check's
# by-product and are removed (≈ 60 MB of target/). Examples are documented too: with a target that
# needs dev-dependencies, Cargo resolves the same features as clippy's --all-targets, so rustdoc
# reuses clippy's checked dependencies instead of checking a second set (≈ 90 MB of target/).
RUSTDOCFLAGS="-D warnings" cargo doc --workspace --no-deps --lib --bins --examples --locked -q ||
    problems+=("cargo doc")
rm -rf target/doc
bash scripts/audit.sh || problems+=("cargo audit")
cargo test --workspace --locked --no-fail-fast 2>&1 | tee -a "$log"
[ "${PIPESTATUS[0]}" -eq 0 ] || problems+=("cargo test --workspace")
bash scripts/deb-check.sh 2>&1 | tee -a "$log"
[ "${PIPESTATUS[0]}" -eq 0 ] || problems+=("scripts/deb-check.sh")

# `test result: ok. 12 passed; 0 failed; 1 ignored; …` — one per test binary and doc-test run.
read -r passed failed < <(awk '/^test result: / {
    for (i = 1; i <= NF; i++) {
      if ($(i+1) ~ /^passed;?$/) p += $i
      if ($(i+1) ~ /^failed;?$/) f += $i
    } } END { print p + 0, f + 0 }' "$log")
for p in "${problems[@]}"; do echo "test.sh: FAILED step: $p"; done
echo "$passed passed, $failed failed"
[ "$failed" -eq 0 ] && [ "${#problems[@]}" -eq 0 ]
