"""The USB mouse: five buttons, X, Y, the wheel and the horizontal wheel, one byte each, 5 bytes.

Its first three bytes are the boot mouse's (HID 1.11, Appendix B.2: buttons, X, Y), so boot
protocol hosts read it too; the wheel (Generic Desktop Wheel, 0x38) and the horizontal wheel
(Consumer page AC Pan, 0x0238, what hid-input maps to REL_HWHEEL) follow. The layout is
docs/reports.md, "mouse: the mouse".

From a :class:`~neurotouch_hid.core.controller.ControllerState`: buttons 1..5 are BTN_LEFT,
BTN_RIGHT, BTN_MIDDLE, BTN_SIDE, BTN_EXTRA of ``state.keys``; X, Y, wheel and pan are
``state.rel``'s REL_X, REL_Y, REL_WHEEL, REL_HWHEEL (a wheel given only in hi-res units, 1/120
detent, counts whole detents), each clamped to -127..127: a larger motion in one state is cut
there (the profiles' pointer speeds move a few counts per window).

Sources: Device Class Definition for HID 1.11 (usb.org), Appendix B.2; HID Usage Tables 1.4
(usb.org), 4 (Generic Desktop), 12 (Button), 15 (Consumer: AC Pan).
"""

from __future__ import annotations

import struct

from neurotouch_hid.core.controller import MOUSE_BUTTONS, ControllerState
from neurotouch_hid.targets.reports.fields import InputOnly, clamp

#: One motion field's range (8-bit signed, the boot mouse's -127..127).
REL_MIN, REL_MAX = -127, 127
#: Hi-res wheel units per detent (the kernel's REL_WHEEL_HI_RES convention).
HI_RES_PER_DETENT = 120

DESCRIPTOR = bytes(
    [
        0x05, 0x01,  # Usage Page (Generic Desktop)
        0x09, 0x02,  # Usage (Mouse)
        0xA1, 0x01,  # Collection (Application)
        0x09, 0x01,  #   Usage (Pointer)
        0xA1, 0x00,  #   Collection (Physical)
        0x05, 0x09,  #     Usage Page (Button)
        0x19, 0x01,  #     Usage Minimum (Button 1)
        0x29, 0x05,  #     Usage Maximum (Button 5)
        0x15, 0x00,  #     Logical Minimum (0)
        0x25, 0x01,  #     Logical Maximum (1)
        0x75, 0x01,  #     Report Size (1)
        0x95, 0x05,  #     Report Count (5)
        0x81, 0x02,  #     Input (Data, Variable, Absolute): buttons 1..5
        0x75, 0x03,  #     Report Size (3)
        0x95, 0x01,  #     Report Count (1)
        0x81, 0x01,  #     Input (Constant): padding
        0x05, 0x01,  #     Usage Page (Generic Desktop)
        0x09, 0x30,  #     Usage (X)
        0x09, 0x31,  #     Usage (Y)
        0x09, 0x38,  #     Usage (Wheel)
        0x15, 0x81,  #     Logical Minimum (-127)
        0x25, 0x7F,  #     Logical Maximum (127)
        0x75, 0x08,  #     Report Size (8)
        0x95, 0x03,  #     Report Count (3)
        0x81, 0x06,  #     Input (Data, Variable, Relative)
        0x05, 0x0C,  #     Usage Page (Consumer)
        0x0A, 0x38, 0x02,  # Usage (AC Pan)
        0x95, 0x01,  #     Report Count (1)
        0x81, 0x06,  #     Input (Data, Variable, Relative)
        0xC0,  #   End Collection
        0xC0,  # End Collection
    ]
)  # fmt: skip

_REPORT = struct.Struct("<B4b")


def _wheel(rel: dict[str, int], name: str) -> int:
    if rel.get(name):
        return rel[name]
    return int(rel.get(f"{name}_HI_RES", 0) / HI_RES_PER_DETENT)


class Mouse(InputOnly):
    """The mouse's report format (:class:`~neurotouch_hid.targets.reports.ReportFormat`): no
    feature report, no output report."""

    name = "mouse"
    descriptor = DESCRIPTOR
    report_length = _REPORT.size

    def pack(self, state: ControllerState) -> bytes:
        """The 5-byte input report (docs/reports.md, "mouse: the mouse"): :data:`MOUSE_BUTTONS` of
        ``state.keys`` as bits 0..4, then REL_X, REL_Y, the wheel and the horizontal wheel of
        ``state.rel``, each clamped to -127..127."""
        buttons = sum(1 << bit for bit, name in enumerate(MOUSE_BUTTONS) if name in state.keys)
        rel = state.rel
        return _REPORT.pack(
            buttons,
            clamp(rel.get("REL_X", 0), REL_MIN, REL_MAX),
            clamp(rel.get("REL_Y", 0), REL_MIN, REL_MAX),
            clamp(_wheel(rel, "REL_WHEEL"), REL_MIN, REL_MAX),
            clamp(_wheel(rel, "REL_HWHEEL"), REL_MIN, REL_MAX),
        )

    def neutral(self) -> bytes:
        """Five zero bytes: no button, no motion."""
        return self.pack(ControllerState.neutral())


#: The one instance (the format keeps no state).
MOUSE = Mouse()
