"""The USB gadget in configfs: made, found, bound to a UDC, unbound and removed.

Everything here is the kernel's documented file interface, nothing more:
Documentation/usb/gadget_configfs.rst (a gadget is a folder under
``/sys/kernel/config/usb_gadget``: ``idVendor``, ``idProduct``, ``bcdDevice``, ``strings/0x409``,
``configs/c.1``, ``functions/TYPE.INSTANCE`` linked into the configuration, and ``UDC``, which
binds it to a USB device controller named in ``/sys/class/udc``), Documentation/usb/gadget_hid.rst
(the ``hid`` function: ``protocol``, ``subclass``, ``report_length``, ``report_desc``; its
``/dev/hidgN`` node) and Documentation/usb/functionfs.rst (the ``ffs`` function: a FunctionFS
mount named like the instance, whose ``ep0`` takes the descriptors).

The gadget of a run is one composite device (:func:`plan`): the controller (``hid.usb0`` for a
protocol on the kernel's ``hid`` function, ``ffs.xinput`` for ``xinput``, ``ffs.pad`` for a HID
interface on FunctionFS), and ``hid.usb1`` (boot keyboard) and ``hid.usb2`` (mouse) when the
profile uses keys or the mouse. Its ids (and release, where two protocols share ids) say which
protocol it speaks (:func:`protocol_of`), so that a run finds what a ``gadget setup`` made.

Every attribute read from sysfs or configfs goes through :func:`read_attr`, at most
:data:`MAX_ATTR_BYTES`.
"""

from __future__ import annotations

import errno
import logging
import os
import subprocess
import time
from dataclasses import dataclass
from pathlib import Path

from neurotouch_hid.core.errors import DeviceError
from neurotouch_hid.targets.identity import DEFAULT_USB_SERIAL

log = logging.getLogger(__name__)

#: Where configfs keeps the gadgets, and the controllers' class in sysfs.
CONFIGFS = Path("/sys/kernel/config")
UDC_CLASS = Path("/sys/class/udc")
#: What a machine with no USB device controller is told, wherever a gadget needs one.
NO_UDC = "this machine has no USB device controller (/sys/class/udc is empty): it cannot be a USB device"
#: The gadget's folder name under ``usb_gadget``.
GADGET_NAME = "neurotouch"
#: Where the XInput function's FunctionFS is mounted (one folder per instance).
FFS_ROOT = Path("/dev/ffs-neurotouch")
#: The FunctionFS instance (and mount source) of the XInput pad.
FFS_INSTANCE = "xinput"
#: Largest sysfs/configfs attribute read (bytes): they are one short line; a page at most.
MAX_ATTR_BYTES = 4096
#: The kernel modules a gadget needs (doctor names them).
MODULES = ("libcomposite", "usb_f_hid", "usb_f_fs")
#: How long :func:`hidg_node` waits for a function's /dev/hidgN (s).
NODE_WAIT_S = 5.0
#: umount attempts of the FunctionFS mount in :func:`remove`, 0.1 s apart.
UMOUNT_TRIES = 30


@dataclass(frozen=True)
class HidFunction:
    """One ``hid`` function of the gadget: its instance, report format name
    (:mod:`neurotouch_hid.targets.reports`), interface subclass (1: boot) and protocol (1
    keyboard, 2 mouse, 0 none), its endpoints' wMaxPacketSize (bytes; 0: the format's report
    length) and polling interval (``interval_ms``, written to the function's ``interval``
    attribute where the kernel has it, Linux 6.16 and later; 0: the function's default, 10 ms at
    full speed). f_hid makes both endpoints ``report_length`` bytes and sends each report as it is
    written, so an 8-byte report on a 64-byte endpoint goes as one 8-byte packet
    (Documentation/usb/gadget_hid.rst; drivers/usb/gadget/function/f_hid.c)."""

    instance: str
    format: str
    subclass: int = 0
    protocol: int = 0
    max_packet: int = 0
    interval_ms: int = 0


@dataclass(frozen=True)
class GadgetPlan:
    """What a gadget is made of: ids, strings, its ``hid`` functions and its FunctionFS function's
    instance (``ffs``: ``xinput`` for the Xbox 360 pad, ``pad`` for a HID interface that answers
    its host's requests itself, "" for none), mounted at ``FFS_ROOT/INSTANCE``."""

    protocol: str
    vendor: int
    product: int
    version: int
    manufacturer: str
    product_name: str
    hid: tuple[HidFunction, ...]
    ffs: str = ""
    #: iSerialNumber: the camera's (``targets.identity.Identity.usb_serial``), so a host tells
    #: two boards' pads apart and remembers each
    serial: str = DEFAULT_USB_SERIAL


