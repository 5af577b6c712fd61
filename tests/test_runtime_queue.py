"""The runtime's queue between the source and the pipeline (unit tests with small fakes for the
stages): what it drops and reports, its bound in camera time, the batches it joins, and a slow
pipeline behind a live source."""

from __future__ import annotations

import threading

import numpy as np
from runtime_fakes import FakePipeline, batch
from runtime_helpers import make_runtime

from neurotouch_hid.engine.mode import RunMode
from neurotouch_hid.engine.queue import DropOldestQueue, item_end_us
from neurotouch_hid.sources import Frame


# --- the queue ----------------------------------------------------------------------------------
def test_queue_drops_oldest_and_reports_them():
    dropped = []
    q = DropOldestQueue(3, drop_oldest=True, on_drop=dropped.append)
    for i in range(5):
        q.put((0, i))
    q.close()
    got = []
    while (entry := q.get()) is not None:
        got.append(entry[1])
    assert got == [2, 3, 4]
    assert dropped == [0, 1]
    assert q.finished


def test_runtime_counts_dropped_oldest_batches_when_the_pipeline_falls_behind():
    gate = threading.Event()
    n, size = 40, 5
    pipeline = FakePipeline(gate=gate)

    def source():
        yield batch(0)
        pipeline.started.wait(5)  # the pipeline holds the first batch ...
        for i in range(1, n):
            yield batch(i * 1000)
        gate.set()  # ... until the source has handed over everything

    rt, pipeline, _ = make_runtime(source(), pipeline=pipeline, mode=RunMode.LIVE, queue_items=size)
    stats = rt.run()
    # the pipeline held the first batch while the source filled the queue: all but the
    # newest `size` of the rest were dropped, oldest first; those `size` came in one call
    assert pipeline.seen == [item_end_us(batch(0)), item_end_us(batch((n - 1) * 1000))]
    assert pipeline.sizes == [3, 3 * size]
    assert stats.dropped_items == n - 1 - size
    assert stats.dropped_events == (n - 1 - size) * 3
    assert stats.events == 3 * (1 + size) and stats.windows == 2


def test_queue_bounded_in_camera_time_drops_what_reaches_back_too_far():
    """max_span_us: the queued data reaches back at most that far (oldest start to newest end);
    older batches are dropped, oldest first; a queue that waits (--fast) ignores the bound."""
    dropped = []
    q = DropOldestQueue(1000, on_drop=dropped.append, max_span_us=2_500)
    for i in range(6):
        q.put((i, batch(i * 1000)))  # 0..200, 1000..1200, ...: each 200 us long
    assert [item_end_us(b) for b in dropped] == [200, 1_200, 2_200]
    assert [q.get()[0] for _ in range(3)] == [3, 4, 5]
    waiting = DropOldestQueue(1000, drop_oldest=False, max_span_us=2_500)
    for i in range(6):
        waiting.put((i, batch(i * 1000)))
    assert [waiting.get()[0] for _ in range(6)] == list(range(6))


def test_queue_joins_the_event_batches_behind_one_but_never_a_frame():
    q = DropOldestQueue(10)
    frame = Frame(t_us=2_500, image=np.zeros((2, 2), np.uint8))
    for entry in [(1, batch(0)), (2, batch(1_000)), (3, frame), (4, batch(3_000)), (5, batch(4_000, n=5))]:
        q.put(entry)
    q.close()
    arrival, joined = q.get_joined(max_events=100)
    assert arrival == 1 and joined["timestamp"].tolist() == [0, 100, 200, 1_000, 1_100, 1_200]
    assert q.get_joined(max_events=100) == (3, frame)  # a frame alone, in its place
    arrival, first = q.get_joined(max_events=4)  # 3 + 5 > 4: not joined
    assert arrival == 4 and len(first) == 3
    assert len(q.get_joined(max_events=4)[1]) == 5 and q.get_joined() is None and q.finished


def test_a_slow_pipeline_behind_a_live_source_gets_every_event_in_fewer_calls():
    """A pipeline whose every call takes longer than a batch lasts (as on a slow machine) catches
    up by taking what was queued meanwhile in one call: nothing is dropped."""
    gate = threading.Event()
    n, size = 40, 50
    pipeline = FakePipeline(gate=gate)

    def source():
        yield batch(0)
        pipeline.started.wait(5)
        for i in range(1, n):
            yield batch(i * 1000)
        gate.set()

    rt, pipeline, _ = make_runtime(source(), pipeline=pipeline, mode=RunMode.LIVE, queue_items=size)
    stats = rt.run()
    assert stats.dropped_items == 0 and stats.events == 3 * n == sum(pipeline.sizes)
    assert len(pipeline.sizes) < n and pipeline.seen[-1] == item_end_us(batch((n - 1) * 1000))


def test_fast_mode_drops_nothing():
    rt, pipeline, _ = make_runtime((batch(i * 1000) for i in range(300)), queue_items=4)
    stats = rt.run()
    assert stats.dropped_items == 0
    assert len(pipeline.seen) == 300 and stats.events == 900
