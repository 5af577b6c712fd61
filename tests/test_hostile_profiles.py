"""Profiles and sensor.yaml crafted to break the driver (docs/limits.md): YAML bombs, FIFOs and huge
files, numbers past what the kernel holds, keys the machine acts on, and the keyboard device they
make. Each is refused with one short message, no traceback, and bounded memory."""

from __future__ import annotations

import os
import sys
import tempfile
from pathlib import Path

import pytest
from hostile_helpers import MAX_RSS_KB, _env, _user_profiles, assert_refused, bounded_run, cli
from hostile_inputs import ALIAS_BOMB, DEEP_YAML

from neurotouch_hid.core.errors import ProfileError, SensorError


# --- YAML ---------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    "text, says",
    [
        (ALIAS_BOMB, "aliases"),
        (DEEP_YAML, "nested more than"),
        ("mappings: {}\ndescription: " + "1" * 5000 + "\n", "a number of 5000 characters"),
        ("mappings: {}\ndescription: x\ndescription: y\n", "duplicate key"),
    ],
    ids=["alias-bomb", "8000-deep", "5000-digits", "duplicate-key"],
)
def test_profile_validate_refuses_yaml_bombs_in_one_line(tmp_path, text, says):
    path = tmp_path / "crafted.yaml"
    path.write_text(text)
    assert_refused(cli("profile", "validate", str(path)), says, f"{path}:")


def test_profile_numbers_must_be_finite():
    text = "mappings:\n  move: {input: push, output: left_stick, deadzone_mm: .inf}\n"
    with pytest.raises(ProfileError, match="finite number"):
        from neurotouch_hid.mapping.profile import parse_profile

        parse_profile(text, "inf.yaml")


def test_yaml_errors_carry_a_plain_hint_beside_file_and_line():
    from neurotouch_hid.mapping.profile import parse_profile

    with pytest.raises(ProfileError) as tab:
        parse_profile("mappings:\n\tjump: {input: push, output: A}\n", "tabs.yaml")
    assert str(tab.value).startswith("tabs.yaml:2: not valid YAML") and "never tabs" in str(tab.value)
    with pytest.raises(ProfileError) as indent:
        parse_profile("mappings:\n  jump: {input: push, output: A}\n kick: x\n", "indent.yaml")
    assert str(indent.value).startswith("indent.yaml:3:") and "indentation" in str(indent.value)


def _load_sensor_in_child(path: Path):
    code = (
        "import sys\nfrom neurotouch_hid.core.errors import SensorError\n"
        "from neurotouch_hid.core.sensor import SensorGeometry\n"
        "try:\n    SensorGeometry.load(sys.argv[1])\nexcept SensorError as exc:\n"
        "    print(exc, file=sys.stderr)\n    sys.exit(2)\n"
    )
    return bounded_run([sys.executable, "-c", code, str(path)], env=_env())


@pytest.mark.parametrize(
    "text, says",
    [
        (ALIAS_BOMB, "aliases"),
        (DEEP_YAML, "nested more than"),
        ("width: " + "3" * 5000 + "\n", "a number of 5000 characters"),
        ("px_per_mm: .inf\n", "finite number"),
        ("gel_radius_px: 1e300\n", "gel_radius_px"),
        ("gel_center_px: [1e300, 130]\n", "gel_center_px"),
        ("rotation_deg: 1e300\n", "rotation_deg"),
        ("width: 346\nwidth: 640\n", "duplicate key"),
    ],
    ids=["alias-bomb", "8000-deep", "5000-digits", "inf", "huge", "huge-centre", "huge-rotation", "duplicate-key"],
)
def test_sensor_yaml_bombs_are_one_line(tmp_path, text, says):
    path = tmp_path / "sensor.yaml"
    path.write_text(text)
    assert_refused(_load_sensor_in_child(path), says)