#: The FunctionFS instance of each gadget function carried by FunctionFS (the protocol table's
#: ``gadget_function``): the Xbox 360 pad, and a HID interface that answers its host itself.
FFS_INSTANCES = {"xinput": FFS_INSTANCE, "ffs-hid": "pad"}


#: Instance name prefix of a pad's ``hid`` function in a gadget with one pad per camera: the
#: camera's gadget serial follows (:func:`pad_instance`).
PAD_PREFIX = "pad"


def pad_instance(usb_serial: str) -> str:
    """The ``hid`` function instance of the pad of the camera whose gadget serial is
    ``usb_serial`` (``Identity.usb_serial``: letters, digits and ``_``), in a gadget with one pad
    per camera: ``pad`` + the serial. A run finds its own function by it."""
    return PAD_PREFIX + usb_serial


def plan(
    protocol: str,
    keyboard: bool = False,
    mouse: bool = False,
    serial: str = DEFAULT_USB_SERIAL,
    pads: tuple[str, ...] = (),
) -> GadgetPlan:
    """The gadget for ``protocol`` (a row of :data:`~neurotouch_hid.targets.protocols.PROTOCOLS`
    that runs on a gadget: its ids, strings, function, endpoint size and interval), with a
    keyboard and a mouse function when asked, and ``serial`` as its iSerialNumber.

    ``pads``: two or more cameras' gadget serials for one gadget that carries a pad for each (two
    gels on one board, one host): one ``hid`` function per camera (:func:`pad_instance`), in
    that order (the host numbers their interfaces so), the serials joined by ``-`` as the
    gadget's iSerialNumber, no keyboard or mouse (the runs of the cameras would share them).

    Raises:
        DeviceError: an unknown protocol or one that does not run on a gadget; a keyboard or a
            mouse asked of a protocol whose gadget carries the pad alone (the row's ``alone``);
            several pads of a protocol not on the kernel's ``hid`` function or that goes alone,
            the same serial twice, or several pads with a keyboard or a mouse.
    """
    from neurotouch_hid.core.errors import NeurotouchError
    from neurotouch_hid.targets.protocols import protocol as protocol_row

    try:
        row = protocol_row(protocol, "gadget")
    except NeurotouchError as exc:
        raise DeviceError(str(exc)) from None
    if (keyboard or mouse) and row.alone:
        raise DeviceError(alone(protocol))
    if len(pads) > 1:
        return _plan_of_pads(row, pads, keyboard or mouse)
    extra = []
    if keyboard:
        extra.append(HidFunction("usb1", "keyboard", subclass=1, protocol=1))
    if mouse:
        extra.append(HidFunction("usb2", "mouse", subclass=1, protocol=2))
    ids = (row.vendor, row.product, row.bcd_device, row.manufacturer, row.product_name)
    if row.gadget_function in FFS_INSTANCES:
        return GadgetPlan(protocol, *ids, tuple(extra), FFS_INSTANCES[row.gadget_function], serial)
    pad = HidFunction("usb0", row.report.name, max_packet=row.max_packet or 0, interval_ms=row.interval_ms or 0)
    return GadgetPlan(protocol, *ids, (pad, *extra), "", serial)


def _plan_of_pads(row, pads: tuple[str, ...], extra: bool) -> GadgetPlan:
    """:func:`plan`'s gadget of one pad per camera (its docstring)."""
    if row.gadget_function != "hid" or row.alone:
        why = f"it goes alone: {row.alone}" if row.alone else "its pad is not on the kernel's hid function"
        raise DeviceError(f"a {row.name} gadget carries one pad ({why}): for several cameras use --protocol hid")
    if len(set(pads)) != len(pads):
        raise DeviceError(f"the same camera twice in {', '.join(pads)}: one pad per camera")
    if extra:
        raise DeviceError(
            "a gadget with a pad per camera carries no USB keyboard or mouse: leave out --keyboard, --mouse"
        )
    functions = tuple(
        HidFunction(pad_instance(p), row.report.name, max_packet=row.max_packet or 0, interval_ms=row.interval_ms or 0)
        for p in pads
    )
    ids = (row.vendor, row.product, row.bcd_device, row.manufacturer, row.product_name)
    return GadgetPlan(row.name, *ids, functions, "", "-".join(pads))


