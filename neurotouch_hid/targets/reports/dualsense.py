"""Sony's DualSense (054c:0ce6) on USB: the pad whose touchpad the hosts know.

Linux's hid-playstation makes three input devices of it (the pad, its Touchpad with two
multi-touch slots, its Motion Sensors), SDL and Steam read it through hidraw, and macOS, iOS and
Android take it natively. The layout, byte by byte, is docs/reports.md, "dualsense: the
DualSense on USB". Every fact here was read in the two host drivers that parse it: the kernel's
``drivers/hid/hid-playstation.c`` (``struct dualsense_input_report``, ``dualsense_parse_report``,
``dualsense_get_calibration_data``, ``dualsense_get_mac_address``,
``dualsense_get_firmware_info``, ``struct dualsense_output_report_common``) and SDL's
``src/joystick/hidapi/SDL_hidapi_ps5.c`` (``PS5StatePacket_t``, ``DS5EffectsState_t``,
``HIDAPI_DriverPS5_InitDevice``); the report descriptor is the USB DualSense's own layout as
github.com/nondebug/dualsense documents it. No code was copied.

* **Input report 0x01**, 64 bytes with its id: sticks and triggers 0..255 (128 centred), a
  counter, the hat and 15 button bits, gyro and accelerometer (int16, zero here: the gel has no
  IMU), the sensor timestamp (uint32 in 1/3 us: the state's camera time x 3, so it advances as
  the state does), the touchpad's two points, the battery status (full, on USB power).
* **Feature reports** (GET_REPORT), each with its id first: 0x05 calibration (41 bytes), 0x09
  pairing (20 bytes: the MAC), 0x20 firmware (64 bytes). hid-playstation reads all three before
  it binds ("Failed to retrieve ..." when one is missing or short) and refuses a second device
  with the same MAC ("Duplicate device found"), so the MAC is the camera's
  (:class:`~neurotouch_hid.targets.identity.Identity`).
* **Output report 0x02** (the host's rumble, lightbar and player LEDs; 0x31, the Bluetooth one,
  is read too: SDL sends it when no input report came in its first 16 ms, its sign of Bluetooth) becomes
  :class:`~neurotouch_hid.core.controller.Feedback`.

The buttons map by position, as the other protocols do: BTN_SOUTH (Xbox A, bottom) is cross,
BTN_EAST circle, BTN_NORTH (Xbox X as xpad names it, left) square, BTN_WEST (Xbox Y, top)
triangle; BTN_TL/BTN_TR L1/R1, BTN_SELECT create, BTN_START options, BTN_THUMBL/R L3/R3,
BTN_MODE the PS button; the triggers' analogue values also set the L2/R2 bits when above 0;
the touchpad click is :attr:`~neurotouch_hid.core.controller.ControllerState.touch_click`; nothing
drives the mute button.
"""

from __future__ import annotations

import struct
from typing import TYPE_CHECKING

from neurotouch_hid.core.controller import (
    TOUCH_SLOTS,
    TOUCHPAD_HEIGHT,
    TOUCHPAD_WIDTH,
    ControllerState,
    Feedback,
    TouchPoint,
)
from neurotouch_hid.targets.reports.fields import axis, clamp
from neurotouch_hid.targets.reports.hid import hat_value

if TYPE_CHECKING:
    from neurotouch_hid.targets.identity import Identity

#: USB ids: Sony Interactive Entertainment, DualSense Wireless Controller.
VENDOR, PRODUCT = 0x054C, 0x0CE6
#: The report ids (hid-playstation's DS_INPUT_REPORT_USB, DS_OUTPUT_REPORT_USB, DS_OUTPUT_REPORT_BT,
#: DS_FEATURE_REPORT_*).
INPUT_ID, OUTPUT_ID, OUTPUT_ID_BT = 0x01, 0x02, 0x31
CALIBRATION_ID, PAIRING_ID, FIRMWARE_ID = 0x05, 0x09, 0x20
#: Lengths with the report id, what hid-playstation requires of each.
INPUT_LENGTH = 64
FEATURE_LENGTHS: dict[int, int] = {CALIBRATION_ID: 41, PAIRING_ID: 20, FIRMWARE_ID: 64}
#: The output report's common part: hid-playstation's struct dualsense_output_report_common (47
#: bytes), after the report id on USB; on Bluetooth after id, sequence and tag (0x10) as
#: hid-playstation writes it, after id and 0x02 as SDL writes it.
OUTPUT_COMMON_AT = {OUTPUT_ID: 1, OUTPUT_ID_BT: 2}
#: hid-playstation's tag in byte 2 of a Bluetooth output report (DS_OUTPUT_TAG).
BT_TAG = 0x10
#: Longest output report looked at (the Bluetooth one, 78 bytes, is the longest there is).
MAX_OUTPUT_REPORT = 78

