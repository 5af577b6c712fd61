#!/bin/sh
# Build dist/neurotouch-hid_VERSION-1_ARCH.deb: the driver with its own Python environment.
#
# usage: sudo packaging/build-deb.sh [--stage-only DIR]
#
# The venv is made with Debian 12's python3 (3.11) INSIDE a Debian 12 root
# (packaging/debian12-root.sh build, cached), at its final place /opt/neurotouch-hid (a venv
# holds its own path), from the checkout's files (tracked and new, not ignored); numba,
# OpenCV, dv-processing & co. come from PyPI as wheels built for that interpreter (evdev as
# evdev-binary on amd64; compiled there elsewhere: the uinput extra), with the extras plots and video (eval
# --report, view), but not imageio-ffmpeg's own ffmpeg: Debian's (Recommends). The package holds:
#   /opt/neurotouch-hid/                         the venv (python3 -> /usr/bin/python3.11)
#   /usr/bin/neurotouch-hid                      -> /opt/neurotouch-hid/bin/neurotouch-hid
#   /usr/lib/udev/rules.d/60-neurotouch.rules    camera + /dev/uinput access, starts the unit
#   /usr/lib/modules-load.d/neurotouch-hid.conf  uinput at every boot
#   /usr/lib/systemd/user/neurotouch-hid.service the user unit, started by udev when the camera
#                                                is plugged in (SYSTEMD_USER_WANTS)
#   /usr/share/{bash-completion,zsh,fish}/...    shell completion; /usr/share/man/man1: the man page
# and maintainer scripts (packaging/debian/) that reload udev's rules and load uinput, and undo it.
# --stage-only DIR: write the package's tree to DIR without the venv (no root, no chroot; tests).
# Needs root, debootstrap, dpkg-deb, and Debian's and PyPI's archives.
set -eu

here=$(cd "$(dirname "$0")" && pwd)
src=$(dirname "$here")
prefix=/opt/neurotouch-hid
stage_only=""
if [ "${1:-}" = "--stage-only" ]; then
    stage_only=${2:?--stage-only needs a folder}
