"""Which DAVIS-346 cameras are plugged in, which of them this user can open, and why not.

Two views of the USB bus are merged into one :class:`Camera` record per device:

* **pyusb** (with libusb-package's bundled libusb) lists every USB device 152a:841a, whether or
  not this user may open it. For each: bus, address, its ``/dev/bus/usb/BBB/DDD`` node, the
  serial/product strings (from sysfs, which anyone may read, through the bounded reader of
  ``limits.py``; else from the device when it can be opened), and an access verdict: the node
  is readable and writable, and interface 0 can be claimed (then released at once: nothing is
  sent to the camera). When not: permission denied
  (the fix: the udev rule), busy (another program, or a kernel driver, holds the interface), gone.
* **dv-processing** (``dv_processing.io.camera.discover()``, iniVation's libusb-based driver)
  lists the cameras it would open, with serial number, camera model and firmware version. A
  152a:841a device it does not list cannot be used by the live source even when accessible.

The two are matched by (bus, address). ``neurotouch-hid devices`` prints the records,
``neurotouch-hid doctor`` checks them, and the live source calls :func:`explain_no_camera` when it
finds or opens no camera, for a one-line message that says what to do.
"""

from __future__ import annotations

import contextlib
import errno
import grp
import os
import pwd
import re
import stat
import sys
import tempfile
from dataclasses import asdict, dataclass, field
from enum import StrEnum
from pathlib import Path

from neurotouch_hid.core.errors import DeviceError
from neurotouch_hid.core.limits import read_proc_file
from neurotouch_hid.service.udev import camera_access_fix, installed_rules

#: USB ids of the DAVIS-346 (iniVation FX3 boards).
CAMERA_VID, CAMERA_PID = 0x152A, 0x841A
CAMERA_USB_ID = f"{CAMERA_VID:04x}:{CAMERA_PID:04x}"
_SYSFS_USB = Path("/sys/bus/usb/devices")
#: Most bytes read of a sysfs attribute or ``/proc/PID/comm``: the kernel serves one page at most.
_KERNEL_FILE_BYTES = 4096
#: dv-processing's logger prefix ("[ERROR] usb_discovery: ").
_DV_LOG_PREFIX = re.compile(r"^\[[A-Z]+\] \w+: ")


class UsbAccess(StrEnum):
    """The pyusb probe's verdict on one camera's USB node (:attr:`UsbCamera.access`)."""

    OK = "ok"
    DENIED = "denied"
    BUSY = "busy"
    GONE = "gone"
    ERROR = "error"


class CameraStatus(StrEnum):
    """Both views together (:attr:`Camera.status`): what pyusb and dv-processing say of a camera,
    most usable first."""

    READY = "ready"  #: accessible and listed by dv-processing: the live source can open it
    NOT_IN_DV = "not-in-dv"  #: accessible, but dv-processing does not list it
    DV_UNAVAILABLE = "dv-unavailable"  #: accessible, but dv-processing could not list cameras at all
    BUSY = "busy"  #: another program (or a kernel driver) holds it
    NO_ACCESS = "no-access"  #: permission denied: the udev rule
    ERROR = "error"  #: libusb could not open it for another reason
    GONE = "gone"  #: unplugged while being checked
    OTHER_CAMERA = "other-camera"  #: dv-processing lists it, but it is not a 152a:841a device


#: Most usable first (the enum's order): :func:`explain` talks about the best camera there is.
_STATUS_ORDER = tuple(CameraStatus)


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


@dataclass(frozen=True)
class DvCamera:
    """One camera as ``dv_processing.io.camera.discover()`` lists it (a ``DeviceDescriptor``).

    Attributes:
        serial: serial number (what ``dv_processing.io.camera.open(serial)`` takes).
        model: camera model (``CameraModel`` name, e.g. ``"DAVIS"``).
        device_type: USB board (``USBDeviceType`` name, e.g. ``"FX3_MB"``).
        firmware: firmware version (int, as dv-processing reports it: the low byte of the USB
            bcdDevice; ``open()`` refuses versions older than the one it requires).
        bus, address: libusb bus number and device address.
        pid: USB product id (0x841A for a DAVIS-346).

    When dv-processing cannot open the device to read its serial number (permission denied), it
    still lists it, with an empty ``serial``.
    """

    serial: str
    model: str
    device_type: str
    firmware: int
    bus: int
    address: int
    pid: int = CAMERA_PID


