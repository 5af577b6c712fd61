"""Camera discovery (sources/discovery.py, sources/usb_probe.py) and ``neurotouch-hid devices``.

This machine has no USB camera: the real pyusb and dv-processing scans are checked to find none,
and ``devices`` to say so with exit code 1. The merging and diagnosis logic is checked on small
stand-ins for pyusb devices, sysfs and dv-processing records. The real thing (an emulated
152a:841a device in a real kernel, as root, busy, and as an unprivileged user) is in
tests/kernel/checks_devices.py.
"""

from __future__ import annotations

import errno
import json
import os
import subprocess
import sys
from types import SimpleNamespace

import pytest
import usb.core
import usb.util
from helpers import run_cli

from neurotouch_hid.service.udev import RULES_INSTALL
from neurotouch_hid.sources import discovery, usb_probe
from neurotouch_hid.sources.discovery import CameraStatus, Discovery, DvCamera, explain, merge
from neurotouch_hid.sources.usb_probe import UsbAccess, UsbCamera


def usb_cam(bus=1, address=5, access=UsbAccess.OK, reason="", serial="00000123", holders=()) -> UsbCamera:
    return UsbCamera(
        bus=bus,
        address=address,
        node=usb_probe.node_path(bus, address),
        port=f"{bus}-1",
        serial=serial,
        product="DAVIS346",
        manufacturer="iniVation",
        speed_mbps=5000.0,
        access=access,
        reason=reason,
        holders=holders,
    )


def dv_cam(bus=1, address=5, serial="00000123", pid=0x841A, model="DAVIS") -> DvCamera:
    return DvCamera(serial=serial, model=model, device_type="FX3_MB", firmware=6, bus=bus, address=address, pid=pid)


# --- the real scans on this machine (no camera) --------------------------------------------------
def test_real_scans_find_no_camera_here():
    assert usb_probe.find_cameras() == []  # pyusb + libusb-package's libusb
    assert usb_probe.usb_cameras() == []
    assert discovery.dv_cameras() == []  # dv_processing.io.camera.discover()
    found = discovery.discover()
    assert found == Discovery((), None, None, ())
    assert found.ready == [] and found.davis346 == []


def test_explain_no_camera_here_says_plug_it_in_and_lsusb():
    message = discovery.explain_no_camera()
    assert message.startswith("no DAVIS-346 (USB 152a:841a) found: plug")
    assert "lsusb -d 152a:841a" in message and "\n" not in message


def test_cli_devices_without_a_camera_says_so_and_exits_1():
    proc = run_cli("devices", columns=200)
    assert proc.returncode == 1, proc.stdout + proc.stderr
    assert "no DAVIS-346 (USB 152a:841a) found" in proc.stdout and "lsusb -d 152a:841a" in proc.stdout
    assert "Traceback" not in proc.stderr


def test_cli_devices_json_without_a_camera():
    proc = run_cli("devices", "--json")
    assert proc.returncode == 1, proc.stdout + proc.stderr
    data = json.loads(proc.stdout)
    assert data["cameras"] == [] and data["ready"] == 0
    assert data["usb_error"] is None and data["dv_error"] is None
    assert data["message"].startswith("no DAVIS-346 (USB 152a:841a) found")


# --- merging the two views, and the verdicts ---------------------------------------------------
def test_accessible_and_listed_by_dv_is_ready():
    found = merge([usb_cam()], [dv_cam()])
    (camera,) = found.cameras
    assert camera.status == CameraStatus.READY and camera.ready and camera.problem == "" and found.ready == [camera]
    assert camera.dv.firmware == 6 and camera.node == "/dev/bus/usb/001/005"
    assert camera.label() == "DAVIS-346 at bus 1 device 5 (/dev/bus/usb/001/005), serial 00000123"
    assert found.summary() == found.to_json()["message"] == f"ready: {camera.label()}"