elif [ $# -gt 0 ]; then
    sed -n '2,21p' "$0" >&2
    exit 2
fi

die() { echo "build-deb.sh: $*" >&2; exit 1; }
version=$(sed -n 's/^version = "\(.*\)"$/\1/p' "$src/pyproject.toml" | head -n 1)
[ -n "$version" ] || die "no version in pyproject.toml"
deb_version="$version-1"
arch=$(dpkg --print-architecture)

# --- the files that do not come from the venv -------------------------------------------------
stage_files() {
    stage=$1
    install -D -m 644 "$src/udev/60-neurotouch.rules" "$stage/usr/lib/udev/rules.d/60-neurotouch.rules"
    install -d -m 755 "$stage/usr/lib/modules-load.d"
    echo uinput > "$stage/usr/lib/modules-load.d/neurotouch-hid.conf"
    chmod 644 "$stage/usr/lib/modules-load.d/neurotouch-hid.conf"
    install -d -m 755 "$stage/usr/lib/systemd/user" "$stage/usr/bin"
    sed "s|^\(Exec[A-Za-z]*\)=/usr/bin/env neurotouch-hid |\1=/usr/bin/neurotouch-hid |" \
        "$src/packaging/neurotouch-hid.service" > "$stage/usr/lib/systemd/user/neurotouch-hid.service"
    chmod 644 "$stage/usr/lib/systemd/user/neurotouch-hid.service"
    sed "s|^\(Exec[A-Za-z]*\)=/usr/bin/env neurotouch-hid |\1=/usr/bin/neurotouch-hid |" \
        "$src/packaging/neurotouch-hid@.service" > "$stage/usr/lib/systemd/user/neurotouch-hid@.service"
    chmod 644 "$stage/usr/lib/systemd/user/neurotouch-hid@.service"
    ln -sf "$prefix/bin/neurotouch-hid" "$stage/usr/bin/neurotouch-hid"
    doc="$stage/usr/share/doc/neurotouch-hid"
    install -d -m 755 "$doc"
    install -m 644 "$src/packaging/debian/copyright" "$doc/copyright"
    install -m 644 "$src/packaging/README.md" "$doc/README.md"
    sed "s/@VERSION@/$deb_version/; s/@DATE@/$(date -R -d "@${SOURCE_DATE_EPOCH:-$(date +%s)}")/" \
        "$src/packaging/debian/changelog" | gzip -9n > "$doc/changelog.Debian.gz"
    chmod 644 "$doc/changelog.Debian.gz"
    install -d -m 755 "$stage/DEBIAN"
    for script in postinst prerm postrm; do
        install -m 755 "$src/packaging/debian/$script" "$stage/DEBIAN/$script"
    done
}

# The control file, once the tree is complete (Installed-Size counts it, KiB).
write_control() {
    stage=$1
    size=$(du -sk --exclude=DEBIAN "$stage" | cut -f1)
    sed "s/@VERSION@/$deb_version/; s/@ARCH@/$arch/; s/@SIZE@/$size/" \
        "$src/packaging/debian/control" > "$stage/DEBIAN/control"
    (cd "$stage" && find . -path ./DEBIAN -prune -o -type f -print | sed 's|^\./||' | LC_ALL=C sort \
        | xargs -d '\n' md5sum > DEBIAN/md5sums)
    chmod 644 "$stage/DEBIAN/control" "$stage/DEBIAN/md5sums"
}

if [ -n "$stage_only" ]; then
    [ ! -e "$stage_only" ] || die "$stage_only already exists"
    stage_files "$stage_only"
    write_control "$stage_only"
    echo "$stage_only"
    exit 0
fi

# What the build needs, all said at once before it starts (debootstrap only when the Debian 12
# root is not cached yet: debian12-root.sh's cache).
roots=${NEUROTOUCH_ROOTS:-${XDG_CACHE_HOME:-$HOME/.cache}/neurotouch-hid/debian12}
missing=""
for tool in dpkg-deb chroot mount; do
    command -v "$tool" > /dev/null || missing="$missing $tool"
done
[ -x "$roots/base/usr/bin/apt-get" ] || command -v debootstrap > /dev/null || missing="$missing debootstrap"
problems=""
[ "$(id -u)" = 0 ] || problems="needs root (a Debian 12 root, chroot): sudo $0"
[ -z "$missing" ] || problems="${problems:+$problems; }missing:$missing (Debian: apt-get install debootstrap dpkg coreutils mount)"
[ -z "$problems" ] || die "$problems"
[ -x "$roots/base/usr/bin/apt-get" ] \
    || echo "build-deb.sh: a first build: making a Debian 12 root with debootstrap in $roots (minutes; reused later)" >&2
root=$("$here/debian12-root.sh" build)
work=$(mktemp -d "${TMPDIR:-/tmp}/neurotouch-deb.XXXXXX")
cleanup() {
    ! mountpoint -q "$root/proc" || umount "$root/proc"
    rm -rf "$work" "$root/build" "$root$prefix" "$src/dist/"*.deb.partial
}
trap cleanup EXIT
trap 'exit 130' INT TERM

# --- the venv, built in the Debian 12 root at its final place ---------------------------------
rm -rf "$root/build" "$root$prefix"
mkdir -p "$root/build/src"
if git -C "$src" rev-parse --git-dir > /dev/null 2>&1; then
    git -C "$src" ls-files -z --cached --others --exclude-standard \
        | (cd "$src" && xargs -0 sh -c 'for f; do [ -e "$f" ] && printf "%s\0" "$f"; done' sh) \
        | tar -C "$src" --null -T - -cf - | tar -C "$root/build/src" -xf -
else  # an unpacked sdist
    tar -C "$src" --exclude=./dist -cf - . | tar -C "$root/build/src" -xf -
fi
cp "$here/man_commands.py" "$root/build/"
echo "build-deb.sh: building the venv in $root (Debian 12, python3.11) ..." >&2
"$here/debian12-root.sh" chroot "$root" "set -e
    python3.11 -m venv $prefix
    $prefix/bin/pip install --no-cache-dir --quiet '/build/src[plots,video,uinput]'
    # imageio-ffmpeg's own ffmpeg (~170 MB): view --out FILE.mp4 runs Debian's (Recommends: ffmpeg)
    rm -f $prefix/lib/python3.11/site-packages/imageio_ffmpeg/binaries/ffmpeg-*
    $prefix/bin/pip uninstall --yes --quiet pip setuptools wheel 2>/dev/null || true
    rm -f $prefix/bin/pip* $prefix/bin/Activate.ps1
    cd /build
    $prefix/bin/python man_commands.py > commands.h2m
    TYPER_USE_RICH=0 COLUMNS=100 help2man --no-info --version-string=$version \
        --name='NeuroTouch soft tactile sensor as a game controller' \
        --include=commands.h2m --output=neurotouch-hid.1 $prefix/bin/neurotouch-hid
    for shell in bash zsh fish; do
        _NEUROTOUCH_HID_COMPLETE=source_\$shell $prefix/bin/neurotouch-hid > completion.\$shell
    done
    $prefix/bin/python -m compileall -q $prefix/lib > /dev/null || true
" || die "building the venv failed"

stage="$work/stage"
mkdir -p "$stage/opt"
tar -C "$root/opt" -cf - neurotouch-hid | tar -C "$stage/opt" -xf -
stage_files "$stage"
install -D -m 644 "$root/build/completion.bash" "$stage/usr/share/bash-completion/completions/neurotouch-hid"
install -D -m 644 "$root/build/completion.zsh" "$stage/usr/share/zsh/vendor-completions/_neurotouch-hid"
install -D -m 644 "$root/build/completion.fish" "$stage/usr/share/fish/vendor_completions.d/neurotouch-hid.fish"
install -d -m 755 "$stage/usr/share/man/man1"
gzip -9n < "$root/build/neurotouch-hid.1" > "$stage/usr/share/man/man1/neurotouch-hid.1.gz"
chmod 644 "$stage/usr/share/man/man1/neurotouch-hid.1.gz"
write_control "$stage"

mkdir -p "$src/dist"
out="$src/dist/neurotouch-hid_${deb_version}_${arch}.deb"
# gzip: xz took ~10 times longer on ~800 MB; zstd, which Debian 12's dpkg reads, its lintian
# calls a malformed archive
dpkg-deb --root-owner-group -Zgzip --build "$stage" "$out.partial" > /dev/null
mv "$out.partial" "$out"  # a reader of the previous .deb never sees half of the new one
echo "$out"
