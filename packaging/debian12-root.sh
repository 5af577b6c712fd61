#!/bin/sh
# Debian 12 (bookworm) roots for building and testing the .deb, cached between runs.
#
# usage: packaging/debian12-root.sh base            the pristine root (debootstrap --variant=minbase)
#        packaging/debian12-root.sh build           the build root: base + python3, its venv
#                                                   package, help2man (build-deb.sh)
#        packaging/debian12-root.sh copy DIR        a fresh copy of the base root at DIR (a clean
#                                                   machine to install the package into)
#        packaging/debian12-root.sh chroot DIR CMD  run CMD (sh -c) in DIR with /proc mounted
# Prints the root's path (base, build, copy). Cache: $NEUROTOUCH_ROOTS, else
# ~/.cache/neurotouch-hid/debian12. Needs root, debootstrap, and Debian's package archive (the
# mirror is debootstrap's default unless $DEBIAN_MIRROR is set).
set -eu

cache=${NEUROTOUCH_ROOTS:-${XDG_CACHE_HOME:-$HOME/.cache}/neurotouch-hid/debian12}
base="$cache/base"
build="$cache/build"

die() { echo "debian12-root.sh: $*" >&2; exit 1; }
[ "$(id -u)" = 0 ] || die "needs root (debootstrap, chroot, mount)"

# Run "$2" with sh -c inside root "$1": /proc mounted, the host's DNS and CA certificates (pip
# and apt reach the package archives the host reaches), no service may start (policy-rc.d).
in_root() {
    root=$1
    cp -L /etc/resolv.conf "$root/etc/resolv.conf"
    if [ -f /etc/ssl/certs/ca-certificates.crt ]; then
        mkdir -p "$root/etc/ssl/certs"
        cp -L /etc/ssl/certs/ca-certificates.crt "$root/etc/ssl/certs/host-ca.crt"
    fi
    printf '#!/bin/sh\nexit 101\n' > "$root/usr/sbin/policy-rc.d"
    chmod 755 "$root/usr/sbin/policy-rc.d"
    mountpoint -q "$root/proc" || mount -t proc proc "$root/proc"
    status=0
    chroot "$root" /usr/bin/env -i HOME=/root PATH=/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin \
        LANG=C.UTF-8 DEBIAN_FRONTEND=noninteractive PIP_CERT=/etc/ssl/certs/host-ca.crt \
        PIP_DISABLE_PIP_VERSION_CHECK=1 PIP_DEFAULT_TIMEOUT=180 \
        /bin/sh -c "$2" || status=$?
    umount "$root/proc"
    rm -f "$root/usr/sbin/policy-rc.d"
    return $status
}

# A root's /proc left mounted by a run killed inside in_root (SIGKILL skips its umount): unmount
# it before the root is removed, or rm would walk into the host's /proc.
release() {
    ! mountpoint -q "$1/proc" || umount -l "$1/proc"
}

make_base() {
    [ -x "$base/usr/bin/apt-get" ] && return 0
    command -v debootstrap > /dev/null || die "debootstrap is missing: apt-get install debootstrap"
    release "$base.partial"  # debootstrap mounts it too
    rm -rf --one-file-system "$base.partial"
    mkdir -p "$cache"
    debootstrap --variant=minbase bookworm "$base.partial" ${DEBIAN_MIRROR:-} > "$cache/debootstrap.log" 2>&1 \
        || die "debootstrap failed; see $cache/debootstrap.log"
    rm -rf "$base.partial/var/cache/apt/archives/"*.deb
    mv "$base.partial" "$base"
}

# python3-venv makes the venv; help2man writes the man page. Every dependency is a wheel on amd64
# (evdev as evdev-binary, x86_64 only); elsewhere evdev is compiled: gcc, Python's and the
# kernel's headers.
BUILD_PACKAGES="python3 python3-venv help2man ca-certificates"
[ "$(dpkg --print-architecture)" = amd64 ] \
    || BUILD_PACKAGES="$BUILD_PACKAGES python3-dev gcc libc6-dev linux-libc-dev"

make_build() {
    [ "$(cat "$build/.neurotouch-build-packages" 2>/dev/null)" = "$BUILD_PACKAGES" ] && return 0
    make_base
    release "$build"
    rm -rf --one-file-system "$build"
    cp -a "$base" "$build"
    in_root "$build" "apt-get update -q && apt-get install -y -q --no-install-recommends $BUILD_PACKAGES \
        && apt-get clean" > "$cache/build-root.log" 2>&1 \
        || die "could not install the build tools into $build; see $cache/build-root.log"
    echo "$BUILD_PACKAGES" > "$build/.neurotouch-build-packages"
}

case "${1:-}" in
    base) make_base; echo "$base" ;;
    build) make_build; echo "$build" ;;
    copy)
        dest=${2:?copy needs a folder}
        make_base
        [ ! -e "$dest" ] || die "$dest already exists"
        cp -a "$base" "$dest"
        echo "$dest"
        ;;
    chroot) in_root "${2:?chroot needs a root folder}" "${3:?chroot needs a command}" ;;
    *) sed -n '2,12p' "$0" >&2; exit 2 ;;
esac
