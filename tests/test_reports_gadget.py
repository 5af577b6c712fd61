"""The Switch (HORIPAD) and Xbox 360 (XInput) reports, byte for byte (docs/reports.md)."""

import os

import pytest

from neurotouch_hid.core.controller import ControllerState
from neurotouch_hid.core.stages import Feedback
from neurotouch_hid.targets.reports.switch import DESCRIPTOR, SwitchFormat
from neurotouch_hid.targets.reports.xinput import XInputFormat, parse_output


def state(**changes) -> ControllerState:
    s = ControllerState.neutral()
    for name, value in changes.items():
        if name.startswith("BTN_"):
            s.buttons[name] = value
        else:
            s.axes[name] = value
    return s


# --- switch ----------------------------------------------------------------------------------


def test_switch_neutral_report():
    assert SwitchFormat().neutral() == bytes.fromhex("0000 08 80808080 00")
    assert SwitchFormat().report_length == len(SwitchFormat().neutral()) == 8


@pytest.mark.parametrize(
    ("changes", "report"),
    [
        ({"BTN_SOUTH": True}, "0200 08 80808080 00"),  # B
        ({"BTN_EAST": True}, "0400 08 80808080 00"),  # A
        ({"BTN_NORTH": True}, "0100 08 80808080 00"),  # Y
        ({"BTN_WEST": True}, "0800 08 80808080 00"),  # X
        ({"BTN_TL": True, "BTN_TR": True}, "3000 08 80808080 00"),
        ({"ABS_Z": 128, "ABS_RZ": 127}, "4000 08 80808080 00"),  # ZL pressed, ZR not yet
        ({"BTN_SELECT": True, "BTN_START": True}, "0003 08 80808080 00"),
        ({"BTN_THUMBL": True, "BTN_THUMBR": True, "BTN_MODE": True}, "001c 08 80808080 00"),
        ({"ABS_X": 32767}, "0000 08 ff808080 00"),
        ({"ABS_X": -32768, "ABS_Y": 32767}, "0000 08 00ff8080 00"),
        ({"ABS_RX": 256, "ABS_RY": -257}, "0000 08 80 80 81 7e 00"),
        ({"ABS_HAT0Y": -1}, "0000 00 80808080 00"),  # up
        ({"ABS_HAT0X": 1, "ABS_HAT0Y": -1}, "0000 01 80808080 00"),
        ({"ABS_HAT0X": 1}, "0000 02 80808080 00"),
        ({"ABS_HAT0X": 1, "ABS_HAT0Y": 1}, "0000 03 80808080 00"),
        ({"ABS_HAT0Y": 1}, "0000 04 80808080 00"),
        ({"ABS_HAT0X": -1, "ABS_HAT0Y": 1}, "0000 05 80808080 00"),
        ({"ABS_HAT0X": -1}, "0000 06 80808080 00"),
        ({"ABS_HAT0X": -1, "ABS_HAT0Y": -1}, "0000 07 80808080 00"),
        ({"ABS_X": 10**9, "ABS_Y": -(10**9)}, "0000 08 ff008080 00"),  # out of range: clamped
    ],
)
def test_switch_report(changes, report):
    assert SwitchFormat().pack(state(**changes)) == bytes.fromhex(report)


def test_switch_descriptor_is_horis_length():
    """86 bytes, the length HORI's HID class descriptor gives (its walk: tests/test_reports.py)."""
    assert len(DESCRIPTOR) == 86


# --- xinput ----------------------------------------------------------------------------------


def test_xinput_neutral_report():
    assert XInputFormat().neutral() == bytes.fromhex("0014") + bytes(18)
    assert XInputFormat().descriptor == b"" and XInputFormat().report_length == 20


def _x(low: str, high: str, lt: str = "00", rt: str = "00", sticks: str = "0000" * 4) -> bytes:
    return bytes.fromhex("0014" + low + high + lt + rt + sticks) + bytes(6)


@pytest.mark.parametrize(
    ("changes", "report"),
    [
        ({"ABS_HAT0Y": -1}, _x("01", "00")),
        ({"ABS_HAT0Y": 1}, _x("02", "00")),
        ({"ABS_HAT0X": -1}, _x("04", "00")),
        ({"ABS_HAT0X": 1, "ABS_HAT0Y": -1}, _x("09", "00")),
        ({"BTN_START": True, "BTN_SELECT": True}, _x("30", "00")),
        ({"BTN_THUMBL": True, "BTN_THUMBR": True}, _x("c0", "00")),
        ({"BTN_TL": True, "BTN_TR": True, "BTN_MODE": True}, _x("00", "07")),
        ({"BTN_SOUTH": True}, _x("00", "10")),
        ({"BTN_EAST": True}, _x("00", "20")),
        ({"BTN_NORTH": True}, _x("00", "40")),
        ({"BTN_WEST": True}, _x("00", "80")),
        ({"ABS_Z": 255, "ABS_RZ": 1}, _x("00", "00", "ff", "01")),
        ({"ABS_X": 32767}, _x("00", "00", sticks="ff7f" + "0000" * 3)),
        ({"ABS_X": -32768}, _x("00", "00", sticks="0080" + "0000" * 3)),
        ({"ABS_Y": -32768}, _x("00", "00", sticks="0000" + "ff7f" + "0000" * 2)),  # up: +32767
        ({"ABS_Y": 32767}, _x("00", "00", sticks="0000" + "0180" + "0000" * 2)),  # down: -32767
        ({"ABS_RX": 258, "ABS_RY": 1}, _x("00", "00", sticks="0000" * 2 + "0201" + "ffff")),
    ],
)
def test_xinput_report(changes, report):
    assert XInputFormat().pack(state(**changes)) == report