def alone(protocol: str) -> str:
    """What a user is told who asks for a keyboard or a mouse beside a protocol whose gadget
    carries the pad alone (the protocol table's ``alone``: why)."""
    from neurotouch_hid.targets.protocols import PROTOCOLS

    return (
        f"a {protocol} gadget carries the pad alone, no USB keyboard or mouse ({PROTOCOLS[protocol].alone}): "
        "for a profile that presses keys or moves the pointer, use --protocol hid"
    )


def read_attr(path: str | os.PathLike) -> str:
    """A sysfs or configfs attribute's text, at most :data:`MAX_ATTR_BYTES`, stripped.

    Raises:
        OSError: as ``open`` and ``read`` do (FileNotFoundError when there is no such file).
    """
    fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | os.O_CLOEXEC)
    try:
        return os.read(fd, MAX_ATTR_BYTES).decode(errors="replace").strip()
    finally:
        os.close(fd)


def write_attr(path: Path, value: str | bytes) -> None:
    """Write one configfs attribute (one ``write``, as the kernel expects). Raises OSError."""
    data = value.encode() if isinstance(value, str) else value
    fd = os.open(path, os.O_WRONLY | os.O_CLOEXEC)
    try:
        os.write(fd, data)
    finally:
        os.close(fd)


def gadget_dir(name: str = GADGET_NAME) -> Path:
    """The gadget's folder in configfs."""
    return CONFIGFS / "usb_gadget" / name


def no_udc() -> str:
    """:data:`NO_UDC`, saying whether ``/sys/class/udc`` is empty or does not exist at all (no UDC
    driver in this kernel, or a container without that part of /sys)."""
    state = "is empty" if UDC_CLASS.is_dir() else "does not exist"
    return f"this machine has no USB device controller ({UDC_CLASS} {state}): it cannot be a USB device"


def udcs() -> list[str]:
    """The USB device controllers of this machine (``/sys/class/udc``), sorted; [] when none."""
    try:
        return sorted(p.name for p in UDC_CLASS.iterdir())
    except OSError:
        return []


def protocol_of(name: str = GADGET_NAME) -> str | None:
    """The protocol of the gadget ``name``: ``xinput`` when it has the FunctionFS pad, else the row
    of :data:`~neurotouch_hid.targets.protocols.PROTOCOLS` with its ids (``idVendor``,
    ``idProduct``, ``bcdDevice`` where two rows share ids), else ``hid``; None when there is no
    such gadget."""
    from neurotouch_hid.targets.protocols import by_ids

    folder = gadget_dir(name)
    if not folder.is_dir():
        return None
    if (folder / "functions" / f"ffs.{FFS_INSTANCE}").is_dir():
        return "xinput"
    try:
        ids = int(read_attr(folder / "idVendor"), 16), int(read_attr(folder / "idProduct"), 16)
        row = by_ids(*ids, _release(folder))
    except (OSError, ValueError):
        row = None
    return "hid" if row is None else row.name


def _release(folder: Path) -> int | None:
    """The gadget's ``bcdDevice``, None when it cannot be read."""
    try:
        return int(read_attr(folder / "bcdDevice"), 16)
    except (OSError, ValueError):
        return None


def bound_udc(name: str = GADGET_NAME) -> str:
    """The UDC the gadget is bound to, "" when none."""
    try:
        return read_attr(gadget_dir(name) / "UDC")
    except OSError:
        return ""


def hidg_node(instance: str, name: str = GADGET_NAME, wait_s: float = NODE_WAIT_S) -> Path:
    """The ``/dev/hidgN`` of the gadget's ``hid.INSTANCE`` function: the node whose device
    number is the function's ``dev`` attribute (``MAJOR:MINOR``), waited for up to ``wait_s``
    (the kernel makes it when the function is linked or bound, depending on its version; udev or
    devtmpfs then makes the node).

    Raises:
        DeviceError: the function has no ``dev``, or no node in /dev has that number, in time.
    """
    deadline = time.monotonic() + wait_s
    while True:
        try:
            return _hidg_node(instance, name)
        except DeviceError:
            if time.monotonic() > deadline:
                raise
            time.sleep(0.05)


def _hidg_node(instance: str, name: str) -> Path:
    attr = gadget_dir(name) / "functions" / f"hid.{instance}" / "dev"
    try:
        major, minor = (int(x) for x in read_attr(attr).split(":"))
    except (OSError, ValueError) as exc:
        raise DeviceError(f"{attr}: no device number ({exc})") from None
    want = os.makedev(major, minor)
    for node in sorted(Path("/dev").glob("hidg*")):
        try:
            if node.stat().st_rdev == want:
                return node
        except OSError:
            continue
    raise DeviceError(f"no /dev/hidg* node is {major}:{minor} (the gadget's hid.{instance}); is udev running?")


