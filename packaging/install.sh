#!/bin/sh
# Install neurotouch-hid's udev rules (system-wide, root) and its systemd user unit (per user).
#
# usage: install.sh [--system] [--user] [--bin PATH] [--gadget PROTOCOL:USER]
#   --system  udev/60-neurotouch.rules -> /etc/udev/rules.d/, "uinput" -> /etc/modules-load.d/
#             (loaded at every boot), then reload udev, re-trigger devices and load uinput now.
#             Needs root.
#   --user    neurotouch-hid.service and neurotouch-hid@.service (one driver per camera,
#             docs/several-sensors.md) -> ~/.config/systemd/user/ (or $XDG_CONFIG_HOME/systemd/user/)
#             with ExecStart/ExecReload set to the neurotouch-hid on PATH, else pipx's
#             ~/.local/bin/neurotouch-hid (or --bin PATH), a ~/.config/neurotouch-hid/service.env
#             to pick the profile, and `systemctl --user daemon-reload`. Run as yourself, not root.
#   --gadget PROTOCOL:USER  (root) neurotouch-hid-gadget.service -> /etc/systemd/system/, enabled
#             and started: at every boot it makes the USB gadget for run --output usb (hid,
#             switch or xinput; docs/any-host.md) and hands its device nodes to USER (an
#             existing user's name: letters, digits, _ . -; anything else is refused).
#   neither   both: the system part through sudo, the user part as you (with DESTDIR: the
#             system part only, staged).
# DESTDIR=DIR stages the system files under DIR and touches nothing live (packagers, tests).
# The script ships inside the installed package too: `neurotouch-hid doctor` prints its path.
set -eu

here=$(cd "$(dirname "$0")" && pwd)
src=$(dirname "$here")
do_system=0 do_user=0 bin="" gadget=""
while [ $# -gt 0 ]; do
    case "$1" in
        --system) do_system=1 ;;
        --user) do_user=1 ;;
        --bin) shift; bin=${1:?--bin needs a path} ;;
        --gadget) shift; gadget=${1:?--gadget needs PROTOCOL:USER, e.g. hid:$USER} ;;
        -h|--help) sed -n '2,/^[^#]/{/^#/s/^# \{0,1\}//p}' "$0"; exit 0 ;;
        *) echo "install.sh: unknown option $1 (see --help)" >&2; exit 2 ;;
    esac
    shift