@dataclass(frozen=True)
class Camera:
    """One camera, both views merged (either may be None, never both).

    Attributes:
        usb: the pyusb view, or None when pyusb could not list devices.
        dv: the dv-processing view, or None when dv-processing does not list this device.
        status: a :class:`CameraStatus`.
        problem: what is wrong, one clause naming the device (empty when CameraStatus.READY).
        fix: what to do about it (empty when CameraStatus.READY).
    """

    usb: UsbCamera | None
    dv: DvCamera | None
    status: CameraStatus
    problem: str = ""
    fix: str = ""

    @property
    def bus(self) -> int:
        return self.usb.bus if self.usb else self.dv.bus  # type: ignore[union-attr]

    @property
    def address(self) -> int:
        return self.usb.address if self.usb else self.dv.address  # type: ignore[union-attr]

    @property
    def node(self) -> str:
        return node_path(self.bus, self.address)

    @property
    def serial(self) -> str | None:
        """dv-processing's serial number, else the USB serial string, else None."""
        return (self.dv.serial if self.dv and self.dv.serial else None) or (self.usb.serial if self.usb else None)

    @property
    def ready(self) -> bool:
        return self.status == CameraStatus.READY

    @property
    def is_davis346(self) -> bool:
        """A USB 152a:841a device (all records but CameraStatus.OTHER_CAMERA ones)."""
        return self.status != CameraStatus.OTHER_CAMERA

    def label(self) -> str:
        """``"DAVIS-346 at bus 1 device 5 (/dev/bus/usb/001/005), serial 00000123"``."""
        serial = f", serial {self.serial}" if self.serial else ""
        what = "DAVIS-346" if self.is_davis346 else f"{self.dv.model} camera"  # type: ignore[union-attr]
        return f"{what} at bus {self.bus} device {self.address} ({self.node}){serial}"

    def to_json(self) -> dict:
        """A JSON-able dict: bus, address, node, serial, status, ready, problem, fix, usb, dv."""
        return {
            "bus": self.bus,
            "address": self.address,
            "node": self.node,
            "serial": self.serial,
            "status": self.status,
            "ready": self.ready,
            "problem": self.problem,
            "fix": self.fix,
            "usb": _json_usb(self.usb),
            "dv": asdict(self.dv) if self.dv else None,
        }


@dataclass(frozen=True)
class Discovery:
    """Every camera found, and what could not be looked at.

    Attributes:
        cameras: one :class:`Camera` per device, sorted by (bus, address).
        usb_error: why pyusb could not list USB devices, or None.
        dv_error: why dv-processing could not list cameras (not installed, failed), or None
            (also None when it was not asked).
        dv_log: what dv-processing and its libusb printed on stderr while listing (e.g.
            "libusb requires write access to USB device nodes"), captured rather than printed.
    """

    cameras: tuple[Camera, ...] = field(default_factory=tuple)
    usb_error: str | None = None
    dv_error: str | None = None
    dv_log: tuple[str, ...] = ()

    @property
    def ready(self) -> list[Camera]:
        """The cameras the live source can open."""
        return [c for c in self.cameras if c.ready]

    @property
    def davis346(self) -> list[Camera]:
        """The USB 152a:841a devices (every camera but other models dv-processing lists)."""
        return [c for c in self.cameras if c.is_davis346]

    def summary(self) -> str:
        """One line: ``"ready: DAVIS-346 at bus 1 device 5 (...)"`` (and how many more) when a camera
        is ready, else :func:`explain`'s line (what is wrong and what to do)."""
        ready = self.ready
        if not ready:
            return explain(self)
        more = f" (and {len(ready) - 1} more)" if len(ready) > 1 else ""
        return f"ready: {ready[0].label()}{more}"

    def to_json(self) -> dict:
        """``{"cameras": [...], "ready": N, "usb_error": ..., "dv_error": ..., "dv_log": [...],
        "message": ...}``; ``message`` is :meth:`summary`."""
        return {
            "cameras": [c.to_json() for c in self.cameras],
            "ready": len(self.ready),
            "usb_error": self.usb_error,
            "dv_error": self.dv_error,
            "dv_log": list(self.dv_log),
            "message": self.summary(),
        }