def test_records_are_matched_by_bus_and_address():
    found = merge([usb_cam(1, 5, serial="A"), usb_cam(3, 2, serial="B")], [dv_cam(3, 2, serial="B")])
    assert [(c.bus, c.address, c.status) for c in found.cameras] == [
        (1, 5, CameraStatus.NOT_IN_DV),
        (3, 2, CameraStatus.READY),
    ]


def test_permission_denied_without_rules_says_install_the_udev_rule():
    reason = "permission denied: /dev/bus/usb/001/005 is crw-rw-r-- root:root, this user is bob (uid 1000)"
    found = merge([usb_cam(access=UsbAccess.DENIED, reason=reason)], [dv_cam(serial="")], rules=None)
    (camera,) = found.cameras
    assert camera.status == CameraStatus.NO_ACCESS and not found.ready
    assert (
        camera.problem
        == f"DAVIS-346 at bus 1 device 5 (/dev/bus/usb/001/005), serial 00000123 is not accessible ({reason})"
    )
    assert (
        camera.fix
        == f"install the udev rule (60-neurotouch.rules):\n{RULES_INSTALL}\nthen unplug and replug the camera"
    )
    assert camera.serial == "00000123"  # dv-processing could not read it (empty): the USB string


def test_permission_denied_with_rules_installed_explains_uaccess():
    found = merge(
        [usb_cam(access=UsbAccess.DENIED, reason="permission denied")],
        [],
        rules="/etc/udev/rules.d/60-neurotouch.rules",
    )
    fix = found.cameras[0].fix
    assert "(/etc/udev/rules.d/60-neurotouch.rules)" in fix and "uaccess" in fix and "not over SSH" in fix
    assert 'GROUP="plugdev", MODE="0660"' in fix


def test_busy_names_the_holder_and_the_service():
    found = merge(
        [
            usb_cam(
                access=UsbAccess.BUSY,
                reason="in use by another program (PID 42 (neurotouch-hid))",
                holders=("PID 42 (neurotouch-hid)",),
            )
        ],
        [dv_cam()],
    )
    camera = found.cameras[0]
    assert camera.status == CameraStatus.BUSY and "PID 42 (neurotouch-hid)" in camera.problem
    assert "systemctl --user stop neurotouch-hid.service" in camera.fix


@pytest.mark.parametrize(
    "access,status,words",
    [
        (UsbAccess.GONE, CameraStatus.GONE, "plug it in again"),
        (UsbAccess.ERROR, CameraStatus.ERROR, "dmesg"),
    ],
)
def test_gone_and_error(access, status, words):
    camera = merge([usb_cam(access=access, reason="x")], None).cameras[0]
    assert camera.status == status and words in camera.fix


def test_accessible_but_not_listed_by_dv_points_at_firmware():
    camera = merge([usb_cam()], []).cameras[0]
    assert camera.status == CameraStatus.NOT_IN_DV and "dv-processing does not list it" in camera.problem
    assert "firmware" in camera.fix and "replug" in camera.fix


def test_dv_processing_unavailable():
    camera = merge([usb_cam()], None, dv_error="dv-processing cannot be imported").cameras[0]
    assert camera.status == CameraStatus.DV_UNAVAILABLE and "cannot be imported" in camera.problem
    assert "pip install --upgrade dv-processing" in camera.fix


def test_other_dv_cameras_are_listed_but_are_not_davis346():
    found = merge([], [dv_cam(4, 9, pid=0x8419, model="DVXPLORER")])
    (camera,) = found.cameras
    assert camera.status == CameraStatus.OTHER_CAMERA and not camera.is_davis346 and found.davis346 == []
    assert camera.label().startswith("DVXPLORER camera at bus 4 device 9") and "152a:8419" in camera.problem
    assert "dv-processing sees only: DVXPLORER camera" in explain(found)


def test_without_pyusb_dv_processing_alone_is_believed():
    found = merge(None, [dv_cam()], usb_error="cannot list USB devices: x")
    assert [c.status for c in found.cameras] == [CameraStatus.READY] and found.cameras[0].usb is None
    assert (
        merge(None, [], usb_error="x")
        .to_json()["message"]
        .startswith("no DAVIS-346 found, and pyusb cannot list USB devices (x)")
    )


