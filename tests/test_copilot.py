"""The copilot (a profile's ``copilot:``): the schema and its errors, which devices match, what a
device's controls become, the merge policies, and the runtime publishing a merged device's input
at once. The real devices (grab, hot-plug, rumble) are checked in a real kernel:
tests/kernel/checks_copilot.py."""

from __future__ import annotations

import os
import threading
from pathlib import Path

import pytest
from evdev import ecodes
from runtime_fakes import EstimatesThrough

from neurotouch_hid.core.controller import ControllerState
from neurotouch_hid.core.errors import ProfileError
from neurotouch_hid.core.estimate import GestureEstimate, GestureType
from neurotouch_hid.core.stages import Feedback
from neurotouch_hid.engine.engine import Engine, RunParts
from neurotouch_hid.engine.mode import RunMode, RunOptions
from neurotouch_hid.inputs.copilot import Copilot
from neurotouch_hid.inputs.match import InputInfo, input_devices, matches
from neurotouch_hid.mapping.merge import NEUTRAL, AxisRange, DeviceMap, Levels, combine_axis, merge_state
from neurotouch_hid.mapping.profile import load_profile, parse_profile

SHORT_FORM = """\
mappings:
  stick: {input: push, output: left_stick}
copilot:
  - device: "Helper Pad"            # a name, "045e:02ea", or a /dev/input/by-id/ path
  - device: "Switch Box"
    map: {KEY_SPACE: BTN_SOUTH}
"""


def line_of(text: str, needle: str) -> int:
    return next(i for i, line in enumerate(text.splitlines(), start=1) if needle in line)


# --- the schema ---------------------------------------------------------------------------------
def test_the_short_form_loads_with_its_defaults():
    profile = parse_profile(SHORT_FORM, "p.yaml")
    pad, box = profile.copilot
    assert pad.device == "Helper Pad" and pad.passthrough and pad.map == {} and pad.policies == {}
    assert box.map == {"KEY_SPACE": "BTN_SOUTH"}
    assert profile.uses_pad


def test_ids_are_kept_in_lower_case_and_aliases_resolved():
    text = 'copilot:\n  - device: "045E:02EA"\n    map: {BTN_SOUTH: B}\n    policy: {dpad_up: sum, A: either}\n'
    (entry,) = parse_profile(text, "p.yaml").copilot
    assert entry.device == "045e:02ea"
    assert entry.map == {"BTN_SOUTH": "BTN_EAST"}
    assert entry.policies == {"ABS_HAT0Y": "sum", "BTN_SOUTH": "either"}


