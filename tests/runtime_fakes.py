"""Small fakes for the runtime's stages (unit tests of the runtime: tests/test_runtime_*.py,
tests/test_control.py, tests/test_copilot_runtime.py, tests/test_first_run_messages.py; acceptance runs the
real stages), and waits on what a runtime did."""

from __future__ import annotations

import threading

import numpy as np
from helpers import wait_until

from neurotouch_hid.core.controller import ControllerState
from neurotouch_hid.core.estimate import GestureEstimate, GestureType
from neurotouch_hid.engine.queue import item_end_us
from neurotouch_hid.sources import EVENT_DTYPE, Frame


def batch(t0_us: int, n: int = 3, step_us: int = 100) -> np.ndarray:
    ev = np.zeros(n, dtype=EVENT_DTYPE)
    ev["timestamp"] = t0_us + np.arange(n) * step_us
    return ev


class FakePipeline:
    """One estimate per event batch: a push whose intensity is the batch's index, then rest."""

    def __init__(self, push_batches: int = 5, fail_at: int | None = None, gate: threading.Event | None = None):
        self.started = threading.Event()
        self.seen: list[int] = []
        self.sizes: list[int] = []  # events per call
        self.resting: list[tuple[object, int]] = []
        self.push_batches = push_batches
        self.fail_at = fail_at
        self.gate = gate

    def process(self, item):
        self.started.set()
        if self.gate is not None:
            self.gate.wait(5)
        if isinstance(item, Frame):
            return []
        self.seen.append(item_end_us(item))
        self.sizes.append(len(item))
        if self.fail_at is not None and len(self.seen) == self.fail_at:
            raise RuntimeError("pipeline failure")
        k = len(self.seen)
        if k <= self.push_batches:
            return [
                GestureEstimate(t_us=item_end_us(item), gesture=GestureType.PUSH, resting=False, intensity_mm=float(k))
            ]
        return [GestureEstimate(t_us=item_end_us(item))]

    def process_newest(self, events):
        """Joined batches: one estimate, as for one batch (nothing coalesced)."""
        return self.process(events), []

    def set_resting(self, result, t_us):
        self.resting.append((result, t_us))

    def set_type_wait(self, wait):
        pass


class EstimatesThrough:
    """A pipeline a source of estimates goes through as it is (what a predictions file's replay
    is): each estimate is its own window."""

    def process(self, item):
        return [item]

    def set_resting(self, result, t_us):
        pass

    def restart(self):
        pass

    def set_type_wait(self, wait):
        pass

    def markers(self):
        return None


class FakeMapper:
    """ABS_X follows the intensity (x1000), BTN_SOUTH pressed during a push."""

    #: never at a fixed point: every window is mapped
    resting_state = None

    def __init__(self, profile):
        self.profile = profile

    def update(self, est: GestureEstimate) -> ControllerState:
        state = ControllerState.neutral(est.t_us)
        state.axes["ABS_X"] = int(est.intensity_mm * 1000) * self.profile.get("sign", 1)
        state.buttons["BTN_SOUTH"] = est.gesture is GestureType.PUSH
        return state


class RecordingOutput:
    """Remembers every call, in order: the states published that changed, as writes."""

    wants_markers = False

    def publish(self, record):
        if record.state_changed:
            self.write(record.state)

    def __init__(self):
        self.calls: list[tuple[str, ControllerState | None]] = []

    def write(self, state):
        self.calls.append(("write", state))

    def neutralise(self):
        self.calls.append(("neutralise", None))

    def prepare(self, profile):
        pass


def endless(step_us: int = 1000):
    t = 0
    while True:
        yield batch(t)
        t += step_us


def writes_of(calls):
    return [s for k, s in calls if k == "write"]


def once(condition, action, timeout_s: float = 60.0) -> threading.Thread:
    """Run ``action`` in a thread as soon as ``condition()`` holds (:func:`wait_until`), so a test
    waits for what the runtime did, not for a wall-clock delay a loaded machine can overrun."""
    thread = threading.Thread(target=lambda: (wait_until(condition, timeout_s), action()), daemon=True)
    thread.start()
    return thread
