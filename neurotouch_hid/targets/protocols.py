"""The protocol table: one row per protocol the controller can speak to a host.

A row names a protocol (``run --protocol``, a profile's ``device: protocol``), its wire format
(a :class:`~neurotouch_hid.targets.reports.ReportFormat`: the input report, the feature reports a
host reads, the output reports parsed into :class:`~neurotouch_hid.core.controller.Feedback`), the
transports it runs on (``"uhid"``: a HID device on this machine, :mod:`neurotouch_hid.targets.uhid`;
``"gadget"``: a USB gadget for another host, :mod:`neurotouch_hid.targets.gadget`), the gadget
function that carries it, and the USB identity the host sees (ids and strings). The command line,
the profile's validation, ``gadget setup``, doctor and docs/any-host.md read :data:`PROTOCOLS`;
none writes the protocols out.

Adding a protocol is one encoder module under ``targets/reports/``, one row here and one golden
test (tests/test_protocol_table.py; docs/architecture.md, "Adding a protocol").

Sources: USB 2.0 specification, 9.6.1 (device descriptor: idVendor, idProduct, bcdDevice,
iManufacturer, iProduct) and 9.6.6 (endpoint descriptor: wMaxPacketSize, bInterval);
Documentation/usb/gadget_configfs.rst.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum

from neurotouch_hid.core.errors import NeurotouchError
from neurotouch_hid.targets.reports import ReportFormat
from neurotouch_hid.targets.reports.dualsense import DUALSENSE
from neurotouch_hid.targets.reports.hid import HID_JOYSTICK
from neurotouch_hid.targets.reports.switch import SWITCH
from neurotouch_hid.targets.reports.xac import XAC
from neurotouch_hid.targets.reports.xinput import VERSION as XINPUT_VERSION
from neurotouch_hid.targets.reports.xinput import XINPUT

#: The transports a protocol may run on.
TRANSPORTS = ("uhid", "gadget")
#: The gadget functions that carry a protocol: the kernel's ``hid`` function (``/dev/hidgN``,
#: Documentation/usb/gadget_hid.rst), a HID interface on FunctionFS (``ffs-hid``: answers the
#: host's requests on ep0 itself), the Xbox 360 vendor interface on FunctionFS (``xinput``).
GADGET_FUNCTIONS = ("hid", "ffs-hid", "xinput")


@dataclass(frozen=True)
class ProtocolRow:
    """One protocol (module docstring).

    Attributes:
        name: what ``--protocol`` and ``device: protocol`` take (``"hid"``, ``"switch"``, ...).
        summary: one line for the command's help and the docs: the hosts that take it.
        report: the wire format (input, feature and output reports).
        transports: a subset of :data:`TRANSPORTS`.
        gadget_function: one of :data:`GADGET_FUNCTIONS` (used when ``"gadget"`` is a transport).
        vendor, product, bcd_device: the USB ids and device release (0..0xFFFF each).
        manufacturer, product_name: the USB strings (iManufacturer, iProduct); on UHID the
            device's name is ``product_name``.
        profile_ids: a profile's ``device:`` name and ids may replace these on UHID (a generic
            joystick; a protocol that a host driver binds by its ids keeps the row's).
        max_packet: the interrupt endpoints' wMaxPacketSize (bytes); None: the input report's
            length.
        interval_ms: the interrupt endpoints' polling interval (ms); None: the function's default.
        alone: why the protocol's gadget carries the pad alone, never a USB keyboard or mouse
            beside it (a host that ignores a device with more); "" when they may join it.
    """

    name: str
    summary: str
    report: ReportFormat
    transports: frozenset[str]
    gadget_function: str
    vendor: int
    product: int
    bcd_device: int
    manufacturer: str
    product_name: str
    profile_ids: bool = False
    max_packet: int | None = None
    interval_ms: int | None = None
    alone: str = ""

    def __post_init__(self) -> None:
        if not self.transports or not self.transports <= set(TRANSPORTS):
            raise ValueError(f"protocol {self.name}: transports {sorted(self.transports)} not within {TRANSPORTS}")
        if self.gadget_function not in GADGET_FUNCTIONS:
            raise ValueError(f"protocol {self.name}: gadget function {self.gadget_function!r}")
        for key in ("vendor", "product", "bcd_device"):
            if not 0 <= getattr(self, key) <= 0xFFFF:
                raise ValueError(f"protocol {self.name}: {key} is not a 16-bit number")
        if "uhid" in self.transports and not self.report.descriptor:
            raise ValueError(f"protocol {self.name}: UHID needs a report descriptor")


def _rows() -> list[ProtocolRow]:
    return [
        ProtocolRow(
            name="hid",
            summary="a generic HID joystick: Windows, macOS, Linux, Android (Steam Input for XInput games)",
            report=HID_JOYSTICK,
            transports=frozenset({"uhid", "gadget"}),
            gadget_function="hid",
            # the Linux Foundation's "Multifunction Composite Gadget" (gadget_configfs.rst's example)
            vendor=0x1D6B,
            product=0x0104,
            bcd_device=0x0100,
            manufacturer="neurotouch-hid",
            product_name="NeuroTouch Joystick",
            profile_ids=True,
        ),
        ProtocolRow(
            name="switch",
            summary="the HORIPAD-style wired pad a Nintendo Switch takes",
            report=SWITCH,
            transports=frozenset({"gadget"}),
            gadget_function="hid",
            vendor=SWITCH.vendor,  # HORI
            product=SWITCH.product,  # HORIPAD S
            bcd_device=0x0100,
            manufacturer="HORI CO.,LTD.",
            product_name="HORIPAD S (NeuroTouch)",
            # a wired HORI pad's 64-byte endpoints (GP2040-CE's SwitchDescriptors.h, which copies
            # HORI's, github.com/OpenStickCommunity/GP2040-CE); its 8-byte report goes as it is
            max_packet=64,
        ),
        ProtocolRow(
            name="xinput",
            summary="the Xbox 360 wired pad: Linux's xpad, SDL, Steam (not Windows from this board: docs/any-host.md)",
            report=XINPUT,
            transports=frozenset({"gadget"}),
            gadget_function="xinput",
            vendor=XINPUT.vendor,  # Microsoft
            product=XINPUT.product,  # Xbox 360 Controller
            bcd_device=XINPUT_VERSION,
            manufacturer="Microsoft",
            product_name="Controller (NeuroTouch)",
            # reported by ArduinoXInput's users (its tracker, github.com/dmadison/ArduinoXInput)
            alone="Windows' XInput driver ignores an Xbox 360 pad with a keyboard or a mouse beside it",
        ),
        ProtocolRow(
            name="xac",
            summary="the joystick the Xbox Adaptive Controller takes on its side USB ports",
            report=XAC,
            transports=frozenset({"gadget"}),
            gadget_function="hid",
            # the Linux Foundation's (as hid's), a product of its own: a run finds the protocol by ids
            vendor=0x1D6B,
            product=0x0104,
            bcd_device=0x0200,
            manufacturer="neurotouch-hid",
            product_name="NeuroTouch Adaptive Joystick",
            interval_ms=1,
            alone="the Xbox Adaptive Controller is reported to refuse a device with more than its joystick",
        ),
        ProtocolRow(
            name="dualsense",
            summary="Sony's DualSense with its touchpad: Steam, SDL, Linux (hid-playstation), macOS, iOS, Android",
            report=DUALSENSE,
            transports=frozenset({"uhid", "gadget"}),
            # its feature reports need answers of our own: the kernel's f_hid answers GET_REPORT with zeros
            gadget_function="ffs-hid",
            vendor=DUALSENSE.vendor,  # Sony Interactive Entertainment
            product=DUALSENSE.product,  # DualSense Wireless Controller
            bcd_device=0x0100,
            manufacturer="Sony Interactive Entertainment",
            product_name="DualSense Wireless Controller",
            max_packet=64,
            interval_ms=4,
        ),
    ]


#: Every protocol by name, in the order the help lists them.
PROTOCOLS: dict[str, ProtocolRow] = {row.name: row for row in _rows()}
#: The protocol when none is asked for.
DEFAULT_PROTOCOL = "hid"


def choices(transport: str | None = None) -> type[StrEnum]:
    """The protocols (those that run on ``transport`` when given) as a ``str`` enum, from which
    typer makes an option's choices."""
    return StrEnum(f"Protocol{(transport or '').title()}", {name: name for name in names(transport)})


