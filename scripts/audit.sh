#!/usr/bin/env bash
# `cargo audit` against a RustSec advisory database that is already on this machine (CI reaches only
# package registries, so the database cannot be fetched there). Never a silent skip: without a
# database or without cargo-audit it prints ONE line saying it did not run and why, and exits 0;
# with both, it runs `cargo audit --db DB --no-fetch` and exits with its status (ignores and their
# reasons: .cargo/audit.toml; the last measured result: docs/security.md).
# DB: $RETROCOMP_ADVISORY_DB, else cargo-audit's own default ~/.cargo/advisory-db (a clone of the
# rustsec/advisory-db repository). cargo-audit: on PATH, else <repo>/.venv/bin (scripts/setup-peers.sh
# installs it there from PyPI).
set -uo pipefail
cd "$(dirname "$0")/.."

db="${RETROCOMP_ADVISORY_DB:-$HOME/.cargo/advisory-db}"
bin="$(command -v cargo-audit || true)"
[ -n "$bin" ] || { [ -x .venv/bin/cargo-audit ] && bin="$PWD/.venv/bin/cargo-audit"; }
if [ -z "$bin" ]; then
  echo "audit.sh: cargo audit NOT run: cargo-audit is not installed (run scripts/setup-peers.sh, or cargo install cargo-audit --locked)"
  exit 0
fi
if [ ! -d "$db/crates" ]; then
  echo "audit.sh: cargo audit NOT run: no RustSec advisory database at $db (this machine cannot fetch it; clone rustsec/advisory-db there or set RETROCOMP_ADVISORY_DB)"
  exit 0
fi
rev="$(git -C "$db" log -1 --format='%h %cs' 2>/dev/null || echo 'unknown revision')"
echo "audit.sh: cargo audit against $db ($rev)"
"$bin" audit --db "$db" --no-fetch