def load_modules() -> None:
    """``modprobe`` the gadget's modules (a module built in, or already loaded, is fine)."""
    for module in MODULES:
        subprocess.run(["modprobe", module], check=False, capture_output=True)


def mount_configfs() -> None:
    """Mount configfs at /sys/kernel/config when it is not mounted yet."""
    if not (CONFIGFS / "usb_gadget").is_dir():
        subprocess.run(["mount", "-t", "configfs", "none", str(CONFIGFS)], check=False, capture_output=True)
    if not (CONFIGFS / "usb_gadget").is_dir():
        if not udcs():  # no module or mount makes this machine a USB device: the board comes first
            raise DeviceError(
                f"{CONFIGFS}/usb_gadget does not exist, and {no_udc()}; `neurotouch-hid doctor` says what a board "
                "needs (docs/any-host.md)"
            )
        raise DeviceError(
            f"{CONFIGFS}/usb_gadget does not exist: configfs or libcomposite is missing\n"
            "sudo modprobe libcomposite\nsudo mount -t configfs none /sys/kernel/config"
        )


def create(gadget: GadgetPlan, *, name: str = GADGET_NAME, uid: int = -1) -> Path:
    """Make the gadget in configfs (not bound: :func:`bind`), its ``hid`` functions with their
    descriptors, the FunctionFS function mounted at ``FFS_ROOT/INSTANCE`` (owned by ``uid`` when
    given; its folder mode 0500 and its files 0600, group root: the mount options ``rmode``,
    ``fmode`` of Documentation/usb/functionfs.rst), everything linked into configuration
    ``c.1``. The ``UDC`` file (configfs mode 0644) is handed to ``uid`` too, so that the user's run
    can bind a FunctionFS function once its descriptors are written. Root only. Returns the
    gadget's folder.

    Raises:
        DeviceError: configfs is missing, a gadget of that name exists, or the kernel refused a
            step (the message names the file, and the module when the kernel has no function of a
            type). The gadget is removed again first.
    """
    from neurotouch_hid.targets.reports import format_for

    load_modules()
    mount_configfs()
    folder = gadget_dir(name)
    if folder.exists():
        raise DeviceError(f"{folder} exists already: remove it first (neurotouch-hid gadget remove)")
    try:
        folder.mkdir()
        write_attr(folder / "idVendor", f"0x{gadget.vendor:04x}")
        write_attr(folder / "idProduct", f"0x{gadget.product:04x}")
        write_attr(folder / "bcdDevice", f"0x{gadget.version:04x}")
        write_attr(folder / "bcdUSB", "0x0200")
        strings = folder / "strings" / "0x409"
        strings.mkdir()
        write_attr(strings / "manufacturer", gadget.manufacturer)
        write_attr(strings / "product", gadget.product_name)
        write_attr(strings / "serialnumber", gadget.serial)
        config = folder / "configs" / "c.1"
        config.mkdir()
        (config / "strings" / "0x409").mkdir()
        write_attr(config / "strings" / "0x409" / "configuration", "neurotouch-hid")
        write_attr(config / "MaxPower", "100")
        functions = []
        for hid in gadget.hid:
            fmt = format_for(hid.format)
            function = folder / "functions" / f"hid.{hid.instance}"
            function.mkdir()
            write_attr(function / "protocol", str(hid.protocol))
            write_attr(function / "subclass", str(hid.subclass))
            write_attr(function / "report_length", str(max(fmt.report_length, hid.max_packet)))
            write_attr(function / "report_desc", fmt.descriptor)
            if hid.interval_ms and (function / "interval").exists():
                write_attr(function / "interval", str(hid.interval_ms))
            elif hid.interval_ms:
                log.warning(
                    "%s: this kernel's hid function has no interval attribute (Linux 6.16 and later): the host polls "
                    "it at the function's default, not every %d ms",
                    function,
                    hid.interval_ms,
                )
            functions.append(function)
        if gadget.ffs:
            function = folder / "functions" / f"ffs.{gadget.ffs}"
            function.mkdir()
            mount = FFS_ROOT / gadget.ffs
            mount.mkdir(parents=True, exist_ok=True)
            options = ["rmode=0500", "fmode=0600", *([f"uid={uid}"] if uid >= 0 else [])]
            cmd = ["mount", "-t", "functionfs", "-o", ",".join(options), gadget.ffs]
            subprocess.run([*cmd, str(mount)], check=True, capture_output=True)
            if uid >= 0:
                os.chown(mount, uid, 0)
            functions.insert(0, function)
        for function in functions:
            (config / function.name).symlink_to(function)
        if uid >= 0:
            os.chown(folder / "UDC", uid, 0)
    except (OSError, subprocess.CalledProcessError) as exc:
        remove(name)
        raise DeviceError(f"making the USB gadget {folder} failed: {exc}{_module_missing(exc)}") from None
    return folder


