"""The copilot's devices (neurotouch_hid/inputs/device.py, copilot.py) against fake evdev nodes: a
SYN_DROPPED frame, a node python-evdev could open read-only only, a node another program grabbed
(EBUSY), two devices of one name, several rumble effects of a game at once.

The fakes: :class:`FakeNode` is a device as the kernel holds it (its keys held and axes' values,
which EVIOCGKEY/EVIOCGABS return; the reads its client gets, one list of events a read; a pipe
whose read end is its descriptor, so ``select`` wakes on it); :class:`FakeInputDevice` stands in
for python-evdev's ``InputDevice`` (a node opened read-only writes through python-evdev's own
``write``, which raises ``EvdevError`` on such a descriptor); the ioctls of device.py (EVIOCSFF,
EVIOCRMFF) are recorded. /dev/input and /sys/class/input are folders of plain files, as in
tests/test_copilot_controls.py. The real kernel's devices are checked in tests/kernel/checks_copilot.py.
"""

from __future__ import annotations

import contextlib
import errno
import logging
import os
import time
import types
from collections import deque
from pathlib import Path

import evdev
import evdev.eventio
import pytest
from evdev import AbsInfo, InputEvent, ecodes, ff
from helpers import wait_until

import neurotouch_hid.inputs.copilot as copilot_module
import neurotouch_hid.inputs.device as device_module
from neurotouch_hid.core.controller import ControllerState
from neurotouch_hid.core.stages import Feedback
from neurotouch_hid.engine.loop import Loop
from neurotouch_hid.inputs.copilot import Copilot, FeedbackRelay
from neurotouch_hid.inputs.device import EVIOCRMFF, MergedInput
from neurotouch_hid.inputs.match import InputInfo
from neurotouch_hid.mapping.profile import parse_profile

#: A wait that ends a hang only (helpers.wait_until): what is waited for is asserted, never a delay.
HANG_S = 15.0
HELPER = 'copilot:\n  - {device: "Helper Pad"}\n'


def _event(etype: int, code: int, value: int) -> InputEvent:
    return InputEvent(0, 0, etype, code, value)


REPORT = (ecodes.EV_SYN, ecodes.SYN_REPORT, 0)
DROPPED = (ecodes.EV_SYN, ecodes.SYN_DROPPED, 0)


