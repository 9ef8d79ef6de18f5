# Sourced (POSIX sh) by the scripts that need a Debian package's files WITHOUT installing it:
# scripts/vcan-qemu/fetch-qemu.sh (qemu-system-x86 for the vcan guest) and
# scripts/fetch-qemu-user.sh (qemu-user-static for the arm64 package check). Installing them could
# remove or downgrade a host package (a newer qemu-utils from backports), and qemu-user-static's
# maintainer scripts would register binfmt handlers for every foreign binary on the host. So the
# packages are `apt-get download`ed and `dpkg -x`ed into a cache: no dpkg database change, no root.
#
# apt_unpack CACHE NAME PACKAGE...
#   Unpacks PACKAGE... into CACHE/NAME-<candidate version of the first package>/root and prints
#   that tree. Reuses a complete tree (it holds .unpacked); when the apt lists give no candidate,
#   the newest complete NAME-* tree in the cache (an offline rerun). Concurrent callers are
#   serialized with flock; a tree is unpacked in a private folder and renamed into place only when
#   complete; older NAME-* trees are removed.
#   APT_UNPACK_WALK   packages whose hard dependencies are walked (breadth first): those the host
#                     lacks are fetched too (first alternative of OR groups; virtuals skipped)
#   APT_UNPACK_SEEN   packages never fetched nor walked
#   APT_UNPACK_HOOK   a function run as `HOOK WORK FINAL_TREE VERSION` after unpacking into
#                     WORK/root, before the tree is marked complete (fetch-qemu.sh writes its
#                     wrapper there); its failure leaves no tree
# Needs: apt-get, apt-cache, dpkg, dpkg-query; up-to-date apt lists (apt-get update).
# On failure: a message on stderr naming the caller ($0) and exit 2.

apt_unpack_fail() {
    echo "$(basename "$0"): $*" >&2
    exit 2
}

apt_unpack_installed() {
    [ "$(dpkg-query -W -f='${db:Status-Status}' "$1" 2>/dev/null)" = installed ]
}

# Direct hard dependencies of a package (first alternative of OR groups included; virtuals skipped).
apt_unpack_deps() {
    apt-cache depends --no-recommends --no-suggests --no-conflicts --no-breaks --no-replaces \
        --no-enhances "$1" 2>/dev/null | sed -n 's/^ *|\{0,1\}Depends: \([a-z0-9][^ <>]*\)$/\1/p'
}

# apt_unpack_ready CACHE TREE: prints TREE and succeeds when it is complete (.unpacked); else takes
# CACHE's lock (held until this process exits: parallel test runs share the cache) and checks again,
# so the caller that goes on to unpack is alone.
apt_unpack_ready() {
    [ -f "$2/.unpacked" ] && echo "$2" && return 0
    if command -v flock >/dev/null 2>&1; then
        exec 9>"$1/.lock"
        flock 9
        [ -f "$2/.unpacked" ] && echo "$2" && return 0
    fi
    return 1
}

apt_unpack() {
    _cache=$1
    _name=$2
    shift 2
    mkdir -p "$_cache"
    command -v apt-cache >/dev/null 2>&1 || apt_unpack_fail "apt-cache not found; this needs a Debian-like host"
    _ver=$(apt-cache policy "$1" 2>/dev/null | sed -n 's/^ *Candidate: //p' | head -n 1)
    if [ -z "$_ver" ] || [ "$_ver" = "(none)" ]; then
        _cached=$(ls -d "$_cache/$_name"-* 2>/dev/null | tail -n 1 || true)
        if [ -n "$_cached" ] && [ -f "$_cached/.unpacked" ]; then
            echo "$_cached"
            return 0
        fi
        apt_unpack_fail "no candidate for $1 in the apt lists: run 'apt-get update'"
    fi
    _tree="$_cache/$_name-$(echo "$_ver" | tr ':+~' '___')"
    apt_unpack_ready "$_cache" "$_tree" && return 0
    _want="$*"
    _seen=" $* ${APT_UNPACK_SEEN:-} "
    _queue=""
    for _p in ${APT_UNPACK_WALK:-}; do _queue="$_queue $(apt_unpack_deps "$_p")"; done
    while [ -n "$(echo "$_queue" | tr -d ' \n')" ]; do
        _next=""
        for _p in $_queue; do
            case "$_seen" in *" $_p "*) continue ;; esac
            _seen="$_seen$_p "
            apt_unpack_installed "$_p" && continue
            _want="$_want $_p"
            _next="$_next $(apt_unpack_deps "$_p")"
        done
        _queue=$_next
    done
    _work=$(mktemp -d "$_cache/.unpack.XXXXXX")
    # shellcheck disable=SC2064
    trap "rm -rf '$_work'" EXIT
    echo "$(basename "$0"): apt-get download $_want" >&2
    # apt-get download writes into the current directory; as root it warns about the _apt sandbox.
    # shellcheck disable=SC2086
    (cd "$_work" && apt-get download $_want >&2) ||
        apt_unpack_fail "'apt-get download $_want' failed (network? stale apt lists? run 'apt-get update')"
    mkdir -p "$_work/root"
    for _deb in "$_work"/*.deb; do dpkg -x "$_deb" "$_work/root"; done
    rm -f "$_work"/*.deb
    if [ -n "${APT_UNPACK_HOOK:-}" ]; then
        "$APT_UNPACK_HOOK" "$_work" "$_tree" "$_ver" || apt_unpack_fail "preparing $_tree failed"
    fi
    echo "$_ver $_want" >"$_work/.unpacked"
    rm -rf "$_tree"
    mv "$_work" "$_tree"
    trap - EXIT
    for _old in "$_cache/$_name"-*; do
        [ "$_old" = "$_tree" ] || rm -rf "$_old"
    done
    echo "$_tree"
}