def test_a_fifo_as_sensor_yaml_does_not_hang(tmp_path):
    fifo = tmp_path / "sensor.yaml"
    os.mkfifo(fifo)
    assert_refused(_load_sensor_in_child(fifo), "not a regular file")
    with pytest.raises(SensorError, match="not a regular file"):
        from neurotouch_hid.core.sensor import SensorGeometry

        SensorGeometry.load(fifo)


def test_a_fifo_or_a_huge_file_as_profile_is_refused(tmp_path):
    from neurotouch_hid.mapping.profile import load_profile

    fifo = tmp_path / "fifo.yaml"
    os.mkfifo(fifo)
    with pytest.raises(ProfileError, match="not a regular file"):
        load_profile(fifo)
    big = tmp_path / "big.yaml"
    big.write_text("# " + "x" * (300 * 1024) + "\nmappings: {}\n")
    with pytest.raises(ProfileError, match="larger than 256 KB"):
        load_profile(big)


def test_error_messages_do_not_echo_long_values():
    from neurotouch_hid.core.errors import NeurotouchError
    from neurotouch_hid.evaluation.runner import pipeline_config
    from neurotouch_hid.mapping.profile import parse_profile

    with pytest.raises(ProfileError) as err:
        parse_profile("mappings:\n  m: {input: push, output: A, press_mm: [" + "1, " * 20000 + "1]}\n", "long.yaml")
    assert len(str(err.value)) < 600
    many = "mappings:\n" + "".join(f"  m{i}: {{input: nope, output: A}}\n" for i in range(500))
    with pytest.raises(ProfileError, match="and 490 more") as err:
        parse_profile(many, "many.yaml")
    assert len(str(err.value)) < 4096
    with pytest.raises(NeurotouchError) as err:
        pipeline_config(["contacts.r_mm=" + "x" * 100_000])
    assert len(str(err.value)) < 600
    with pytest.raises(NeurotouchError, match="finite"):
        pipeline_config(["contacts.r_mm=inf"])


# --- the keyboard: SysRq and what the device offers --------------------------------------------
@pytest.mark.parametrize(
    "output, says",
    [("KEY_LEFTALT+KEY_SYSRQ+KEY_B", "KEY_SYSRQ"), ("KEY_SYSRQ", "reboots")],
)
def test_sysrq_is_refused_at_validation_with_the_reason(output, says):
    from neurotouch_hid.mapping.profile import parse_profile

    with pytest.raises(ProfileError, match=says):
        parse_profile(f"mappings:\n  boom: {{input: push_intensity, output: {output}}}\n", "sysrq.yaml")


@pytest.mark.parametrize(
    "output", ["KEY_POWER", "KEY_POWER2", "KEY_RESTART", "KEY_SLEEP", "KEY_LEFTCTRL+KEY_SUSPEND", "KEY_RFKILL"]
)
def test_keys_the_machine_acts_on_are_refused_and_never_offered(output):
    """logind powers off, reboots, suspends or hibernates on these keys, rfkill-input turns the
    radios off: no profile may press them, and the virtual keyboard never has them."""
    from evdev import ecodes

    from neurotouch_hid.mapping.profile import KERNEL_COMMAND_KEYS, keyboard_keys, parse_profile
    from neurotouch_hid.targets.uinput.desktop import keyboard_codes

    with pytest.raises(ProfileError, match="the system acts on it"):
        parse_profile(f"mappings:\n  off: {{input: push_intensity, output: {output}}}\n", "power.yaml")
    offered = set(keyboard_codes(keyboard_keys()))
    assert not offered & {ecodes.ecodes[name] for name in KERNEL_COMMAND_KEYS}