@pytest.mark.parametrize(
    "text, needle, field, expected",
    [
        (  # a device named twice (ids in another case are the same device)
            'copilot:\n  - device: "045e:02ea"\n  - device: "Box"\n  - device: "045E:02EA"\n',
            '"045E:02EA"',
            "copilot.2.device",
            "each device once: '045e:02ea' is named by entries 0 and 2",
        ),
        (  # the driver's own pad, by its name
            'device: {name: "My Pad"}\ncopilot:\n  - device: "My Pad"\n',
            '  - device: "My Pad"',
            "copilot.0.device",
            "a device other than the driver's own",
        ),
        (  # the driver's keyboard
            'copilot:\n  - device: "NeuroTouch keyboard"\n',
            "device:",
            "copilot.0.device",
            "a device other than the driver's own",
        ),
        (  # an axis policy on a button
            'copilot:\n  - device: "Pad"\n    policy: {BTN_SOUTH: further}\n',
            "policy:",
            "copilot.0.policy.BTN_SOUTH",
            "found 'further'; expected the policy either for BTN_SOUTH (a button)",
        ),
        (  # a policy on a control a switch box without passthrough does not drive
            'copilot:\n  - device: "Box"\n    passthrough: false\n    map: {KEY_SPACE: A}\n    policy: {ABS_X: sum}\n',
            "policy:",
            "copilot.0.policy.ABS_X",
            "a policy only on a control this device drives; ABS_X is not one of them",
        ),
        (  # a policy no one knows
            'copilot:\n  - device: "Pad"\n    policy: {ABS_X: loudest}\n',
            "policy:",
            "copilot.0.policy.ABS_X",
            "'further', 'gel', 'helper' or 'sum'",
        ),
        (  # a key the device cannot have
            'copilot:\n  - device: "Box"\n    map: {KEY_SPACEBAR: A}\n',
            "map:",
            "copilot.0.map.KEY_SPACEBAR",
            "did you mean 'KEY_SPACE'",
        ),
        (  # an axis mapped to a button
            'copilot:\n  - device: "Pad"\n    map: {ABS_X: A}\n',
            "map:",
            "copilot.0.map.ABS_X",
            "found 'A'; expected a pad axis (ABS_X, ABS_Y, ABS_RX, ABS_RY, ABS_Z, ABS_RZ, ABS_HAT0X, ABS_HAT0Y) "
            "for the axis ABS_X",
        ),
        (  # a key the system acts on
            'copilot:\n  - device: "Box"\n    map: {KEY_A: KEY_POWER}\n',
            "map:",
            "copilot.0.map.KEY_A",
            "a key other than KEY_POWER",
        ),
        (  # a path outside /dev/input
            'copilot:\n  - device: "/tmp/pad"\n',
            "device:",
            "copilot.0.device",
            "a path under /dev/input/",
        ),
        (  # a path that only starts under /dev/input: .. takes it out (never opened, still refused)
            'copilot:\n  - device: "/dev/input/../../etc/shadow"\n',
            "device:",
            "copilot.0.device",
            "a path under /dev/input/ (such as /dev/input/by-id/usb-...-event-joystick); "
            "'/dev/input/../../etc/shadow' is '/etc/shadow'",
        ),
        (  # an unknown field of an entry lists the known ones
            'copilot:\n  - device: "Pad"\n    wobble: 1\n',
            "wobble:",
            "copilot.0.wobble",
            "one of device, map, passthrough, policy",
        ),
    ],
)
def test_a_bad_copilot_entry_names_file_line_field_and_what_was_expected(tmp_path, text, needle, field, expected):
    path = tmp_path / "bad.yaml"
    path.write_text(text)
    with pytest.raises(ProfileError) as info:
        load_profile(path)
    hits = [line.strip() for line in str(info.value).splitlines()[1:] if f" {field}:" in line]
    assert len(hits) == 1, str(info.value)
    assert hits[0].startswith(f"{path}:{line_of(text, needle)}: {field}:"), hits[0]
    assert expected in hits[0], hits[0]


def test_every_problem_of_a_copilot_section_is_listed_at_once_each_on_its_line(tmp_path):
    """Three bad map lines and two bad policies in one entry, a device named twice and the
    driver's mouse in the list: every one is named, on its own line."""
    text = (
        "copilot:\n"
        "  - device: Box\n"
        "    map:\n"
        "      KEY_SPACEBAR: A\n"
        "      KEY_B: KEY_POWER\n"
        "      ABS_X: A\n"
        "    policy:\n"
        "      BTN_SOUTH: further\n"
        "      WOBBLE: sum\n"
        "  - device: Pad\n"
        "  - device: Pad\n"
        "  - device: NeuroTouch mouse\n"
    )
    path = tmp_path / "bad.yaml"
    path.write_text(text)
    with pytest.raises(ProfileError) as info:
        load_profile(path)
    entry = [line.strip() for line in str(info.value).splitlines()[1:]]
    assert [line.split(": ")[0] for line in entry] == [f"{path}:{n}" for n in (4, 5, 6, 8, 9)], entry
    path.write_text(
        text.replace("KEY_SPACEBAR", "KEY_SPACE")
        .replace("KEY_POWER", "KEY_C")
        .replace("ABS_X: A", "ABS_X: ABS_Y")
        .replace("      BTN_SOUTH: further\n      WOBBLE: sum\n", "      ABS_Y: sum\n")
    )
    with pytest.raises(ProfileError) as info:
        load_profile(path)
    lists = [line.strip() for line in str(info.value).splitlines()[1:]]
    assert [line.split(": ")[:2] for line in lists] == [
        [f"{path}:10", "copilot.2.device"],
        [f"{path}:11", "copilot.3.device"],
    ]