def test_to_json_is_json():
    found = merge(
        [usb_cam(access=UsbAccess.BUSY, reason="r", holders=("PID 1 (a)",)), usb_cam(2, 3)],
        [dv_cam(2, 3)],
        dv_log=["libusb: error"],
    )
    data = json.loads(json.dumps(found.to_json()))
    assert data["ready"] == 1 and data["dv_log"] == ["libusb: error"]
    assert data["cameras"][0]["usb"]["holders"] == ["PID 1 (a)"] and data["cameras"][0]["dv"] is None
    assert data["cameras"][1]["dv"]["firmware"] == 6 and data["cameras"][1]["status"] == CameraStatus.READY


# --- explain: the one line for the live source --------------------------------------------------
def test_explain_talks_about_the_most_usable_camera():
    found = merge([usb_cam(1, 5, access=UsbAccess.DENIED, reason="permission denied"), usb_cam(1, 6)], [])
    message = explain(found)
    assert message.startswith("DAVIS-346 at bus 1 device 6") and "dv-processing does not list it" in message
    assert message.endswith("(1 more found: see `neurotouch-hid devices`)")


def test_explain_not_accessible_gives_the_udev_rule():
    found = merge([usb_cam(access=UsbAccess.DENIED, reason="permission denied")], [])
    assert explain(found) == (
        f"DAVIS-346 at bus 1 device 5 (/dev/bus/usb/001/005), serial 00000123 is not "
        f"accessible (permission denied)\ninstall the udev rule (60-neurotouch.rules):\n{RULES_INSTALL}\nthen "
        f"unplug and replug the camera"
    )


def test_explain_ready_camera_with_the_open_error():
    found = merge([usb_cam()], [dv_cam()])
    assert "is another program using it?" in explain(found)
    message = explain(found, error="Device firmware version incorrect. You have version 1; but version 6 is required.")
    assert "opening it failed: Device firmware version incorrect" in message


def test_explain_with_a_serial_number():
    found = merge([usb_cam(serial="AAA")], [dv_cam(serial="AAA")])
    assert "is accessible and listed" in explain(found, serial="AAA")
    assert explain(found, serial="BBB").startswith("no DAVIS-346 with serial number BBB; found DAVIS-346 at bus 1")


def test_explain_no_camera_never_raises(monkeypatch):
    def broken(dv=True):
        raise OSError("boom")

    monkeypatch.setattr(discovery, "discover", broken)
    message = discovery.explain_no_camera()
    assert "OSError while looking: boom" in message and "neurotouch-hid doctor" in message


# --- the pyusb probe, on a fake device, fake sysfs and a stand-in node -------------------------
@pytest.fixture
def fake_usb(tmp_path, monkeypatch):
    """A device at bus 2 address 7: sysfs folder 2-1 with its strings, a node file, claim/dispose
    recorded (``calls``); ``state.claim_error`` makes claiming raise."""
    sysfs = tmp_path / "sys"
    dev = sysfs / "2-1"
    dev.mkdir(parents=True)
    for name, value in (
        ("busnum", "2"),
        ("devnum", "7"),
        ("serial", "00000042"),
        ("product", "DAVIS346"),
        ("manufacturer", "iniVation"),
        ("speed", "5000"),
    ):
        (dev / name).write_text(value + "\n")
    node = tmp_path / "node"
    node.write_text("")
    monkeypatch.setattr(usb_probe, "_SYSFS_USB", sysfs)
    monkeypatch.setattr(usb_probe, "node_path", lambda bus, address: str(node))
    state = SimpleNamespace(calls=[], claim_error=None, sysfs=dev, node=str(node))

    def claim(device, interface):
        state.calls.append(("claim", interface))
        if state.claim_error is not None:
            raise state.claim_error

    monkeypatch.setattr(usb.util, "claim_interface", claim)
    monkeypatch.setattr(usb.util, "dispose_resources", lambda device: state.calls.append(("dispose",)))
    state.device = SimpleNamespace(bus=2, address=7, port_numbers=(1,), iSerialNumber=3, iProduct=2, iManufacturer=1)
    return state