@pytest.mark.parametrize(
    ("data", "feedback"),
    [
        (bytes.fromhex("0008 00 ff 80 000000"), Feedback("rumble", strong=1.0, weak=128 / 255, source="x")),
        (bytes.fromhex("0008 00 00 00 000000"), Feedback("rumble", source="x")),
        (bytes.fromhex("010302"), Feedback("led", led=2, source="x")),
        (bytes.fromhex("0103f6"), Feedback("led", led=6, source="x")),
        (
            bytes.fromhex("0008 00 ff 80 000000") + bytes(1000),
            Feedback("rumble", strong=1.0, weak=128 / 255, source="x"),
        ),
        (b"", None),
        (b"\x01\x03", None),  # LED without its pattern
        (b"\x00\x08\x00\xff", None),  # rumble cut short
        (b"\x00\x08\x00\xff\xff", None),  # its length byte says 8: cut short too
        (b"\x01\x05\x02", None),  # an LED report saying 5 bytes in 3
        (b"\x02\x08\x00\xff\xff", None),  # unknown type
        (bytes(range(256)) * 4, None),
    ],
)
def test_xinput_output_reports(data, feedback):
    assert parse_output(data, "x") == feedback


def test_the_xinput_out_endpoint_is_read_a_packet_at_a_time():
    """The OUT endpoint's packets are 32 bytes: a host's full 32-byte report followed by a rumble
    must be read as two reports (a 64-byte read joined them and the rumble was lost). A pipe
    stands in for the endpoint's file."""
    import threading

    from helpers import wait_until

    from neurotouch_hid.targets.gadget.ffs import XInputTarget
    from neurotouch_hid.targets.reports.xinput import XINPUT

    target = object.__new__(XInputTarget)
    read_end, write_end = os.pipe()
    target._out, target._closed, target.what, target.format = read_end, False, "x", XINPUT
    announced: list[Feedback] = []
    target._announce = announced.extend
    reader = threading.Thread(target=target._read_out, daemon=True)
    reader.start()
    os.write(write_end, bytes.fromhex("0220") + bytes(30) + bytes.fromhex("0008 00 ff 80 000000"))
    wait_until(lambda: announced, 10)
    target._closed = True
    os.close(read_end)
    os.close(write_end)
    reader.join(10)
    assert announced == [Feedback("rumble", strong=1.0, weak=128 / 255, source="x")]


@pytest.mark.parametrize(
    "profile, functions, says",
    [
        ("mouse", ["hid.usb0"], ["the profile moves the pointer or clicks but the USB gadget has no mouse"]),
        ("mouse", ["hid.usb0", "hid.usb2"], []),
        ("switch-access", ["hid.usb0"], ["the profile presses keys but the USB gadget has no keyboard"]),
        ("switch-access", ["hid.usb0", "hid.usb1"], []),
        ("default", ["hid.usb0"], []),
    ],
)
def test_the_gadget_says_what_of_a_profile_it_cannot_carry(tmp_path, profile, functions, says):
    """A gadget set up without a mouse (or a keyboard) function: a profile that needs it is told,
    not silently dropped (the boot unit's gadget has the pad only)."""
    from neurotouch_hid.mapping.profile import load_profile
    from neurotouch_hid.targets.gadget import say_what_cannot_go

    for name in functions:
        (tmp_path / name).mkdir()
    said = say_what_cannot_go(load_profile(profile), tmp_path)
    assert [line.split(":")[0] for line in said] == says


def test_the_gadget_names_the_keys_its_keyboard_cannot_carry(tmp_path):
    from neurotouch_hid.mapping.profile import parse_profile
    from neurotouch_hid.targets.gadget import say_what_cannot_go

    (tmp_path / "hid.usb1").mkdir()
    profile = parse_profile(
        "mappings:\n  p: {input: pinch, output: KEY_PLAYPAUSE}\n  e: {input: zoom, output: KEY_ENTER}\n", "p.yaml"
    )
    assert say_what_cannot_go(profile, tmp_path) == [
        "the USB keyboard has no usage for KEY_PLAYPAUSE: the host gets nothing for them"
    ]


def test_a_hosts_keyboard_leds_are_said():
    """The host lights Caps Lock on the gadget's keyboard: read (bounded) and said, as a pad's
    rumble is; a joystick's node gives nothing back."""
    from neurotouch_hid.targets import describe_feedback
    from neurotouch_hid.targets.gadget.targets import HidgTarget
    from neurotouch_hid.targets.reports import format_for

    def node_with(fmt: str, data: bytes) -> HidgTarget:
        target = object.__new__(HidgTarget)
        read_end, write_end = os.pipe()
        os.set_blocking(read_end, False)
        os.write(write_end, data)
        os.close(write_end)
        target._fd, target.format, target.what = read_end, format_for(fmt), f"USB gadget ({fmt})"
        return target

    keyboard = node_with("keyboard", b"\x02")
    (leds,) = keyboard.feedback()
    assert describe_feedback(leds) == "keyboard LEDs (the gel has none): Caps Lock, on USB gadget (keyboard)"
    assert node_with("hid", b"\x02").feedback() == []
