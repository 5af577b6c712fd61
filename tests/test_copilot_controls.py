"""The copilot's devices and their controls: which devices match (name, ids, stable path; sysfs read,
a missing device waited for), what a device's controls become (passthrough scaled to the pad,
centred sticks, a hat, pedals, a switch box's keys, a map) and the merge policies."""

from __future__ import annotations

from pathlib import Path

import pytest
from copilot_helpers import HELPER, SHORT_FORM
from evdev import ecodes

from neurotouch_hid.core.controller import ControllerState
from neurotouch_hid.core.stages import Feedback
from neurotouch_hid.inputs.copilot import Copilot
from neurotouch_hid.inputs.match import InputInfo, input_devices, matches
from neurotouch_hid.mapping.merge import NEUTRAL, AxisRange, DeviceMap, Levels, combine_axis, merge_state
from neurotouch_hid.mapping.profile import parse_profile

OURS = InputInfo("/dev/input/event9", "Helper Pad", "neurotouch-hid/gamepad", 0x045E, 0x02EA)


@pytest.mark.parametrize(
    "rule, hit",
    [
        ("Helper Pad", True),
        ("helper pad", False),  # names are exact
        ("045e:02ea", True),
        ("045e:028e", False),
        ("/dev/input/by-id/usb-Helper-event-joystick", True),
        ("/dev/input/event7", True),
        ("/dev/input/by-id/usb-Other-event-joystick", False),
    ],
)
def test_a_rule_matches_by_name_ids_or_stable_path(rule, hit):
    assert matches(rule, HELPER) is hit
    assert not matches(rule, OURS)  # the driver's own devices never match


def _fake_system(root: Path, devices: dict[str, tuple[str, str, str, str]]) -> tuple[Path, Path]:
    """A /dev/input and /sys/class/input of plain files and links: node -> (name, phys, vendor, product)."""
    dev, sys_ = root / "dev" / "input", root / "sys" / "class" / "input"
    (dev / "by-id").mkdir(parents=True)
    for node, (name, phys, vendor, product) in devices.items():
        (dev / node).write_text("")
        folder = sys_ / node / "device"
        (folder / "id").mkdir(parents=True)
        (folder / "name").write_text(name + "\n")
        (folder / "phys").write_text(phys + "\n")
        (folder / "id" / "vendor").write_text(vendor + "\n")
        (folder / "id" / "product").write_text(product + "\n")
    return dev, sys_


def test_input_devices_reads_sysfs_and_resolves_stable_links(tmp_path):
    dev, sys_ = _fake_system(
        tmp_path,
        {
            "event10": ("Switch Box", "usb-1/input0", "1234", "5678"),
            "event2": ("Helper Pad", "usb-2/input0", "045e", "02ea"),
            "event3": ("Microsoft X-Box 360 pad", "neurotouch-hid/gamepad", "045e", "028e"),
        },
    )
    (dev / "by-id" / "usb-Helper-event-joystick").symlink_to("../event2")
    (dev / "mouse0").write_text("")  # not an event node
    found = input_devices(dev, sys_)
    assert [(i.path.rsplit("/", 1)[1], i.name, i.ids, i.own) for i in found] == [
        ("event2", "Helper Pad", "045e:02ea", False),
        ("event3", "Microsoft X-Box 360 pad", "045e:028e", True),
        ("event10", "Switch Box", "1234:5678", False),
    ]
    assert found[0].links == (str(dev / "by-id" / "usb-Helper-event-joystick"),)


def test_a_missing_device_is_waited_for_not_an_error(tmp_path):
    dev, sys_ = _fake_system(tmp_path, {})
    copilot = Copilot(parse_profile(SHORT_FORM, "p.yaml").copilot, input_dir=dev, sysfs=sys_, say=lambda line: None)
    calls = []
    copilot.start(lambda: calls.append(1))
    try:
        assert copilot.status() == ((), ("Helper Pad", "Switch Box"))
        gel = ControllerState.neutral(5)
        gel.axes["ABS_X"] = 1000
        assert copilot.merge(gel) is gel  # nothing merged: the gel's state as it is
        copilot.feedback(Feedback("rumble", strong=1.0))  # no one to rumble: nothing happens
    finally:
        copilot.stop()
    copilot.stop()  # idempotent
    assert calls == []


# --- what a device's controls become ------------------------------------------------------------------
def _names(*names: str) -> dict[int, list[str]]:
    codes: dict[int, list[str]] = {}
    for name in names:
        codes.setdefault(ecodes.ecodes[name], []).append(name)
    return codes


XBOX_KEYS = _names("BTN_SOUTH", "BTN_EAST", "BTN_NORTH", "BTN_WEST", "BTN_TL", "BTN_TR", "BTN_START", "BTN_MODE")
XBOX_KEYS[ecodes.BTN_SOUTH] += ["BTN_A", "BTN_GAMEPAD"]


