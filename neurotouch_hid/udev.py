"""What the driver knows about udev: its rules file, where udev reads rules, and the fixes that
name them.

The rules file is ``udev/60-neurotouch.rules`` (camera access, /dev/uinput access, a mark on our
own virtual devices); ``packaging/install.sh`` installs it. The camera's discovery
(:mod:`neurotouch_hid.sources.discovery`), the virtual devices (:mod:`neurotouch_hid.output.gamepad`)
and ``doctor`` all take their rule names, folders and advice from here, so the three say the same.
Rule syntax and folders: udev(7).
"""

from __future__ import annotations

from pathlib import Path

#: The project's udev rules file (udev/60-neurotouch.rules).
RULES_NAME = "60-neurotouch.rules"
#: Where udev reads rules from (udev(7)), most specific first.
RULES_DIRS = ("/etc/udev/rules.d", "/run/udev/rules.d", "/usr/lib/udev/rules.d", "/lib/udev/rules.d")
#: How to install the rules from a source checkout (packaging/install.sh does the same).
RULES_INSTALL = (
    "sudo install -m644 udev/60-neurotouch.rules /etc/udev/rules.d/ && "
    "sudo udevadm control --reload && sudo udevadm trigger "
    "(or: sudo packaging/install.sh --system)"
)
#: The rule that gives the seated user access to /dev/uinput (udev/60-neurotouch.rules carries the
#: same line; tests/test_packaging.py checks they agree).
UINPUT_RULE = 'KERNEL=="uinput", SUBSYSTEM=="misc", TAG+="uaccess", OPTIONS+="static_node=uinput"'
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
    udev rule, or (``rules``: where it is installed) log in at the seat or use a group rule."""
    if rules is None:
        return f"install the udev rule: {RULES_INSTALL}; then unplug and replug the camera"
    return (
        f"the udev rule is installed ({rules}) but it gives access only to the user logged in at this "
        f"computer itself (uaccess): log in there (not over SSH) and unplug and replug the camera; "
        f"for headless use add a group rule to /etc/udev/rules.d/: {GROUP_RULE} (and join that group)"
    )


def uinput_help() -> str:
    """The fix for a missing or unwritable /dev/uinput: the module, the udev rule, the install
    command."""
    return (
        f"load the uinput module: sudo modprobe uinput (at every boot: "
        f"echo uinput | sudo tee /etc/modules-load.d/neurotouch-hid.conf); give the seated user "
        f"access with the udev rule `{UINPUT_RULE}`: {RULES_INSTALL}; then log out and in. "
        f"Check with: neurotouch-hid doctor"
    )
