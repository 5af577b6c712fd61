"""The report encoders (neurotouch_hid/targets/reports): each descriptor walked item by item as
HID 1.11 section 6.2.2 defines them, and the input reports checked byte for byte against
docs/reports.md's layouts."""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import pytest

from neurotouch_hid.core.controller import BUTTONS, MOUSE_BUTTONS, ControllerState
from neurotouch_hid.core.errors import NeurotouchError
from neurotouch_hid.targets.reports import FORMATS, format_for
from neurotouch_hid.targets.reports.hid import BUTTON_ORDER, HID_JOYSTICK
from neurotouch_hid.targets.reports.keyboard import BOOT_KEYBOARD, USAGES, unrepresentable
from neurotouch_hid.targets.reports.mouse import MOUSE

DOCS = Path(__file__).resolve().parents[1] / "docs" / "reports.md"


@dataclass
class Field:
    """One Main item of a report descriptor, with the global and local state it was declared in."""

    kind: str  # "input", "output"
    page: int
    usages: list[int]
    usage_range: tuple[int, int] | None
    size: int
    count: int
    flags: int
    logical: tuple[int, int]
    unit: int

    @property
    def constant(self) -> bool:
        return bool(self.flags & 0x01)

    @property
    def variable(self) -> bool:
        return bool(self.flags & 0x02)

    @property
    def relative(self) -> bool:
        return bool(self.flags & 0x04)

    @property
    def null_state(self) -> bool:
        return bool(self.flags & 0x40)


def walk(descriptor: bytes) -> tuple[list[tuple[int, int]], list[Field]]:
    """The collections (page, usage) and the Main items of ``descriptor`` (short items only;
    HID 1.11, 6.2.2.2: prefix bSize in bits 0-1 (0, 1, 2, 4 bytes), bType in 2-3, bTag in 4-7)."""
    state = {"page": 0, "lmin": 0, "lmax": 0, "size": 0, "count": 0, "unit": 0}
    usages: list[int] = []
    usage_min = usage_max = None
    collections: list[tuple[int, int]] = []
    fields: list[Field] = []
    depth = 0
    i = 0
    while i < len(descriptor):
        prefix = descriptor[i]
        assert prefix != 0xFE, "long items are not used"
        size = (0, 1, 2, 4)[prefix & 0x03]
        data = descriptor[i + 1 : i + 1 + size]
        assert len(data) == size, f"item at {i} runs past the end"
        unsigned = int.from_bytes(data, "little")
        signed = int.from_bytes(data, "little", signed=True)
        kind, tag = (prefix >> 2) & 0x03, prefix >> 4
        i += 1 + size
        if kind == 0:  # Main
            if tag in (0x8, 0x9):  # Input, Output
                usage_range = (usage_min, usage_max) if usage_min is not None else None
                fields.append(
                    Field(
                        "input" if tag == 0x8 else "output",
                        state["page"],
                        list(usages),
                        usage_range,
                        state["size"],
                        state["count"],
                        unsigned,
                        (state["lmin"], state["lmax"]),
                        state["unit"],
                    )
                )
            elif tag == 0xA:  # Collection
                assert usages, "a collection names its usage"
                collections.append((state["page"], usages[0]))
                depth += 1
            elif tag == 0xC:  # End Collection
                depth -= 1
                assert depth >= 0
            else:
                raise AssertionError(f"unexpected main item tag {tag:#x}")
            usages, usage_min, usage_max = [], None, None
        elif kind == 1:  # Global
            key = {
                0x0: "page",
                0x1: "lmin",
                0x2: "lmax",
                0x3: "pmin",
                0x4: "pmax",
                0x6: "unit",
                0x7: "size",
                0x9: "count",
            }
            assert tag in key, f"unexpected global item tag {tag:#x}"
            state[key[tag]] = signed if tag in (0x1, 0x3) else unsigned
            if tag == 0x2 and state["lmin"] >= 0:
                state["lmax"] = unsigned
            elif tag == 0x2:
                state["lmax"] = signed
        elif kind == 2:  # Local
            if tag == 0x0:
                usages.append(unsigned)
            elif tag == 0x1:
                usage_min = unsigned
            elif tag == 0x2:
                usage_max = unsigned
            else:
                raise AssertionError(f"unexpected local item tag {tag:#x}")
    assert depth == 0, "every collection is closed"
    return collections, fields


def input_bits(fields: list[Field]) -> int:
    return sum(f.size * f.count for f in fields if f.kind == "input")