STICK = AxisRange(-32768, 32767, 128)


XBOX_AXES = {
    ecodes.ABS_X: (["ABS_X"], STICK),
    ecodes.ABS_Y: (["ABS_Y"], STICK),
    ecodes.ABS_Z: (["ABS_Z"], AxisRange(0, 1023)),
    ecodes.ABS_HAT0X: (["ABS_HAT0X"], AxisRange(-1, 1)),
}


def _entry(text: str):
    return parse_profile("copilot:\n  - " + text + "\n", "p.yaml").copilot[0]


def test_a_pads_controls_pass_through_to_the_same_controls_scaled_to_the_pad():
    device = DeviceMap(_entry("{device: Pad}"), XBOX_KEYS, XBOX_AXES)
    levels = device.levels(
        {ecodes.BTN_SOUTH, ecodes.BTN_START},
        {ecodes.ABS_X: 40000, ecodes.ABS_Y: 100, ecodes.ABS_Z: 1023, ecodes.ABS_HAT0X: -1},
    )
    assert levels.buttons == {"BTN_SOUTH", "BTN_START"} and levels.keys == frozenset()
    # clamped to the device's range; within its flat: centred; a 0..1023 trigger as the pad's 0..255
    assert levels.axes == {"ABS_X": 32767, "ABS_Y": 0, "ABS_Z": 255, "ABS_HAT0X": -1}
    rest = device.levels(set(), {ecodes.ABS_X: 0, ecodes.ABS_Y: 0, ecodes.ABS_Z: 0, ecodes.ABS_HAT0X: 0})
    assert rest.axes == {"ABS_X": 0, "ABS_Y": 0, "ABS_Z": 0, "ABS_HAT0X": 0} and not rest.buttons


def test_a_0_to_255_stick_is_centred_at_its_middle_and_dpad_buttons_drive_the_hat():
    keys = _names("BTN_TRIGGER_HAPPY1", "BTN_TRIGGER_HAPPY3")
    device = DeviceMap(_entry("{device: Pad}"), keys, {ecodes.ABS_RX: (["ABS_RX"], AxisRange(0, 255))})
    levels = device.levels({ecodes.BTN_TRIGGER_HAPPY1, ecodes.BTN_TRIGGER_HAPPY3}, {ecodes.ABS_RX: 0})
    assert levels.axes == {"ABS_RX": -32768, "ABS_HAT0X": -1, "ABS_HAT0Y": -1}
    assert device.levels(set(), {ecodes.ABS_RX: 255}).axes["ABS_RX"] == 32767


@pytest.mark.parametrize("resting", [127, 128])
def test_a_stick_with_an_even_count_of_values_rests_centred_on_either_middle_value(resting):
    """0..255 with no flat has no middle value: 127 and 128 are its centre, so under ``helper``
    the gel's stick goes on while the helper's stick rests (not locked out by half a unit)."""
    device = DeviceMap(_entry("{device: Pad}"), {}, {ecodes.ABS_RX: (["ABS_RX"], AxisRange(0, 255))})
    rest = device.levels(set(), {ecodes.ABS_RX: resting})
    assert rest.axes == {"ABS_RX": 0}
    gel = ControllerState.neutral(0)
    gel.axes["ABS_RX"] = 9000
    assert merge_state(gel, [(rest, {"ABS_RX": "helper"})]).axes["ABS_RX"] == 9000
    assert device.levels(set(), {ecodes.ABS_RX: resting + (1 if resting == 128 else -1)}).axes["ABS_RX"] != 0


def test_a_right_stick_on_abs_z_and_abs_rz_mapped_to_the_right_stick_rests_centred():
    """A DirectInput-style pad (hid-generic) reports its right stick as ABS_Z / ABS_RZ, 0..255
    resting at 128: mapped to ABS_RX / ABS_RY it is a stick, centred at rest and full at its
    ends; passed through to the triggers it stays a trigger (0 at its minimum)."""
    axes = {ecodes.ABS_Z: (["ABS_Z"], AxisRange(0, 255, 15)), ecodes.ABS_RZ: (["ABS_RZ"], AxisRange(0, 255, 15))}
    mapped = DeviceMap(_entry("{device: Pad, map: {ABS_Z: ABS_RX, ABS_RZ: ABS_RY}}"), {}, axes)
    assert mapped.levels(set(), {ecodes.ABS_Z: 128, ecodes.ABS_RZ: 127}).axes == {"ABS_RX": 0, "ABS_RY": 0}
    assert mapped.levels(set(), {ecodes.ABS_Z: 0, ecodes.ABS_RZ: 255}).axes == {"ABS_RX": -32768, "ABS_RY": 32767}
    passed = DeviceMap(_entry("{device: Pad}"), {}, axes)
    assert passed.levels(set(), {ecodes.ABS_Z: 0, ecodes.ABS_RZ: 255}).axes == {"ABS_Z": 0, "ABS_RZ": 255}


