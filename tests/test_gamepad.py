"""VirtualGamepad without a kernel device: the DeviceError paths, the event diff, the layout.

The device itself (uinput, udev, SDL, SIGTERM) is tested in a real kernel: tests/test_kernel.py.
"""

from __future__ import annotations

import os

import pytest
from evdev import ecodes
from hypothesis import given, settings
from hypothesis import strategies as st

from neurotouch_hid.core.controller import AXES, BUTTONS, ControllerState
from neurotouch_hid.core.errors import DeviceError
from neurotouch_hid.service.udev import INSTALL_SCRIPT, RULES_FILE, RULES_INSTALL, UINPUT_RULE
from neurotouch_hid.targets.uinput import gamepad
from neurotouch_hid.targets.uinput.gamepad import (
    GamepadIdentity,
    VirtualGamepad,
    capabilities,
    changed_events,
    normalised,
)


def _assert_says_how_to_fix(message: str) -> None:
    assert RULES_INSTALL in message.splitlines()  # the install command alone on its line
    assert INSTALL_SCRIPT.is_file() and RULES_FILE.is_file() and UINPUT_RULE in RULES_FILE.read_text()


@pytest.mark.skipif(
    os.path.exists("/dev/uinput"), reason="this machine has /dev/uinput (the kernel tests cover the device)"
)
def test_missing_dev_uinput_raises_device_error_with_the_fix():
    with pytest.raises(DeviceError) as info:
        VirtualGamepad()
    assert "/dev/uinput does not exist" in str(info.value)
    _assert_says_how_to_fix(str(info.value))


def test_missing_node_names_it(tmp_path):
    node = tmp_path / "uinput"
    with pytest.raises(DeviceError, match=f"{node} does not exist") as info:
        VirtualGamepad(devnode=str(node))
    _assert_says_how_to_fix(str(info.value))


def test_regular_file_is_not_taken_for_uinput(tmp_path):
    node = tmp_path / "uinput"
    node.write_bytes(b"")
    with pytest.raises(DeviceError, match="not a character device"):
        VirtualGamepad(devnode=str(node))


def test_a_character_device_that_is_not_uinput_is_refused_by_the_kernel():
    # /dev/null accepts the open but not uinput's ioctls (ENOTTY): a real kernel refusal.
    with pytest.raises(DeviceError, match="refused") as info:
        VirtualGamepad(devnode="/dev/null")
    _assert_says_how_to_fix(str(info.value))


def test_no_permission_says_so(monkeypatch):
    monkeypatch.setattr(gamepad.os, "access", lambda path, mode: False)  # root may open anything
    with pytest.raises(DeviceError, match="no permission to open /dev/null") as info:
        VirtualGamepad(devnode="/dev/null")
    _assert_says_how_to_fix(str(info.value))


def test_overlong_name_is_a_device_error():
    with pytest.raises(DeviceError, match="must be 1..79 bytes"):
        VirtualGamepad(GamepadIdentity(name="x" * 80), devnode="/dev/null")


def test_capabilities_are_the_xbox360_layout_with_rumble_and_nothing_mouse_like():
    caps = capabilities()
    assert set(caps) == {ecodes.EV_KEY, ecodes.EV_ABS, ecodes.EV_FF}
    assert caps[ecodes.EV_FF] == [ecodes.FF_RUMBLE]  # like xpad
    assert caps[ecodes.EV_KEY] == [ecodes.ecodes[b] for b in BUTTONS]
    assert ecodes.BTN_LEFT not in caps[ecodes.EV_KEY] and ecodes.BTN_TOUCH not in caps[ecodes.EV_KEY]
    ranges = {code: (info.min, info.max) for code, info in caps[ecodes.EV_ABS]}
    assert ranges == {ecodes.ecodes[n]: (lo, hi) for n, (lo, hi, _) in AXES.items()}
    flats = {code: info.flat for code, info in caps[ecodes.EV_ABS]}
    assert flats[ecodes.ABS_X] == gamepad.STICK_FLAT and flats[ecodes.ABS_Z] == 0


def test_first_write_sends_everything_then_only_changes():
    neutral = ControllerState.neutral()
    first = changed_events(None, neutral)
    assert [n for n, _ in first] == list(AXES) + list(BUTTONS)
    assert changed_events(neutral, ControllerState.neutral(t_us=5)) == []
    pressed = ControllerState.neutral()
    pressed.buttons["BTN_SOUTH"] = True
    pressed.axes["ABS_RZ"] = 200
    assert changed_events(neutral, pressed) == [("ABS_RZ", 200), ("BTN_SOUTH", 1)]
    assert changed_events(pressed, neutral) == [("ABS_RZ", 0), ("BTN_SOUTH", 0)]