#: Bits of the button bytes (report bytes 8, 9, 10): state button -> (byte, bit).
BUTTON_BITS: dict[str, tuple[int, int]] = {
    "BTN_NORTH": (8, 4),  # square (left)
    "BTN_SOUTH": (8, 5),  # cross (bottom)
    "BTN_EAST": (8, 6),  # circle (right)
    "BTN_WEST": (8, 7),  # triangle (top)
    "BTN_TL": (9, 0),  # L1
    "BTN_TR": (9, 1),  # R1
    "BTN_SELECT": (9, 4),  # create
    "BTN_START": (9, 5),  # options
    "BTN_THUMBL": (9, 6),  # L3
    "BTN_THUMBR": (9, 7),  # R3
    "BTN_MODE": (10, 0),  # PS
}
#: L2 and R2's bits (byte 9): set while the trigger's analogue value is above 0.
L2_BIT, R2_BIT = 2, 3
#: The touchpad click (byte 10, bit 1) and the mute button (bit 2, never set).
TOUCH_CLICK_BIT, MUTE_BIT = 1, 2
#: A touch point's contact byte: bit 7 set = not touching (hid-playstation's DS_TOUCH_POINT_INACTIVE),
#: bits 0-6 the tracking id.
INACTIVE = 0x80
#: Where the two touch points start (4 bytes each).
TOUCH_AT = 33
#: The status byte: charging state 2 (full: hid-playstation reports 100 %, "Full") in bits 4-7,
#: level 10 (100 %) in bits 0-3: the gel runs on USB power.
STATUS_AT, STATUS_FULL = 53, 0x2A

