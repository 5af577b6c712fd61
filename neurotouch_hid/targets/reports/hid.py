"""The generic USB HID joystick: two sticks, two analogue triggers, a hat and 16 buttons.

What any HID host reads without a driver of its own: Windows (DirectInput), macOS, Linux
(hid-generic, hid-input), Android. (The Xbox Adaptive Controller takes a narrower joystick, four
8-bit axes, a hat and 12 buttons: the ``xac`` layout, :mod:`~neurotouch_hid.targets.reports.xac`.)
The layout, byte by byte, is docs/reports.md, "hid: the generic HID joystick".

Choices, and why:

* Application collection **Joystick** (Generic Desktop 0x04; HID Usage Tables 1.4, 4.1), not
  Gamepad (0x05), as the Adaptive Controller's joysticks have it. hid-input then names the buttons
  BTN_TRIGGER..BTN_DEAD (its joystick range) and udev classes the device a joystick.
* Sticks: X/Y (0x30/0x31) the left stick, **Z/Rz** (0x32/0x35) the right one, 16-bit signed,
  -32768..32767, the :class:`~neurotouch_hid.core.controller.ControllerState` values as they are
  (+x right, +y down, HID's convention too). hid-input maps them to ABS_X/ABS_Y/ABS_Z/ABS_RZ.
* Triggers: Simulation Controls **Brake** (0x02/0xC5, the left trigger) and **Accelerator**
  (0x02/0xC4, the right one), 0..255: what the Stadia controller and 8BitDo's DirectInput mode
  use beside Z/Rz sticks. Rx/Ry would have been the other choice, but hosts and SDL's guesses
  read Rx/Ry as a right stick; hid-input maps Brake/Accelerator to ABS_BRAKE/ABS_GAS, which SDL
  reads as two more joystick axes, and Windows as axes of their own.
* Hat switch (0x39): 4 bits, logical 0..7 clockwise from north in 45 degree steps (Physical
  0..315, Unit degrees), 8 = centred: out of the logical range with the Null State flag set
  (HID 1.11, 6.2.2.5 Main items, bit 6), which hid-input reads as centred.
* Buttons (Button page 0x09, usages 1..16), one bit each: 1..11 are the controller's buttons in
  :data:`BUTTON_ORDER` (the order an Xbox 360 pad has under DirectInput, then the guide), 12..16
  are always 0.

Sources: Device Class Definition for HID 1.11 (usb.org), 6.2.2 (report descriptor items);
HID Usage Tables 1.4 (usb.org), 4 (Generic Desktop), 5 (Simulation Controls), 12 (Button).
"""

from __future__ import annotations

import struct

from neurotouch_hid.core.controller import BUTTONS, ControllerState
from neurotouch_hid.targets.reports.fields import InputOnly, axis