def test_out_of_range_missing_and_unknown_names():
    state = ControllerState(
        axes={"ABS_X": 10**6, "ABS_Z": -4, "ABS_HAT0Y": 3, "ABS_BOGUS": 1},
        buttons={"BTN_START": True, "BTN_BOGUS": True},
    )
    full = normalised(state)
    assert full.axes["ABS_X"] == 32767 and full.axes["ABS_Z"] == 0 and full.axes["ABS_HAT0Y"] == 1
    assert full.axes["ABS_RX"] == 0  # missing = neutral
    assert set(full.axes) == set(AXES) and set(full.buttons) == set(BUTTONS)
    assert full.buttons["BTN_START"] and not full.buttons["BTN_SOUTH"]


_axis_values = st.fixed_dictionaries({n: st.integers(lo - 1000, hi + 1000) for n, (lo, hi, _) in AXES.items()})
_button_values = st.fixed_dictionaries({b: st.booleans() for b in BUTTONS})
_states = st.builds(lambda a, b: ControllerState(axes=a, buttons=b), _axis_values, _button_values)


@settings(deadline=None)  # behaviour, not speed: a loaded machine must not fail it
@given(_states, _states)
def test_applying_the_changes_reaches_the_new_state(old, new):
    events = changed_events(old, new)
    reached = normalised(old)
    for name, value in events:
        if name in AXES:
            reached.axes[name] = value
        else:
            reached.buttons[name] = bool(value)
    assert reached.axes == normalised(new).axes and reached.buttons == normalised(new).buttons
    names = [n for n, _ in events]
    assert len(names) == len(set(names))  # each changed name once


def test_a_rumble_effect_is_described_in_one_line():
    from evdev import ff

    from neurotouch_hid.targets.uinput.gamepad import describe_effect

    rumble = ff.Rumble(strong_magnitude=32767, weak_magnitude=65535)
    effect = ff.Effect(
        ecodes.FF_RUMBLE, 3, 0, ff.Trigger(0, 0), ff.Replay(300, 0), ff.EffectType(ff_rumble_effect=rumble)
    )
    assert describe_effect(effect) == "effect 3: FF_RUMBLE strong 32767 weak 65535 for 300 ms"


class _RecordingUinput:
    """Stands in for evdev.UInput (unit test only; tests/kernel/ checks the real device)."""

    def __init__(self, fail_writes: bool = False) -> None:
        self.events: list[tuple[int, int, int]] = []
        self.closed = 0
        self.fail_writes = fail_writes
        self.device = None

    def write(self, etype: int, code: int, value: int) -> None:
        if self.fail_writes:
            raise OSError(19, "No such device")
        self.events.append((etype, code, value))

    def syn(self) -> None:
        self.events.append((0, 0, 0))

    def close(self) -> None:
        self.closed += 1


@pytest.mark.parametrize("fail_release", [False, True])
def test_keyboard_close_releases_held_keys_once_and_destroys_even_if_release_fails(monkeypatch, fail_release):
    from evdev import ecodes

    from neurotouch_hid.core.controller import ControllerState
    from neurotouch_hid.core.errors import DeviceError
    from neurotouch_hid.targets.uinput import desktop

    fake = _RecordingUinput()
    monkeypatch.setattr(desktop, "create_uinput", lambda *a, **k: fake)
    keyboard = desktop.VirtualKeyboard({"KEY_LEFTSHIFT", "KEY_A"})
    held = ControllerState(keys=frozenset({"KEY_LEFTSHIFT", "KEY_A"}))
    keyboard.write(held)
    assert (ecodes.EV_KEY, ecodes.KEY_A, 1) in fake.events
    fake.events.clear()
    fake.fail_writes = fail_release
    if fail_release:
        with pytest.raises(DeviceError):
            keyboard.close()
    else:
        keyboard.close()
        # modifiers are released last, so no shifted key is left for a reader
        assert fake.events == [(ecodes.EV_KEY, ecodes.KEY_A, 0), (ecodes.EV_KEY, ecodes.KEY_LEFTSHIFT, 0), (0, 0, 0)]
    assert fake.closed == 1
    keyboard.close()  # idempotent
    keyboard.write(held)  # a write after close is ignored
    assert fake.closed == 1


class _SharedLog:
    """uinput devices that write into one log, as a reader of both devices sees the order."""

    def __init__(self) -> None:
        self.events: list[tuple[str, int, int]] = []

    def make(self, what, caps, *args, **kwargs):
        log = self

        class _Device:
            device = None

            def write(self, etype, code, value):
                log.events.append((what, code, value))

            def syn(self):
                pass

            def close(self):
                pass

        return _Device()