def test_the_names_refused_are_those_of_the_keyboard_and_mouse_the_driver_makes():
    from neurotouch_hid.mapping.profile import OWN_INPUT_NAMES
    from neurotouch_hid.targets.uinput.desktop import KEYBOARD_NAME, MOUSE_NAME

    assert set(OWN_INPUT_NAMES) == {KEYBOARD_NAME, MOUSE_NAME}


def test_a_profile_touching_no_pad_control_needs_no_pad():
    assert not load_profile("mouse").uses_pad
    assert not load_profile("switch-access").uses_pad
    assert load_profile("default").uses_pad
    box = (
        "mappings:\n  k: {input: pinch, output: KEY_A}\n"
        "copilot:\n  - {device: Box, passthrough: false, map: {KEY_F1: KEY_B}}\n"
    )
    profile = parse_profile(box, "p.yaml")
    assert not profile.uses_pad and profile.keyboard_keys == {"KEY_A", "KEY_B"}
    assert parse_profile(box.replace("KEY_B}", "A}"), "p.yaml").uses_pad


def test_the_accessibility_profiles_commented_switch_box_loads_once_uncommented(tmp_path):
    from neurotouch_hid.mapping.profile import shipped_profiles_dir

    text = (shipped_profiles_dir() / "accessibility.yaml").read_text()
    assert not load_profile("accessibility").copilot  # shipped commented out: nothing is grabbed
    start = text.index("# copilot:")
    uncommented = text[:start] + "\n".join(line[2:] for line in text[start:].splitlines()) + "\n"
    path = tmp_path / "accessibility.yaml"
    path.write_text(uncommented)
    (box,) = load_profile(path).copilot
    assert box.map == {"KEY_SPACE": "BTN_SOUTH", "KEY_ENTER": "BTN_EAST"} and not box.passthrough


# --- matching ---------------------------------------------------------------------------------------
HELPER = InputInfo(
    "/dev/input/event7",
    "Helper Pad",
    "usb-0000:00:14.0-2/input0",
    0x045E,
    0x02EA,
    ("/dev/input/by-id/usb-Helper-event-joystick",),
)
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


# --- the runtime ----------------------------------------------------------------------------------
class ScriptedMerge:
    """A Merge whose device's levels the test sets; ``press`` calls the runtime's ``on_input``
    from another thread, as the copilot's thread does."""

    def __init__(self):
        self.levels = NEUTRAL
        self.events: list[str] = []
        self.on_input = None

    def start(self, on_input):
        self.events.append("start")
        self.on_input = on_input

    def merge(self, gel):
        return merge_state(gel, [(self.levels, {})])

    def feedback(self, request):
        self.events.append(f"feedback {request.kind}")

    def stop(self):
        self.events.append("stop")

    def status(self):
        return (("Helper Pad",), ()) if "stop" not in self.events else ((), ("Helper Pad",))

    def press(self, levels):
        self.levels = levels
        thread = threading.Thread(target=self.on_input)
        thread.start()
        thread.join()


class Written:
    wants_markers = False

    def __init__(self):
        self.states: list[ControllerState] = []
        self.calls: list[str] = []

    def publish(self, record):
        if record.state_changed:
            self.states.append(record.state)
            self.calls.append("write")

    def neutralise(self):
        self.calls.append("neutralise")

    def prepare(self, profile):
        self.calls.append("prepare")


def test_the_runtime_merges_each_window_and_publishes_a_helpers_press_at_once():
    profile = parse_profile(SHORT_FORM, "p.yaml")
    merge, out = ScriptedMerge(), Written()
    gate = threading.Event()

    def source():
        yield GestureEstimate(
            t_us=10_000, gesture=GestureType.PUSH, resting=False, intensity_mm=6.0, translation_mm=(6.0, 0.0)
        )
        gate.wait(30)  # the gel holds its push: no window comes meanwhile
        yield GestureEstimate(t_us=20_000)

    rt = Engine(RunParts(source(), EstimatesThrough()), profile, [out], RunOptions(mode=RunMode.FAST, merge=merge))

    def helper():
        from helpers import wait_until

        wait_until(lambda: out.states, 30)
        merge.press(Levels(axes={"ABS_X": -32768}, buttons=frozenset({"BTN_SOUTH"})))
        merge.press(Levels(axes={"ABS_X": -32768}, buttons=frozenset({"BTN_SOUTH"})))  # no change: nothing
        gate.set()

    thread = threading.Thread(target=helper)
    thread.start()
    stats = rt.run()
    thread.join()
    first, pressed, *rest = out.states
    assert first.axes["ABS_X"] > 20000 and not first.buttons["BTN_SOUTH"]  # the gel's push alone
    assert pressed.axes["ABS_X"] == -32768 and pressed.buttons["BTN_SOUTH"]  # the helper's, before the next window
    assert rest == []  # the gel at rest: the helper's stick and button alone, as the pad shows already
    assert merge.events == ["start", "stop"] and out.calls[-1] == "neutralise"
    assert stats.states_written == len(out.states) and stats.merged == ("Helper Pad",)


