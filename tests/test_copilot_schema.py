"""The copilot's schema (a profile's ``copilot:``) and its errors: the short form and its defaults, ids
and aliases, every problem of a section named with file, line and field at once, the names refused,
and the profiles that need no pad."""

from __future__ import annotations

import pytest
from copilot_helpers import SHORT_FORM

from neurotouch_hid.core.errors import ProfileError
from neurotouch_hid.mapping.profile import load_profile, parse_profile


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