#: The kernel module of each configfs function type, and the option that builds it in.
FUNCTION_MODULES = {"hid": ("usb_f_hid", "CONFIG_USB_CONFIGFS_F_HID"), "ffs": ("usb_f_fs", "CONFIG_USB_CONFIGFS_F_FS")}


def _module_missing(exc: BaseException) -> str:
    """What to do when ``exc`` is configfs refusing ``functions/TYPE.INSTANCE`` with ENOENT: the
    kernel has no function driver of that type (gadget_configfs.rst, "Creating the functions");
    "" otherwise."""
    path = Path(str(getattr(exc, "filename", "") or ""))
    module = FUNCTION_MODULES.get(path.name.split(".")[0]) if path.parent.name == "functions" else None
    if not isinstance(exc, FileNotFoundError) or module is None:
        return ""
    return (
        f"\nthe kernel has no {module[0]}: sudo modprobe {module[0]} (a kernel built with {module[1]}); "
        "`neurotouch-hid doctor` says what this machine has"
    )


def bind(name: str = GADGET_NAME, udc: str | None = None) -> str:
    """Bind the gadget to ``udc`` (default: the first of :func:`udcs`); returns its name.

    Raises:
        DeviceError: no UDC on this machine, or the kernel refused (e.g. the controller is in
            use by another gadget, or a FunctionFS function has no descriptors yet).
    """
    names = udcs()
    if udc is None:
        if not names:
            raise DeviceError(f"{no_udc()}; see `neurotouch-hid doctor`")
        udc = names[0]
    try:
        write_attr(gadget_dir(name) / "UDC", udc)
    except OSError as exc:
        if exc.errno == errno.EBUSY and bound_udc(name) == udc:
            return udc
        gadgets = sorted((CONFIGFS / "usb_gadget").glob("*"))
        holders = [g for g in gadgets if g.name != name and bound_udc(g.name) == udc]  # only read
        if exc.errno == errno.EBUSY and holders:
            raise DeviceError(
                f"{udc} is used by another gadget, {holders[0]}: this machine's USB device port is one device at a "
                f"time. Unbind that gadget (its program's own way, or sudo sh -c 'echo > {holders[0]}/UDC'), then "
                "try again"
            ) from None
        raise DeviceError(f"binding the USB gadget to {udc} failed: {exc.strerror}") from None
    return udc


def unbind(name: str = GADGET_NAME) -> None:
    """Unbind the gadget from its UDC (the host sees it unplugged); nothing when it is not bound."""
    if bound_udc(name):
        try:
            write_attr(gadget_dir(name) / "UDC", "\n")
        except OSError:
            pass


def remove(name: str = GADGET_NAME) -> None:
    """Unbind and remove the gadget, in the reverse order of gadget_configfs.rst's "Cleaning
    up": links, configuration strings, configurations, functions (a FunctionFS one unmounted
    first), gadget strings, the gadget. Missing parts are skipped; safe to call again."""
    folder = gadget_dir(name)
    if not folder.exists():
        return
    unbind(name)
    config = folder / "configs" / "c.1"
    for link in sorted(config.glob("*.*")) if config.is_dir() else []:
        if link.is_symlink():
            link.unlink()
    for path in (config / "strings" / "0x409", config):
        _rmdir(path)
    for function in sorted((folder / "functions").glob("*.*")):
        if function.name.startswith("ffs."):
            mount = FFS_ROOT / function.name.removeprefix("ffs.")
            for _ in range(UMOUNT_TRIES):  # busy while a closed endpoint's last read returns
                if not os.path.ismount(mount):
                    break
                subprocess.run(["umount", str(mount)], check=False, capture_output=True)
                time.sleep(0.1)
            _rmdir(mount)
            _rmdir(FFS_ROOT)
        _rmdir(function)
    _rmdir(folder / "strings" / "0x409")
    _rmdir(folder)


def _rmdir(path: Path) -> None:
    try:
        path.rmdir()
    except OSError:
        pass