def test_the_registry_names_every_format_and_refuses_others():
    assert {"hid", "keyboard", "mouse"} <= set(FORMATS)
    for name, fmt in FORMATS.items():
        assert fmt.name == name and format_for(name) is fmt
        assert len(fmt.neutral()) == fmt.report_length
    with pytest.raises(NeurotouchError, match="unknown report format 'nes'.*hid"):
        format_for("nes")


@pytest.mark.parametrize("name", ["hid", "keyboard", "mouse", "switch"])
def test_the_descriptor_walks_and_its_input_report_is_report_length_long(name):
    fmt = FORMATS[name]
    _, fields = walk(fmt.descriptor)
    assert input_bits(fields) == 8 * fmt.report_length


def test_hid_descriptor_is_a_joystick_with_the_adaptive_controllers_fields():
    collections, fields = walk(HID_JOYSTICK.descriptor)
    assert collections == [(0x01, 0x04)]  # Application collection: Generic Desktop Joystick
    inputs = [f for f in fields if f.kind == "input"]
    sticks, triggers, hat, padding, buttons = inputs
    assert (sticks.page, sticks.usages, sticks.size, sticks.count) == (0x01, [0x30, 0x31, 0x32, 0x35], 16, 4)
    assert sticks.logical == (-32768, 32767) and sticks.variable and not sticks.relative
    assert (triggers.page, triggers.usages, triggers.size, triggers.logical) == (0x02, [0xC5, 0xC4], 8, (0, 255))
    assert (hat.page, hat.usages, hat.size, hat.logical, hat.unit) == (0x01, [0x39], 4, (0, 7), 0x14)
    assert hat.null_state
    assert padding.constant and padding.size * padding.count == 4
    assert (buttons.page, buttons.usage_range, buttons.size, buttons.count) == (0x09, (1, 16), 1, 16)
    assert not any(f.kind == "output" for f in fields)


def _state(**axes: int) -> ControllerState:
    state = ControllerState.neutral()
    state.axes.update(axes)
    return state


def test_hid_neutral_report_is_zero_but_the_hat_null():
    assert HID_JOYSTICK.neutral() == bytes.fromhex("00000000 00000000 0000 08 0000")


def test_hid_sticks_are_int16_little_endian_x_y_z_rz():
    full_left = HID_JOYSTICK.pack(_state(ABS_X=-32768))
    assert full_left == bytes.fromhex("0080 0000 0000 0000 0000 08 0000")
    right_stick = HID_JOYSTICK.pack(_state(ABS_X=32767, ABS_Y=1, ABS_RX=-2, ABS_RY=300))
    assert right_stick == bytes.fromhex("ff7f 0100 feff 2c01 0000 08 0000")
    assert HID_JOYSTICK.pack(_state(ABS_X=99999, ABS_RY=-99999)) == HID_JOYSTICK.pack(
        _state(ABS_X=32767, ABS_RY=-32768)
    )


def test_hid_triggers_are_brake_then_accelerator():
    assert HID_JOYSTICK.pack(_state(ABS_Z=255))[8:10] == bytes([255, 0])
    assert HID_JOYSTICK.pack(_state(ABS_RZ=128))[8:10] == bytes([0, 128])
    assert HID_JOYSTICK.pack(_state(ABS_Z=300, ABS_RZ=-5))[8:10] == bytes([255, 0])


@pytest.mark.parametrize(
    ("x", "y", "value"),
    [(0, -1, 0), (1, -1, 1), (1, 0, 2), (1, 1, 3), (0, 1, 4), (-1, 1, 5), (-1, 0, 6), (-1, -1, 7), (0, 0, 8)],
)
def test_hid_hat_goes_clockwise_from_north_and_centred_is_null(x, y, value):
    report = HID_JOYSTICK.pack(_state(ABS_HAT0X=x, ABS_HAT0Y=y))
    assert report[10] == value
    assert report[:10] == bytes(10) and report[11:] == bytes(2)


@pytest.mark.parametrize("bit", range(len(BUTTON_ORDER)))
def test_hid_each_button_is_its_bit(bit):
    state = ControllerState.neutral()
    state.buttons[BUTTON_ORDER[bit]] = True
    report = HID_JOYSTICK.pack(state)
    assert int.from_bytes(report[11:13], "little") == 1 << bit
    assert report[:11] == HID_JOYSTICK.neutral()[:11]


def test_hid_button_order_is_the_controllers_buttons_guide_last():
    assert sorted(BUTTON_ORDER) == sorted(BUTTONS) and BUTTON_ORDER[-1] == "BTN_MODE"
    state = ControllerState.neutral()
    state.buttons.update({name: True for name in BUTTONS})
    assert HID_JOYSTICK.pack(state)[11:13] == (0x07FF).to_bytes(2, "little")


