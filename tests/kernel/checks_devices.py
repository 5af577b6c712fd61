"""Guest checks of ``neurotouch-hid devices`` (sources/discovery.py) against a real kernel's USB stack.

The camera is the emulated one of checks_packaging.py (dummy_hcd + a configfs gadget with the
DAVIS-346's ids 152a:841a; it speaks the kernel's SourceSink test protocol, not the DAVIS one).
The camera is plugged in once, and the command runs as a process of its own, with a timeout, as
the unprivileged user nobody (present but not accessible: the udev-rule fix). While this process
holds the camera's interface, the discovery finds it busy, and who holds it. What dv-processing
makes of a device with the camera's ids that is no DAVIS, asked to open it, is recorded, in a
process of its own too. ``devices`` as root on a camera that dv-processing opens is checked on the
emulated DAVIS-346 (checks_davis.py, part "devices"). Under software emulation every Python start
takes tens of seconds, so those processes are forks of this one (``guestlib.forked``): this
process never opens a USB context itself, which a fork could not share. Each part's verdict is
kept on its own.
Run by tests/kernel/guest.py; asserted on by tests/test_kernel.py.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import guestlib
from checks_packaging import _plug_camera, _unplug_camera

TIMEOUT_S = 600
#: Per command: dv-processing takes ~10 s to import under software emulation, minutes on a loaded
#: host.
COMMAND_TIMEOUT_S = 300
#: The environment of each command's process.
COMMAND_ENV = {"HOME": "/tmp", "COLUMNS": "200"}
RULES = Path("/run/udev/rules.d/60-neurotouch.rules")  # where guest.py's setup installs them


def _open_first_camera() -> dict[str, str]:
    """What dv-processing says when it is asked to open the first camera it finds (the emulated
    one), through explain_no_camera: ``{"OPENED": name}`` or ``{"ERROR": ..., "EXPLAIN": ...}``."""
    import dv_processing as dv

    from neurotouch_hid.sources.discovery import explain_no_camera
    from neurotouch_hid.sources.dv import DV_ERRORS, dv_error_text

    found = dv.io.camera.discover()
    try:
        camera = dv.io.camera.open(found[0])
        return {"OPENED": camera.getCameraName()}
    except DV_ERRORS as exc:
        return {"ERROR": dv_error_text(str(exc)), "EXPLAIN": explain_no_camera(error=dv_error_text(str(exc)))}


def _devices_json(as_nobody: bool = False) -> tuple[int, dict]:
    """``neurotouch-hid devices --json`` in a process of its own (as nobody when ``as_nobody``):
    its exit code and JSON."""
    code, out, err = guestlib.forked(
        lambda: guestlib.cli_in_process("devices", "--json"),
        as_nobody=as_nobody,
        env=COMMAND_ENV,
        timeout_s=COMMAND_TIMEOUT_S,
    )
    try:
        return code, json.loads(out)
    except ValueError:
        raise AssertionError(f"devices --json printed no JSON (exit {code}): {out[-2000:]}\n{err[-2000:]}") from None


def _node(sysdev: str) -> tuple[int, int, str]:
    bus, dev = (int(Path(sysdev, n).read_text()) for n in ("busnum", "devnum"))
    return bus, dev, f"/dev/bus/usb/{bus:03d}/{dev:03d}"


def _only_camera(data: dict, node: str) -> dict:
    assert len(data["cameras"]) == 1, data
    camera = data["cameras"][0]
    assert camera["node"] == node and camera["usb"] is not None, camera
    assert camera["usb"]["serial"] == "00000001" and "DAVIS346" in camera["usb"]["product"], camera
    return camera


def _dv_open(bus: int, address: int, node: str) -> dict:
    """dv-processing asked to open the emulated camera (it is no DAVIS: it refuses it) and the line
    explain_no_camera(error=...) makes of its error; in a process of its own, with a timeout."""
    lines = guestlib.forked(_open_first_camera, env=COMMAND_ENV, timeout_s=COMMAND_TIMEOUT_S)
    assert "OPENED" in lines or "EXPLAIN" in lines, lines
    if "EXPLAIN" in lines:
        assert lines["EXPLAIN"].startswith(f"DAVIS-346 at bus {bus} device {address} ({node})"), lines
        assert f"opening it failed: {lines['ERROR']}" in lines["EXPLAIN"], lines
    return {"dv_open": lines}


#: usbfs ioctl USBDEVFS_CLAIMINTERFACE, _IOR('U', 15, unsigned int) (linux/usbdevice_fs.h).
USBDEVFS_CLAIMINTERFACE = 0x8004550F


def _busy(bus: int, address: int, node: str) -> dict:
    """While another process holds the camera's interface 0 (a forked child claims it through
    usbfs, as libusb does; a fork, because a new interpreter takes tens of seconds to start under
    emulation): busy, and which process."""
    import fcntl
    import struct

    from neurotouch_hid.sources.discovery import discover

    ready_r, ready_w = os.pipe()
    done_r, done_w = os.pipe()
    child = os.fork()
    if child == 0:  # the holder: claim, say so, wait until told (or the parent is gone), exit
        try:
            os.close(ready_r)
            os.close(done_w)
            fd = os.open(node, os.O_RDWR)
            fcntl.ioctl(fd, USBDEVFS_CLAIMINTERFACE, struct.pack("I", 0))
            os.write(ready_w, b"1")
            os.read(done_r, 1)
        finally:
            os._exit(0)
    os.close(ready_w)  # a child that fails closes its end: the read below then returns b""
    os.close(done_r)
    try:
        assert os.read(ready_r, 1) == b"1", "the child could not claim the camera's interface"
        found = discover(dv=False)
    finally:
        os.close(done_w)  # tells the child to exit
        os.close(ready_r)
        os.waitpid(child, 0)
    assert len(found.cameras) == 1, found.to_json()
    camera = found.cameras[0].to_json()
    assert camera["node"] == node and camera["status"] == "busy" and camera["usb"]["access"] == "busy", camera
    assert f"PID {child} " in camera["problem"], camera
    assert "neurotouch-hid.service" in camera["fix"], camera
    return {"camera": camera, "holder_pid": child}


def _unprivileged(bus: int, address: int, node: str) -> dict:
    """As the user nobody, without the rules file installed: present but not accessible, and the fix
    is to install the udev rule (with the rule installed the fix explains uaccess instead: a
    unit test on the host covers that wording)."""
    aside = RULES.with_name(RULES.name + ".aside")
    with guestlib.python_readable_by_all():
        RULES.rename(aside)
        try:
            code, data = _devices_json(as_nobody=True)
        finally:
            aside.rename(RULES)
    camera = _only_camera(data, node)
    assert code == 1 and data["ready"] == 0, data
    assert camera["status"] == "no-access" and camera["usb"]["access"] == "denied", camera
    assert "permission denied" in camera["problem"] and "uid 65534" in camera["problem"], camera
    first, command = camera["fix"].splitlines()[:2]
    assert first == "install the udev rule (60-neurotouch.rules):", camera
    assert command.startswith("sudo sh /") and command.endswith("/install.sh --system"), camera
    assert data["message"].startswith(f"DAVIS-346 at bus {bus} device {address}"), data
    return {"exit_code": code, "camera": camera, "message": data["message"], "dv_log": data["dv_log"]}


PARTS = {"dv_open": _dv_open, "busy": _busy, "unprivileged": _unprivileged}


def check_devices() -> dict:
    """The emulated camera plugged in once; every part of PARTS on it. Returns, per part,
    ``{"ok": True, "details": ...}`` or ``{"ok": False, "error": ...}`` (a failing part does not hide
    the others); fails only when the camera cannot be plugged in."""
    import traceback

    sysdev = _plug_camera()
    results = {}
    try:
        bus, address, node = _node(sysdev)
        for name, part in PARTS.items():
            try:
                results[name] = {"ok": True, "details": part(bus, address, node)}
            except Exception as exc:  # noqa: BLE001 - recorded for the host-side test of that part
                results[name] = {
                    "ok": False,
                    "error": f"{type(exc).__name__}: {exc}",
                    "traceback": traceback.format_exc()[-3000:],
                }
    finally:
        _unplug_camera()
    return results
