"""What the runtime's unit tests share (tests/test_runtime_*.py): an Engine built on the small fakes
of tests/runtime_fakes.py, and a clock that moves only when the pacer sleeps."""

from __future__ import annotations

import threading

from runtime_fakes import FakeMapper, FakePipeline, RecordingOutput

from neurotouch_hid.engine.engine import Engine, RunParts
from neurotouch_hid.engine.mode import RunMode, RunOptions


def make_runtime(
    source, pipeline=None, output=None, *, resting=None, mode=RunMode.FAST, **options
) -> tuple[Engine, FakePipeline, RecordingOutput]:
    pipeline = pipeline or FakePipeline()
    output = output or RecordingOutput()
    options = RunOptions(mode=mode, mapper_factory=FakeMapper, **options)
    return Engine(RunParts(source, pipeline, resting=resting), {"sign": 1}, [output], options), pipeline, output


class ManualClock:
    """A clock (ns) that moves only when the pacer sleeps on it; remembers each sleep (s)."""

    def __init__(self):
        self.now_ns = 0
        self.slept: list[float] = []

    def sleep(self, stop: threading.Event, seconds: float) -> bool:
        self.slept.append(seconds)
        self.now_ns += round(seconds * 1e9)
        return stop.is_set()