def pip_command() -> str:
    """pip of the Python this driver runs in (its pipx or venv environment), as a command for a
    fix: the distribution's ``python3 -m pip`` is refused under PEP 668 and would not reach this
    installation anyway."""
    return f"{sys.executable} -m pip"


def _json_usb(usb: UsbCamera | None) -> dict | None:
    if usb is None:
        return None
    data = asdict(usb)
    data["holders"] = list(usb.holders)
    return data


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


# --- dv-processing ----------------------------------------------------------------------------
@contextlib.contextmanager
def _stderr_into(lines: list[str]):
    """Redirect file descriptor 2 (where native libraries print) into ``lines`` for the block."""
    try:
        sys.stderr.flush()
        saved = os.dup(2)
    except (OSError, ValueError):  # no stderr at all: nothing to capture
        yield
        return
    with tempfile.TemporaryFile() as tmp:
        os.dup2(tmp.fileno(), 2)
        try:
            yield
        finally:
            os.dup2(saved, 2)
            os.close(saved)
            tmp.seek(0)
            text = tmp.read().decode(errors="replace")
            lines.extend(dict.fromkeys(line.strip() for line in text.splitlines() if line.strip()))


def dv_cameras(log: list[str] | None = None) -> list[DvCamera]:
    """The cameras ``dv_processing.io.camera.discover()`` lists (any model; empty when none).

    ``log``: when given, what dv-processing and its libusb print on stderr meanwhile is appended
    there (one entry per distinct line, dv-processing's logger prefix removed) instead of being
    printed. Measured: ~0.3 s with one device.

    Raises:
        DeviceError: dv-processing cannot be imported, or discover() fails.
    """
    try:
        import dv_processing as dv
    except Exception as exc:  # ImportError, or its native library failing to load
        raise DeviceError(
            f"dv-processing cannot be imported ({type(exc).__name__}: {exc}): "
            f"{pip_command()} install --upgrade dv-processing"
        ) from None
    from neurotouch_hid.sources.dv import DV_ERRORS, dv_error_text

    captured: list[str] = []
    try:
        with _stderr_into(captured) if log is not None else contextlib.nullcontext():
            found = dv.io.camera.discover()
    except DV_ERRORS as exc:
        raise DeviceError(f"dv-processing cannot list cameras: {dv_error_text(str(exc))}") from None
    finally:
        if log is not None:  # its logger repeats each libusb line as "[ERROR] usb_discovery: <line>"
            log.extend(dict.fromkeys(_DV_LOG_PREFIX.sub("", line) for line in captured))
    return [
        DvCamera(
            serial=str(d.serialNumber),
            model=_enum_name(d.cameraModel),
            device_type=_enum_name(d.deviceType),
            firmware=int(d.firmwareVersion),
            bus=int(d.busNumber),
            address=int(d.devAddress),
            pid=int(d.pid),
        )
        for d in found
    ]


def _enum_name(value) -> str:
    return str(getattr(value, "name", value))


