"""The copilot's devices (neurotouch_hid/inputs/device.py, copilot.py) against fake evdev nodes
(tests/copilot_devices_helpers.py): a SYN_DROPPED frame, a node python-evdev could open read-only
only, a node another program grabbed (EBUSY), two devices of one name. The real kernel's devices
are checked in tests/kernel/checks_copilot.py."""

from __future__ import annotations

import logging
import time

import copilot_devices_helpers
from copilot_devices_helpers import HANG_S, HELPER, REPORT, FakeNode, Rig, _effect, _pad_rumble, _rumbler
from evdev import ecodes
from helpers import wait_until

import neurotouch_hid.inputs.copilot as copilot_module
from neurotouch_hid.core.controller import ControllerState
from neurotouch_hid.core.stages import Feedback
from neurotouch_hid.engine.loop import Loop
from neurotouch_hid.inputs.device import MergedInput
from neurotouch_hid.inputs.match import InputInfo
from neurotouch_hid.mapping.profile import parse_profile

rig = copilot_devices_helpers.rig  # a shared fixture, found by pytest under this name


DROPPED = (ecodes.EV_SYN, ecodes.SYN_DROPPED, 0)


def _merged(rig: Rig, device: FakeNode, name: str = "Helper Pad") -> MergedInput:
    path = str(rig.dev / "event3")
    rig.nodes[path] = device
    return MergedInput(parse_profile(HELPER.replace("Helper Pad", name), "p.yaml").copilot[0], InputInfo(path, name))


def _buttons(state: ControllerState) -> set[str]:
    return {button for button, down in state.buttons.items() if down}


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