def test_probe_ok_reads_sysfs_and_claims_then_releases(fake_usb):
    cam = usb_probe.probe_usb(fake_usb.device)
    assert cam == UsbCamera(
        bus=2,
        address=7,
        node=fake_usb.node,
        port="2-1",
        serial="00000042",
        product="DAVIS346",
        manufacturer="iniVation",
        speed_mbps=5000.0,
        access=UsbAccess.OK,
    )
    assert fake_usb.calls == [("claim", 0), ("dispose",)]


def test_probe_unreadable_node_is_denied_without_opening(fake_usb, monkeypatch):
    monkeypatch.setattr(usb_probe.os, "access", lambda path, mode: False)
    cam = usb_probe.probe_usb(fake_usb.device)
    assert cam.access == UsbAccess.DENIED and cam.serial == "00000042"  # strings from sysfs all the same
    assert cam.reason.startswith(f"permission denied: {fake_usb.node} is -rw-") and f"uid {os.getuid()}" in cam.reason
    assert fake_usb.calls == []


def test_probe_libusb_access_error_is_denied(fake_usb):
    fake_usb.claim_error = usb.core.USBError("Access denied (insufficient permissions)", -3, errno.EACCES)
    cam = usb_probe.probe_usb(fake_usb.device)
    assert cam.access == UsbAccess.DENIED and "Access denied" in cam.reason
    assert fake_usb.calls[-1] == ("dispose",)