def test_a_pedal_mapped_to_a_stick_axis_counts_from_its_rest():
    """A foot pedal (ABS_GAS, resting at its minimum) on ABS_X: at rest the stick is centred,
    pressed down it is full right."""
    pedal = DeviceMap(
        _entry("{device: Pedal, map: {ABS_GAS: ABS_X}}"), {}, {ecodes.ABS_GAS: (["ABS_GAS"], AxisRange(0, 1023))}
    )
    assert pedal.levels(set(), {ecodes.ABS_GAS: 0}).axes == {"ABS_X": 0}
    assert pedal.levels(set(), {ecodes.ABS_GAS: 1023}).axes == {"ABS_X": 32767}


def test_a_switch_box_key_presses_what_its_map_says_and_nothing_else():
    box = DeviceMap(
        _entry("{device: Box, map: {KEY_SPACE: BTN_SOUTH, KEY_ENTER: KEY_TAB, KEY_1: dpad_right}}"),
        _names("KEY_SPACE", "KEY_ENTER", "KEY_1", "KEY_2"),
        {},
    )
    levels = box.levels({ecodes.KEY_SPACE, ecodes.KEY_ENTER, ecodes.KEY_1, ecodes.KEY_2}, {})
    assert levels == Levels(axes={"ABS_HAT0X": 1}, buttons=frozenset({"BTN_SOUTH"}), keys=frozenset({"KEY_TAB"}))


def test_map_overrides_passthrough_and_passthrough_can_be_off():
    swapped = DeviceMap(_entry("{device: Pad, map: {BTN_SOUTH: B, BTN_EAST: A}}"), XBOX_KEYS, XBOX_AXES)
    assert swapped.levels({ecodes.BTN_SOUTH}, {}).buttons == {"BTN_EAST"}
    assert swapped.levels({ecodes.BTN_NORTH}, {}).buttons == {"BTN_NORTH"}
    only = DeviceMap(_entry("{device: Pad, passthrough: false, map: {BTN_A: BTN_TL}}"), XBOX_KEYS, XBOX_AXES)
    assert only.levels({ecodes.BTN_SOUTH, ecodes.BTN_NORTH}, {ecodes.ABS_X: 30000}) == Levels(
        axes={}, buttons=frozenset({"BTN_TL"}), keys=frozenset()
    )


# --- the policies -----------------------------------------------------------------------------------
@pytest.mark.parametrize(
    "policy, gel, device, want",
    [
        ("further", 10000, -20000, -20000),
        ("further", -30000, 20000, -30000),
        ("gel", 10000, -20000, 10000),
        ("gel", 0, -20000, -20000),  # the gel at centre: the device's
        ("helper", 10000, -20000, -20000),
        ("helper", 10000, 0, 10000),
        ("sum", 20000, 20000, 32767),  # clipped
        ("sum", 20000, -5000, 15000),
    ],
)
def test_axis_policies(policy, gel, device, want):
    assert combine_axis(policy, gel, device, "ABS_X") == want


def test_triggers_sum_from_their_rest_and_merge_state_keeps_the_gel_untouched():
    assert combine_axis("sum", 200, 100, "ABS_Z") == 255 and combine_axis("sum", 20, 30, "ABS_Z") == 50
    gel = ControllerState.neutral(7)
    gel.axes.update(ABS_X=12000, ABS_Y=-3000)
    gel.buttons["BTN_EAST"] = True
    gel.rel["REL_X"] = 4
    pad = Levels(axes={"ABS_X": -20000, "ABS_Y": 2000}, buttons=frozenset({"BTN_SOUTH"}))
    box = Levels(axes={}, buttons=frozenset({"BTN_SOUTH", "BTN_WEST"}), keys=frozenset({"KEY_TAB"}))
    merged = merge_state(gel, [(pad, {"ABS_Y": "sum"}), (box, {}), (NEUTRAL, {})])
    assert merged.t_us == 7 and merged.rel == {"REL_X": 4}
    assert merged.axes["ABS_X"] == -20000 and merged.axes["ABS_Y"] == -1000
    assert {b for b, down in merged.buttons.items() if down} == {"BTN_EAST", "BTN_SOUTH", "BTN_WEST"}
    assert merged.keys == {"KEY_TAB"}
    assert gel.axes["ABS_X"] == 12000 and not gel.buttons["BTN_SOUTH"]  # not changed in place
    assert merge_state(gel, [(NEUTRAL, {})]).axes == gel.axes  # a device gone: the gel's own