def test_a_profile_switch_releases_the_old_merge_and_starts_the_new_ones():
    made: list[ScriptedMerge | None] = []

    def merge_for(profile):
        made.append(ScriptedMerge() if profile.copilot else None)
        return made[-1]

    with_copilot = parse_profile(SHORT_FORM, "p.yaml")
    without = parse_profile("mappings: {}\n", "q.yaml")
    out = Written()
    started = threading.Event()

    def source():
        yield GestureEstimate(t_us=10_000)
        started.wait(30)

    rt = Engine(
        RunParts(source(), EstimatesThrough()), with_copilot, [out], RunOptions(mode=RunMode.FAST, merge_for=merge_for)
    )
    thread = threading.Thread(target=rt.run)
    thread.start()
    from helpers import wait_until

    wait_until(lambda: made and made[0].events == ["start"], 30)
    rt.switch_profile(without)
    assert made[0].events == ["start", "stop"] and made[1] is None and rt.stats.merged == ()
    rt.switch_profile(with_copilot)
    assert made[2].events == ["start"]
    started.set()
    thread.join(30)
    assert made[2].events == ["start", "stop"]


@pytest.mark.parametrize("camera", ["waiting", "lost"])
def test_the_helpers_pad_drives_the_pad_while_the_gels_camera_is_missing(camera):
    """No camera yet, or the camera lost after a window: the helper's pad is merged (grabbed, so
    the game does not see it apart) and its press and stick reach the pad at once, over a gel at
    rest; the driver's stop leaves the pad neutral."""
    from helpers import wait_until

    from neurotouch_hid.sources import SourceStatus, StatusKind

    profile = parse_profile(SHORT_FORM, "p.yaml")
    merge, out = ScriptedMerge(), Written()
    gate = threading.Event()

    def source():
        if camera == "waiting":
            yield SourceStatus(StatusKind.WAITING, "waiting for a camera")
        else:
            yield GestureEstimate(t_us=10_000)
            yield SourceStatus(StatusKind.LOST, "camera lost")
        gate.wait(30)

    rt = Engine(RunParts(source(), EstimatesThrough()), profile, [out], RunOptions(mode=RunMode.LIVE, merge=merge))
    thread = threading.Thread(target=rt.run)
    thread.start()
    wait_until(lambda: merge.on_input is not None and (camera == "waiting" or rt.stats.camera_losses == 1), 30)
    merge.press(Levels(axes={"ABS_X": -32768}, buttons=frozenset({"BTN_SOUTH"})))
    gate.set()
    thread.join(30)
    pressed = [s for s in out.states if s.buttons["BTN_SOUTH"]]
    assert pressed and pressed[0].axes["ABS_X"] == -32768 and pressed[0].axes["ABS_Y"] == 0
    assert out.calls[-1] == "neutralise"


# --- what the user is told ------------------------------------------------------------------------
def test_presence_names_what_is_plugged_in_and_what_is_waited_for():
    from neurotouch_hid.inputs.match import presence, presence_line

    box = InputInfo("/dev/input/event8", "Switch Box", "usb-3/input0", 0x1234, 0x5678)
    assert presence_line(["Helper Pad", "Switch Box", "045e:028e"], [HELPER]) == (
        "present: Helper Pad (/dev/input/event7); missing: Switch Box, 045e:028e"
    )
    # one device is taken by the first rule naming it, as the running driver takes it
    assert presence(["045e:02ea", "Helper Pad", "Switch Box"], [HELPER, box]) == [
        ("045e:02ea", HELPER),
        ("Helper Pad", None),
        ("Switch Box", box),
    ]


