"""Which DAVIS-346 cameras are plugged in, which of them this user can open, and why not.

Two views of the USB bus are merged into one :class:`Camera` record per device:

* **pyusb** (with libusb-package's bundled libusb; :mod:`neurotouch_hid.sources.usb_probe`) lists
  every USB device 152a:841a, whether or not this user may open it. For each: bus, address, its
  ``/dev/bus/usb/BBB/DDD`` node, the serial/product strings (from sysfs, which anyone may read,
  through the bounded reader of ``limits.py``; else from the device when it can be opened), and
  an access verdict: the node is readable and writable, and interface 0 can be claimed (then
  released at once: nothing is sent to the camera). When not: permission denied
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
import os
import re
import sys
import tempfile
from dataclasses import asdict, dataclass, field
from enum import StrEnum

from neurotouch_hid.core.errors import DeviceError
from neurotouch_hid.service.udev import camera_access_fix, installed_rules
from neurotouch_hid.sources.usb_probe import (
    CAMERA_PID,
    CAMERA_USB_ID,
    UsbAccess,
    UsbCamera,
    node_path,
    pip_command,
    usb_cameras,
)

#: dv-processing's logger prefix ("[ERROR] usb_discovery: ").
_DV_LOG_PREFIX = re.compile(r"^\[[A-Z]+\] \w+: ")


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


def _json_usb(usb: UsbCamera | None) -> dict | None:
    if usb is None:
        return None
    data = asdict(usb)
    data["holders"] = list(usb.holders)
    return data


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
