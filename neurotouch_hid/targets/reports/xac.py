"""The joystick the Xbox Adaptive Controller reads on its side USB ports: four 8-bit axes, a hat,
12 buttons, nothing else.

The Adaptive Controller takes a USB joystick on each of its two side ports and maps it to one side
of the Xbox pad (the left port: left stick, the right port: right stick, the hat the d-pad, the
buttons to its own button mapping). The devices makers report working there (joysticks made with
microcontrollers) have one HID interface whose application collection is a **Joystick** with four
unsigned 8-bit axes 0..255 (X, Y, Z, Rz), a hat and 12 buttons, and nothing more in the device
(no keyboard, no mouse, no other report), polled every 1 ms; the controller's firmware of June
2024 or later. Signed 16-bit axes, Brake/Accelerator triggers (the ``hid`` report) and more
functions in the device are what it is reported to refuse. Input report, 7 bytes, no report id
(docs/reports.md, "xac: the Adaptive Controller's joystick"):

====== ==========================================================================================
byte   field
====== ==========================================================================================
0-3    X Y Z Rz: the left stick (X, Y) and the right stick (Z, Rz), 0..255, 128 centred, Y down
4      hat, low nibble: 0 up, clockwise to 7 up-left, 8 centred (Null State); high nibble 0
5-6    12 buttons, little-endian bits 0..11 (usages 1..12); bits 12..15 0
====== ==========================================================================================

Buttons 1..11 are the ``hid`` report's (:data:`~neurotouch_hid.targets.reports.hid.BUTTON_ORDER`:
A, B, X, Y, the bumpers, back, start, the stick clicks, the guide); button 12 is always 0. The
analogue triggers are not carried (the layout has no axis for them): a profile maps a trigger's
gesture to a button for this protocol.

Sources: Device Class Definition for HID 1.11 (usb.org), 6.2.2 (report descriptor items); HID
Usage Tables 1.4 (usb.org), 4 (Generic Desktop), 12 (Button).
"""

from __future__ import annotations

import struct

from neurotouch_hid.core.controller import ControllerState
from neurotouch_hid.targets.reports.fields import InputOnly, axis
from neurotouch_hid.targets.reports.hid import BUTTON_ORDER, hat_value
from neurotouch_hid.targets.reports.switch import stick_byte

#: HID buttons in the report (usages 1..12); BUTTON_ORDER fills the first ones.
BUTTON_COUNT = 12

# The report descriptor, item by item (HID 1.11, 6.2.2: prefix byte = tag | type | size code).
DESCRIPTOR = bytes(
    [
        0x05, 0x01,  # Usage Page (Generic Desktop)
        0x09, 0x04,  # Usage (Joystick)
        0xA1, 0x01,  # Collection (Application)
        0x09, 0x30,  #   Usage (X)          left stick
        0x09, 0x31,  #   Usage (Y)
        0x09, 0x32,  #   Usage (Z)          right stick
        0x09, 0x35,  #   Usage (Rz)
        0x15, 0x00,  #   Logical Minimum (0)
        0x26, 0xFF, 0x00,  # Logical Maximum (255)
        0x75, 0x08,  #   Report Size (8)
        0x95, 0x04,  #   Report Count (4)
        0x81, 0x02,  #   Input (Data, Variable, Absolute)
        0x09, 0x39,  #   Usage (Hat switch)
        0x25, 0x07,  #   Logical Maximum (7)
        0x35, 0x00,  #   Physical Minimum (0)
        0x46, 0x3B, 0x01,  # Physical Maximum (315)
        0x65, 0x14,  #   Unit (English Rotation, degrees)
        0x75, 0x04,  #   Report Size (4)
        0x95, 0x01,  #   Report Count (1)
        0x81, 0x42,  #   Input (Data, Variable, Absolute, Null State)
        0x65, 0x00,  #   Unit (none)
        0x45, 0x00,  #   Physical Maximum (0): physical = logical again
        0x81, 0x03,  #   Input (Constant): the hat byte's high nibble
        0x05, 0x09,  #   Usage Page (Button)
        0x19, 0x01,  #   Usage Minimum (1)
        0x29, 0x0C,  #   Usage Maximum (12)
        0x25, 0x01,  #   Logical Maximum (1)
        0x75, 0x01,  #   Report Size (1)
        0x95, 0x0C,  #   Report Count (12)
        0x81, 0x02,  #   Input (Data, Variable, Absolute)
        0x75, 0x04,  #   Report Size (4)
        0x95, 0x01,  #   Report Count (1)
        0x81, 0x03,  #   Input (Constant): bits 12..15
        0xC0,  # End Collection
    ]
)  # fmt: skip

_REPORT = struct.Struct("<4BBH")


class XacJoystick(InputOnly):
    """The Adaptive Controller's joystick report (module docstring): ``pack`` gives 7 bytes;
    ``neutral`` the sticks at 128, the hat centred (8), nothing pressed; no feature and no output
    report (:class:`~neurotouch_hid.targets.reports.fields.InputOnly`)."""

    name = "xac"
    descriptor = DESCRIPTOR
    report_length = _REPORT.size

    def pack(self, state: ControllerState) -> bytes:
        """``state`` as one 7-byte input report (X Y Z Rz, hat, buttons 1..12 little-endian)."""
        sticks = (stick_byte(axis(state, name)) for name in ("ABS_X", "ABS_Y", "ABS_RX", "ABS_RY"))
        hat = hat_value(axis(state, "ABS_HAT0X"), axis(state, "ABS_HAT0Y"))
        buttons = sum(1 << i for i, name in enumerate(BUTTON_ORDER[:BUTTON_COUNT]) if state.buttons.get(name, False))
        return _REPORT.pack(*sticks, hat, buttons)

    def neutral(self) -> bytes:
        """The report of :meth:`ControllerState.neutral`: ``80 80 80 80 08 00 00``."""
        return self.pack(ControllerState.neutral())


#: The Adaptive Controller joystick's format.
XAC = XacJoystick()