# The report descriptor of a USB DualSense (HID 1.11, 6.2.2), item by item.
DESCRIPTOR = bytes(
    [
        0x05, 0x01,  # Usage Page (Generic Desktop)
        0x09, 0x05,  # Usage (Game Pad)
        0xA1, 0x01,  # Collection (Application)
        0x85, 0x01,  #   Report ID (1): the input report
        0x09, 0x30,  #   Usage (X)      left stick
        0x09, 0x31,  #   Usage (Y)
        0x09, 0x32,  #   Usage (Z)      right stick
        0x09, 0x35,  #   Usage (Rz)
        0x09, 0x33,  #   Usage (Rx)     L2
        0x09, 0x34,  #   Usage (Ry)     R2
        0x15, 0x00,  #   Logical Minimum (0)
        0x26, 0xFF, 0x00,  # Logical Maximum (255)
        0x75, 0x08,  #   Report Size (8)
        0x95, 0x06,  #   Report Count (6)
        0x81, 0x02,  #   Input (Data, Variable, Absolute)
        0x06, 0x00, 0xFF,  # Usage Page (Vendor 0xFF00)
        0x09, 0x20,  #   Usage (0x20)   counter
        0x95, 0x01,  #   Report Count (1)
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
        0x05, 0x09,  #   Usage Page (Button)
        0x19, 0x01,  #   Usage Minimum (1)
        0x29, 0x0F,  #   Usage Maximum (15)
        0x15, 0x00,  #   Logical Minimum (0)
        0x25, 0x01,  #   Logical Maximum (1)
        0x75, 0x01,  #   Report Size (1)
        0x95, 0x0F,  #   Report Count (15)
        0x81, 0x02,  #   Input (Data, Variable, Absolute)
        0x06, 0x00, 0xFF,  # Usage Page (Vendor 0xFF00)
        0x09, 0x21,  #   Usage (0x21)   13 more bits
        0x95, 0x0D,  #   Report Count (13)
        0x81, 0x02,  #   Input (Data, Variable, Absolute)
        0x06, 0x00, 0xFF,  # Usage Page (Vendor 0xFF00)
        0x09, 0x22,  #   Usage (0x22)   sensors, touchpad, status
        0x15, 0x00,  #   Logical Minimum (0)
        0x26, 0xFF, 0x00,  # Logical Maximum (255)
        0x75, 0x08,  #   Report Size (8)
        0x95, 0x34,  #   Report Count (52)
        0x81, 0x02,  #   Input (Data, Variable, Absolute)
        0x85, 0x02,  #   Report ID (2): the output report
        0x09, 0x23,  #   Usage (0x23)
        0x95, 0x2F,  #   Report Count (47)
        0x91, 0x02,  #   Output (Data, Variable, Absolute)
        0x85, 0x05, 0x09, 0x33, 0x95, 0x28, 0xB1, 0x02,  # Feature 0x05, 40 bytes: calibration
        0x85, 0x08, 0x09, 0x34, 0x95, 0x2F, 0xB1, 0x02,  # Feature 0x08, 47 bytes
        0x85, 0x09, 0x09, 0x24, 0x95, 0x13, 0xB1, 0x02,  # Feature 0x09, 19 bytes: pairing (MAC)
        0x85, 0x0A, 0x09, 0x25, 0x95, 0x1A, 0xB1, 0x02,  # Feature 0x0A, 26 bytes
        0x85, 0x20, 0x09, 0x26, 0x95, 0x3F, 0xB1, 0x02,  # Feature 0x20, 63 bytes: firmware
        0x85, 0x21, 0x09, 0x27, 0x95, 0x04, 0xB1, 0x02,  # Feature 0x21, 4 bytes
        0x85, 0x22, 0x09, 0x40, 0x95, 0x3F, 0xB1, 0x02,  # Feature 0x22, 63 bytes
        0x85, 0x80, 0x09, 0x28, 0x95, 0x3F, 0xB1, 0x02,  # Feature 0x80, 63 bytes
        0x85, 0x81, 0x09, 0x29, 0x95, 0x3F, 0xB1, 0x02,  # Feature 0x81, 63 bytes
        0x85, 0x82, 0x09, 0x2A, 0x95, 0x09, 0xB1, 0x02,  # Feature 0x82, 9 bytes
        0x85, 0x83, 0x09, 0x2B, 0x95, 0x3F, 0xB1, 0x02,  # Feature 0x83, 63 bytes
        0x85, 0x84, 0x09, 0x2C, 0x95, 0x3F, 0xB1, 0x02,  # Feature 0x84, 63 bytes
        0x85, 0x85, 0x09, 0x2D, 0x95, 0x02, 0xB1, 0x02,  # Feature 0x85, 2 bytes
        0x85, 0xA0, 0x09, 0x2E, 0x95, 0x01, 0xB1, 0x02,  # Feature 0xA0, 1 byte
        0x85, 0xE0, 0x09, 0x2F, 0x95, 0x3F, 0xB1, 0x02,  # Feature 0xE0, 63 bytes
        0x85, 0xF0, 0x09, 0x30, 0x95, 0x3F, 0xB1, 0x02,  # Feature 0xF0, 63 bytes
        0x85, 0xF1, 0x09, 0x31, 0x95, 0x3F, 0xB1, 0x02,  # Feature 0xF1, 63 bytes
        0x85, 0xF2, 0x09, 0x32, 0x95, 0x0F, 0xB1, 0x02,  # Feature 0xF2, 15 bytes
        0x85, 0xF4, 0x09, 0x35, 0x95, 0x3F, 0xB1, 0x02,  # Feature 0xF4, 63 bytes
        0x85, 0xF5, 0x09, 0x36, 0x95, 0x03, 0xB1, 0x02,  # Feature 0xF5, 3 bytes
        0xC0,  # End Collection
    ]
)  # fmt: skip

#: Feature 0x05, after its id: 17 int16 (hid-playstation's order): the gyro's pitch, yaw, roll
#: bias; pitch +/-, yaw +/-, roll +/- at the calibration speed; that speed + and -; the
#: accelerometer's x +/-, y +/-, z +/- at 1 g. Gyro: +/-8640 at +/-540 deg/s (16 counts per deg/s,
#: a DualSense's BMI gyro at +/-2000 deg/s) gives hid-playstation 1080 * 1024 / 17280 = 64 units
#: of 1/1024 deg/s per count; accelerometer: +/-8192 at 1 g (its +/-4 g range), bias 0, 2 * 8192
#: / 16384 = 1 unit of 1/8192 g per count. No divisor is zero and the gel's zero samples read 0.
CALIBRATION: tuple[int, ...] = (0, 0, 0) + (8640, -8640) * 3 + (540, 540) + (8192, -8192) * 3
#: Feature 0x20: build date and time (ASCII, bytes 1-11 and 12-19), the hardware and firmware
#: versions (uint32 at 24 and 28, what hid-playstation logs and shows in sysfs) and the update
#: version (uint16 at 44): 0x0224 makes hid-playstation (from 2.21, 0x0215) and SDL (from
#: 0x0224) send rumble the way current firmware takes it (valid_flag2 bit 2).
FIRMWARE_DATE, FIRMWARE_TIME = b"Jan  1 2026", b"00:00:00"
HW_VERSION, FW_VERSION, UPDATE_VERSION = 0x00000001, 0x00010000, 0x0224

