#!/bin/sh
# Assemble the vcan guest's initramfs (newc cpio, gzip): busybox-static, the CAN kernel modules in
# dependency order, can-utils cansend/candump, the retrocomp guest test program, their shared
# libraries (from ldd), and init (scripts/vcan-qemu/init).
#
# Usage: build-initramfs.sh KERNEL_TREE GUEST_BIN OUT.cpio.gz
#   KERNEL_TREE  the directory printed by fetch-kernel.sh (boot/vmlinuz-<abi>, lib/modules/<abi>/)
#   GUEST_BIN    the in-guest test program (target/<profile>/vcan_guest), stripped into the image
# Needs: busybox (static), cansend, candump, cpio, gzip, ldd; xz/zstd only if modules are compressed.
# Install them with scripts/setup-peers.sh.
set -eu

tree=$1
guest_bin=$2
out=$3
here=$(cd "$(dirname "$0")" && pwd)

fail() {
    echo "build-initramfs.sh: $*" >&2
    echo "  install the peers with: scripts/setup-peers.sh (apt-get install busybox-static can-utils cpio xz-utils)" >&2
    exit 2
}

busybox=$(command -v busybox || true)
[ -n "$busybox" ] || fail "busybox not found"
# A dynamic busybox would need its libs; busybox-static is what the guest expects.
if ldd "$busybox" >/dev/null 2>&1; then fail "$busybox is dynamically linked; install busybox-static"; fi
cansend=$(command -v cansend || true)
candump=$(command -v candump || true)
[ -n "$cansend" ] && [ -n "$candump" ] || fail "cansend/candump (can-utils) not found"
command -v cpio >/dev/null || fail "cpio not found"
[ -x "$guest_bin" ] || fail "guest program $guest_bin is missing or not executable"

abi=$(ls "$tree/lib/modules" | head -n 1)
moddir="$tree/lib/modules/$abi/kernel"

stage=$(mktemp -d "${TMPDIR:-/tmp}/retrocomp-vcan-initramfs.XXXXXX")
trap 'rm -rf "$stage"' EXIT
mkdir -p "$stage/bin" "$stage/sbin" "$stage/usr/bin" "$stage/lib/modules" "$stage/proc" "$stage/sys" \
    "$stage/dev" "$stage/tmp" "$stage/etc"

# busybox and the applets init uses.
cp "$busybox" "$stage/bin/busybox"
for applet in sh mount insmod ip cat cut echo sleep poweroff mkdir ls dmesg uname; do
    ln -s busybox "$stage/bin/$applet"
done

# Copy a dynamic executable and every library ldd names, at the same absolute paths.
copy_with_libs() {
    src=$1
    dst=$2
    cp -L "$src" "$stage$dst"
    ldd "$src" | sed -n 's/.*=> \(\/[^ ]*\) .*/\1/p; s/^[[:space:]]*\(\/[^ ]*\) (0x.*/\1/p' | while read -r lib; do
        mkdir -p "$stage$(dirname "$lib")"
        [ -e "$stage$lib" ] || cp -L "$lib" "$stage$lib"
    done
}
copy_with_libs "$cansend" /usr/bin/cansend
copy_with_libs "$candump" /usr/bin/candump
copy_with_libs "$guest_bin" /bin/vcan_guest
# Debug info is useless in the guest and would triple the image.
strip "$stage/bin/vcan_guest" 2>/dev/null || true

# Kernel modules: find one (.ko, .ko.xz, .ko.zst), decompress on the host (busybox insmod may lack
# xz/zstd support), and emit it after its dependencies (read from the module's own .modinfo
# `depends=` string, because the .deb ships no modules.dep: depmod runs at install time).
order=""
find_module() {
    for ext in ko ko.xz ko.zst; do
        f=$(find "$moddir" -name "$1.$ext" | head -n 1)
        if [ -n "$f" ]; then echo "$f"; return 0; fi
    done
    return 1
}
add_module() {
    local name f deps d
    name=$1
    case " $order " in *" $name "*) return 0 ;; esac
    f=$(find_module "$name") || fail "kernel module $name not found under $moddir"
    case "$f" in
    *.ko.xz) xz -dc "$f" >"$stage/lib/modules/$name.ko" || fail "xz -d $f failed (install xz-utils)" ;;
    *.ko.zst) zstd -dcq "$f" >"$stage/lib/modules/$name.ko" || fail "zstd -d $f failed (install zstd)" ;;
    *) cp "$f" "$stage/lib/modules/$name.ko" ;;
    esac
    deps=$(tr '\0' '\n' <"$stage/lib/modules/$name.ko" | sed -n 's/^depends=//p' | tr ',' ' ')
    for d in $deps; do add_module "$d"; done
    # Re-check: a dependency's recursion cannot add $name (no cycles in kernel modules), so append.
    order="$order $name"
}
for m in can can-raw can-dev vcan; do add_module "$m"; done
echo "$order" | sed 's/^ //' >"$stage/etc/modules.order"

cp "$here/init" "$stage/init"
chmod +x "$stage/init"

mkdir -p "$(dirname "$out")"
(cd "$stage" && find . | cpio -o -H newc --quiet) | gzip -1 >"$out.tmp"
mv "$out.tmp" "$out"
echo "$out"
