"""Profile schema, loading, where profiles live, and the errors a bad profile gives."""

from __future__ import annotations

import re
import textwrap

import pytest

from neurotouch_hid.core.controller import AXES, BUTTONS
from neurotouch_hid.core.errors import ProfileError
from neurotouch_hid.mapping.profile import (
    AxisMapping,
    ButtonMapping,
    StickMapping,
    available_profiles,
    find_profile,
    load_profile,
    parse_profile,
    shipped_profiles_dir,
    user_profiles_dir,
)


@pytest.fixture()
def xdg(tmp_path, monkeypatch):
    monkeypatch.setenv("XDG_CONFIG_HOME", str(tmp_path / "config"))
    return tmp_path / "config" / "neurotouch-hid" / "profiles"


def line_of(text: str, needle: str) -> int:
    """1-based line of the first line containing ``needle`` (computed from the test's own text)."""
    return next(i for i, line in enumerate(text.splitlines(), start=1) if needle in line)


@pytest.mark.parametrize("name", ["default", "spacecraft", "accessibility"])
def test_shipped_profiles_load_and_use_known_outputs(name, xdg):
    profile = load_profile(name)
    assert profile.mappings, "a shipped profile maps something"
    assert profile.device.vendor == 0x045E and profile.device.product == 0x028E and profile.device.version == 0x0114
    assert profile.device.name in ("Microsoft X-Box 360 pad", "NeuroTouch (Xbox 360 layout)")
    for mapping in profile.mappings.values():
        if isinstance(mapping, AxisMapping):
            assert mapping.output in AXES
        elif isinstance(mapping, ButtonMapping):
            assert mapping.output in BUTTONS or mapping.output.startswith("dpad_")
        else:
            assert isinstance(mapping, StickMapping)


def test_shipped_profiles_document_their_units():
    for path in shipped_profiles_dir().glob("*.yaml"):
        text = path.read_text()
        assert "millimetres" in text and "user frame" in text, path


def test_shipped_profiles_map_each_gesture_where_docs_profiles_says():
    default = load_profile(shipped_profiles_dir() / "default.yaml")
    by_input = {m.input: m for m in default.mappings.values()}
    assert by_input["push"].output == "left_stick"
    assert by_input["twist"].output == "ABS_RX"
    assert by_input["zoom"].output == "ABS_RZ" and by_input["pinch"].output == "ABS_Z"
    space = load_profile(shipped_profiles_dir() / "spacecraft.yaml")
    assert {(m.input, m.output) for m in space.mappings.values()} >= {
        ("push", "left_stick"),
        ("twist", "ABS_RX"),
        ("zoom", "ABS_RZ"),
        ("pinch", "ABS_Z"),
    }
    access = load_profile(shipped_profiles_dir() / "accessibility.yaml")
    digital = [m for m in access.mappings.values() if isinstance(m, ButtonMapping)]
    assert {m.output for m in digital} >= {"dpad_up", "dpad_down", "dpad_left", "dpad_right"}
    assert any(m.mode == "tap" for m in digital)  # one press per twist: nothing left latched
    assert all(m.smoothing is not None for m in access.mappings.values())
    analog = [m for m in access.mappings.values() if isinstance(m, StickMapping)]
    assert all(m.deadzone_mm >= 2.0 for m in analog)


def test_defaults_fill_in_a_minimal_profile():
    profile = parse_profile("mappings:\n  m: {input: contact, output: right_stick}\n", "mini.yaml")
    assert profile.device.name == "Microsoft X-Box 360 pad"
    assert (profile.device.vendor, profile.device.product, profile.device.version) == (0x045E, 0x028E, 0x0114)
    assert profile.mappings["m"].saturation == 30.0  # the gel radius
    push = parse_profile("mappings:\n  m: {input: push, output: left_stick}\n", "mini.yaml")
    assert push.mappings["m"].saturation == 8.0