# --- both together ----------------------------------------------------------------------------
def _diagnose(usb: UsbCamera | None, dv: DvCamera | None, dv_error: str | None, rules: str | None) -> Camera:
    """One merged record with its status, problem and fix (pure: no I/O)."""
    if usb is None:  # not a USB record: dv-processing's word alone
        if dv is not None and dv.pid != CAMERA_PID:
            other = Camera(None, dv, CameraStatus.OTHER_CAMERA)
            return Camera(
                None,
                dv,
                CameraStatus.OTHER_CAMERA,
                f"{other.label()} is not a DAVIS-346 (USB 152a:{dv.pid:04x}, not {CAMERA_USB_ID})",
                f"NeuroTouch's camera is a DAVIS-346 (USB {CAMERA_USB_ID}): plug that one in",
            )
        return Camera(None, dv, CameraStatus.READY)  # pyusb could not list devices
    where = Camera(usb, dv, CameraStatus.READY).label()
    if usb.access == UsbAccess.DENIED:
        return Camera(
            usb, dv, CameraStatus.NO_ACCESS, f"{where} is not accessible ({usb.reason})", camera_access_fix(rules)
        )
    if usb.access == UsbAccess.BUSY:
        fix = (
            "stop that program (the driver's own service: systemctl --user stop neurotouch-hid.service), "
            "or unplug and replug the camera"
        )
        if usb.reason.startswith("the kernel driver"):
            fix = "unbind that driver from the device, or unplug and replug the camera"
        return Camera(usb, dv, CameraStatus.BUSY, f"{where} is busy: {usb.reason}", fix)
    if usb.access == UsbAccess.GONE:
        return Camera(usb, dv, CameraStatus.GONE, f"{where} was unplugged while being checked", "plug it in again")
    if usb.access == UsbAccess.ERROR:
        return Camera(
            usb,
            dv,
            CameraStatus.ERROR,
            f"{where} cannot be opened: {usb.reason}",
            "unplug and replug it (another USB port or cable); `dmesg` may say more",
        )
    if dv is not None:
        return Camera(usb, dv, CameraStatus.READY)
    if dv_error is not None:
        return Camera(
            usb,
            None,
            CameraStatus.DV_UNAVAILABLE,
            f"{where} is accessible but dv-processing cannot list cameras ({dv_error})",
            f"{pip_command()} install --upgrade dv-processing",
        )
    return Camera(
        usb,
        None,
        CameraStatus.NOT_IN_DV,
        f"{where} is accessible but dv-processing does not list it",
        "unplug and replug it; if it stays unlisted, it does not answer as a DAVIS camera: "
        "update its firmware with iniVation's DV software (Flashy)",
    )


def merge(
    usb: list[UsbCamera] | None,
    dv: list[DvCamera] | None,
    *,
    usb_error: str | None = None,
    dv_error: str | None = None,
    rules: str | None = None,
    dv_log: tuple[str, ...] | list[str] = (),
) -> Discovery:
    """Merge the pyusb and dv-processing views into one :class:`Camera` per device (pure).

    Args:
        usb: :func:`usb_cameras`'s records, or None when pyusb could not list (``usb_error``).
        dv: :func:`dv_cameras`'s records, or None when dv-processing was not asked or failed
            (``dv_error``).
        rules: :func:`installed_rules`'s answer (it chooses the fix for permission denied).
        dv_log: what dv-processing printed while listing (kept in the result).

    Returns a :class:`Discovery`, cameras sorted by (bus, address). Devices are matched by
    (bus, address). A dv-processing camera without a USB record is another model (CameraStatus.OTHER_CAMERA,
    e.g. a DVXplorer), or, when pyusb could not list devices, a DAVIS-346 known from dv-processing
    alone.
    """
    by_place = {(d.bus, d.address): d for d in dv or ()}
    cameras = []
    for u in usb or ():
        cameras.append(_diagnose(u, by_place.pop((u.bus, u.address), None), dv_error, rules))
    for d in by_place.values():
        if d.pid != CAMERA_PID or usb is None:
            cameras.append(_diagnose(None, d, dv_error, rules))
    cameras.sort(key=lambda c: (c.bus, c.address))
    return Discovery(tuple(cameras), usb_error, dv_error, tuple(dv_log))