def names(transport: str | None = None) -> tuple[str, ...]:
    """The protocols' names (those that run on ``transport`` when given), in table order."""
    return tuple(name for name, row in PROTOCOLS.items() if transport is None or transport in row.transports)


def help_text(transport: str | None = None) -> str:
    """The protocols as one line for a command's help: ``hid (...), switch (...)``."""
    return "; ".join(f"{name}: {PROTOCOLS[name].summary}" for name in names(transport))


def protocol(name: str, transport: str | None = None) -> ProtocolRow:
    """The row called ``name``, which must run on ``transport`` when given.

    Raises:
        NeurotouchError: no such protocol, or it does not run on ``transport``; the message lists
            those that do.
    """
    row = PROTOCOLS.get(name)
    where = {"uhid": "on this machine (--output hid)", "gadget": "over USB (--output usb)"}.get(transport or "", "")
    if row is None:
        raise NeurotouchError(f"unknown protocol {name!r} (expected one of: {', '.join(names(transport))})")
    if transport is not None and transport not in row.transports:
        raise NeurotouchError(
            f"the {name} protocol does not run {where} (those that do: {', '.join(names(transport))})"
        )
    return row


def by_ids(vendor: int, product: int, bcd_device: int | None = None) -> ProtocolRow | None:
    """The row whose USB ids are ``vendor``:``product`` (a gadget found in configfs) and, where two
    rows share them, whose device release is ``bcd_device``; None when no row has them."""
    found = [row for row in PROTOCOLS.values() if (row.vendor, row.product) == (vendor, product)]
    return next((row for row in found if row.bcd_device == bcd_device), found[0] if found else None)
