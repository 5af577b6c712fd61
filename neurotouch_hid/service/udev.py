"""What the driver knows about udev: its rules file, where udev reads rules, and the fixes that
name them.

The rules file is ``udev/60-neurotouch.rules`` (camera access, /dev/uinput access, a mark on our
own virtual devices); ``packaging/install.sh`` installs it. Both ship inside the package
(``neurotouch_hid/data/udev`` and ``neurotouch_hid/data/packaging`` link to those folders, and
pyproject.toml's package data copies them into every wheel), so the fixes name absolute paths that
exist wherever the driver is installed, not only in a checkout. The camera's discovery
(:mod:`neurotouch_hid.sources.discovery`), the virtual devices (:mod:`neurotouch_hid.targets.uinput.gamepad`)
and ``doctor`` all take their rule names, folders and advice from here, so the three say the same.
Rule syntax and folders: udev(7).
"""

from __future__ import annotations

import os
import shlex
import shutil
import sys
from pathlib import Path

#: The project's udev rules file (udev/60-neurotouch.rules).
RULES_NAME = "60-neurotouch.rules"
#: Where udev reads rules from (udev(7)), most specific first.
RULES_DIRS = ("/etc/udev/rules.d", "/run/udev/rules.d", "/usr/lib/udev/rules.d", "/lib/udev/rules.d")
#: The installed package's copies of udev/ and packaging/ (absolute; in a checkout, the folders).
DATA_DIR = Path(__file__).resolve().parents[1] / "data"
#: The udev rules file and the install script that ship with this installation.
RULES_FILE = (DATA_DIR / "udev" / RULES_NAME).resolve()
INSTALL_SCRIPT = (DATA_DIR / "packaging" / "install.sh").resolve()
#: How to install the rules (and load uinput now and at every boot): one command.
RULES_INSTALL = f"sudo sh {shlex.quote(str(INSTALL_SCRIPT))} --system"
#: The rule that gives the seated user access to /dev/uinput (udev/60-neurotouch.rules carries the
#: same line; tests/test_packaging.py checks they agree).
UINPUT_RULE = 'KERNEL=="uinput", SUBSYSTEM=="misc", TAG+="uaccess", OPTIONS+="static_node=uinput"'
#: The rule that gives the seated user access to /dev/uhid (``run --output hid``; the rules file
#: carries the same line).
UHID_RULE = 'KERNEL=="uhid", SUBSYSTEM=="misc", TAG+="uaccess", OPTIONS+="static_node=uhid"'
#: A camera rule for machines without a seated user (headless, over SSH): uaccess only serves the
#: user logged in at the machine itself, so give a group access instead.
GROUP_RULE = 'SUBSYSTEM=="usb", ATTR{idVendor}=="152a", ATTR{idProduct}=="841a", GROUP="plugdev", MODE="0660"'


def installed_rules(dirs: tuple[str, ...] = RULES_DIRS) -> str | None:
    """The path of the project's udev rules file in the first of udev's rules folders (``dirs``)
    that has it, or None."""
    for d in dirs:
        path = Path(d) / RULES_NAME
        if path.is_file():
            return str(path)
    return None


def camera_access_fix(rules: str | None = None) -> str:
    """What to do when a camera's USB node is not readable and writable by this user: install the
    udev rule, or (``rules``: where it is installed) log in at the seat or use a group rule.
    Several lines, one step each; the commands stand alone on their lines (copyable)."""
    if rules is None:
        return f"install the udev rule ({RULES_NAME}):\n{RULES_INSTALL}\nthen unplug and replug the camera"
    return (
        f"the udev rule is installed ({rules}) but it gives access only to the user logged in at this "
        "computer itself (uaccess): log in there (not over SSH), then unplug and replug the camera\n"
        "for headless use, give the plugdev group the camera and join that group:\n"
        f"echo '{GROUP_RULE}' | sudo tee /etc/udev/rules.d/61-neurotouch-group.rules\n"
        "sudo udevadm control --reload\n"
        "sudo usermod -aG plugdev $USER\n"
        "then log out and in, and unplug and replug the camera"
    )


def uinput_help() -> str:
    """The fix for a missing or unwritable /dev/uinput, a few short lines: the install command
    (the udev rule, and the uinput module now and at every boot), log out and in, check."""
    return (
        "to fix it, install the udev rule and load uinput (now and at every boot):\n"
        f"{RULES_INSTALL}\n"
        "then log out and in, and check with: neurotouch-hid doctor"
    )


def uhid_help() -> str:
    """The fix for a missing or unwritable /dev/uhid, a few short lines: load the module, install
    the udev rule (which gives the seated user access), log out and in, check."""
    return (
        "to fix it, load the uhid module and install the udev rule:\n"
        "sudo modprobe uhid\n"
        f"{RULES_INSTALL}\n"
        "then log out and in, and check with: neurotouch-hid doctor"
    )


def char_device_problem(devnode: str, module: str) -> str | None:
    """Why ``devnode`` (a misc character device such as /dev/uhid) cannot be used: missing (the
    kernel's ``module`` is not loaded), not a character device, not readable and writable by this
    process; None when it can."""
    import os
    import stat

    try:
        mode = os.stat(devnode).st_mode
    except FileNotFoundError:
        return f"{devnode} does not exist (the kernel's {module} module is not loaded)"
    except OSError as exc:
        return f"cannot stat {devnode}: {exc.strerror}"
    if not stat.S_ISCHR(mode):
        return f"{devnode} is not a character device, so not the {module} device"
    if not os.access(devnode, os.R_OK | os.W_OK):
        return f"no permission to open {devnode} for reading and writing (uid {os.getuid()})"
    return None


def uinput_problem(devnode: str = "/dev/uinput") -> str | None:
    """Why ``devnode`` cannot be used to create a uinput device (missing, not a character device,
    not readable and writable by this process), or None when it can (:func:`char_device_problem`
    for the uinput module)."""
    return char_device_problem(devnode, "uinput")


def this_command() -> str | None:
    """The absolute path of the ``neurotouch-hid`` command that is running (pipx's link, a venv's
    script), else the one on PATH, else None."""
    argv0 = Path(sys.argv[0])
    if argv0.name == "neurotouch-hid" and argv0.exists():
        return os.path.abspath(argv0)
    return shutil.which("neurotouch-hid")


def sudo_command(args: str) -> str:
    """``sudo /ABSOLUTE/neurotouch-hid ARGS``, the command given by its absolute path
    (:func:`this_command`; else this Python's ``-m neurotouch_hid.cli``): sudo searches only its
    ``secure_path`` (Debian's: /usr/local/sbin, /usr/local/bin, /usr/sbin, /usr/bin, /sbin,
    /bin; sudoers(5)), not ~/.local/bin where pipx installs the command. ``args`` is appended as
    given (shell text: ``$USER`` stays for the shell)."""
    command = this_command()
    parts = [command] if command is not None else [sys.executable, "-m", "neurotouch_hid.cli"]
    return f"sudo {' '.join(shlex.quote(p) for p in parts)} {args}"
