#!/bin/sh
# Manual run of the vcan QEMU guest with its console on this terminal (the automated version is
# `cargo test --test vcan_qemu`). Builds the guest program, fetches the kernel (cached), assembles
# the initramfs and boots it. Extra arguments go to qemu.
set -eu
here=$(cd "$(dirname "$0")" && pwd)
repo=$(cd "$here/../.." && pwd)
target="${CARGO_TARGET_DIR:-$repo/target}"
# The test profile (opt-level 1) as `cargo test` uses: at opt-level 0 the guest runs ~5x slower under TCG.
(cd "$repo" && cargo build --profile test -p vcan-guest --bin vcan_guest)
tree=$(sh "$here/fetch-kernel.sh" | tail -n 1)
initrd=$(sh "$here/build-initramfs.sh" "$tree" "$target/debug/vcan_guest" "$target/vcan-qemu/initramfs.cpio.gz")
qemu=$(sh "$here/fetch-qemu.sh" | tail -n 1)
exec "$qemu" -accel tcg -m 512 -smp 1 -nographic -no-reboot -nic none \
    -kernel "$(ls "$tree"/boot/vmlinuz-* | head -n 1)" -initrd "$initrd" \
    -append "console=ttyS0 quiet panic=-1" "$@"
