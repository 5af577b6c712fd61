"""``neurotouch-hid doctor``: is this machine ready to run the driver? Each failure comes with its fix.

Checks: the DAVIS-346 is on USB (pyusb with libusb-package's bundled libusb), its
/dev/bus/usb node is readable and writable, /dev/uinput exists and is writable, the udev rules are
installed, dv-processing / numba / evdev import (with versions), and (a warning only) the
plug-and-play systemd user unit is installed.
"""

from __future__ import annotations

import importlib
import importlib.metadata
import os
from dataclasses import dataclass
from pathlib import Path

from rich.console import Console
from rich.table import Table

from neurotouch_hid.errors import DeviceError
from neurotouch_hid.output.gamepad import RULES_INSTALL, uinput_help, uinput_problem

#: USB ids of the DAVIS-346 (iniVation).
CAMERA_VID, CAMERA_PID = 0x152A, 0x841A
RULES_NAME = "60-neurotouch.rules"
#: Where udev reads rules from (udev(7)), most specific first.
RULES_DIRS = ("/etc/udev/rules.d", "/run/udev/rules.d", "/usr/lib/udev/rules.d", "/lib/udev/rules.d")
SERVICE_NAME = "neurotouch-hid.service"
#: (import name, distribution name) of the libraries the driver needs at run time.
LIBRARIES = (("dv_processing", "dv-processing"), ("numba", "numba"), ("evdev", "evdev"))

OK, FAIL, WARN, SKIP = "ok", "fail", "warn", "skip"


@dataclass(frozen=True)
class Check:
    """One line of the report. ``status``: ok, fail (exit code 1), warn or skip (do not fail)."""

    name: str
    status: str
    detail: str
    fix: str = ""


def find_cameras() -> list:
    """The DAVIS-346 devices on USB (pyusb ``usb.core.Device`` objects; empty list if none).

    Raises DeviceError when pyusb has no usable libusb backend."""
    import libusb_package
    import usb.core

    backend = libusb_package.get_libusb1_backend()
    if backend is None:
        raise DeviceError("libusb-package has no libusb for this platform: pip install --force-reinstall libusb-package")
    try:
        return list(usb.core.find(idVendor=CAMERA_VID, idProduct=CAMERA_PID, find_all=True, backend=backend))
    except usb.core.USBError as exc:
        raise DeviceError(f"cannot list USB devices: {exc}") from None


def usb_node(device) -> str:
    """The /dev/bus/usb/BBB/DDD node of a pyusb device (what libusb opens)."""
    return f"/dev/bus/usb/{device.bus:03d}/{device.address:03d}"


def check_camera(cameras: list | None) -> Check:
    """``cameras`` from :func:`find_cameras`, or None when listing failed."""
    if cameras is None:
        return Check("camera on USB", FAIL, "pyusb cannot list USB devices",
                     "python3 -m pip install --force-reinstall pyusb libusb-package")
    if not cameras:
        return Check("camera on USB", FAIL, f"no DAVIS-346 ({CAMERA_VID:04x}:{CAMERA_PID:04x}) on USB",
                     f"plug the NeuroTouch's USB cable in (a USB 3 port); `lsusb -d "
                     f"{CAMERA_VID:04x}:{CAMERA_PID:04x}` must list it")
    where = ", ".join(f"bus {d.bus} device {d.address}" for d in cameras)
    return Check("camera on USB", OK, f"DAVIS-346 at {where}")


def check_camera_access(cameras: list | None) -> Check:
    """Read/write permission on each camera's /dev/bus/usb node (skip when there is no camera)."""
    if not cameras:
        return Check("camera permissions", SKIP, "no camera to check")
    denied = [usb_node(d) for d in cameras if not os.access(usb_node(d), os.R_OK | os.W_OK)]
    if denied:
        return Check("camera permissions", FAIL, f"no read/write access to {', '.join(denied)} (uid {os.getuid()})",
                     f"install the udev rules ({RULES_INSTALL}), then unplug and replug the camera")
    return Check("camera permissions", OK, ", ".join(usb_node(d) for d in cameras) + " readable and writable")


def check_uinput(devnode: str = "/dev/uinput") -> Check:
    """/dev/uinput exists, is a character device and is writable (see output/gamepad.py)."""
    problem = uinput_problem(devnode)
    if problem:
        return Check("virtual gamepad (uinput)", FAIL, problem, uinput_help(devnode))
    return Check("virtual gamepad (uinput)", OK, f"{devnode} is writable")


def check_rules(dirs: tuple[str, ...] = RULES_DIRS) -> Check:
    """The project's udev rules file is in one of udev's rules folders."""
    found = [str(Path(d) / RULES_NAME) for d in dirs if (Path(d) / RULES_NAME).is_file()]
    if found:
        return Check("udev rules", OK, found[0])
    return Check("udev rules", FAIL, f"{RULES_NAME} is not in {', '.join(dirs)}", RULES_INSTALL)


def check_library(module: str, dist: str) -> Check:
    """``module`` imports; the detail is its distribution's version."""
    try:
        importlib.import_module(module)
    except Exception as exc:  # an ImportError, or a broken native library underneath
        return Check(dist, FAIL, f"import {module} failed: {type(exc).__name__}: {exc}",
                     f"python3 -m pip install --upgrade {dist}")
    try:
        version = importlib.metadata.version(dist)
    except importlib.metadata.PackageNotFoundError:
        version = "version unknown"
    return Check(dist, OK, version)


def check_service(home: Path | None = None) -> Check:
    """The plug-and-play systemd user unit is installed (a warning only: `run` works without)."""
    home = home or Path.home()
    dirs = (home / ".config/systemd/user", Path("/etc/systemd/user"), Path("/usr/lib/systemd/user"))
    found = [str(d / SERVICE_NAME) for d in dirs if (d / SERVICE_NAME).is_file()]
    if found:
        return Check("plug-and-play service", OK, found[0])
    return Check("plug-and-play service", WARN, f"{SERVICE_NAME} is not installed (start by hand with "
                 "`neurotouch-hid run`)", "packaging/install.sh --user")


def run_checks() -> list[Check]:
    """Every check, in the order the report shows them."""
    try:
        cameras: list | None = find_cameras()
    except DeviceError:
        cameras = None
    return [check_camera(cameras), check_camera_access(cameras), check_uinput(), check_rules(),
            *(check_library(m, d) for m, d in LIBRARIES), check_service()]


def report(checks: list[Check], console: Console) -> int:
    """Print the checks as a rich table; return the exit code (1 if any check failed, else 0)."""
    style = {OK: "green", FAIL: "bold red", WARN: "yellow", SKIP: "dim"}
    table = Table(title="neurotouch-hid doctor", show_lines=True)
    for column in ("check", "status", "detail", "fix"):
        table.add_column(column, overflow="fold")
    for c in checks:
        table.add_row(c.name, f"[{style[c.status]}]{c.status}[/]", c.detail, c.fix)
    console.print(table)
    failed = [c.name for c in checks if c.status == FAIL]
    console.print(f"[bold red]{len(failed)} problem(s):[/] {', '.join(failed)}" if failed
                  else "[green]all checks passed[/]")
    return 1 if failed else 0