# The output report's common part (hid-playstation's dualsense_output_report_common), offsets
# within it, and its valid_flag bits.
_FLAG0, _FLAG1, _MOTOR_RIGHT, _MOTOR_LEFT, _FLAG2, _PLAYER_LEDS, _RED = 0, 1, 2, 3, 38, 43, 44
_COMPATIBLE_VIBRATION = 0x01  # valid_flag0 bit 0
_COMPATIBLE_VIBRATION2 = 0x04  # valid_flag2 bit 2 (firmware from 2.21)
_LIGHTBAR = 0x04  # valid_flag1 bit 2
_PLAYER_INDICATOR = 0x10  # valid_flag1 bit 4
#: The five player LEDs (bits 0-4 of player_leds; bit 5 = change at once rather than fade).
PLAYER_LED_MASK = 0x1F


def stick_byte(value: int) -> int:
    """A stick axis (-32768..32767, clamped) as the DualSense's 0..255 (128 centred)."""
    return (clamp(value, -32768, 32767) + 32768) >> 8


def touch_bytes(point: TouchPoint | None) -> bytes:
    """One touch point's 4 bytes: contact (tracking id in bits 0-6, bit 7 set when not
    touching), x (12 bits: bits 0-7 in byte 1, 8-11 in the low nibble of byte 2), y (12 bits:
    bits 0-3 in the high nibble of byte 2, 4-11 in byte 3); x, y clamped to the pad.
    ``None`` (no point): ``80 00 00 00``."""
    if point is None:
        return bytes([INACTIVE, 0, 0, 0])
    x = clamp(point.x, 0, TOUCHPAD_WIDTH - 1)
    y = clamp(point.y, 0, TOUCHPAD_HEIGHT - 1)
    contact = (point.id & 0x7F) | (0 if point.active else INACTIVE)
    return bytes([contact, x & 0xFF, (x >> 8) | (y & 0x0F) << 4, y >> 4])