def test_a_chord_or_a_profile_cannot_ask_for_every_key():
    """A chord holds at most MAX_CHORD_KEYS keys, a profile presses at most MAX_PROFILE_KEYS."""
    from neurotouch_hid.mapping.profile import (
        KERNEL_COMMAND_KEYS,
        MAX_CHORD_KEYS,
        MAX_PROFILE_KEYS,
        keyboard_keys,
        parse_profile,
    )

    keys = sorted(keyboard_keys() - KERNEL_COMMAND_KEYS)
    chord = "+".join(keys[:300])
    with pytest.raises(ProfileError, match=f"a chord of at most {MAX_CHORD_KEYS} keys") as err:
        parse_profile(f"mappings:\n  all: {{input: push_intensity, output: {chord}}}\n", "chord.yaml")
    assert len(str(err.value)) < 1000
    plain = [k for k in keys if k[4:].isalnum() and k not in ("KEY_DELETE", "KEY_KPDOT")][: MAX_PROFILE_KEYS + 1]
    many = "mappings:\n" + "".join(f"  m{i}: {{input: push_intensity, output: {k}}}\n" for i, k in enumerate(plain))
    with pytest.raises(ProfileError, match=f"at most {MAX_PROFILE_KEYS} different keyboard keys"):
        parse_profile(many, "many.yaml")
    assert len(parse_profile(many.rsplit("  m", 1)[0] + "\n", "fits.yaml").keyboard_keys) == MAX_PROFILE_KEYS


def test_ctrl_alt_delete_is_refused_even_over_several_mappings():
    from neurotouch_hid.mapping.profile import parse_profile

    text = (
        "mappings:\n  a: {input: push_intensity, output: KEY_LEFTCTRL+KEY_LEFTALT}\n"
        "  b: {input: pinch, output: KEY_DELETE}\n"
    )
    with pytest.raises(ProfileError, match="Ctrl\\+Alt\\+Delete"):
        parse_profile(text, "cad.yaml")


class _FakeUinput:
    def __init__(self, capabilities):
        self.capabilities, self.events, self.closed, self.device = capabilities, [], False, None

    def write(self, etype, code, value):
        self.events.append((etype, code, value))

    def syn(self):
        self.events.append((0, 0, 0))

    def close(self):
        self.closed = True


class _Pad:
    device_path = None

    def write(self, state):
        pass

    def neutralise(self):
        pass

    close = neutralise


def test_keyboard_offers_only_the_profiles_keys_and_is_made_again_for_new_ones(monkeypatch):
    """The keyboard offers the loaded profiles' keys and udev's keyboard block, never SysRq; a
    profile needing more replaces it by one offering both, after releasing what was held."""
    from evdev import ecodes

    from neurotouch_hid.core.controller import ControllerState
    from neurotouch_hid.mapping.profile import parse_profile
    from neurotouch_hid.targets.uinput import desktop

    made: list[_FakeUinput] = []
    monkeypatch.setattr(
        desktop, "create_uinput", lambda what, caps, *a, **k: made.append(_FakeUinput(caps)) or made[-1]
    )
    monkeypatch.setattr(desktop, "RELEASE_GRACE_S", 0.0, raising=False)
    first = parse_profile("mappings:\n  jump: {input: push_intensity, output: KEY_F5}\n", "a.yaml")
    known = parse_profile("mappings:\n  go: {input: pinch, output: KEY_F6}\n", "b.yaml")
    outputs = desktop.UinputOutputs(_Pad(), first, known=[known])
    codes = set(made[0].capabilities[ecodes.EV_KEY])
    assert codes == set(range(1, 32)) | {ecodes.KEY_F5, ecodes.KEY_F6}
    assert ecodes.KEY_SYSRQ not in codes and ecodes.KEY_POWER not in codes
    outputs.write(ControllerState(keys=frozenset({"KEY_F5", "KEY_POWER"})))
    assert (ecodes.EV_KEY, ecodes.KEY_F5, 1) in made[0].events
    assert all(code != ecodes.KEY_POWER for _, code, _ in made[0].events)  # not offered: not written
    outputs.prepare(known)  # offered already: the same device
    assert len(made) == 1
    more = parse_profile("mappings:\n  save: {input: push_intensity, output: KEY_LEFTCTRL+KEY_S+KEY_F9}\n", "c.yaml")
    outputs.prepare(more)
    assert len(made) == 2 and made[0].closed and (ecodes.EV_KEY, ecodes.KEY_F5, 0) in made[0].events
    assert set(made[1].capabilities[ecodes.EV_KEY]) == codes | {ecodes.KEY_F9}
    outputs.close()