#: The controller's buttons (evdev names) as HID buttons 1..11: A, B, X, Y (the evdev names xpad
#: gives them), the bumpers, back, start, the stick clicks (the controller's order), then the guide.
BUTTON_ORDER: tuple[str, ...] = tuple(b for b in BUTTONS if b != "BTN_MODE") + ("BTN_MODE",)
#: HID buttons in the report (usages 1..BUTTON_COUNT); those past BUTTON_ORDER are always 0.
BUTTON_COUNT = 16
#: The hat's value for each (ABS_HAT0X, ABS_HAT0Y) (evdev: -1 left / up): 0 north, clockwise.
HAT_VALUES: dict[tuple[int, int], int] = {
    (0, -1): 0,
    (1, -1): 1,
    (1, 0): 2,
    (1, 1): 3,
    (0, 1): 4,
    (-1, 1): 5,
    (-1, 0): 6,
    (-1, -1): 7,
}
#: The hat centred: outside its logical range 0..7 (the Null State).
HAT_NULL = 8

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
        0x16, 0x00, 0x80,  # Logical Minimum (-32768)
        0x26, 0xFF, 0x7F,  # Logical Maximum (32767)
        0x75, 0x10,  #   Report Size (16)
        0x95, 0x04,  #   Report Count (4)
        0x81, 0x02,  #   Input (Data, Variable, Absolute)
        0x05, 0x02,  #   Usage Page (Simulation Controls)
        0x09, 0xC5,  #   Usage (Brake)      left trigger
        0x09, 0xC4,  #   Usage (Accelerator) right trigger
        0x15, 0x00,  #   Logical Minimum (0)
        0x26, 0xFF, 0x00,  # Logical Maximum (255)
        0x75, 0x08,  #   Report Size (8)
        0x95, 0x02,  #   Report Count (2)
        0x81, 0x02,  #   Input (Data, Variable, Absolute)
        0x05, 0x01,  #   Usage Page (Generic Desktop)
        0x09, 0x39,  #   Usage (Hat switch)
        0x15, 0x00,  #   Logical Minimum (0)
        0x25, 0x07,  #   Logical Maximum (7)
        0x35, 0x00,  #   Physical Minimum (0)
        0x46, 0x3B, 0x01,  # Physical Maximum (315)
        0x65, 0x14,  #   Unit (English Rotation: degrees)
        0x75, 0x04,  #   Report Size (4)
        0x95, 0x01,  #   Report Count (1)
        0x81, 0x42,  #   Input (Data, Variable, Absolute, Null State)
        0x65, 0x00,  #   Unit (None)
        0x45, 0x00,  #   Physical Maximum (0)
        0x81, 0x03,  #   Input (Constant, Variable, Absolute): 4 bits of padding
        0x05, 0x09,  #   Usage Page (Button)
        0x19, 0x01,  #   Usage Minimum (Button 1)
        0x29, BUTTON_COUNT,  # Usage Maximum (Button 16)
        0x15, 0x00,  #   Logical Minimum (0)
        0x25, 0x01,  #   Logical Maximum (1)
        0x75, 0x01,  #   Report Size (1)
        0x95, BUTTON_COUNT,  # Report Count (16)
        0x81, 0x02,  #   Input (Data, Variable, Absolute)
        0xC0,  # End Collection
    ]
)  # fmt: skip

#: The input report: X, Y, Z, Rz (int16 little-endian), Brake, Accelerator (uint8), the hat in
#: the low nibble of one byte, the buttons (uint16 little-endian, button 1 in bit 0). 13 bytes.
_REPORT = struct.Struct("<4h2BBH")


def hat_value(x: int, y: int) -> int:
    """The hat switch's value for the d-pad's ``ABS_HAT0X``/``ABS_HAT0Y`` (-1..1 each, clamped):
    0 north .. 7 north-west, :data:`HAT_NULL` when centred."""
    return HAT_VALUES.get((max(-1, min(1, x)), max(-1, min(1, y))), HAT_NULL)


class HidJoystick(InputOnly):
    """The generic HID joystick's report format (:class:`~neurotouch_hid.targets.reports.ReportFormat`):
    no feature report, no output report."""

    name = "hid"
    descriptor = DESCRIPTOR
    report_length = _REPORT.size

    def pack(self, state: ControllerState) -> bytes:
        """The 13-byte input report for ``state`` (docs/reports.md, "hid: the generic HID
        joystick"): sticks and triggers clamped to their ranges, the d-pad as the hat,
        :data:`BUTTON_ORDER` as buttons 1..11."""
        buttons = 0
        for bit, name in enumerate(BUTTON_ORDER):
            if state.buttons.get(name, False):
                buttons |= 1 << bit
        return _REPORT.pack(
            axis(state, "ABS_X"),
            axis(state, "ABS_Y"),
            axis(state, "ABS_RX"),
            axis(state, "ABS_RY"),
            axis(state, "ABS_Z"),
            axis(state, "ABS_RZ"),
            hat_value(axis(state, "ABS_HAT0X"), axis(state, "ABS_HAT0Y")),
            buttons,
        )

    def neutral(self) -> bytes:
        """The report of :meth:`ControllerState.neutral`: all zero but the hat's null (8)."""
        return self.pack(ControllerState.neutral())


#: The one instance (the format keeps no state).
HID_JOYSTICK = HidJoystick()