BAD = textwrap.dedent("""\
    description: several problems at once
    device:
      vendor: 0x10000
    mappings:
      push:
        input: push
        output: left_stick
        deadzone_mm: lots
        saturation_mm: 6.0
        wobble: 3
      roll:
        input: twist
        output: ABS_ROLL
      fire:
        input: pinch
        output: BTN_SOUTH
        press_mm: 1.0
        release_mm: 2.0
        mode: sometimes
""")


def test_a_bad_profile_lists_every_problem_with_file_line_field_value_and_expectation(tmp_path):
    path = tmp_path / "bad.yaml"
    path.write_text(BAD)
    with pytest.raises(ProfileError) as info:
        load_profile(path)
    message = str(info.value)
    lines = message.splitlines()[1:]
    assert "5 problems" in message.splitlines()[0] or len(lines) >= 5
    expected = {
        # field: (line needle, value shown, expectation words)
        "device.vendor": ("vendor:", "65536", "less than or equal to 65535"),
        "mappings.push.deadzone_mm": ("deadzone_mm: lots", "'lots'", "number"),
        "mappings.push.wobble": ("wobble:", "3", "known field"),
        "mappings.roll.output": ("ABS_ROLL", "'ABS_ROLL'", "'ABS_RX'"),
        "mappings.fire.release_mm": ("release_mm:", "2.0", "<= press_mm"),
        "mappings.fire.mode": (
            "mode: sometimes",
            "'sometimes'",
            "'hold', 'tap', 'toggle', 'long_press', 'double_press' or 'turbo'",
        ),
    }
    for field, (needle, value, expectation) in expected.items():
        hits = [ln for ln in lines if f" {field}:" in ln]
        assert len(hits) == 1, (field, message)
        hit = hits[0]
        assert hit.strip().startswith(f"{path}:{line_of(BAD, needle)}:"), (hit, line_of(BAD, needle))
        assert value in hit and expectation in hit, hit
    assert "deadzone_mm" in next(ln for ln in lines if "wobble" in ln)  # lists the known fields


def test_unknown_top_level_field_and_missing_field(tmp_path):
    text = "mapings: {}\nmappings:\n  m:\n    output: ABS_X\n"
    with pytest.raises(ProfileError) as info:
        parse_profile(text, "t.yaml")
    message = str(info.value)
    assert re.search(r"t\.yaml:1: mapings: unknown field .*mappings", message)
    assert re.search(r"t\.yaml:3: mappings\.m\.input: missing", message)


def test_saturation_must_exceed_dead_zone():
    with pytest.raises(
        ProfileError, match=r"x\.yaml:3: mappings\.m\.saturation_mm: found 1\.0; expected a value > deadzone_mm"
    ):
        parse_profile(
            "mappings:\n  m: {input: zoom, output: ABS_RZ, deadzone_mm: 2.0,\n       saturation_mm: 1.0}\n", "x.yaml"
        )


def test_wrong_input_kind_for_the_output():
    text = "mappings:\n  m:\n    input: push\n    output: ABS_RX\n"
    with pytest.raises(ProfileError, match=r"y\.yaml:3: mappings\.m\.input: found 'push'; expected .*'twist'"):
        parse_profile(text, "y.yaml")


@pytest.mark.parametrize(
    "text, needle",
    [
        ("mappings:\n  m: [unclosed\n", "not valid YAML"),
        ("", "empty"),
        ("- a list\n", "(top level)"),
        ("mappings:\n  m: {input: zoom, output: ABS_RZ, invert: 1}\n", "valid boolean"),
        ("mappings:\n  m: {input: zoom, output: ABS_RZ, gain: '2'}\n", "valid number"),
    ],
)
def test_other_bad_files_give_one_profile_error(text, needle):
    with pytest.raises(ProfileError, match=re.escape(needle)) as info:
        parse_profile(text, "z.yaml")
    assert "z.yaml" in str(info.value)


def test_yaml_is_loaded_safely():
    with pytest.raises(ProfileError):
        parse_profile("!!python/object/apply:os.system ['echo hi']\n", "evil.yaml")