def discover(dv: bool = True) -> Discovery:
    """Look for DAVIS-346 cameras with pyusb and (``dv``) dv-processing; never raises.

    Returns a :class:`Discovery`: one merged :class:`Camera` per device, and the reasons either
    view was unavailable (``usb_error``, ``dv_error``). dv-processing's stderr chatter (libusb
    errors on devices it may not open) is captured into ``dv_log``. ``dv=False``: pyusb only (no
    dv-processing import; ``dv_error`` says so and every accessible camera is CameraStatus.DV_UNAVAILABLE)."""
    usb_error = dv_error = None
    try:
        usb: list[UsbCamera] | None = usb_cameras()
    except DeviceError as exc:
        usb, usb_error = None, str(exc)
    found: list[DvCamera] | None = None
    log: list[str] = []
    if not dv:
        dv_error = "not asked (pyusb only)"
    else:
        try:
            found = dv_cameras(log)
        except DeviceError as exc:
            dv_error = str(exc)
    return merge(usb, found, usb_error=usb_error, dv_error=dv_error, rules=installed_rules(), dv_log=log)


def explain(found: Discovery, serial: str | None = None, error: str | None = None) -> str:
    """For a person, one line or a few short ones: the state of the best camera in ``found`` and
    what to do, a command alone on its line (pure).

    ``serial``: the camera asked for (None: any). ``error``: why opening it failed, if it was
    tried (dv-processing's text, e.g. its firmware-version message), said when the camera looks
    usable. Talks about the most usable camera (ready, then accessible, busy, no access, ...).
    Examples: no 152a:841a on USB (plug it in, check lsusb); at bus X device Y but not accessible
    (install the udev rule, replug); accessible but not listed by dv-processing (firmware, replug);
    ready (when the open failed anyway: its error, in use, replug).
    """
    cameras = found.davis346
    if serial is not None:
        matching = [
            c for c in cameras if serial in ((c.dv.serial if c.dv else None), (c.usb.serial if c.usb else None))
        ]
        if not matching and cameras:
            others = ", ".join(c.label() for c in cameras)
            return (
                f"no DAVIS-346 with serial number {serial}; found {others}: "
                f"leave out the serial number, or plug in the camera {serial}"
            )
        cameras = matching
    if not cameras:
        others = [c for c in found.cameras if not c.is_davis346]
        seen = f"; dv-processing sees only: {', '.join(c.label() for c in others)}" if others else ""
        if found.usb_error is not None:
            return (
                f"no DAVIS-346 found, and pyusb cannot list USB devices ({found.usb_error}){seen}: "
                f"{pip_command()} install --force-reinstall pyusb libusb-package"
            )
        return (
            f"no DAVIS-346 (USB {CAMERA_USB_ID}) found{seen}: plug the NeuroTouch's USB cable in "
            f"(a USB 3 port) and check that `lsusb -d {CAMERA_USB_ID}` lists it"
        )
    best = min(cameras, key=lambda c: _STATUS_ORDER.index(c.status))
    more = f" ({len(cameras) - 1} more found: see `neurotouch-hid devices`)" if len(cameras) > 1 else ""
    if best.ready:
        if error:
            return (
                f"{best.label()} is accessible and listed by dv-processing, but opening it failed: {error} "
                f"(if that does not say what to do: close other programs using it, unplug and replug it){more}"
            )
        return (
            f"{best.label()} is accessible and listed by dv-processing, but could not be used: is another "
            f"program using it? unplug and replug it, then see `neurotouch-hid doctor`{more}"
        )
    return f"{best.problem}\n{best.fix}{more}"


def explain_no_camera(serial: str | None = None, error: str | None = None) -> str:
    """Why no camera could be found or opened, as one actionable line (:func:`explain` of a fresh
    :func:`discover`). For the live source after ``dv_processing.io.camera.discover()`` listed
    nothing, or ``open()`` failed (pass its message as ``error``, e.g. via ``dv_error_text``).

    Takes ~0.5 s (pyusb scan, dv-processing import and discover). Never raises (an unexpected
    failure of the look-up itself becomes part of the message)."""
    try:
        return explain(discover(), serial, error)
    except Exception as exc:  # the explanation must never be the thing that crashes
        return (
            f"no usable DAVIS-346 ({type(exc).__name__} while looking: {exc}): plug it in, check that "
            f"`lsusb -d {CAMERA_USB_ID}` lists it, and run `neurotouch-hid doctor`"
        )