@pytest.mark.parametrize("stop", ["release", "neutralise", "close"])
def test_a_ctrl_click_chord_lets_the_mouse_button_go_before_ctrl(monkeypatch, stop):
    """KEY_LEFTCTRL+BTN_LEFT across the keyboard and the mouse: Ctrl down before the button, and
    the button up before Ctrl (a Ctrl-click, not a click, whatever lets it go)."""
    from evdev import ecodes

    from neurotouch_hid.core.controller import ControllerState
    from neurotouch_hid.mapping.profile import Profile
    from neurotouch_hid.targets.uinput import desktop

    log = _SharedLog()
    monkeypatch.setattr(desktop, "create_uinput", log.make)
    chord = Profile.model_validate({"mappings": {"c": {"input": "zoom", "output": "KEY_LEFTCTRL+BTN_LEFT"}}})
    outputs = desktop.UinputOutputs(None, chord)
    outputs.write(ControllerState(keys=frozenset({"KEY_LEFTCTRL", "BTN_LEFT"})))
    stops = {"release": lambda: outputs.write(ControllerState()), "neutralise": outputs.neutralise}
    stops.get(stop, outputs.close)()
    ctrl, left = ("keyboard", ecodes.KEY_LEFTCTRL), ("mouse", ecodes.BTN_LEFT)
    assert [(what, code, value) for what, code, value in log.events if (what, code) in (ctrl, left)] == [
        (*ctrl, 1),
        (*left, 1),
        (*left, 0),
        (*ctrl, 0),
    ]


class _ForceFeedbackUinput(_RecordingUinput):
    """A uinput device whose reader side holds the game's force-feedback requests (EV_UINPUT
    uploads, EV_FF plays), read as python-evdev's non-blocking read gives them."""

    fd = 99

    def __init__(self) -> None:
        super().__init__()
        self.pending: list = []
        self.answered: list[str] = []

    def read(self):
        if not self.pending:
            raise BlockingIOError(11, "Resource temporarily unavailable")
        events, self.pending = self.pending, []
        return iter(events)

    def end_upload(self, upload) -> None:
        self.answered.append(f"upload {upload.effect.id} -> {upload.retval}")

    def end_erase(self, erase) -> None:
        self.answered.append(f"erase {erase.effect_id} -> {erase.retval}")


def test_the_pad_answers_uploads_at_once_and_returns_its_rumble_on_the_feedback_path(monkeypatch):
    """The pad is a Target: what a game sends (upload, play, stop, erase) is read when its fd is
    readable (TargetOutputs' one feedback path), every upload answered in the same call, each
    play or stop returned as a rumble Feedback (the merged pads play it). No thread of its own."""
    from evdev import InputEvent, ff

    fake = _ForceFeedbackUinput()
    monkeypatch.setattr(gamepad, "create_uinput", lambda *a, **k: fake)
    rumble = ff.Rumble(strong_magnitude=0xFFFF, weak_magnitude=0x8000)
    effect = ff.Effect(
        ecodes.FF_RUMBLE, 2, 0, ff.Trigger(0, 0), ff.Replay(300, 0), ff.EffectType(ff_rumble_effect=rumble)
    )

    def begin(ui, kind, request_id):
        request = ff.UInputUpload() if kind == "upload" else ff.UInputErase()
        request.request_id = request_id
        if kind == "upload":
            request.effect = effect
        else:
            request.effect_id = 2
        return request

    monkeypatch.setattr(gamepad, "_begin_ff_request", begin)
    pad = VirtualGamepad()
    assert pad.fileno() == 99 and pad.feedback() == []  # nothing waiting: no blocking read
    fake.pending = [
        InputEvent(0, 0, ecodes.EV_UINPUT, ecodes.UI_FF_UPLOAD, 0),
        InputEvent(0, 0, ecodes.EV_FF, 2, 1),
        InputEvent(0, 0, ecodes.EV_FF, 2, 0),
        InputEvent(0, 0, ecodes.EV_UINPUT, ecodes.UI_FF_ERASE, 1),
    ]
    played, stopped, erased = pad.feedback()
    assert fake.answered == ["upload 2 -> 0", "erase 2 -> 0"]
    assert (played.kind, played.strong, round(played.weak, 3), played.duration_ms) == ("rumble", 1.0, 0.5, 300)
    assert (played.effect, played.source) == (2, "uinput pad")
    assert (stopped.strong, stopped.weak) == (erased.strong, erased.weak) == (0, 0)
    assert pad.effects == 4
    pad.close()
    assert pad.fileno() is None and pad.feedback() == []
