"""TargetOutputs (neurotouch_hid/targets): one subscriber over the run's targets, the feedback
thread asleep in select at rest. Targets here are small recording ones with a real pipe as their
readable side (the UHID and gadget targets are tested in the kernel)."""

from __future__ import annotations

import os
import threading
import time

import pytest

from neurotouch_hid.core.controller import ControllerState
from neurotouch_hid.core.stages import Feedback
from neurotouch_hid.targets import TargetOutputs, describe_feedback


class PipeTarget:
    """A target that logs what it is asked and reads feedback lines from a pipe: b"rumble\\n"."""

    def __init__(self, what: str, log: list, *, fail_on: str = "", readable: bool = True) -> None:
        self.what = what
        self.log = log
        self.fail_on = fail_on
        self.read_fd, self.write_fd = os.pipe() if readable else (None, None)
        self.reads = 0

    def _note(self, action: str) -> None:
        self.log.append((self.what, action))
        if action == self.fail_on:
            raise OSError(f"{self.what} failed to {action}")

    def write(self, state: ControllerState) -> None:
        self._note(f"write {state.axes['ABS_X']}")

    def neutralise(self) -> None:
        self._note("neutralise")

    def prepare(self, profile) -> None:
        self._note("prepare")

    def fileno(self) -> int | None:
        return self.read_fd

    def feedback(self) -> list[Feedback]:
        self.reads += 1
        data = os.read(self.read_fd, 100)
        if data.startswith(b"boom"):
            raise OSError("the host went away")
        return [Feedback("rumble", strong=0.5, weak=0.25, duration_ms=200, source=self.what) for _ in data.split()]

    def close(self) -> None:
        self._note("close")


class Record:
    def __init__(self, state: ControllerState, changed: bool) -> None:
        self.state, self.state_changed = state, changed


def _state(x: int) -> ControllerState:
    state = ControllerState.neutral()
    state.axes["ABS_X"] = x
    return state


def test_changed_states_go_to_every_target_in_order():
    log: list = []
    with TargetOutputs([PipeTarget("a", log), PipeTarget("b", log, readable=False)]) as outputs:
        outputs.publish(Record(_state(5), True))
        outputs.publish(Record(_state(5), False))
        outputs.prepare(None)
    assert log[:4] == [("a", "write 5"), ("b", "write 5"), ("a", "prepare"), ("b", "prepare")]
    assert log[4:] == [("a", "neutralise"), ("b", "neutralise"), ("a", "close"), ("b", "close")]


def test_close_releases_every_target_even_when_one_fails_and_raises_the_first_failure():
    log: list = []
    outputs = TargetOutputs([PipeTarget("a", log, fail_on="neutralise"), PipeTarget("b", log, fail_on="close")])
    with pytest.raises(OSError, match="a failed to neutralise"):
        outputs.close()
    assert log == [("a", "neutralise"), ("b", "neutralise"), ("a", "close"), ("b", "close")]
    outputs.close()  # idempotent
    outputs.write(_state(1))  # nothing after close
    assert len(log) == 4


def test_neutralise_tries_every_target_then_raises():
    log: list = []
    with TargetOutputs([PipeTarget("a", log, fail_on="neutralise"), PipeTarget("b", log)]) as outputs:
        with pytest.raises(OSError):
            outputs.neutralise()
        assert log == [("a", "neutralise"), ("b", "neutralise")]
        outputs.targets[0].fail_on = ""


def _until(condition, seconds: float = 5.0) -> bool:
    end = time.monotonic() + seconds
    while not condition() and time.monotonic() < end:
        time.sleep(0.01)
    return condition()


def test_feedback_is_told_once_per_repeat_and_forwarded_every_time():
    lines: list[str] = []
    forwarded: list[Feedback] = []
    target = PipeTarget("UHID joystick", [])
    with TargetOutputs([target], say=lines.append, forward=forwarded.append) as outputs:
        os.write(target.write_fd, b"r\n")
        assert _until(lambda: len(forwarded) == 1)
        os.write(target.write_fd, b"r\n")
        assert _until(lambda: len(forwarded) == 2)
        assert outputs.feedbacks == 2
    assert lines == ["rumble (the gel has no motor): strong 0.50 weak 0.25 for 200 ms, on UHID joystick"]
    assert forwarded[0] == Feedback("rumble", 0.5, 0.25, 200, source="UHID joystick")


