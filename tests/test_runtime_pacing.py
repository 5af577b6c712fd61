"""The runtime's pacing (unit tests with small fakes for the stages): a paced source follows its
timestamps, a source that waits starts its clock with the run, and the pacer maps camera time onto
wall time."""

from __future__ import annotations

import pytest
from runtime_fakes import batch, endless
from runtime_helpers import ManualClock, make_runtime

from neurotouch_hid.engine.mode import RunMode
from neurotouch_hid.sources import Pacer


def test_pacing_follows_the_timestamps():
    clock = ManualClock()
    pacer = Pacer(clock=lambda: clock.now_ns, sleep=clock.sleep)
    rt, pipeline, _ = make_runtime((batch(i * 50_000, n=1) for i in range(5)), mode=RunMode.PACED, pacer=pacer)
    rt.run()
    # 5 batches 50 ms apart in camera time: each waited for, 200 ms of the clock in all
    assert clock.slept == pytest.approx([0.05] * 4)
    assert clock.now_ns == 200_000_000
    # the clock's sleeps take no wall time, so the worker may take the batches joined: all five
    assert sum(pipeline.sizes) == 5 and pipeline.seen[-1] == 200_000


def test_a_source_that_waits_starts_its_clock_with_the_run_and_catches_up_a_late_first_item():
    """The simulated gel waits for its first run's compile before its first item: that wait is
    caught up after, as any other (the stream's clock started with the run), not added to it."""
    clock = ManualClock()
    pacer = Pacer(clock=lambda: clock.now_ns, sleep=clock.sleep)

    def late_source():
        clock.now_ns += 120_000_000  # 120 ms before the first item (a compile)
        yield from (batch(i * 50_000, n=1) for i in range(5))

    rt, pipeline, _ = make_runtime(late_source(), mode=RunMode.PACED_WAITING, pacer=pacer)
    rt.run()
    # items at 0, 50, ..., 200 ms of camera time: those due by 120 ms go at once, then on time
    assert clock.slept == pytest.approx([0.03, 0.05])
    assert clock.now_ns == 200_000_000 and sum(pipeline.sizes) == 5


def test_without_pacing_nothing_waits():
    clock = ManualClock()
    pacer = Pacer(clock=lambda: clock.now_ns, sleep=clock.sleep)
    rt, pipeline, _ = make_runtime((batch(i * 50_000, n=1) for i in range(5)), pacer=pacer)
    rt.run()
    assert clock.slept == [] and len(pipeline.seen) == 5


def test_seconds_limits_the_camera_time_read():
    rt, pipeline, _ = make_runtime(endless(1000))
    rt.run(seconds=0.05)
    assert len(pipeline.seen) == 50


def test_the_pacer_maps_camera_time_onto_wall_time_from_its_first_item():
    import threading

    from neurotouch_hid.sources import Pacer

    clock = Pacer()
    first = clock.due_ns(5_000_000)  # the first item anchors the clock: due now
    assert clock.first_us == 5_000_000 and clock.first_ns == first
    assert clock.due_ns(5_002_500) - first == 2_500_000  # 2.5 ms of camera time later, in ns
    stop = threading.Event()
    assert clock.wait(4_000_000, stop) is False  # already due: no wait, not stopped
    stop.set()
    assert clock.wait(5_000_000 + 3_600_000_000, stop) is True  # an hour ahead: the stop ends the wait