def test_probe_busy_names_the_process_holding_the_node(fake_usb):
    fake_usb.claim_error = usb.core.USBError("Resource busy", -6, errno.EBUSY)
    holder = subprocess.Popen(
        [sys.executable, "-c", f"import time; f = open({fake_usb.node!r}); print(1, flush=True); time.sleep(60)"],
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert holder.stdout.readline().strip() == "1"
        cam = usb_probe.probe_usb(fake_usb.device)
    finally:
        holder.kill()
        holder.wait()
    assert cam.access == UsbAccess.BUSY and len(cam.holders) == 1, cam
    assert cam.holders[0].startswith(f"PID {holder.pid} (")
    assert cam.reason == f"in use by another program ({cam.holders[0]})"


def test_probe_busy_by_a_kernel_driver(fake_usb, tmp_path):
    fake_usb.claim_error = usb.core.USBError("Resource busy", -6, errno.EBUSY)
    (tmp_path / "drivers" / "usbtest").mkdir(parents=True)
    (fake_usb.sysfs / "2-1:1.0").mkdir()
    (fake_usb.sysfs / "2-1:1.0" / "driver").symlink_to(tmp_path / "drivers" / "usbtest")
    cam = usb_probe.probe_usb(fake_usb.device)
    assert cam.access == UsbAccess.BUSY and cam.reason == "the kernel driver usbtest holds its interface 0"
    assert "unbind that driver" in merge([cam], []).cameras[0].fix


def test_probe_other_libusb_error(fake_usb):
    fake_usb.claim_error = usb.core.USBError("Input/Output Error", -1, errno.EIO)
    cam = usb_probe.probe_usb(fake_usb.device)
    assert cam.access == UsbAccess.ERROR and "Input/Output Error" in cam.reason


def test_probe_unplugged_meanwhile_is_gone(fake_usb, tmp_path):
    os.remove(fake_usb.node)
    for f in fake_usb.sysfs.iterdir():
        f.unlink()
    fake_usb.sysfs.rmdir()
    cam = usb_probe.probe_usb(fake_usb.device)
    assert cam.access == UsbAccess.GONE and cam.port == "2-1"  # from pyusb's port numbers
    assert cam.serial is None


def test_sysfs_attributes_are_read_within_a_page_and_a_bad_one_is_no_value(fake_usb):
    """sysfs is read through the bounded reader: an attribute longer than the page the kernel
    serves (a link to a large file in a tampered tree), not UTF-8, or missing is no value; a
    folder whose busnum is no number, or is too long, is passed over."""
    with open(fake_usb.sysfs / "serial", "wb") as fh:
        fh.truncate(8 << 20)  # 8 MB (sparse): read whole, it would be an 8 MB serial number
    (fake_usb.sysfs / "product").write_bytes(b"\xffDAVIS\n")
    (fake_usb.sysfs / "speed").unlink()
    for name, busnum in (("1-1", b"two\n"), ("1-2", b"2" * 5000)):
        other = fake_usb.sysfs.parent / name
        other.mkdir()
        (other / "busnum").write_bytes(busnum)
        (other / "devnum").write_bytes(b"7\n")
    fake_usb.device.iSerialNumber = fake_usb.device.iProduct = 0  # no strings from the device itself
    cam = usb_probe.probe_usb(fake_usb.device)
    assert cam.port == "2-1" and cam.access == UsbAccess.OK  # found, past the two bad folders
    assert (cam.serial, cam.product, cam.manufacturer, cam.speed_mbps) == (None, None, "iniVation", None)


# --- dv-processing's stderr --------------------------------------------------------------------
def test_native_stderr_is_captured_once_per_line():
    lines: list[str] = []
    with discovery._stderr_into(lines):
        os.write(2, b"libusb: error [get_usbfs_fd] libusb couldn't open USB device\n")
        os.write(2, b"libusb: error [get_usbfs_fd] libusb couldn't open USB device\n\n")
        os.write(2, b"libusb requires write access to USB device nodes\n")
    assert lines == [
        "libusb: error [get_usbfs_fd] libusb couldn't open USB device",
        "libusb requires write access to USB device nodes",
    ]


def test_dv_cameras_converts_descriptors_and_captures_its_log(monkeypatch):
    import dv_processing as dv

    def fake_discover():
        os.write(2, b"libusb: error [get_usbfs_fd] libusb requires write access to USB device nodes\n")
        os.write(
            2, b"[ERROR] usb_discovery: libusb: error [get_usbfs_fd] libusb requires write access to USB device nodes\n"
        )
        return [
            SimpleNamespace(
                serialNumber="",
                cameraModel=dv.io.camera.CameraModel.DAVIS,
                deviceType=dv.io.camera.USBDeviceType.FX3_MB,
                firmwareVersion=6,
                busNumber=1,
                devAddress=5,
                pid=0x841A,
            )
        ]

    monkeypatch.setattr(dv.io.camera, "discover", fake_discover)
    log: list[str] = []
    assert discovery.dv_cameras(log) == [DvCamera("", "DAVIS", "FX3_MB", 6, 1, 5, 0x841A)]
    assert log == ["libusb: error [get_usbfs_fd] libusb requires write access to USB device nodes"]


def test_dv_cameras_error_is_a_device_error(monkeypatch):
    import dv_processing as dv

    def broken():
        raise RuntimeError("/project/x.hpp(1): f()\nRuntimeError: libusb init failed\n")

    monkeypatch.setattr(dv.io.camera, "discover", broken)
    with pytest.raises(discovery.DeviceError, match="dv-processing cannot list cameras"):
        discovery.dv_cameras()
    assert discovery.discover().dv_error.startswith("dv-processing cannot list cameras")


def test_discover_without_dv_says_it_was_not_asked(monkeypatch):
    import dv_processing as dv

    asked = []
    monkeypatch.setattr(dv.io.camera, "discover", lambda: asked.append(1) or [])
    found = discovery.discover(dv=False)
    assert found.dv_error == "not asked (pyusb only)" and found.cameras == ()
    assert not asked  # dv-processing's search (seconds with cameras on USB) is not made