def test_a_target_whose_feedback_fails_is_no_longer_read_and_the_others_are():
    lines: list[str] = []
    bad, good = PipeTarget("bad", []), PipeTarget("good", [])
    with TargetOutputs([bad, good], say=lines.append) as outputs:
        os.write(bad.write_fd, b"boom")
        assert _until(lambda: bad.reads == 1)
        os.write(bad.write_fd, b"r")  # readable again: it must not be read (nor select spin on it)
        os.write(good.write_fd, b"r")
        assert _until(lambda: outputs.feedbacks == 1)
        assert bad.reads == 1
    assert lines == ["rumble (the gel has no motor): strong 0.50 weak 0.25 for 200 ms, on good"]


def _context_switches(tid: int) -> int:
    with open(f"/proc/self/task/{tid}/status") as status:
        fields = dict(line.split(":", 1) for line in status)
    return int(fields["voluntary_ctxt_switches"]) + int(fields["nonvoluntary_ctxt_switches"])


def _settled(tid: int) -> int:
    """The thread's context switches after 50 ms: equal to those before when it slept throughout."""
    time.sleep(0.05)
    return _context_switches(tid)


def test_the_feedback_thread_sleeps_at_rest():
    with TargetOutputs([PipeTarget("a", [])]) as outputs:
        thread = next(t for t in threading.enumerate() if t.name == "nt-feedback")
        # let it reach select (on a loaded machine its start may take more than a moment)
        assert _until(lambda: _context_switches(thread.native_id) == _settled(thread.native_id))
        before = _context_switches(thread.native_id)
        time.sleep(0.3)
        assert _context_switches(thread.native_id) == before  # blocked in select: never woken
        assert outputs.feedbacks == 0
    assert not thread.is_alive()


def test_describe_feedback_says_stop_and_leds():
    assert describe_feedback(Feedback("rumble")) == "rumble (the gel has no motor): stop"
    assert describe_feedback(Feedback("led", led=2, source="xinput")) == (
        "player LED (the gel has none): pattern 2, on xinput"
    )


class LateTarget(PipeTarget):
    """A target whose device (and readable side) is made at its first prepare, as the uinput pad
    is when a profile first drives a pad control."""

    def __init__(self, what: str, log: list) -> None:
        super().__init__(what, log)
        self.made = False

    def prepare(self, profile) -> None:
        super().prepare(profile)
        self.made = True

    def fileno(self) -> int | None:
        return self.read_fd if self.made else None


def test_a_device_made_at_prepare_is_read_from_then_on():
    forwarded: list[Feedback] = []
    late = LateTarget("uinput pad", [])
    with TargetOutputs([late], forward=forwarded.append) as outputs:
        outputs.prepare(None)
        os.write(late.write_fd, b"r")
        assert _until(lambda: forwarded)
    assert forwarded[0].source == "uinput pad"


def test_feedback_lines_are_bounded_per_source_with_a_count_of_those_held_back():
    """A game rumbling every frame with new magnitudes: one line a second per target, the next
    saying how many were held back; another target's lines are not held back by the first's."""
    from neurotouch_hid.targets import FeedbackLines

    now = [0.0]
    said: list[str] = []
    lines = FeedbackLines(said.append, repeat_s=1.0, clock=lambda: now[0])
    for frame in range(100):  # 100 frames in 0.99 s, each a new magnitude
        now[0] = frame / 100
        lines.tell(Feedback("rumble", strong=(frame + 1) / 100, source="uinput pad"))
        if frame == 50:
            lines.tell(Feedback("led", led=2, source="xinput"))
    now[0] = 1.0
    lines.tell(Feedback("rumble", source="uinput pad"))
    assert said == [
        "rumble (the gel has no motor): strong 0.01 weak 0.00, on uinput pad",
        "player LED (the gel has none): pattern 2, on xinput",
        "rumble (the gel has no motor): stop, on uinput pad (99 more since the last line)",
    ]