done
case "$bin" in ""|/*) ;; *) bin="$(pwd)/$bin" ;; esac  # --bin relative to where you are

# the neurotouch-hid the units run: --bin, else the one on PATH, else pipx's; exits when none
find_bin() {
    if [ -z "$bin" ]; then
        bin=$(command -v neurotouch-hid || true)
        if [ -z "$bin" ] && [ -x "$HOME/.local/bin/neurotouch-hid" ]; then
            bin=$HOME/.local/bin/neurotouch-hid  # pipx's, before ~/.local/bin is on PATH
        fi
    fi
    case "$bin" in
        /*) [ -x "$bin" ] || { echo "install.sh: $bin is not executable" >&2; exit 1; } ;;
        *) echo "install.sh: neurotouch-hid is not on PATH; install it (pipx install .) or pass --bin /path/to/neurotouch-hid" >&2; exit 1 ;;
    esac
}
# $bin as a unit's Exec line's command, and escaped for sed's replacement: quoted when it has a
# space, % doubled (systemd's specifiers)
exec_bin() {
    case "$bin" in *[[:space:]]*) set -- "\"$bin\"" ;; *) set -- "$bin" ;; esac
    printf '%s\n' "$1" | sed -e 's/%/%%/g' -e 's/[\\|&]/\\&/g'
}

if [ -n "$gadget" ]; then
    case "$gadget" in *:?*) ;; *) echo "install.sh: --gadget $gadget: give PROTOCOL:USER, e.g. hid:${USER:-you}" >&2; exit 2 ;; esac
    protocol=${gadget%%:*} owner=${gadget#*:}
    case "$protocol" in hid|switch|xinput) ;; *) echo "install.sh: --gadget $gadget: the protocol is hid, switch or xinput" >&2; exit 2 ;; esac
    # USER goes into a root unit's command line: only a user name of this machine (or, staged, of
    # DESTDIR's /etc/passwd), never text sed, systemd (%, $, ;) or the shell would read
    case "$owner" in
        *[!A-Za-z0-9_.-]*|-*|.*) echo "install.sh: --gadget $protocol:USER: '$owner' is not a user name (letters, digits, _ . -)" >&2; exit 2 ;;
    esac
    [ ${#owner} -le 32 ] || { echo "install.sh: --gadget: '$owner' is longer than a user name (32)" >&2; exit 2; }
    entry=$(getent passwd "$owner" || true)
    if [ -z "$entry" ] && [ -n "${DESTDIR:-}" ] && [ -f "$DESTDIR/etc/passwd" ]; then
        entry=$(awk -F: -v u="$owner" '$1 == u || $3 == u { print; exit }' "$DESTDIR/etc/passwd")
    fi
    [ -n "$entry" ] || { echo "install.sh: --gadget $protocol:$owner: no user $owner on this machine${DESTDIR:+ nor in $DESTDIR/etc/passwd}" >&2; exit 2; }
    owner=${entry%%:*}  # the name, also when a uid was given
    case "$owner" in ""|*[!A-Za-z0-9_.-]*|-*|.*) echo "install.sh: --gadget: the passwd entry's name '$owner' is not a plain user name" >&2; exit 2 ;; esac
    [ "$(id -u)" = 0 ] || [ -n "${DESTDIR:-}" ] || { echo "install.sh: --gadget needs root: sudo sh $0 --gadget $gadget" >&2; exit 1; }
    # not find_bin: a staged unit (DESTDIR) may name the command of the system it is for
    [ -n "$bin" ] || bin=$(command -v neurotouch-hid || true)
    case "$bin" in /*) ;; *) echo "install.sh: neurotouch-hid is not on PATH; pass --bin /path/to/neurotouch-hid" >&2; exit 1 ;; esac
    unit="${DESTDIR:-}/etc/systemd/system/neurotouch-hid-gadget.service"
    install -d -m 755 "$(dirname "$unit")"
    sed -e "s|^\(Exec[A-Za-z]*\)=/usr/bin/env neurotouch-hid |\1=$(exec_bin) |" \
        -e "s|--protocol hid --user root|--protocol $protocol --user $owner|" \
        "$here/neurotouch-hid-gadget.service" > "$unit"
    chmod 644 "$unit"
    if [ -z "${DESTDIR:-}" ]; then
        printf '%s\n' libcomposite usb_f_hid usb_f_fs > /etc/modules-load.d/neurotouch-hid-gadget.conf
        systemctl daemon-reload && systemctl enable --now neurotouch-hid-gadget.service
    fi
    echo "installed $unit (protocol $protocol, for $owner)"
    [ $do_system = 1 ] || [ $do_user = 1 ] || exit 0
fi
if [ $do_system = 0 ] && [ $do_user = 0 ]; then
    if [ "$(id -u)" = 0 ]; then
        do_system=1
        echo "install.sh: running as root: system part only; run 'sh $0 --user' as your own user" >&2
    elif [ -n "${DESTDIR:-}" ]; then
        do_system=1  # staged, nothing live: no sudo, no user part
    else
        find_bin  # before sudo: stop with nothing installed when the user part cannot be done
        sudo sh "$0" --system
        do_user=1
    fi
fi

if [ $do_user = 1 ] && [ "$(id -u)" = 0 ] && { [ -n "${SUDO_USER:-}" ] || [ "$HOME" = /root ]; }; then
    # the unit would go to root's folders and the service run as root, not for the user at the seat
    echo "install.sh: --user installs the service for the user who runs it, and this is root: run 'sh $0 --user' as yourself, without sudo" >&2
    exit 1
fi

if [ $do_system = 1 ]; then
    dest=${DESTDIR:-}
    if [ -z "$dest" ] && [ "$(id -u)" != 0 ]; then
        echo "install.sh: --system needs root: sudo sh $0 --system" >&2; exit 1
    fi
    install -D -m 644 "$src/udev/60-neurotouch.rules" "$dest/etc/udev/rules.d/60-neurotouch.rules"
    install -d -m 755 "$dest/etc/modules-load.d"
    echo uinput > "$dest/etc/modules-load.d/neurotouch-hid.conf"
    chmod 644 "$dest/etc/modules-load.d/neurotouch-hid.conf"
    if [ -z "$dest" ]; then
        modprobe uinput || echo "install.sh: modprobe uinput failed (is uinput built into this kernel?)" >&2
        udevadm control --reload
        udevadm trigger --subsystem-match=misc --subsystem-match=usb --subsystem-match=input
    fi
    echo "installed the udev rules; replug the camera, then log out and in (uaccess ACLs)"
fi

if [ $do_user = 1 ]; then
    find_bin
    config=${XDG_CONFIG_HOME:-$HOME/.config}
    units="$config/systemd/user"
    install -d -m 755 "$units" "$config/neurotouch-hid"
    sed "s|^\(Exec[A-Za-z]*\)=/usr/bin/env neurotouch-hid |\1=$(exec_bin) |" \
        "$here/neurotouch-hid.service" > "$units/neurotouch-hid.service"
    chmod 644 "$units/neurotouch-hid.service"
    sed "s|^\(Exec[A-Za-z]*\)=/usr/bin/env neurotouch-hid |\1=$(exec_bin) |" \
        "$here/neurotouch-hid@.service" > "$units/neurotouch-hid@.service"
    chmod 644 "$units/neurotouch-hid@.service"
    env_file="$config/neurotouch-hid/service.env"
    if [ ! -e "$env_file" ]; then
        printf '%s\n' "# The profile neurotouch-hid.service runs: a name (default, accessibility, ...) or a path." \
            "NEUROTOUCH_PROFILE=default" \
            "# Its output: gamepad (the default), hid, or usb (this board as a USB controller for another" \
            "# computer or a console, docs/any-host.md); uncomment to change it." \
            "#NEUROTOUCH_OUTPUT=usb" > "$env_file"
    fi
    systemctl --user daemon-reload 2>/dev/null \
        || echo "install.sh: no systemd user manager reachable; it reads the unit at your next login" >&2
    echo "installed $units/neurotouch-hid.service (ExecStart: $bin); it starts when the camera is plugged in"
    echo "it shares the compiled pipeline your own runs cached when the package's folder is yours (pipx); a system-wide install's is not, and its first start compiles once more, into ${XDG_CACHE_HOME:-$HOME/.cache}/neurotouch-hid: the pad appears after ~25 s of CPU, a minute or more on a busy machine; journalctl --user -u neurotouch-hid -f shows the progress"
fi