def assert_refused_briefly(result, *must_say: str) -> None:
    """Exit 2, a short message (a line and a hint) naming the problem, no traceback, bounded
    memory."""
    code, out, err, rss = result
    assert code == 2, f"exit {code}: {err[-2000:]}"
    assert "Traceback" not in err and len(out) + len(err) <= 1000, err[-2000:]
    for words in must_say:
        assert words in err, err
    assert rss < MAX_RSS_KB, f"peak memory {rss // 1024} MB"


@pytest.mark.parametrize(
    "args",
    [
        ("set", "deep", "description", "x"),
        ("unset", "deep", "description"),
        ("set", "zero", "description", "x"),
        ("unset", "zero", "description"),
        ("show", "zero"),
        ("new", "copy", "--from", "zero"),
    ],
)
def test_the_editor_reads_user_profiles_within_the_bounds(user_config_in_tmp, args):
    """A user profile nested 8000 deep (``profile set`` raised RecursionError), and one that is
    a link to /dev/zero (``profile show`` read gigabytes): a short message, bounded memory."""
    folder = _user_profiles(user_config_in_tmp)
    (folder / "deep.yaml").write_text(DEEP_YAML)
    (folder / "zero.yaml").symlink_to("/dev/zero")
    says = "nested more than" if "deep" in args else "not a regular file"
    assert_refused_briefly(cli("profile", *args), says)


@pytest.mark.parametrize("command", ["validate", "show", "new", "use"])
@pytest.mark.parametrize("suffix", ["", ".yaml"])
def test_a_300_character_profile_name_is_one_short_line(command, suffix):
    """A name (or a file name) of 300 characters: the file system refuses it (ENAMETOOLONG),
    which was a traceback; the message quotes an excerpt."""
    name = "p" * 300 + suffix
    code, out, err, _ = cli("profile", command, name, env=_env(XDG_RUNTIME_DIR=tempfile.mkdtemp()))
    assert code == 2 and "Traceback" not in err and len(err) < 1000, err
    assert len(err.strip().splitlines()) == 1 and "p" * 300 not in err, err


def test_relative_counts_per_step_stay_within_an_event():
    """2000 wheel mappings at the highest speed sum to more hi-res counts in a step than an
    event's signed 32 bits hold (python-evdev raised OverflowError): the step is clamped."""
    from neurotouch_hid.core.estimate import GestureEstimate, GestureType
    from neurotouch_hid.mapping.mapper import Mapper
    from neurotouch_hid.mapping.profile import parse_profile
    from neurotouch_hid.mapping.rel_motion import MAX_REL_COUNTS_PER_STEP

    text = "mappings:\n" + "".join(
        f"  w{i}: {{input: intensity, output: {'REL_WHEEL' if i % 2 else 'REL_X'}, speed: 100000}}\n"
        for i in range(2000)
    )
    mapper = Mapper(parse_profile(text, "wheels.yaml"))
    push = dict(gesture=GestureType.PUSH, intensity_mm=20.0, translation_mm=(1.0, 0.0), resting=False)
    for t_us in (0, 100_000, 200_000):
        state = mapper.update(GestureEstimate(t_us=t_us, **push))
        assert all(abs(v) <= MAX_REL_COUNTS_PER_STEP < 2**31 for v in state.rel.values()), state.rel
    assert state.rel["REL_X"] == MAX_REL_COUNTS_PER_STEP and state.rel["REL_WHEEL_HI_RES"] == MAX_REL_COUNTS_PER_STEP
