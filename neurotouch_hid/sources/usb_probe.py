"""Which USB devices 152a:841a (DAVIS-346) are on the bus, and whether this user can open each.

The USB bus as **pyusb** (with libusb-package's bundled libusb) sees it: every USB device
152a:841a, whether or not this user may open it. For each: bus, address, its
``/dev/bus/usb/BBB/DDD`` node, the serial/product strings (from sysfs, which anyone may read,
through the bounded reader of ``limits.py``; else from the device when it can be opened), and an
access verdict: the node is readable and writable, and interface 0 can be claimed (then released
at once: nothing is sent to the camera). When not: permission denied (the fix: the udev rule),
busy (another program, or a kernel driver, holds the interface; /proc says which program), gone.

:mod:`neurotouch_hid.sources.discovery` merges this view with dv-processing's.
"""

from __future__ import annotations

import errno
import grp
import os
import pwd
import stat
import sys
from dataclasses import dataclass
from enum import StrEnum
from pathlib import Path

from neurotouch_hid.core.errors import DeviceError
from neurotouch_hid.core.limits import read_proc_file

#: USB ids of the DAVIS-346 (iniVation FX3 boards).
CAMERA_VID, CAMERA_PID = 0x152A, 0x841A
CAMERA_USB_ID = f"{CAMERA_VID:04x}:{CAMERA_PID:04x}"
_SYSFS_USB = Path("/sys/bus/usb/devices")
#: Most bytes read of a sysfs attribute or ``/proc/PID/comm``: the kernel serves one page at most.
_KERNEL_FILE_BYTES = 4096


class UsbAccess(StrEnum):
    """The pyusb probe's verdict on one camera's USB node (:attr:`UsbCamera.access`)."""

    OK = "ok"
    DENIED = "denied"
    BUSY = "busy"
    GONE = "gone"
    ERROR = "error"


@dataclass(frozen=True)
class UsbCamera:
    """What pyusb (libusb) and sysfs say about one USB device 152a:841a.

    Attributes:
        bus, address: libusb's bus number and device address (``lsusb``'s "Bus" and "Device").
        node: the ``/dev/bus/usb/BBB/DDD`` character device libusb opens.
        port: the kernel's name for the device's port (sysfs, e.g. ``"2-1.3"``), or None.
        serial, product, manufacturer: the device's USB strings, or None when unreadable.
        speed_mbps: link speed (sysfs ``speed``: 480 = USB 2, 5000 = USB 3), or None.
        access: a :class:`UsbAccess` verdict.
        reason: why it is not ``UsbAccess.OK`` (empty when it is), for a person.
        holders: other processes that have the node open (``"PID 123 (name)"``; only those this
            user may inspect), when busy.
    """

    bus: int
    address: int
    node: str
    port: str | None = None
    serial: str | None = None
    product: str | None = None
    manufacturer: str | None = None
    speed_mbps: float | None = None
    access: UsbAccess = UsbAccess.OK
    reason: str = ""
    holders: tuple[str, ...] = ()


def pip_command() -> str:
    """pip of the Python this driver runs in (its pipx or venv environment), as a command for a
    fix: the distribution's ``python3 -m pip`` is refused under PEP 668 and would not reach this
    installation anyway."""
    return f"{sys.executable} -m pip"


# --- pyusb (libusb) ---------------------------------------------------------------------------
def node_path(bus: int, address: int) -> str:
    """The ``/dev/bus/usb/BBB/DDD`` node of a USB device (what libusb opens on Linux)."""
    return f"/dev/bus/usb/{bus:03d}/{address:03d}"


def find_cameras() -> list:
    """Every USB device 152a:841a, accessible or not (pyusb ``usb.core.Device`` objects, in
    libusb's order; an empty list when there is none).

    Source: pyusb with libusb-package's bundled libusb (listing needs no permission).

    Raises:
        DeviceError: libusb-package has no libusb for this platform, or libusb cannot list devices.
    """
    import libusb_package
    import usb.core

    backend = libusb_package.get_libusb1_backend()
    if backend is None:
        raise DeviceError(
            f"libusb-package has no libusb for this platform: {pip_command()} install --force-reinstall libusb-package"
        )
    try:
        return list(usb.core.find(idVendor=CAMERA_VID, idProduct=CAMERA_PID, find_all=True, backend=backend))
    except usb.core.USBError as exc:
        raise DeviceError(f"cannot list USB devices: {exc}") from None


def _sysfs_device(bus: int, address: int) -> Path | None:
    """The /sys/bus/usb/devices/<port> folder of a device, or None (no sysfs, or gone)."""
    try:
        entries = list(_SYSFS_USB.iterdir())
    except OSError:
        return None
    for entry in entries:
        if _number(entry / "busnum") == bus and _number(entry / "devnum") == address:
            return entry
    return None


def _read(path: Path) -> str | None:
    """A small kernel file's text (a sysfs attribute, ``/proc/PID/comm``), stripped, read through
    :func:`~neurotouch_hid.core.limits.read_proc_file`; None when it is missing, unreadable, empty,
    longer than :data:`_KERNEL_FILE_BYTES` or not UTF-8."""
    try:
        data, more = read_proc_file(path, _KERNEL_FILE_BYTES)
        return None if more else data.decode("utf-8").strip() or None
    except (OSError, UnicodeDecodeError):
        return None


def _number(path: Path) -> int | None:
    """A small kernel file's whole number (:func:`_read`), or None when it holds none."""
    text = _read(path)
    try:
        return None if text is None else int(text)
    except ValueError:
        return None


