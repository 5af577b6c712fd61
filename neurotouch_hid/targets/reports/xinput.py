"""The Xbox 360 wired controller's reports, as Windows' XInput driver and Linux's ``xpad`` read them.

The pad is a vendor interface (class FF, subclass 5D, protocol 01) with an interrupt IN and an
interrupt OUT endpoint, no HID report descriptor. Input report, 20 bytes (docs/reports.md,
"xinput: the Xbox 360 wired pad"; the layout xpad's ``xpad360_process_packet`` reads,
linux/drivers/input/joystick/xpad.c):

======= ========================================================================================
byte    field
======= ========================================================================================
0, 1    message type 0x00, length 0x14
2       d-pad up, down, left, right, Start, Back, left stick press, right stick press (bit 0..7)
3       LB, RB, Guide, (unused), A, B, X, Y (bit 0..7)
4, 5    left and right trigger, 0..255
6-13    LX, LY, RX, RY: little-endian int16, Y *up* (the opposite of evdev)
14-19   0
======= ========================================================================================

Output reports from the host (xpad's ``xpad_play_effect`` and ``xpad_send_led_command``):
rumble ``00 08 00 STRONG WEAK 00 00 00`` (the low- and high-frequency motors, 0..255) and LED
``01 03 NN`` (NN the pattern, 0..15: 0 off, 2-5 player 1-4 on, ...). :func:`parse_output` reads
them, bounded, as :class:`~neurotouch_hid.core.stages.Feedback`.

The Y axes are sent negated (``-y``, 32767 for -32768), so that the neutral state is all zeros;
xpad inverts them bitwise (``~y``), so an evdev reader sees the state's Y minus one (-1 at rest).
"""

from __future__ import annotations

import struct
from typing import TYPE_CHECKING

from neurotouch_hid.core.controller import ControllerState, Feedback
from neurotouch_hid.targets.reports.fields import axis

if TYPE_CHECKING:
    from neurotouch_hid.targets.identity import Identity

#: USB ids of the wired Xbox 360 controller (Microsoft), and its bcdDevice.
VENDOR, PRODUCT, VERSION = 0x045E, 0x028E, 0x0114
#: The interface's class, subclass and protocol (vendor specific; xpad's XPAD_XBOX360_VENDOR).
INTERFACE_CLASS = (0xFF, 0x5D, 0x01)
#: Longest output report handled (bytes); xpad sends 8 (rumble) or 3 (LED). Anything longer
#: is cut to this before it is looked at.
MAX_OUTPUT_REPORT = 32

#: Byte 2's bits: (bit, ``("button", name)`` or ``("hat", axis, value)``).
BYTE2: tuple[tuple[int, tuple], ...] = (
    (0, ("hat", "ABS_HAT0Y", -1)),  # d-pad up
    (1, ("hat", "ABS_HAT0Y", 1)),  # d-pad down
    (2, ("hat", "ABS_HAT0X", -1)),  # d-pad left
    (3, ("hat", "ABS_HAT0X", 1)),  # d-pad right
    (4, ("button", "BTN_START")),
    (5, ("button", "BTN_SELECT")),  # Back
    (6, ("button", "BTN_THUMBL")),
    (7, ("button", "BTN_THUMBR")),
)
#: Byte 3's bits -> button (bit 3 is unused).
BYTE3: tuple[tuple[int, str], ...] = (
    (0, "BTN_TL"),
    (1, "BTN_TR"),
    (2, "BTN_MODE"),  # Guide
    (4, "BTN_SOUTH"),  # A
    (5, "BTN_EAST"),  # B
    (6, "BTN_NORTH"),  # X (evdev's BTN_X is BTN_NORTH)
    (7, "BTN_WEST"),  # Y (evdev's BTN_Y is BTN_WEST)
)


def _bit(state: ControllerState, what: tuple) -> bool:
    if what[0] == "hat":
        return axis(state, what[1]) == what[2]
    return bool(state.buttons.get(what[1], False))


def up(value: int) -> int:
    """An evdev Y axis (+ down, -32768..32767) as XInput's (+ up), clamped to int16."""
    return min(-value, 32767)


class XInputFormat:
    """The 20-byte input report (module docstring); no HID descriptor (``descriptor`` is b"")."""

    name = "xinput"
    descriptor = b""
    report_length = 20
    vendor, product = VENDOR, PRODUCT

    def pack(self, state: ControllerState) -> bytes:
        """``state`` as one 20-byte input report: ``00 14``, the two button bytes, the
        triggers (0..255), the sticks (little-endian int16, Y up), six zero bytes."""
        low = sum(1 << bit for bit, what in BYTE2 if _bit(state, what))
        high = sum(1 << bit for bit, name in BYTE3 if state.buttons.get(name, False))
        return struct.pack(
            "<BBBBBBhhhh6x",
            0x00,
            0x14,
            low,
            high,
            axis(state, "ABS_Z"),
            axis(state, "ABS_RZ"),
            axis(state, "ABS_X"),
            up(axis(state, "ABS_Y")),
            axis(state, "ABS_RX"),
            up(axis(state, "ABS_RY")),
        )

    def neutral(self) -> bytes:
        """``00 14`` and 18 zero bytes: nothing pressed, sticks centred, triggers 0."""
        return self.pack(ControllerState.neutral())

    #: The Xbox 360 pad has no feature report (a vendor interface: no GET_REPORT).
    feature_ids: tuple[int, ...] = ()

    def feature(self, report_id: int, identity: Identity) -> bytes:
        """Raises KeyError: the pad has no feature report."""
        raise KeyError(report_id)

    def parse_output(self, data: bytes) -> list[Feedback]:
        """The rumble or LED request in the host's output report (:func:`parse_output`); ``[]``
        for anything else."""
        request = parse_output(data)
        return [] if request is None else [request]


#: The Xbox 360 report's format.
XINPUT = XInputFormat()


def parse_output(data: bytes, source: str = "") -> Feedback | None:
    """One output report the host sent on the OUT endpoint (``data``: at most
    :data:`MAX_OUTPUT_REPORT` bytes are looked at) as :class:`Feedback`: rumble
    (``00 08 00 STRONG WEAK ...`` -> strong, weak in 0..1) or LED (``01 03 NN`` -> led NN & 0x0F);
    None for anything else (too short, shorter than its own length byte says, an unknown type).
    Never raises on any bytes."""
    data = bytes(data[:MAX_OUTPUT_REPORT])
    if len(data) >= 5 and data[0] == 0x00 and 5 <= data[1] <= len(data):
        return Feedback("rumble", strong=data[3] / 255, weak=data[4] / 255, source=source)
    if len(data) >= 3 and data[0] == 0x01 and 3 <= data[1] <= len(data):
        return Feedback("led", led=data[2] & 0x0F, source=source)
    return None