def test_doctor_says_which_copilot_devices_are_there_and_which_are_waited_for(tmp_path, monkeypatch):
    from neurotouch_hid.service.doctor import FAIL, OK, SKIP, WARN, check_copilot

    node = tmp_path / "event7"
    node.write_text("")
    helper = InputInfo(str(node), "Helper Pad", "usb-2/input0", 0x045E, 0x02EA)
    profile = parse_profile(SHORT_FORM, "p.yaml")
    waiting = check_copilot({"mine": profile}, [helper], hiding=True)
    assert waiting.status == WARN
    assert waiting.detail.startswith(f"mine: Helper Pad at {node}, Switch Box missing")
    box = InputInfo(str(node), "Switch Box", "usb-3/input0", 0x1234, 0x5678)
    assert check_copilot({"mine": profile}, [helper, box], hiding=True).status == OK
    # not root: grabbed but not hidden, so a game may list the helper's pad; how to avoid it
    unhidden = check_copilot({"mine": profile}, [helper, box], hiding=False)
    assert unhidden.status == WARN and "SDL_GAMECONTROLLER_IGNORE_DEVICES=0x045e/0x02ea" in unhidden.fix
    closed = InputInfo("/nonexistent/event9", "Switch Box", "usb-3/input0", 0x1234, 0x5678)
    denied = check_copilot({"mine": profile}, [helper, closed])
    assert denied.status == FAIL and "sudo usermod -aG input $USER" in denied.fix
    assert "not readable by this user" in denied.detail
    import neurotouch_hid.service.doctor as doctor

    readable = InputInfo(str(node), "Switch Box", "usb-3/input0", 0x1234, 0x5678)
    # a node this user may read but not write (root may write anything: the test says which)
    monkeypatch.setattr(doctor.os, "access", lambda path, mode: mode == os.R_OK)
    read_only = check_copilot({"mine": profile}, [helper, readable], hiding=True)
    monkeypatch.undo()
    assert read_only.status == WARN and "merged, but a game's rumble is not played on them" in read_only.detail
    assert check_copilot({"default": load_profile("default")}, []).status == SKIP


def test_the_live_view_says_what_is_merged_and_what_is_missing():
    from neurotouch_hid.views.live import copilot_line

    assert copilot_line(("Helper Pad",), ("Switch Box",)).plain == "merged: Helper Pad; missing: Switch Box"
    assert copilot_line((), ()).plain == "merged: none; missing: none"


def test_devices_json_lists_the_input_devices_a_copilot_can_merge():
    import json

    from helpers import run_cli

    from neurotouch_hid.inputs.match import mergeable_devices, to_json

    data = json.loads(run_cli("devices", "--json").stdout)
    assert data["inputs"] == [to_json(info) for info in mergeable_devices()]
    assert to_json(HELPER) == {
        "node": "/dev/input/event7",
        "name": "Helper Pad",
        "ids": "045e:02ea",
        "phys": "usb-0000:00:14.0-2/input0",
        "links": ["/dev/input/by-id/usb-Helper-event-joystick"],
    }


def test_profile_show_says_which_copilot_devices_are_plugged_in(cli, tmp_path):
    path = tmp_path / "helped.yaml"
    path.write_text(SHORT_FORM)
    done = cli("show", str(path))
    assert done.returncode == 0, done.stderr
    assert done.stdout == SHORT_FORM  # a pipe gets the file's exact bytes
    assert "# copilot: present: none; missing: Helper Pad, Switch Box" in done.stderr


def test_the_unhidden_note_says_needs_root_only_to_a_user_who_is_not(monkeypatch):
    """As root, doctor said hiding merged devices 'needs root': where root cannot hide them,
    /dev/input is what is not writable."""
    import os

    from neurotouch_hid.inputs.copilot import unhidden_note

    monkeypatch.setattr(os, "geteuid", lambda: 0)
    as_root = unhidden_note()
    assert "needs root" not in as_root and "/dev/input is not writable here" in as_root
    monkeypatch.setattr(os, "geteuid", lambda: 1000)
    assert "(that needs root)" in unhidden_note() and "run the driver as root" in unhidden_note()
