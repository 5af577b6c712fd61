"""The wired HORIPAD-style report a Nintendo Switch accepts from a USB HID gamepad.

The Switch takes a plain HID gamepad (no handshake) when it has HORI's ids, 0f0d:00c1 ("HORIPAD
S"), and sends one 8-byte input report, no report id (docs/reports.md, "switch: the
HORIPAD-style Switch pad"):

====== =========================================================================================
byte   field
====== =========================================================================================
0-1    14 buttons, little-endian bit 0..13: Y B A X L R ZL ZR Minus Plus L3 R3 Home Capture
2      hat, low nibble: 0 up, clockwise to 7 up-left, 8 centred; high nibble 0
3-6    LX LY RX RY: 0..255, 128 centred, Y down (HID's convention)
7      vendor byte, 0
====== =========================================================================================

Its report descriptor declares 16 buttons, the hat with a null state, four 8-bit axes (X Y Z
Rz), a vendor input byte and an 8-byte vendor output report (which the Switch does not send
in practice). Public reference: GP2040-CE's ``headers/drivers/switch/SwitchDescriptors.h``
(MIT, github.com/OpenStickCommunity/GP2040-CE), read for the layout; the bytes here are written
from the HID 1.11 specification's item encoding.

The Xbox-layout state maps onto it by position: BTN_SOUTH (Xbox A, bottom) is the Switch's B,
BTN_EAST its A, BTN_NORTH (Xbox X, left) its Y, BTN_WEST (Xbox Y, top) its X; the analogue
triggers press ZL and ZR from :data:`TRIGGER_PRESS` on; BTN_MODE is Home; nothing maps to
Capture.
"""

from __future__ import annotations

import struct

from neurotouch_hid.core.controller import AXES, ControllerState
from neurotouch_hid.targets.reports.fields import InputOnly, axis
from neurotouch_hid.targets.reports.hid import hat_value

#: USB ids the Switch accepts a wired pad under: HORI, HORIPAD S.
VENDOR, PRODUCT = 0x0F0D, 0x00C1
#: A trigger at or above this (0..255) presses ZL / ZR: the Switch's triggers are buttons.
TRIGGER_PRESS = 128
#: Report bit -> the controller state's button (or trigger axis) that sets it.
BITS: tuple[tuple[int, str], ...] = (
    (0, "BTN_NORTH"),  # Y (left face button)
    (1, "BTN_SOUTH"),  # B (bottom)
    (2, "BTN_EAST"),  # A (right)
    (3, "BTN_WEST"),  # X (top)
    (4, "BTN_TL"),  # L
    (5, "BTN_TR"),  # R
    (6, "ABS_Z"),  # ZL, from the left trigger
    (7, "ABS_RZ"),  # ZR, from the right trigger
    (8, "BTN_SELECT"),  # Minus
    (9, "BTN_START"),  # Plus
    (10, "BTN_THUMBL"),  # L3
    (11, "BTN_THUMBR"),  # R3
    (12, "BTN_MODE"),  # Home
)

#: HID report descriptor (HID 1.11, 6.2.2): a Game Pad application collection.
DESCRIPTOR = bytes(
    [
        0x05, 0x01,  # Usage Page: Generic Desktop
        0x09, 0x05,  # Usage: Game Pad
        0xA1, 0x01,  # Collection: Application
        0x15, 0x00,  #   Logical Minimum 0
        0x25, 0x01,  #   Logical Maximum 1
        0x35, 0x00,  #   Physical Minimum 0
        0x45, 0x01,  #   Physical Maximum 1
        0x75, 0x01,  #   Report Size 1
        0x95, 0x10,  #   Report Count 16
        0x05, 0x09,  #   Usage Page: Button
        0x19, 0x01,  #   Usage Minimum 1
        0x29, 0x10,  #   Usage Maximum 16
        0x81, 0x02,  #   Input: Data, Variable, Absolute (the buttons, 2 bytes)
        0x05, 0x01,  #   Usage Page: Generic Desktop
        0x25, 0x07,  #   Logical Maximum 7
        0x46, 0x3B, 0x01,  # Physical Maximum 315 (degrees)
        0x75, 0x04,  #   Report Size 4
        0x95, 0x01,  #   Report Count 1
        0x65, 0x14,  #   Unit: English Rotation, degrees
        0x09, 0x39,  #   Usage: Hat switch
        0x81, 0x42,  #   Input: Data, Variable, Absolute, Null State (the hat nibble)
        0x65, 0x00,  #   Unit: none
        0x95, 0x01,  #   Report Count 1
        0x81, 0x01,  #   Input: Constant (the padding nibble)
        0x26, 0xFF, 0x00,  # Logical Maximum 255
        0x46, 0xFF, 0x00,  # Physical Maximum 255
        0x09, 0x30,  #   Usage: X
        0x09, 0x31,  #   Usage: Y
        0x09, 0x32,  #   Usage: Z
        0x09, 0x35,  #   Usage: Rz
        0x75, 0x08,  #   Report Size 8
        0x95, 0x04,  #   Report Count 4
        0x81, 0x02,  #   Input: Data, Variable, Absolute (LX LY RX RY)
        0x06, 0x00, 0xFF,  # Usage Page: Vendor Defined 0xFF00
        0x09, 0x20,  #   Usage: 0x20
        0x95, 0x01,  #   Report Count 1
        0x81, 0x02,  #   Input: Data, Variable, Absolute (the vendor byte)
        0x0A, 0x21, 0x26,  # Usage: 0x2621
        0x95, 0x08,  #   Report Count 8
        0x91, 0x02,  #   Output: Data, Variable, Absolute (8 vendor bytes)
        0xC0,  # End Collection
    ]
)  # fmt: skip


def stick_byte(value: int) -> int:
    """A stick axis (-32768..32767, evdev) as an unsigned byte, 128 centred: the high byte + 128."""
    return (value >> 8) + 128


class SwitchFormat(InputOnly):
    """The HORIPAD report (module docstring): ``pack`` gives 8 bytes; ``neutral`` the report with
    nothing pressed, the hat centred (8) and the sticks at 128. No feature report; the vendor
    output report asks nothing of the driver."""

    name = "switch"
    descriptor = DESCRIPTOR
    report_length = 8
    vendor, product = VENDOR, PRODUCT

    def pack(self, state: ControllerState) -> bytes:
        """``state`` as one 8-byte input report (little-endian buttons, hat, LX LY RX RY, vendor 0)."""
        buttons = 0
        for bit, name in BITS:
            pressed = axis(state, name) >= TRIGGER_PRESS if name in AXES else state.buttons.get(name, False)
            buttons |= bool(pressed) << bit
        sticks = (stick_byte(axis(state, name)) for name in ("ABS_X", "ABS_Y", "ABS_RX", "ABS_RY"))
        hat = hat_value(axis(state, "ABS_HAT0X"), axis(state, "ABS_HAT0Y"))
        return struct.pack("<HB4BB", buttons, hat, *sticks, 0)

    def neutral(self) -> bytes:
        """The report of :meth:`ControllerState.neutral`: ``00 00 08 80 80 80 80 00``."""
        return self.pack(ControllerState.neutral())


#: The Switch report's format.
SWITCH = SwitchFormat()
