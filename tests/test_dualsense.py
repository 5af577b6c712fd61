"""The DualSense encoder (neurotouch_hid/targets/reports/dualsense.py) byte for byte: input report
0x01 against docs/reports.md's layout (which hid-playstation's struct dualsense_input_report and
SDL's PS5StatePacket_t read), the feature reports hid-playstation requests before it binds, and
output reports as hid-playstation and SDL write them parsed into Feedback."""

from __future__ import annotations

import re
import struct
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from neurotouch_hid.core.controller import ControllerState, Feedback, TouchPoint
from neurotouch_hid.targets.identity import identity_for
from neurotouch_hid.targets.reports.dualsense import DESCRIPTOR, DUALSENSE

DOCS = Path(__file__).resolve().parents[1] / "docs" / "reports.md"


def report_sizes(descriptor: bytes) -> dict[tuple[str, int], int]:
    """(kind, report id) -> bytes of that report with its id, walking ``descriptor``'s short
    items (HID 1.11, 6.2.2): Report ID (global tag 8), Report Size (7) and Count (9), and the
    Input (main 8), Output (9) and Feature (0xB) items."""
    sizes: dict[tuple[str, int], int] = {}
    report_id = size = count = 0
    i = 0
    while i < len(descriptor):
        prefix = descriptor[i]
        n = (0, 1, 2, 4)[prefix & 0x03]
        value = int.from_bytes(descriptor[i + 1 : i + 1 + n], "little")
        kind, tag = (prefix >> 2) & 0x03, prefix >> 4
        i += 1 + n
        if kind == 1 and tag == 0x8:
            report_id = value
        elif kind == 1 and tag == 0x7:
            size = value
        elif kind == 1 and tag == 0x9:
            count = value
        elif kind == 0 and tag in (0x8, 0x9, 0xB):
            key = ({0x8: "input", 0x9: "output", 0xB: "feature"}[tag], report_id)
            sizes[key] = sizes.get(key, 0) + size * count
    return {key: bits // 8 + 1 for key, bits in sizes.items()}


def test_the_descriptor_is_a_usb_dualsenses_with_the_reports_the_hosts_read():
    sizes = report_sizes(DESCRIPTOR)
    assert len(DESCRIPTOR) == 273  # a USB DualSense's report descriptor is 273 bytes
    assert DESCRIPTOR[:4] == bytes([0x05, 0x01, 0x09, 0x05])  # Generic Desktop, Game Pad
    assert sizes[("input", 0x01)] == 64 == DUALSENSE.report_length
    assert sizes[("output", 0x02)] == 48  # the id and hid-playstation's 47-byte common part
    assert {rid: sizes[("feature", rid)] for rid in DUALSENSE.feature_ids} == {0x05: 41, 0x09: 20, 0x20: 64}


NEUTRAL = bytes.fromhex(
    "01 80 80 80 80 00 00 00 08 00 00 00 00 00 00 00"
    "00 00 00 00 00 00 00 00 00 00 00 00 00 00 00 00"
    "00 80 00 00 00 80 00 00 00 00 00 00 00 00 00 00"
    "00 00 00 00 00 2a 00 00 00 00 00 00 00 00 00 00"
)


def test_neutral_report_centres_the_sticks_and_touches_nothing():
    assert DUALSENSE.neutral() == NEUTRAL
    assert DUALSENSE.pack(ControllerState.neutral()) == NEUTRAL


def test_a_push_sets_sticks_triggers_hat_buttons_and_the_timestamp():
    state = ControllerState(t_us=1_000_000)
    state.axes.update(ABS_X=32767, ABS_Y=-32768, ABS_RZ=255, ABS_HAT0X=1, ABS_HAT0Y=-1)
    state.buttons.update(BTN_SOUTH=True, BTN_NORTH=True, BTN_TL=True, BTN_MODE=True)
    expected = bytearray(NEUTRAL)
    expected[1:7] = bytes([0xFF, 0x00, 0x80, 0x80, 0x00, 0xFF])  # LX right, LY up, R2 full
    expected[8] = 0x01 | 0x20 | 0x10  # hat north-east, cross (A), square (xpad's X, left)
    expected[9] = 0x01 | 0x08  # L1, R2's bit (its trigger is above 0)
    expected[10] = 0x01  # PS
    expected[28:32] = bytes([0xC0, 0xC6, 0x2D, 0x00])  # 3,000,000 units of 1/3 us
    assert DUALSENSE.pack(state) == bytes(expected)


@pytest.mark.parametrize(
    "button, byte, bit",
    [
        ("BTN_NORTH", 8, 4),  # square
        ("BTN_SOUTH", 8, 5),  # cross
        ("BTN_EAST", 8, 6),  # circle
        ("BTN_WEST", 8, 7),  # triangle
        ("BTN_TL", 9, 0),
        ("BTN_TR", 9, 1),
        ("BTN_SELECT", 9, 4),  # create
        ("BTN_START", 9, 5),  # options
        ("BTN_THUMBL", 9, 6),
        ("BTN_THUMBR", 9, 7),
        ("BTN_MODE", 10, 0),  # PS
    ],
)
def test_each_button_is_its_bit(button, byte, bit):
    state = ControllerState()
    state.buttons[button] = True
    report = DUALSENSE.pack(state)
    assert report[byte] == (0x08 if byte == 8 else 0) | 1 << bit
    assert report[:byte] + report[byte + 1 :] == NEUTRAL[:byte] + NEUTRAL[byte + 1 :]


def test_two_touches_and_the_click():
    state = ControllerState(
        t_us=2_000_000, touches=(TouchPoint(5, 1919, 1079), TouchPoint(6, 0x123, 0x234)), touch_click=True
    )
    report = DUALSENSE.pack(state)
    assert report[10] == 0x02  # the touchpad click
    assert report[28:32] == struct.pack("<I", 6_000_000)
    # contact id 5 at (1919 = 0x77f, 1079 = 0x437); id 6 at (0x123, 0x234): x low byte, x high
    # nibble | y low nibble << 4, y >> 4
    assert report[33:41] == bytes([0x05, 0x7F, 0x77, 0x43, 0x06, 0x23, 0x41, 0x23])
    assert report[:10] == NEUTRAL[:10] and report[41:] == NEUTRAL[41:]


def test_a_lift_sets_the_inactive_bit_and_keeps_the_id():
    state = ControllerState(
        t_us=2_010_000, touches=(TouchPoint(5, 960, 540, active=False), TouchPoint(6, 0x123, 0x234))
    )
    report = DUALSENSE.pack(state)
    assert report[33:41] == bytes([0x85, 0xC0, 0xC3, 0x21, 0x06, 0x23, 0x41, 0x23])


def test_touch_points_outside_the_pad_are_held_at_its_edge_and_ids_keep_7_bits():
    state = ControllerState(touches=(TouchPoint(130, -5, 5000),))
    assert DUALSENSE.pack(state)[33:41] == bytes([0x02, 0x00, 0x70, 0x43, 0x80, 0, 0, 0])


def test_the_sensor_timestamp_wraps_at_32_bits():
    assert DUALSENSE.pack(ControllerState(t_us=(1 << 32) // 3 + 1))[28:32] == struct.pack("<I", 2)


def test_feature_reports_have_the_lengths_and_ids_hid_playstation_requires():
    identity = identity_for("00000499")
    calibration, pairing, firmware = (DUALSENSE.feature(rid, identity) for rid in (0x05, 0x09, 0x20))
    assert (len(calibration), len(pairing), len(firmware)) == (41, 20, 64)
    assert (calibration[0], pairing[0], firmware[0]) == (0x05, 0x09, 0x20)
    assert pairing[1:7] == identity.mac[::-1] and pairing[7:] == bytes(13)
    # %pMR: hid-playstation's uniq is the bytes printed last first, i.e. the identity's uniq
    assert ":".join(f"{b:02x}" for b in reversed(pairing[1:7])) == identity.uniq
    with pytest.raises(KeyError):
        DUALSENSE.feature(0x22, identity)


def test_calibration_is_sane_for_hid_playstation():
    """dualsense_get_calibration_data: no divisor zero, and a zero sample reads 0."""
    values = struct.unpack_from("<17h", DUALSENSE.feature(0x05, identity_for(None)), 1)
    bias, plus_minus, (speed_plus, speed_minus), accel = values[:3], values[3:9], values[9:11], values[11:]
    for axis in range(3):
        denom = abs(plus_minus[2 * axis] - bias[axis]) + abs(plus_minus[2 * axis + 1] - bias[axis])
        assert denom > 0 and (speed_plus + speed_minus) * 1024 // denom == 64
        range_2g = accel[2 * axis] - accel[2 * axis + 1]
        assert range_2g == 16384 and accel[2 * axis] - range_2g // 2 == 0  # bias 0, 1 count = 1/8192 g
    assert DUALSENSE.feature(0x05, identity_for(None)) == bytes.fromhex(
        "05 00 00 00 00 00 00 c0 21 40 de c0 21 40 de c0 21 40 de 1c 02 1c 02"
        "00 20 00 e0 00 20 00 e0 00 20 00 e0 00 00 00 00 00 00"
    )


def test_firmware_report_gives_the_versions_at_hid_playstations_offsets():
    firmware = DUALSENSE.feature(0x20, identity_for(None))
    assert firmware[1:20] == b"Jan  1 2026" + b"00:00:00"
    assert struct.unpack_from("<II", firmware, 24) == (0x00000001, 0x00010000)
    assert struct.unpack_from("<H", firmware, 44) == (0x0224,)  # >= 2.21: rumble in valid_flag2


def usb_output(**fields: int) -> bytes:
    """A 63-byte USB output report 0x02 as hid-playstation's worker sends it (offsets: id 0,
    valid_flag0 1, valid_flag1 2, motor_right 3, motor_left 4, valid_flag2 39, player_leds 44,
    lightbar red/green/blue 45-47)."""
    offsets = {"flag0": 1, "flag1": 2, "right": 3, "left": 4, "flag2": 39, "leds": 44, "r": 45, "g": 46, "b": 47}
    report = bytearray(63)
    report[0] = 0x02
    for name, value in fields.items():
        report[offsets[name]] = value
    return bytes(report)


def test_hid_playstations_rumble_is_feedback():
    """dualsense_output_worker with update_version >= 2.21: HAPTICS_SELECT in valid_flag0,
    COMPATIBLE_VIBRATION2 in valid_flag2; motor_left the strong (low-frequency) motor."""
    report = usb_output(flag0=0x02, flag2=0x04, left=0xFF, right=0x80)
    assert DUALSENSE.parse_output(report) == [Feedback("rumble", strong=1.0, weak=0x80 / 255)]
    older = usb_output(flag0=0x03, left=0x40, right=0)  # COMPATIBLE_VIBRATION, firmware before 2.21
    assert DUALSENSE.parse_output(older, source="UHID dualsense") == [
        Feedback("rumble", strong=0x40 / 255, weak=0.0, source="UHID dualsense")
    ]


def test_lightbar_and_player_leds_are_feedback():
    report = usb_output(flag1=0x04 | 0x10, leds=0x20 | 0x04, r=0x00, g=0x00, b=0x40)
    assert DUALSENSE.parse_output(report) == [Feedback("led", led=0x04), Feedback("lightbar", led=0x000040)]


def test_the_lightbar_setup_report_alone_is_no_feedback():
    """dualsense_reset_leds at probe: valid_flag2 = LIGHTBAR_SETUP_CONTROL_ENABLE only."""
    report = usb_output(flag2=0x02)
    assert DUALSENSE.parse_output(report) == []


def test_bluetooth_reports_are_read_past_their_headers():
    """0x31: hid-playstation writes id, sequence << 4, tag 0x10, then the common part; SDL (when
    it takes the pad for a Bluetooth one) id, 0x02, then the common part."""
    kernel = bytearray(78)
    kernel[0], kernel[1], kernel[2] = 0x31, 0x30, 0x10
    kernel[3], kernel[5], kernel[6] = 0x03, 0x11, 0x22
    assert DUALSENSE.parse_output(bytes(kernel)) == [Feedback("rumble", strong=0x22 / 255, weak=0x11 / 255)]
    sdl = bytearray(78)
    sdl[0], sdl[1] = 0x31, 0x02
    sdl[2], sdl[4], sdl[5], sdl[40] = 0x02, 0xFF, 0x80, 0x04  # haptics select, motors, valid_flag2 bit 2
    assert DUALSENSE.parse_output(bytes(sdl)) == [Feedback("rumble", strong=0x80 / 255, weak=1.0)]
    tickle = bytes([0x31, 0x02]) + bytes(76)  # SDL's Bluetooth "tickle": nothing asked
    assert DUALSENSE.parse_output(tickle) == []


@pytest.mark.parametrize("data", [b"", b"\x02", b"\x02\x01", b"\x02\x01\x00\x10", b"\x01" * 64, b"\x31\x00"])
def test_short_or_foreign_output_reports_give_nothing(data):
    assert DUALSENSE.parse_output(data) == []


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=200))
def test_parse_output_never_raises(data):
    for feedback in DUALSENSE.parse_output(data):
        assert feedback.kind in ("rumble", "led", "lightbar")
        assert 0 <= feedback.strong <= 1 and 0 <= feedback.weak <= 1


def test_docs_give_the_descriptor_byte_for_byte():
    block = re.search(r"<!-- descriptor dualsense -->\n```\n(.*?)```", DOCS.read_text(), re.S)
    assert block, "docs/reports.md has no descriptor block for dualsense"
    assert bytes.fromhex(block.group(1)) == DESCRIPTOR


def test_the_uhid_dualsense_has_its_rows_name_and_ids_and_the_mac_as_uniq():
    """hid-playstation sets uniq from the pairing report's MAC; the UHID device carries the same
    from its creation, with a camera's serial or without (the default identity)."""
    from neurotouch_hid.mapping.profile import DeviceSpec
    from neurotouch_hid.targets.protocols import PROTOCOLS
    from neurotouch_hid.targets.uhid import uhid_identity

    row = PROTOCOLS["dualsense"]
    assert (row.vendor, row.product, row.manufacturer) == (0x054C, 0x0CE6, "Sony Interactive Entertainment")
    assert row.transports == {"uhid", "gadget"}
    for camera in (None, identity_for(None), identity_for("00000499")):
        made = uhid_identity(row, DeviceSpec(name="Mine", vendor=0x1234, product=0x5678), camera)
        assert (made.name, made.vendor, made.product) == ("DualSense Wireless Controller", 0x054C, 0x0CE6)
        assert made.uniq == (camera or identity_for(None)).uniq
    assert uhid_identity(row, DeviceSpec(), identity_for("A")).uniq != uhid_identity(row, DeviceSpec(), None).uniq


def test_each_feedback_of_the_dualsense_is_told_in_one_line():
    from neurotouch_hid.targets import describe_feedback

    report = usb_output(flag0=0x02, flag2=0x04, left=0xFF, right=0, flag1=0x14, leds=0x04, r=0x12, g=0x34, b=0x56)
    lines = [describe_feedback(f) for f in DUALSENSE.parse_output(report, source="UHID dualsense device")]
    assert lines == [
        "rumble (the gel has no motor): strong 1.00 weak 0.00, on UHID dualsense device",
        "player LED (the gel has none): pattern 4, on UHID dualsense device",
        "light bar (the gel has none): colour #123456, on UHID dualsense device",
    ]


def test_the_uhid_device_answers_the_feature_reports_hid_playstation_reads_as_it_binds():
    """hid-playstation reads 0x09, 0x20 and 0x05 right after UHID_START, each given up after 5 s,
    before any reader of the device runs: the device serves them before its constructor returns.
    A socket pair (SOCK_SEQPACKET, one event a read) stands in for /dev/uhid."""
    import socket
    import threading

    from neurotouch_hid.mapping.profile import DeviceSpec
    from neurotouch_hid.targets.protocols import PROTOCOLS
    from neurotouch_hid.targets.uhid import UhidDevice, uhid_identity
    from neurotouch_hid.targets.uhid_events import UHID_EVENT_SIZE, UHID_FEATURE_REPORT, UHID_GET_REPORT, UHID_START

    ours, kernel = socket.socketpair(socket.AF_UNIX, socket.SOCK_SEQPACKET)
    ours.setblocking(False)
    kernel.settimeout(10.0)
    replies: list[bytes] = []

    def probe() -> None:
        kernel.recv(UHID_EVENT_SIZE + 64)  # UHID_CREATE2
        kernel.send(UHID_START.to_bytes(4, "little") + bytes(8))
        for request, rnum in enumerate((0x09, 0x20, 0x05), start=1):
            kernel.send(struct.pack("<IIBB", UHID_GET_REPORT, request, rnum, UHID_FEATURE_REPORT))
            while True:  # the START's report comes first
                reply = kernel.recv(UHID_EVENT_SIZE)
                if int.from_bytes(reply[:4], "little") == 10:  # UHID_GET_REPORT_REPLY
                    replies.append(reply)
                    break

    thread = threading.Thread(target=probe, daemon=True)
    thread.start()
    camera = identity_for("00000499")
    row = PROTOCOLS["dualsense"]
    device = UhidDevice.on_fd(ours.detach(), row.report, uhid_identity(row, DeviceSpec(), camera), camera=camera)
    try:
        thread.join(10)
        assert device.asked == {0x05, 0x09, 0x20}
        answers = {}
        for reply in replies:
            _, request, error, size = struct.unpack_from("<IIHH", reply)
            assert error == 0
            answers[request] = reply[12 : 12 + size]
        assert answers == {
            1: DUALSENSE.feature(0x09, camera),
            2: DUALSENSE.feature(0x20, camera),
            3: DUALSENSE.feature(0x05, camera),
        }
    finally:
        device.close()
        kernel.close()
