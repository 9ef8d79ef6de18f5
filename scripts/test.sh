#!/usr/bin/env bash
# Runs every test of retrocomp on a fresh Debian machine, as CI does (.ci/run calls exactly this).
# 1. installs the third-party peers (apt: socat, mbpoll, qemu, can-utils…; a .venv with pinned
#    python-can, pymodbus, pyserial) — idempotent, quick when already installed;
# 2. runs the whole cargo test suite, which includes the real-peer integration tests and the
#    QEMU guest that runs the socketcan backend against real kernel vcan;
# 3. builds and tests the quadrature injector with the `gpio` feature (real Linux GPIO character
#    device lines; no GPIO chip exists here, so its test checks the clear error for a missing chip).
set -euo pipefail
cd "$(dirname "$0")/.."

bash scripts/setup-peers.sh

export RETROCOMP_PYTHON="$PWD/.venv/bin/python"
cargo fmt --all -- --check
cargo test --workspace --locked
cargo test --locked -p retrocomp --features gpio --lib quadrature