def test_keyboard_descriptor_is_the_boot_keyboards_with_its_led_report():
    collections, fields = walk(BOOT_KEYBOARD.descriptor)
    assert collections == [(0x01, 0x06)]
    modifiers, reserved, keys = [f for f in fields if f.kind == "input"]
    assert (modifiers.page, modifiers.usage_range, modifiers.size, modifiers.count) == (0x07, (0xE0, 0xE7), 1, 8)
    assert reserved.constant and reserved.size == 8
    assert not keys.variable and (keys.size, keys.count, keys.usage_range) == (8, 6, (0, 0x81))
    assert max(USAGES[k] for k in USAGES if USAGES[k] < 0xE0) <= keys.logical[1]
    assert sum(f.size * f.count for f in fields if f.kind == "output") == 8  # 5 LEDs, 3 bits padding


def _keys(*names: str) -> ControllerState:
    return ControllerState(keys=frozenset(names))


def test_keyboard_reports_modifiers_then_keys_ascending():
    assert BOOT_KEYBOARD.neutral() == bytes(8)
    assert BOOT_KEYBOARD.pack(_keys("KEY_A")) == bytes([0, 0, 0x04, 0, 0, 0, 0, 0])
    report = BOOT_KEYBOARD.pack(_keys("KEY_SPACE", "KEY_LEFTSHIFT", "KEY_RIGHTMETA", "KEY_1", "KEY_ENTER"))
    assert report == bytes([0b1000_0010, 0, 0x1E, 0x28, 0x2C, 0, 0, 0])
    assert BOOT_KEYBOARD.pack(_keys("KEY_UP", "KEY_F12", "KEY_KP0", "KEY_Z")) == bytes(
        [0, 0, 0x1D, 0x45, 0x52, 0x62, 0, 0]
    )


def test_keyboard_drops_what_it_cannot_carry_and_says_which():
    state = _keys("KEY_A", "KEY_SYSRQ", "KEY_PLAYPAUSE", "BTN_LEFT")
    assert BOOT_KEYBOARD.pack(state) == bytes([0, 0, 0x04, 0, 0, 0, 0, 0])
    assert unrepresentable(state.keys) == ["KEY_PLAYPAUSE", "KEY_SYSRQ"]


def test_keyboard_more_than_six_keys_is_roll_over_in_every_slot():
    seven = _keys("KEY_LEFTCTRL", *(f"KEY_{c}" for c in "ABCDEFG"))
    assert BOOT_KEYBOARD.pack(seven) == bytes([0x01, 0, 1, 1, 1, 1, 1, 1])
    six = _keys(*(f"KEY_{c}" for c in "ABCDEF"))
    assert BOOT_KEYBOARD.pack(six) == bytes([0, 0, 4, 5, 6, 7, 8, 9])


def test_mouse_descriptor_starts_like_the_boot_mouse():
    collections, fields = walk(MOUSE.descriptor)
    assert collections == [(0x01, 0x02), (0x01, 0x01)]
    buttons, padding, motion, pan = [f for f in fields if f.kind == "input"]
    assert (buttons.page, buttons.usage_range, buttons.count, padding.constant) == (0x09, (1, 5), 5, True)
    assert (motion.usages, motion.logical, motion.relative) == ([0x30, 0x31, 0x38], (-127, 127), True)
    assert (pan.page, pan.usages, pan.relative) == (0x0C, [0x238], True)


@pytest.mark.parametrize("bit", range(len(MOUSE_BUTTONS)))
def test_mouse_each_button_is_its_bit(bit):
    assert MOUSE.pack(_keys(MOUSE_BUTTONS[bit])) == bytes([1 << bit, 0, 0, 0, 0])


def test_mouse_motion_is_int8_clamped_and_hi_res_wheels_count_detents():
    assert MOUSE.neutral() == bytes(5)
    state = ControllerState(rel={"REL_X": 5, "REL_Y": -300, "REL_WHEEL": -1, "REL_HWHEEL_HI_RES": 240})
    assert MOUSE.pack(state) == bytes([0, 5, 0x81, 0xFF, 2])


def test_docs_give_each_descriptor_byte_for_byte():
    text = DOCS.read_text()
    for name in ("hid", "keyboard", "mouse", "switch"):
        block = re.search(rf"<!-- descriptor {name} -->\n```\n(.*?)```", text, re.S)
        assert block, f"docs/reports.md has no descriptor block for {name}"
        assert bytes.fromhex(block.group(1)) == FORMATS[name].descriptor, name