def test_user_profiles_live_in_xdg_config_and_shadow_shipped(xdg):
    assert user_profiles_dir() == xdg
    assert find_profile("default").parent == shipped_profiles_dir()
    xdg.mkdir(parents=True)
    (xdg / "default.yaml").write_text("description: mine\nmappings: {}\n")
    (xdg / "extra.yaml").write_text("mappings: {}\n")
    assert find_profile("default") == xdg / "default.yaml"
    assert load_profile("default").description == "mine"
    assert set(available_profiles()) >= {"default", "spacecraft", "accessibility", "extra"}


def test_unknown_profile_name_lists_the_available_ones(xdg):
    with pytest.raises(ProfileError, match="no profile named 'nope'.*default"):
        load_profile("nope")
    with pytest.raises(ProfileError, match="does not exist"):
        load_profile("/nonexistent/dir/p.yaml")


def test_shipped_profiles_are_package_data():
    """The package's profiles folder (what a wheel ships) holds the top-level profiles/."""
    names = {p.name for p in shipped_profiles_dir().glob("*.yaml")}
    assert names >= {"default.yaml", "spacecraft.yaml", "accessibility.yaml"}
    assert shipped_profiles_dir().parent.name == "neurotouch_hid"


@pytest.mark.parametrize(
    "text, expected",
    [
        ("mappings:\n  m: 5\n", "q.yaml:2: mappings.m: found 5; expected a mapping"),
        ("device: x\nmappings: {}\n", "q.yaml:1: device: found 'x'; expected a mapping"),
        (
            "mappings:\n  m: {input: zoom, output: [1]}\n",
            "q.yaml:2: mappings.m.output: found [1]; expected 'left_stick'",
        ),
        (
            "mappings:\n  bad key: {input: zoom, output: ABS_Z}\n",
            "q.yaml:2: mappings.bad key: found the name 'bad key'",
        ),
    ],
)
def test_wrong_shapes_are_reported_in_plain_words(text, expected):
    with pytest.raises(ProfileError) as info:
        parse_profile(text, "q.yaml")
    assert expected in str(info.value)
    assert "_UnknownOutput" not in str(info.value) and "[key]" not in str(info.value)


@pytest.mark.parametrize(
    "name, expected",
    [
        ('"Pad\\nN: Name=\\"made up\\""', "a device name of printable characters (no newline, tab, escape"),
        ('"Pad\\x1b[31m"', "a device name of printable characters"),
        ('"Pad\\u202eevil"', "a device name of printable characters"),
        (
            '"' + "\U0001f3ae" * 79 + '"',
            "at most 79 bytes of UTF-8 (uinput's limit, 80 with the terminating NUL; "
            "UHID's is 128): this one is 316 bytes",
        ),
        ('"' + "x" * 80 + '"', "at most 79 bytes of UTF-8"),
    ],
    ids=["newline", "escape", "bidi-override", "316-bytes", "80-ascii"],
)
def test_the_device_name_is_refused_where_the_kernel_would_take_it_as_other_lines_or_refuse_it(
    tmp_path, name, expected
):
    """A newline or escape in ``device: name`` added a made-up ``N: Name=`` line to
    /proc/bus/input/devices and a ``HID_NAME=`` line to the UHID device's uevent; a 316-byte name
    passed validation and then run exited 2."""
    text = f"description: mine\ndevice:\n  name: {name}\n"
    path = tmp_path / "named.yaml"
    path.write_text(text, encoding="utf-8")
    with pytest.raises(ProfileError) as info:
        load_profile(path)
    (hit,) = [line.strip() for line in str(info.value).splitlines()[1:] if " device.name:" in line]
    assert hit.startswith(f"{path}:3: device.name: found "), hit
    assert expected in hit, hit


def test_a_device_name_of_79_bytes_of_printable_utf8_loads():
    name = "\u00e9" * 39 + "x"  # 79 bytes
    assert parse_profile(f"device:\n  name: {name}\n", "ok.yaml").device.name == name
