"""The wire formats of the HID outputs, as data: for each protocol, the report descriptor, the
input report that carries a :class:`~neurotouch_hid.core.controller.ControllerState`, the feature
reports a host reads and the output reports it sends.

Every encoder follows :class:`ReportFormat` (structurally; a format without feature or output
reports takes :class:`~neurotouch_hid.targets.reports.fields.InputOnly`'s answers): a ``name``,
the HID report descriptor (HID 1.11, section 6.2.2; ``b""`` for a protocol without one, the
Xbox 360's vendor interface), the length of one input report, :meth:`ReportFormat.pack`,
:meth:`ReportFormat.neutral`, the feature reports (:attr:`ReportFormat.feature_ids`,
:meth:`ReportFormat.feature`) and :meth:`ReportFormat.parse_output`. The same bytes go to a UHID device on this machine
(:mod:`neurotouch_hid.targets.uhid`) and to a USB gadget's HID function; the layouts, byte by byte,
are in docs/reports.md. :data:`FORMATS` names them all; :func:`format_for` finds one.

Sources: Device Class Definition for HID 1.11 (usb.org), HID Usage Tables 1.4 (usb.org).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Protocol

from neurotouch_hid.core.controller import ControllerState, Feedback
from neurotouch_hid.core.errors import NeurotouchError

if TYPE_CHECKING:
    from neurotouch_hid.targets.identity import Identity


class ReportFormat(Protocol):
    """One protocol's input report for a controller state.

    Attributes:
        name: ``"hid"``, ``"keyboard"``, ``"mouse"``, ``"switch"``, ``"xinput"``, ``"dualsense"``.
        descriptor: the HID report descriptor (HID 1.11, 6.2.2), ``b""`` where the protocol has none.
        report_length: bytes of one input report (:meth:`pack`'s length, always).
        feature_ids: the report ids of the feature reports a host may read (GET_REPORT, HID 1.11
            7.2.1), each answered by :meth:`feature`; ``()`` for a format without any.
    """

    name: str
    descriptor: bytes
    report_length: int
    feature_ids: tuple[int, ...]

    def pack(self, state: ControllerState) -> bytes:
        """The input report (``report_length`` bytes) for ``state``; values outside a field's
        range are clamped, names the format has no field for are left out."""

    def neutral(self) -> bytes:
        """``pack(ControllerState.neutral())``: axes centred, triggers 0, nothing pressed."""

    def feature(self, report_id: int, identity: Identity) -> bytes:
        """The answer to a host's GET_REPORT(Feature, ``report_id``): the report with its id as
        byte 0, for the device of ``identity`` (a MAC, a serial).

        Raises:
            KeyError: ``report_id`` is not one of :attr:`feature_ids`.
        """

    def parse_output(self, data: bytes) -> list[Feedback]:
        """A host's output report (``data``, any length; the caller bounds it, a UHID or gadget
        read) as the rumble and LED requests in it; ``[]`` for one that asks nothing or is not
        understood. Never raises on any bytes."""


def _formats() -> dict[str, ReportFormat]:
    from neurotouch_hid.targets.reports.dualsense import DUALSENSE
    from neurotouch_hid.targets.reports.hid import HID_JOYSTICK
    from neurotouch_hid.targets.reports.keyboard import BOOT_KEYBOARD
    from neurotouch_hid.targets.reports.mouse import MOUSE
    from neurotouch_hid.targets.reports.switch import SWITCH
    from neurotouch_hid.targets.reports.xac import XAC
    from neurotouch_hid.targets.reports.xinput import XINPUT

    formats: list[ReportFormat] = [HID_JOYSTICK, BOOT_KEYBOARD, MOUSE, SWITCH, XINPUT, XAC, DUALSENSE]
    return {f.name: f for f in formats}


#: Every format by name.
FORMATS: dict[str, ReportFormat] = _formats()


def format_for(name: str) -> ReportFormat:
    """The format called ``name`` (a key of :data:`FORMATS`).

    Raises:
        NeurotouchError: no such format; the message lists those there are.
    """
    try:
        return FORMATS[name]
    except KeyError:
        raise NeurotouchError(f"unknown report format {name!r} (expected one of: {', '.join(FORMATS)})") from None