class FakeNode:
    """One evdev device: its capabilities (``keys``: key codes; ``axes``: code -> (min, max);
    ``ff``: EV_FF codes), its state now (``held``, ``values``), the reads its client will get."""

    def __init__(self, keys=(), axes=None, ff_codes=(), *, read_only: bool = False) -> None:
        self.keys, self.axes, self.ff = list(keys), dict(axes or {}), list(ff_codes)
        self.held: set[int] = set()
        self.values = {code: (lo + hi) // 2 for code, (lo, hi) in self.axes.items()}
        self.reads: deque[list[InputEvent]] = deque()
        self.r, self.w = os.pipe()
        os.set_blocking(self.r, False)
        self.read_only = read_only  # python-evdev fell back to O_RDONLY (the node is not writable)
        self.gone = False
        self.grabbed = False
        self.held_by_other = False  # another program grabbed it: EVIOCGRAB fails with EBUSY
        self.closed = 0
        self.written: list[tuple[int, int, int]] = []

    def queue(self, *events: tuple[int, int, int]) -> None:
        """One read of these events as they are (the device's state is the test's to set)."""
        self.reads.append([_event(*e) for e in events])
        os.write(self.w, b"x")

    def frame(self, *events: tuple[int, int, int]) -> None:
        """The device sends ``events`` and a SYN_REPORT, read at once; its state follows them."""
        for etype, code, value in events:
            if etype == ecodes.EV_KEY:
                (self.held.add if value else self.held.discard)(code)
            elif etype == ecodes.EV_ABS:
                self.values[code] = value
        self.queue(*events, REPORT)

    def unplug(self) -> None:
        self.gone = True
        os.write(self.w, b"x")


class FakeInputDevice:
    """python-evdev's ``InputDevice`` on a :class:`FakeNode` (the registry is set by the fixture)."""

    nodes: dict[str, FakeNode] = {}

    def __init__(self, path: str) -> None:
        self.path = path
        self.node = self.nodes[path]
        if self.node.gone:
            raise OSError(errno.ENODEV, "No such device")
        self.fd = self.node.r

    def grab(self) -> None:
        if self.node.held_by_other:
            raise OSError(errno.EBUSY, "Device or resource busy")
        self.node.grabbed = True

    def ungrab(self) -> None:
        if not self.node.grabbed:
            raise OSError(errno.EINVAL, "Invalid argument")
        self.node.grabbed = False

    def close(self) -> None:
        if self.fd > -1:
            self.fd = -1
            self.node.closed += 1

    def capabilities(self, absinfo: bool = True) -> dict:
        caps: dict = {}
        if self.node.keys:
            caps[ecodes.EV_KEY] = list(self.node.keys)
        if self.node.axes:
            caps[ecodes.EV_ABS] = [(code, self.absinfo(code)) for code in self.node.axes]
        if self.node.ff:
            caps[ecodes.EV_FF] = list(self.node.ff)
        return caps

    def active_keys(self) -> list[int]:  # EVIOCGKEY
        return sorted(self.node.held)

    def absinfo(self, code: int) -> AbsInfo:  # EVIOCGABS
        lo, hi = self.node.axes[code]
        return AbsInfo(self.node.values[code], lo, hi, 0, 0, 0)

    def read(self):
        if self.node.gone:
            raise OSError(errno.ENODEV, "No such device")
        try:
            os.read(self.node.r, 4096)
        except BlockingIOError:
            pass
        if not self.node.reads:
            raise BlockingIOError(errno.EAGAIN, "Resource temporarily unavailable")
        events = self.node.reads.popleft()
        if self.node.reads:
            os.write(self.node.w, b"x")
        return iter(events)

    def write(self, etype: int, code: int, value: int) -> None:
        if self.node.read_only:  # python-evdev's own write: its need_write check raises EvdevError
            evdev.eventio.EventIO.write(self, etype, code, value)
        self.node.written.append((etype, code, value))


class Rig:
    """A fake /dev/input and /sys/class/input, the nodes in them, and the ioctls device.py made."""

    def __init__(self, root: Path) -> None:
        self.dev, self.sys = root / "dev" / "input", root / "sys" / "class" / "input"
        (self.dev / "by-id").mkdir(parents=True)
        self.sys.mkdir(parents=True)
        self.nodes: dict[str, FakeNode] = {}
        self.ioctls: list[tuple] = []
        self._next_id = 0

    def add(self, name: str, node: str, device: FakeNode, phys: str = "usb-1/input0") -> FakeNode:
        folder = self.sys / node / "device"
        (folder / "id").mkdir(parents=True)
        (folder / "name").write_text(name + "\n")
        (folder / "phys").write_text(phys + "\n")
        (folder / "id" / "vendor").write_text("045e\n")
        (folder / "id" / "product").write_text("02ea\n")
        self.nodes[str(self.dev / node)] = device
        (self.dev / node).write_text("")  # last: the inotify event comes when the device is described
        return device

    def ioctl(self, fd: int, request: int, arg, mutate: bool = False) -> int:
        """EVIOCSFF (the kernel gives a new effect its id) and EVIOCRMFF, recorded."""
        if request == EVIOCRMFF:
            self.ioctls.append(("erase", arg))
        elif isinstance(arg, ff.Effect):
            if arg.id == -1:
                arg.id, self._next_id = self._next_id, self._next_id + 1
            rumble = arg.u.ff_rumble_effect
            self.ioctls.append(("upload", arg.id, rumble.strong_magnitude, rumble.weak_magnitude, arg.ff_replay.length))
        else:
            raise AssertionError(f"unexpected ioctl {request:#x}")
        return 0

    def uploads(self) -> list[tuple]:
        return [call[1:] for call in self.ioctls if call[0] == "upload"]

    def copilot(self, text: str = HELPER, said: list[str] | None = None, loop: Loop | None = None) -> Copilot:
        said = [] if said is None else said
        copilot = parse_profile(text, "p.yaml").copilot
        return Copilot(copilot, input_dir=self.dev, sysfs=self.sys, say=said.append, loop=loop)

    def close(self) -> None:
        for node in self.nodes.values():
            for fd in (node.r, node.w):
                os.close(fd)


@pytest.fixture
def rig(tmp_path, monkeypatch):
    made = Rig(tmp_path)
    monkeypatch.setattr(FakeInputDevice, "nodes", made.nodes)
    monkeypatch.setattr(evdev, "InputDevice", FakeInputDevice)
    monkeypatch.setattr(device_module, "fcntl", types.SimpleNamespace(ioctl=made.ioctl))
    yield made
    made.close()


def _merged(rig: Rig, device: FakeNode, name: str = "Helper Pad") -> MergedInput:
    path = str(rig.dev / "event3")
    rig.nodes[path] = device
    return MergedInput(parse_profile(HELPER.replace("Helper Pad", name), "p.yaml").copilot[0], InputInfo(path, name))


def _rumbler(read_only: bool = False) -> FakeNode:
    """A helper's pad with button A and FF_RUMBLE."""
    return FakeNode(keys=[ecodes.BTN_SOUTH], ff_codes=[ecodes.FF_RUMBLE], read_only=read_only)


def _buttons(state: ControllerState) -> set[str]:
    return {button for button, down in state.buttons.items() if down}


class _PadRumble:
    """The gel's pad's force-feedback side (neurotouch_hid/targets/uinput/gamepad.py) without uinput:
    effects remembered as the pad remembers an upload, each play or stop handed to
    ``on_feedback`` as the run's feedback path forwards what the pad returns."""

    def __init__(self, on_feedback) -> None:
        from neurotouch_hid.targets.uinput.gamepad import VirtualGamepad

        self.pad = object.__new__(VirtualGamepad)
        self.pad._rumbles, self.pad.what = {}, "uinput pad"
        self.on_feedback = on_feedback

    def _remember_rumble(self, effect) -> None:
        self.pad._remember_rumble(effect)

    def _forward_rumble(self, effect_id: int, value: int) -> None:
        request = self.pad._rumble_of(effect_id, value)
        if request is not None:
            self.on_feedback(request)


def _pad_rumble(on_feedback) -> _PadRumble:
    return _PadRumble(on_feedback)


def _effect(effect_id: int, strong: int, weak: int, length_ms: int) -> ff.Effect:
    rumble = ff.Rumble(strong_magnitude=strong, weak_magnitude=weak)
    replay, union = ff.Replay(length_ms, 0), ff.EffectType(ff_rumble_effect=rumble)
    return ff.Effect(ecodes.FF_RUMBLE, effect_id, 0, ff.Trigger(0, 0), replay, union)


# --- 1. SYN_DROPPED (Documentation/input/event-codes.rst) ---------------------------------------------
def test_after_syn_dropped_the_dropped_frame_is_ignored_and_the_state_is_queried(rig):
    """The kernel's buffer overflowed: SYN_DROPPED, then the tail of a frame (A pressed) and its
    SYN_REPORT. The helper has let A go since (EVIOCGKEY: A up, its release flushed from the
    queue): A must not stay held, nor be pressed by a frame read with the dropped one (read before
    the query, which holds it already)."""
    pad = FakeNode(keys=[ecodes.BTN_SOUTH])
    merged = _merged(rig, pad)
    pad.queue(DROPPED, (ecodes.EV_KEY, ecodes.BTN_SOUTH, 1), REPORT)
    merged.read()
    assert merged.levels.buttons == frozenset()
    pad.queue(DROPPED, REPORT, (ecodes.EV_KEY, ecodes.BTN_SOUTH, 1), REPORT)
    merged.read()
    assert merged.levels.buttons == frozenset()


def test_a_dropped_frame_is_ignored_across_reads_and_the_queries_give_the_levels(rig):
    """SYN_DROPPED in one read, the stale rest of its frame and its SYN_REPORT in the next: nothing
    of it counts; the levels are the device's state queried at that SYN_REPORT; frames after it
    count again."""
    pad = FakeNode(keys=[ecodes.BTN_SOUTH, ecodes.BTN_EAST], axes={ecodes.ABS_X: (-32768, 32767)})
    merged = _merged(rig, pad)
    pad.values[ecodes.ABS_X] = 0
    pad.held = {ecodes.BTN_EAST}  # the state now: B held, the stick centred
    pad.queue(DROPPED, (ecodes.EV_KEY, ecodes.BTN_SOUTH, 1))
    merged.read()
    pad.queue((ecodes.EV_ABS, ecodes.ABS_X, 30000), REPORT)
    assert merged.read()
    assert merged.levels.buttons == {"BTN_EAST"} and merged.levels.axes["ABS_X"] == 0
    pad.frame((ecodes.EV_KEY, ecodes.BTN_SOUTH, 1))
    assert merged.read()
    assert merged.levels.buttons == {"BTN_EAST", "BTN_SOUTH"}


# --- 2. a node opened read-only -----------------------------------------------------------------------
def test_rumble_on_a_read_only_node_does_nothing_says_so_once_and_stop_lets_it_go(rig, caplog):
    pad = rig.add("Helper Pad", "event3", _rumbler(read_only=True))
    copilot = rig.copilot()
    copilot.start(lambda: None)
    try:
        with caplog.at_level(logging.WARNING, logger="neurotouch_hid.inputs"):
            copilot.feedback(Feedback("rumble", strong=1.0, weak=0.5, duration_ms=300))
            copilot.feedback(Feedback("rumble", strong=0.2, duration_ms=300))
            copilot.feedback(Feedback("rumble"))
    finally:
        copilot.stop()
    told = [r.getMessage() for r in caplog.records if "writable" in r.getMessage()]
    assert len(told) == 1 and "Helper Pad" in told[0], caplog.text
    assert pad.written == [] and not pad.grabbed and pad.closed == 1
    uploaded = [call[1] for call in rig.ioctls if call[0] == "upload"]
    assert [call[1] for call in rig.ioctls if call[0] == "erase"] == uploaded  # nothing left on the device
    assert copilot.status() == ((), ("Helper Pad",))


def test_close_and_stop_never_raise_and_always_let_the_device_go(rig):
    """Whatever stopping the rumble raises (here python-evdev's EvdevError, no OSError), the grab
    is released and the node closed, and Copilot.stop returns (a profile switch goes on)."""
    pad = rig.add("Helper Pad", "event3", _rumbler())
    copilot = rig.copilot()
    copilot.start(lambda: None)
    copilot.feedback(Feedback("rumble", strong=1.0, duration_ms=300))
    assert wait_until(lambda: pad.written == [(ecodes.EV_FF, 0, 1)], HANG_S)  # written off the loop
    pad.read_only = True
    copilot.stop()
    assert not pad.grabbed and pad.closed == 1
    assert ("erase", 0) in rig.ioctls


def test_a_read_only_node_that_rumbled_rejoins_when_plugged_back(rig):
    """A game rumbles (through the pad, as the driver wires it) on a read-only helper pad, which
    is then unplugged and plugged back: the copilot's thread goes on and takes it again."""
    first = rig.add("Helper Pad", "event3", _rumbler(read_only=True))
    said: list[str] = []
    calls: list[int] = []
    copilot = rig.copilot(said=said)
    copilot.start(lambda: calls.append(1))
    try:
        pad = _pad_rumble(copilot.feedback)
        pad._remember_rumble(_effect(0, 0xFFFF, 0, 300))
        pad._forward_rumble(0, 1)
        first.unplug()
        assert wait_until(lambda: copilot.status() == ((), ("Helper Pad",)), HANG_S)
        (rig.dev / "event3").unlink()
        again = rig.add("Helper Pad", "event5", _rumbler())
        assert wait_until(lambda: again.grabbed, HANG_S), said
        assert copilot.status() == (("Helper Pad",), ())
        again.frame((ecodes.EV_KEY, ecodes.BTN_SOUTH, 1))
        assert wait_until(lambda: "BTN_SOUTH" in _buttons(copilot.merge(ControllerState.neutral())), HANG_S)
    finally:
        copilot.stop()
    assert not first.grabbed


# --- 3. EBUSY -------------------------------------------------------------------------------------------
def test_a_device_another_program_grabbed_is_taken_once_let_go_and_is_retried_only_while_busy(rig, monkeypatch):
    """Another program (Steam) holds the grab at start, then lets go, which makes no inotify
    event: the copilot retries on its own, says "busy" once, and once nothing is busy it sets no
    timer on its loop again (a missing device alone never wakes it)."""
    monkeypatch.setattr(copilot_module, "BUSY_RETRY_S", 0.02, raising=False)  # many retries, at once
    timers: list[float] = []

    class WatchedLoop(Loop):
        def call_at(self, when, callback):
            timers.append(when)
            return super().call_at(when, callback)

    loop = WatchedLoop()
    loop.run_in_thread()
    absent = rig.copilot('copilot:\n  - {device: "Switch Box"}\n', loop=loop)
    absent.start(lambda: None)
    try:
        time.sleep(0.1)
        assert timers == [] and loop.next_timer is None  # nothing to retry: no timer
    finally:
        absent.stop()

    pad = rig.add("Helper Pad", "event3", FakeNode(keys=[ecodes.BTN_SOUTH]))
    pad.held_by_other = True
    said: list[str] = []
    copilot = rig.copilot(said=said, loop=loop)
    copilot.start(lambda: None)
    try:
        assert copilot.status() == ((), ("Helper Pad",))
        assert wait_until(lambda: len(timers) > 3, HANG_S)  # retried while busy: no new node, no event
        assert copilot.status() == ((), ("Helper Pad",)) and not pad.grabbed
        pad.held_by_other = False  # the other program lets go
        assert wait_until(lambda: copilot.status() == (("Helper Pad",), ()), HANG_S), said
        assert pad.grabbed
        assert wait_until(lambda: loop.next_timer is None, HANG_S)  # nothing busy: no timer
    finally:
        copilot.stop()
        loop.close()
    busy = [line for line in said if "another program grabbed it" in line]
    assert len(busy) == 1 and busy[0].endswith("waiting for it"), said


# --- 4. two devices of one name -------------------------------------------------------------------------
def test_when_the_merged_one_of_two_same_named_devices_goes_the_other_is_taken_at_once(rig):
    first = rig.add("Helper Pad", "event3", FakeNode(keys=[ecodes.BTN_SOUTH]))
    other = rig.add("Helper Pad", "event4", FakeNode(keys=[ecodes.BTN_SOUTH]), phys="usb-2/input0")
    said: list[str] = []
    copilot = rig.copilot(said=said)
    copilot.start(lambda: None)
    try:
        assert first.grabbed and not other.grabbed
        first.unplug()  # its node is still there until udev removes it: no inotify event comes
        assert wait_until(lambda: other.grabbed, HANG_S), said
        assert copilot.status() == (("Helper Pad",), ())
        other.frame((ecodes.EV_KEY, ecodes.BTN_SOUTH, 1))
        assert wait_until(lambda: "BTN_SOUTH" in _buttons(copilot.merge(ControllerState.neutral())), HANG_S)
    finally:
        copilot.stop()
    assert not any("cannot merge" in line for line in said), said  # the gone node is not tried again
    assert said[-1] == f"merged Helper Pad ({rig.dev / 'event4'}) into the pad", said


# --- 5. rumble with several effects --------------------------------------------------------------------
@contextlib.contextmanager
def _game_on_the_pad(rig):
    """(the helper's pad, the gel's pad as a game rumbles it), the copilot merging the helper's."""
    pad = rig.add("Helper Pad", "event3", _rumbler())
    copilot = rig.copilot()
    copilot.start(lambda: None)
    try:
        game = _pad_rumble(FeedbackRelay(hide=False))
        game.on_feedback.merge = copilot
        yield pad, game
    finally:
        copilot.stop()


def _last_upload(rig) -> tuple | None:
    """The last effect uploaded to the helper's pad (effect id, strong, weak, length), or None."""
    uploads = rig.uploads()
    return uploads[-1] if uploads else None


def _last_written(pad) -> tuple | None:
    return pad.written[-1] if pad.written else None


def test_a_rumble_of_length_0_plays_until_stopped(rig):
    """ff-memless plays an effect of replay length 0 until it is stopped: so does the helper's
    (played by the copilot's thread, to which the game's rumble is handed)."""
    with _game_on_the_pad(rig) as (pad, game):
        game._remember_rumble(_effect(0, 0x4000, 0x4000, 0))
        game._forward_rumble(0, 1)
        assert wait_until(lambda: pad.written == [(ecodes.EV_FF, 0, 1)], HANG_S), pad.written
        assert rig.uploads() == [(0, 0x4000, 0x4000, 0)]
        game._forward_rumble(0, 0)
        assert wait_until(lambda: _last_written(pad) == (ecodes.EV_FF, 0, 0), HANG_S), pad.written


def test_the_pads_effects_reach_the_helper_by_their_ids(rig):
    """Through the gel's pad as a game drives it: effect 0 (strong) and effect 1 (weak) played,
    effect 1 stopped: the helper's pad goes on with effect 0's; effect 0 stopped: so is the
    helper's rumble."""
    with _game_on_the_pad(rig) as (pad, game):
        game._remember_rumble(_effect(0, 0xFFFF, 0, 0))
        game._remember_rumble(_effect(1, 0, 0x8000, 0))
        game._forward_rumble(0, 1)
        game._forward_rumble(1, 1)
        assert wait_until(lambda: (_last_upload(rig) or (0,))[1:3] == (0xFFFF, 0x8000), HANG_S), rig.uploads()
        game._forward_rumble(1, 0)
        assert wait_until(lambda: _last_upload(rig)[1:3] == (0xFFFF, 0), HANG_S), rig.uploads()
        assert _last_written(pad) == (ecodes.EV_FF, 0, 1)
        game._forward_rumble(0, 0)
        assert wait_until(lambda: _last_written(pad) == (ecodes.EV_FF, 0, 0), HANG_S), pad.written


def test_the_strongest_of_the_playing_effects_is_played_and_a_stop_ends_only_its_effect(rig):
    """A game plays effect 0 (strong motor) and effect 1 (weak motor): the helper's pad plays both
    magnitudes; stopping 1 leaves 0's; stopping 0 stops it. A sender that names no effect (one
    effect, played again with new magnitudes, as SDL does) replaces its last request. The relay
    hands each request to the copilot's thread, which plays them in order."""
    pad = rig.add("Helper Pad", "event3", _rumbler())
    box = rig.add("Switch Box", "event4", FakeNode(keys=[ecodes.KEY_SPACE]), phys="usb-2/input0")
    copilot = rig.copilot(HELPER + '  - {device: "Switch Box", passthrough: false, map: {KEY_SPACE: A}}\n')
    copilot.start(lambda: None)
    relay = FeedbackRelay(hide=False)
    relay.merge = copilot
    try:
        relay(Feedback("rumble", strong=1.0, duration_ms=5000, effect=0))
        relay(Feedback("rumble", weak=0.5, duration_ms=5000, effect=1))
        # until the last of them ends
        assert wait_until(lambda: (_last_upload(rig) or (0,))[1:] == (0xFFFF, 0x8000, 5000), HANG_S), rig.uploads()
        relay(Feedback("rumble", effect=1))  # effect 1 stops; 0 still plays
        assert wait_until(lambda: _last_upload(rig)[1:3] == (0xFFFF, 0), HANG_S), rig.uploads()
        assert _last_written(pad) == (ecodes.EV_FF, 0, 1)
        relay(Feedback("rumble", effect=0))
        assert wait_until(lambda: _last_written(pad) == (ecodes.EV_FF, 0, 0), HANG_S), pad.written
        assert box.written == []

        relay(Feedback("rumble", strong=1.0, duration_ms=1000))
        relay(Feedback("rumble", strong=0.25, duration_ms=1000))
        assert wait_until(lambda: _last_upload(rig)[1:3] == (0x4000, 0), HANG_S), rig.uploads()
        relay(Feedback("rumble"))
        assert wait_until(lambda: _last_written(pad) == (ecodes.EV_FF, 0, 0), HANG_S), pad.written
    finally:
        copilot.stop()


def test_a_merged_pad_that_never_takes_an_effect_does_not_hold_up_the_games_rumble(rig, monkeypatch):
    """The merged pad's EVIOCSFF blocks (a uinput device whose owner never answers): the relay,
    called from the run's one feedback path, returns at once each time, so that path goes on
    answering the game's uploads on the gel's pad; the copilot's thread waits alone."""
    import threading

    rig.add("Helper Pad", "event3", _rumbler())
    copilot = rig.copilot()
    copilot.start(lambda: None)
    stuck, entered = threading.Event(), threading.Event()

    def never_answers(fd, request, arg, mutate=False):
        entered.set()
        stuck.wait()  # until the test ends
        return rig.ioctl(fd, request, arg, mutate)

    monkeypatch.setattr(device_module.fcntl, "ioctl", never_answers)
    relay = FeedbackRelay(hide=False)
    relay.merge = copilot

    def game_rumbles() -> None:  # the game's rumble, frame after frame, as the feedback path forwards it
        for k in range(5):
            relay(Feedback("rumble", strong=0.2 * (k + 1), duration_ms=100, effect=0))

    caller = threading.Thread(target=game_rumbles, daemon=True)
    try:
        caller.start()
        assert wait_until(entered.is_set, HANG_S)  # the copilot's thread is in the merged pad's EVIOCSFF
        assert wait_until(lambda: not caller.is_alive(), HANG_S)  # every call returned meanwhile
    finally:
        stuck.set()
        copilot.stop()


def test_a_merged_pad_that_never_takes_an_effect_does_not_stop_the_runs_loop(rig, monkeypatch):
    """As in a run: the copilot waits on the run's one loop, which also answers the game's uploads
    on the gel's pad. The merged pad's EVIOCSFF blocks (a uinput device whose owner never
    answers, up to uinput's 30 s): the loop must go on serving meanwhile, or the game's next upload
    on the gel's pad waits for that pad."""
    import threading

    rig.add("Helper Pad", "event3", _rumbler())
    loop = Loop()
    loop.run_in_thread("test-run-loop")
    copilot = rig.copilot(loop=loop)
    copilot.start(lambda: None)
    stuck, entered = threading.Event(), threading.Event()

    def never_answers(fd, request, arg, mutate=False):
        entered.set()
        stuck.wait()  # until the test ends
        return rig.ioctl(fd, request, arg, mutate)

    monkeypatch.setattr(device_module.fcntl, "ioctl", never_answers)
    relay = FeedbackRelay(hide=False, loop=loop)
    relay.merge = copilot
    answered = threading.Event()
    try:
        relay(Feedback("rumble", strong=0.5, duration_ms=100, effect=0))
        assert wait_until(entered.is_set, HANG_S)  # the merged pad's EVIOCSFF is under way
        loop.call_soon(answered.set)  # the gel's pad's next upload, answered on the same loop
        assert wait_until(answered.is_set, HANG_S)
        relay(Feedback("rumble", strong=0.9, duration_ms=100, effect=0))  # and the game goes on
        loop.call_soon(answered.clear)
        assert wait_until(lambda: not answered.is_set(), HANG_S)
    finally:
        stuck.set()
        copilot.stop()
        loop.close()


def test_when_a_short_effect_ends_the_longer_ones_magnitudes_are_played(rig):
    """A short strong effect over a weak one that plays until stopped: when the short one ends,
    the helper's pad is given the weak one's magnitudes (it does not go on at the strong one's)."""
    pad = rig.add("Helper Pad", "event3", _rumbler())
    copilot = rig.copilot()
    copilot.start(lambda: None)
    try:
        copilot.feedback(Feedback("rumble", weak=0.5, effect=0))
        copilot.feedback(Feedback("rumble", strong=1.0, duration_ms=30, effect=1))
        assert wait_until(lambda: len(rig.uploads()) >= 2, HANG_S)  # written off the loop, in order
        assert [upload[1:] for upload in rig.uploads()[:2]] == [(0, 0x8000, 0), (0xFFFF, 0x8000, 0)]
        assert wait_until(lambda: rig.uploads()[-1][1:] == (0, 0x8000, 0) and len(rig.uploads()) == 3, HANG_S)
        assert pad.written[-1] == (ecodes.EV_FF, 0, 1)
    finally:
        copilot.stop()
    assert pad.written[-1] == (ecodes.EV_FF, 0, 0) and ("erase", 0) in rig.ioctls


def test_a_helper_pad_that_joins_while_an_effect_plays_is_given_it(rig):
    """An effect that plays until stopped, then the helper's pad is unplugged and plugged back:
    it rumbles again (the game plays nothing new meanwhile)."""
    first = rig.add("Helper Pad", "event3", _rumbler())
    copilot = rig.copilot()
    copilot.start(lambda: None)
    try:
        copilot.feedback(Feedback("rumble", strong=0.25, effect=0))
        assert wait_until(lambda: first.written == [(ecodes.EV_FF, 0, 1)], HANG_S)
        first.unplug()
        assert wait_until(lambda: copilot.status() == ((), ("Helper Pad",)), HANG_S)
        (rig.dev / "event3").unlink()
        again = rig.add("Helper Pad", "event5", _rumbler())
        assert wait_until(lambda: again.written, HANG_S)
        effect_id, *played = rig.uploads()[-1]
        assert again.written == [(ecodes.EV_FF, effect_id, 1)] and played == [0x4000, 0, 0]
    finally:
        copilot.stop()
