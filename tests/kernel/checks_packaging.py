"""Guest checks of udev/60-neurotouch.rules and the doctor against real udev and a real USB device.

The camera is emulated with the kernel's USB gadget stack: dummy_hcd (a virtual host and device
controller pair) and a configfs gadget with the DAVIS-346's ids 152a:841a. udev then sees a USB
device exactly as when the camera is plugged in, so the rules' camera line, the /dev/neurotouch
name, the plug-and-play properties and the doctor's USB checks are all exercised.
Run by tests/kernel/guest.py; asserted on by tests/test_kernel.py.
"""

from __future__ import annotations

import os
from pathlib import Path

import guestlib

from neurotouch_hid.service import doctor
from neurotouch_hid.sources.discovery import discover

TIMEOUT_S = 300
GADGET = Path("/sys/kernel/config/usb_gadget/neurotouch")


def _plug_camera() -> str:
    """Create (the first time) and bind the emulated camera; return its /sys/bus/usb/devices path.

    Also used by checks_devices.py: plugging again after :func:`_unplug_camera` rebinds the same
    gadget."""
    for module in ("dummy_hcd", "libcomposite", "usb_f_ss_lb"):
        assert guestlib.sh(["modprobe", module]).returncode == 0, f"modprobe {module} failed"
    if not Path("/sys/kernel/config/usb_gadget").exists():
        guestlib.sh(["mount", "-t", "configfs", "none", "/sys/kernel/config"])
    if not GADGET.exists():
        _make_gadget()
    udc = sorted(os.listdir("/sys/class/udc"))
    assert udc, "no USB device controller (dummy_udc) to bind the gadget to"
    (GADGET / "UDC").write_text(udc[0])

    def find() -> str | None:
        for dev in Path("/sys/bus/usb/devices").iterdir():
            vid = dev / "idVendor"
            if vid.exists() and vid.read_text().strip() == "152a":
                return str(dev)
        return None

    path = guestlib.wait_for(find, timeout_s=20)
    assert path, "the emulated camera never appeared on the USB bus"
    guestlib.settle()
    return path


def _make_gadget() -> None:
    """The configfs gadget: ids 152a:841a, DAVIS-like strings, one SourceSink function."""
    GADGET.mkdir()
    (GADGET / "idVendor").write_text("0x152a")
    (GADGET / "idProduct").write_text("0x841a")
    strings = GADGET / "strings" / "0x409"
    strings.mkdir()
    (strings / "manufacturer").write_text("iniVation")
    (strings / "product").write_text("DAVIS346 (emulated by dummy_hcd)")
    (strings / "serialnumber").write_text("00000001")
    config = GADGET / "configs" / "c.1"
    config.mkdir()
    function = GADGET / "functions" / "SourceSink.0"
    function.mkdir()
    (config / "SourceSink.0").symlink_to(function)


def _unplug_camera() -> None:
    (GADGET / "UDC").write_text("\n")
    guestlib.settle()


def check_camera_plug_and_play() -> dict:
    """Plugging in a 152a:841a device: uaccess + systemd tags, SYSTEMD_USER_WANTS, /dev/neurotouch;
    the doctor finds it and may open it; unplugging removes /dev/neurotouch again."""
    sysdev = _plug_camera()
    try:
        bus, dev = (int(Path(sysdev, n).read_text()) for n in ("busnum", "devnum"))
        node = f"/dev/bus/usb/{bus:03d}/{dev:03d}"
        props = guestlib.udev_properties(node)
        tags = props.get("CURRENT_TAGS", "").strip(":").split(":")
        assert "uaccess" in tags and "systemd" in tags, f"tags {tags}: {props}"
        assert "neurotouch-hid.service" in props.get("SYSTEMD_USER_WANTS", "").split(), props
        assert props.get("ID_NEUROTOUCH_CAMERA") == "1", props
        assert os.path.realpath("/dev/neurotouch") == node, (
            f"/dev/neurotouch -> {os.path.realpath('/dev/neurotouch')}, camera is {node}"
        )
        mode = os.stat(node).st_mode & 0o777
        assert not mode & 0o002, f"{node} is world-writable: {oct(mode)}"
        found = discover(dv=False)  # dv-processing's view: checks_devices.py
        checks = [
            doctor.check_camera(found),
            doctor.check_camera_access(found),
            doctor.check_uinput(),
            doctor.check_rules(),
        ]
        assert all(c.status == doctor.OK for c in checks), checks
        plugged = {
            "node": node,
            "mode": oct(mode),
            "tags": tags,
            "SYSTEMD_USER_WANTS": props["SYSTEMD_USER_WANTS"],
            "doctor": {c.name: f"{c.status}: {c.detail}" for c in checks},
        }
    finally:
        _unplug_camera()
    gone = guestlib.wait_for(lambda: not os.path.lexists("/dev/neurotouch"), timeout_s=10)
    assert gone, "/dev/neurotouch still there after unplugging"
    after = doctor.check_camera(discover(dv=False))
    assert after.status == doctor.FAIL, after
    return {**plugged, "after_unplug": f"{after.status}: {after.detail}"}