class DualSenseFormat:
    """The DualSense's report format (:class:`~neurotouch_hid.targets.reports.ReportFormat`):
    input report 0x01, feature reports 0x05, 0x09, 0x20, output report 0x02 (and 0x31)."""

    name = "dualsense"
    vendor, product = VENDOR, PRODUCT
    descriptor = DESCRIPTOR
    report_length = INPUT_LENGTH
    feature_ids: tuple[int, ...] = (CALIBRATION_ID, PAIRING_ID, FIRMWARE_ID)

    def pack(self, state: ControllerState) -> bytes:
        """The 64-byte input report 0x01 for ``state`` (docs/reports.md, "dualsense: the DualSense
        on USB"): id, LX, LY, RX, RY, L2, R2 (0..255), counter 0, hat and buttons (bytes 8-10),
        vendor byte 0, 4 reserved, gyro and accelerometer 0, sensor timestamp ``t_us * 3`` mod
        2**32 (1/3 us), the two touch points (:func:`touch_bytes`; slots past the state's are not
        touching), the status (full, on USB power), zeros."""
        report = bytearray(INPUT_LENGTH)
        report[0] = INPUT_ID
        report[1] = stick_byte(axis(state, "ABS_X"))
        report[2] = stick_byte(axis(state, "ABS_Y"))
        report[3] = stick_byte(axis(state, "ABS_RX"))
        report[4] = stick_byte(axis(state, "ABS_RY"))
        left, right = axis(state, "ABS_Z"), axis(state, "ABS_RZ")
        report[5], report[6] = left, right
        report[8] = hat_value(axis(state, "ABS_HAT0X"), axis(state, "ABS_HAT0Y"))
        for name, (byte, bit) in BUTTON_BITS.items():
            if state.buttons.get(name, False):
                report[byte] |= 1 << bit
        report[9] |= (left > 0) << L2_BIT | (right > 0) << R2_BIT
        report[10] |= bool(state.touch_click) << TOUCH_CLICK_BIT
        struct.pack_into("<I", report, 28, (int(state.t_us) * 3) & 0xFFFFFFFF)
        for slot in range(TOUCH_SLOTS):
            point = state.touches[slot] if slot < len(state.touches) else None
            report[TOUCH_AT + 4 * slot : TOUCH_AT + 4 * slot + 4] = touch_bytes(point)
        report[STATUS_AT] = STATUS_FULL
        return bytes(report)

    def neutral(self) -> bytes:
        """``pack(ControllerState.neutral())``: sticks at 128, triggers 0, hat 8, nothing pressed,
        timestamp 0, both touch points not touching (``80 00 00 00``)."""
        return self.pack(ControllerState.neutral())

    def feature(self, report_id: int, identity: Identity) -> bytes:
        """The answer to GET_REPORT(Feature, ``report_id``), the report id first: 0x05 the
        calibration (41 bytes, :data:`CALIBRATION`), 0x09 the pairing information (20 bytes: the
        MAC in bytes 1-6, last octet first, as hid-playstation copies it and prints it with
        ``%pMR``; no paired host), 0x20 the firmware information (64 bytes).

        Raises:
            KeyError: ``report_id`` is not in :attr:`feature_ids`.
        """
        if report_id == CALIBRATION_ID:
            body = struct.pack("<17h", *CALIBRATION)
        elif report_id == PAIRING_ID:
            body = bytes(reversed(identity.mac[:6]))
        elif report_id == FIRMWARE_ID:
            body = bytearray(63)
            body[0:11], body[11:19] = FIRMWARE_DATE, FIRMWARE_TIME
            struct.pack_into("<II", body, 23, HW_VERSION, FW_VERSION)
            struct.pack_into("<H", body, 43, UPDATE_VERSION)
        else:
            raise KeyError(report_id)
        return bytes([report_id]) + bytes(body).ljust(FEATURE_LENGTHS[report_id] - 1, b"\0")

    def parse_output(self, data: bytes, source: str = "") -> list[Feedback]:
        """A host's output report as :class:`~neurotouch_hid.core.controller.Feedback` (at most
        :data:`MAX_OUTPUT_REPORT` bytes are looked at; never raises):

        - ``rumble`` when valid_flag0 bit 0 or valid_flag2 bit 2 is set: strong = motor_left / 255
          (the low-frequency motor), weak = motor_right / 255, until the next one;
        - ``led`` when valid_flag1 bit 4 is set: the five player LEDs' bits (bit 0 leftmost);
        - ``lightbar`` when valid_flag1 bit 2 is set: ``led`` = 0xRRGGBB.

        Report 0x02 (USB) and 0x31 (Bluetooth: its common part from byte 3 after hid-playstation's
        tag 0x10 in byte 2, else from byte 2 as SDL writes it) are read; anything else, or a
        report too short for a field, gives nothing for it."""
        data = bytes(data[:MAX_OUTPUT_REPORT])
        if not data or data[0] not in OUTPUT_COMMON_AT:
            return []
        start = OUTPUT_COMMON_AT[data[0]]
        if data[0] == OUTPUT_ID_BT and len(data) > 2 and data[2] == BT_TAG:
            start = 3  # hid-playstation's: id, sequence << 4, tag
        common = data[start:]

        def at(offset: int) -> int:
            return common[offset] if offset < len(common) else 0

        found: list[Feedback] = []
        if len(common) > _MOTOR_LEFT and (at(_FLAG0) & _COMPATIBLE_VIBRATION or at(_FLAG2) & _COMPATIBLE_VIBRATION2):
            found.append(Feedback("rumble", strong=at(_MOTOR_LEFT) / 255, weak=at(_MOTOR_RIGHT) / 255, source=source))
        if len(common) > _PLAYER_LEDS and at(_FLAG1) & _PLAYER_INDICATOR:
            found.append(Feedback("led", led=at(_PLAYER_LEDS) & PLAYER_LED_MASK, source=source))
        if len(common) > _RED + 2 and at(_FLAG1) & _LIGHTBAR:
            rgb = at(_RED) << 16 | at(_RED + 1) << 8 | at(_RED + 2)
            found.append(Feedback("lightbar", led=rgb, source=source))
        return found


#: The one instance (the format keeps no state).
DUALSENSE = DualSenseFormat()
