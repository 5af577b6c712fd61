"""A game's rumble through the gel's pad to the copilot's helper pad, against fake evdev nodes
(tests/copilot_devices_helpers.py): several effects at once by their ids, the strongest played, a
stop ending only its effect, a merged pad that never takes an effect, a pad that joins while an
effect plays. The real kernel's devices are checked in tests/kernel/checks_copilot.py."""

from __future__ import annotations

import contextlib

import copilot_devices_helpers
from copilot_devices_helpers import HANG_S, HELPER, FakeNode, _effect, _pad_rumble, _rumbler
from evdev import ecodes
from helpers import wait_until

import neurotouch_hid.inputs.device as device_module
from neurotouch_hid.core.stages import Feedback
from neurotouch_hid.engine.loop import Loop
from neurotouch_hid.inputs.copilot import FeedbackRelay

rig = copilot_devices_helpers.rig  # a shared fixture, found by pytest under this name


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