def _holders(node: str) -> tuple[str, ...]:
    """Other processes with ``node`` open ("PID n (comm)"), among those this user may inspect."""
    found = []
    try:
        pids = [p for p in os.listdir("/proc") if p.isdigit() and int(p) != os.getpid()]
    except OSError:
        return ()
    for pid in pids:
        try:
            fds = os.listdir(f"/proc/{pid}/fd")
        except OSError:
            continue
        for fd in fds:
            try:
                if os.readlink(f"/proc/{pid}/fd/{fd}") == node:
                    found.append(f"PID {pid} ({_read(Path(f'/proc/{pid}/comm')) or '?'})")
                    break
            except OSError:
                continue
    return tuple(found)


def _kernel_driver(sysfs: Path | None) -> str | None:
    """The kernel driver bound to the device's first interface (sysfs ``<port>:1.0/driver``)."""
    if sysfs is None:
        return None
    for intf in sorted(sysfs.glob(f"{sysfs.name}:*.0")):
        driver = intf / "driver"
        if driver.exists():
            return os.path.basename(os.readlink(driver))
    return None


def _node_owner(node: str) -> str:
    """``"crw-rw-r-- root:root"`` for a node."""
    st = os.stat(node)
    try:
        user = pwd.getpwuid(st.st_uid).pw_name
    except KeyError:
        user = str(st.st_uid)
    try:
        group = grp.getgrgid(st.st_gid).gr_name
    except KeyError:
        group = str(st.st_gid)
    return f"{stat.filemode(st.st_mode)} {user}:{group}"


def _whoami() -> str:
    uid = os.getuid()
    try:
        return f"{pwd.getpwuid(uid).pw_name} (uid {uid})"
    except KeyError:
        return f"uid {uid}"


def probe_usb(device) -> UsbCamera:
    """Look at one pyusb device: its strings, and whether this user can open and claim it.

    ``device`` is a pyusb ``usb.core.Device`` (from :func:`find_cameras`). The probe opens the
    device through libusb and claims interface 0, then releases and closes it at once (no
    transfer to the camera). Reading strings from sysfs needs no permission; without sysfs they
    are read from the device when it can be opened.

    Returns a :class:`UsbCamera`; never raises for a device problem (it is the verdict).
    Source: pyusb / libusb, sysfs, /proc (who holds a busy device).
    """
    import usb.core
    import usb.util

    bus, address = int(device.bus), int(device.address)
    node = node_path(bus, address)
    sysfs = _sysfs_device(bus, address)
    strings = {k: _read(sysfs / k) if sysfs else None for k in ("serial", "product", "manufacturer")}
    speed = _read(sysfs / "speed") if sysfs else None
    port = sysfs.name if sysfs else None
    if port is None:
        try:
            ports = device.port_numbers
            port = f"{bus}-{'.'.join(str(p) for p in ports)}" if ports else None
        except (usb.core.USBError, NotImplementedError, AttributeError):
            port = None
    base = dict(
        bus=bus,
        address=address,
        node=node,
        port=port,
        speed_mbps=float(speed) if speed and speed.replace(".", "", 1).isdigit() else None,
    )

    def verdict(access: UsbAccess, reason: str = "", holders: tuple[str, ...] = ()) -> UsbCamera:
        return UsbCamera(**base, **strings, access=access, reason=reason, holders=holders)

    if not os.path.exists(node):
        if sysfs is None:
            return verdict(UsbAccess.GONE, "unplugged while being checked")
        return verdict(UsbAccess.ERROR, f"{node} does not exist (no devtmpfs on /dev?)")
    if not os.access(node, os.R_OK | os.W_OK):
        try:
            owner = _node_owner(node)
        except OSError:
            owner = "?"
        return verdict(UsbAccess.DENIED, f"permission denied: {node} is {owner}, this user is {_whoami()}")
    try:
        usb.util.claim_interface(device, 0)
        for key, index in (("serial", "iSerialNumber"), ("product", "iProduct"), ("manufacturer", "iManufacturer")):
            if strings[key] is None and getattr(device, index, 0):
                try:
                    strings[key] = usb.util.get_string(device, getattr(device, index))
                except (usb.core.USBError, ValueError, NotImplementedError):
                    pass
    except usb.core.USBError as exc:
        code = exc.errno
        if code == errno.EACCES:
            return verdict(
                UsbAccess.DENIED, f"permission denied by libusb on {node} ({exc.strerror}), this user is {_whoami()}"
            )
        if code == errno.EBUSY:
            driver = _kernel_driver(sysfs)
            if driver and driver != "usbfs":
                return verdict(UsbAccess.BUSY, f"the kernel driver {driver} holds its interface 0")
            holders = _holders(node)
            who = ", ".join(holders) if holders else "a process this user cannot see"
            return verdict(UsbAccess.BUSY, f"in use by another program ({who})", holders)
        if code in (errno.ENODEV, errno.ENOENT) and _sysfs_device(bus, address) is None:
            return verdict(UsbAccess.GONE, "unplugged while being checked")
        return verdict(UsbAccess.ERROR, f"libusb cannot open or claim it: {exc}")
    except (NotImplementedError, ValueError) as exc:
        return verdict(UsbAccess.ERROR, f"libusb cannot open or claim it: {exc}")
    finally:
        try:
            usb.util.dispose_resources(device)
        except usb.core.USBError:
            pass
    return verdict(UsbAccess.OK)


def usb_cameras() -> list[UsbCamera]:
    """:func:`find_cameras`, each one :func:`probe_usb`-ed (empty list when there is none).

    Raises:
        DeviceError: pyusb / libusb cannot list USB devices.
    """
    return [probe_usb(d) for d in find_cameras()]
