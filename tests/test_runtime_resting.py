"""The runtime while the gel rests (docs/performance.md): the paced source and the live camera woken
once a window and a touch at once, the resting detector's verdicts from their own thread, neither
mapper nor subscribers called at rest, and batches cut at the window ends with the same states at
the same times."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest
from helpers import wait_until
from runtime_fakes import FakeMapper, FakePipeline, RecordingOutput, batch
from runtime_helpers import ManualClock, make_runtime

from neurotouch_hid.core.controller import ControllerState
from neurotouch_hid.core.estimate import GestureEstimate, GestureType
from neurotouch_hid.engine.engine import Engine, RunParts
from neurotouch_hid.engine.mode import RunMode, RunOptions
from neurotouch_hid.sources import Frame, Pacer


class WindowedPipeline:
    """10 ms windows from the first event, as the real pipeline closes them (an estimate for each
    window end an event crossed); the gel rests until ``touch_us``, then pushes."""

    def __init__(self, touch_us: int):
        self.touch_us = touch_us
        self.seen: list[int] = []  # each event's timestamp, in the order processed
        self.next_end: int | None = None
        self.threads: list[tuple[int, str]] = []  # each item's length and the thread that processed it

    def process(self, item):
        if isinstance(item, Frame):
            return []
        self.threads.append((len(item), threading.current_thread().name))
        out = []
        for t in item["timestamp"].tolist():
            self.next_end = t + 10_000 if self.next_end is None else self.next_end
            while t >= self.next_end:
                touched = self.next_end > self.touch_us
                out.append(
                    GestureEstimate(t_us=self.next_end)
                    if not touched
                    else GestureEstimate(t_us=self.next_end, gesture=GestureType.PUSH, resting=False, intensity_mm=3.0)
                )
                self.next_end += 10_000
            self.seen.append(t)
        return out

    def process_newest(self, events):
        """Joined batches: every window they close, as :meth:`process` (nothing coalesced)."""
        return self.process(events), []

    def set_resting(self, result, t_us):
        pass

    def set_type_wait(self, wait):
        pass


def test_a_resting_gel_wakes_the_paced_source_once_per_window_and_a_touch_at_once():
    clock = ManualClock()
    pacer = Pacer(clock=lambda: clock.now_ns, sleep=clock.sleep)
    pipeline = WindowedPipeline(touch_us=60_000)
    times = [k * 1000 + 500 for k in range(100)]  # one event per 1 ms batch; windows end at 10 500 + 10 000 j

    def source():
        for t in times:  # each batch once what was handed on is processed: no race on the clock
            assert wait_until(lambda: not rt.busy)
            yield batch(t, n=1)

    options = RunOptions(mode=RunMode.PACED, mapper_factory=FakeMapper, pacer=pacer)
    rt = Engine(RunParts(source(), pipeline), {"sign": 1}, [RecordingOutput()], options)
    rt.run()
    assert pipeline.seen == times  # everything, in order
    woke = (np.cumsum(clock.slept) * 1e6 + times[0]).round().astype(int).tolist()  # camera time of each wake
    resting = [w for w in woke if w < 60_000]
    moving = [w for w in woke if w > 72_000]
    # at rest (from the second resting window on): once per window, a batch after its end
    assert resting[-4:] == [21_500, 31_500, 41_500, 51_500]
    assert len(resting) < 30  # not one per 1 ms batch
    # the window the touch began in closed when it would have; after it, every batch on its own
    assert 61_500 in woke and 71_500 in woke
    assert moving == times[times.index(72_500) :]
    # at rest the batches of a window went on as one: the pipeline ran once per window, in the
    # source's thread (the pipeline's thread not woken); from the touch on, in the pipeline's
    assert [n for n, _ in pipeline.threads[:26]] == [1] * 22 + [10] * 4
    assert pipeline.threads[22:26] == [(10, "nt-source")] * 4
    # from the touch on, each batch on its own in the pipeline's thread (the first may be taken
    # with the batch handed on right before it: two hand-ons back to back, one queue)
    after = pipeline.threads[26:]
    assert {thread for _, thread in after} == {"nt-pipeline"} and sum(n for n, _ in after) == 38
    assert len(after) >= 37 and set(pipeline.threads[28:]) == {(1, "nt-pipeline")}


# --- the resting detector beside the event path ------------------------------------------------
class FakeResting:
    def __init__(self):
        self.thread_names = set()

    def update(self, frame):
        self.thread_names.add(threading.current_thread().name)
        return ("rest", frame.t_us)


@pytest.mark.parametrize("push_batches", [10**9, 5], ids=["moving", "resting after a push"])
def test_resting_results_reach_the_pipeline_from_their_own_thread(push_batches):
    """While the gel moves, from the resting thread; while it rests, the source's thread computes
    them as it hands the frames on (one thread wakes)."""

    def source():
        for i in range(10):
            yield Frame(i * 40_000, np.zeros((260, 346), np.uint8))
            for k in range(40):
                yield batch(i * 40_000 + k * 1000 + 1)

    resting = FakeResting()
    rt, pipeline, _ = make_runtime(source(), resting=resting, pipeline=FakePipeline(push_batches=push_batches))
    stats = rt.run()
    # (at rest, a frame goes to the resting thread still when the pipeline's is busy)
    allowed = {"nt-resting"} if push_batches > 400 else {"nt-resting", "nt-source"}
    assert "nt-resting" in resting.thread_names <= allowed
    # every frame's verdict reaches the pipeline (set_resting) with its frame's time, in order,
    # except possibly the last ones if the stream ended before the resting thread was done
    ts = [t for _, t in pipeline.resting]
    assert ts == sorted(ts) and set(ts) <= {i * 40_000 for i in range(10)}
    assert stats.frames == 10 and stats.resting_updates == len(ts) > 0


def test_at_rest_neither_mapper_nor_subscribers_are_called_and_the_states_stay_the_mappers():
    """While the gel rests and the mapper rests at its fixed point, a window changes nothing: the
    mapper and the subscribers are not called; the mapper gets the rest's last estimate when it
    ends, so every state published is the one a mapper fed every window gives."""
    from neurotouch_hid.mapping.mapper import Mapper
    from neurotouch_hid.mapping.profile import load_profile

    profile = load_profile("default")
    pipeline = WindowedPipeline(touch_us=400_000)
    calls: list[GestureEstimate] = []

    class CountedMapper(Mapper):
        def update(self, estimate):
            calls.append(estimate)
            return super().update(estimate)

    class Every(RecordingOutput):
        def publish(self, record):
            self.calls.append(("publish", record.state))
            super().publish(record)

    times = [k * 1000 + 500 for k in range(600)]
    out = Every()
    rt = Engine(
        RunParts((batch(t, n=1) for t in times), pipeline),
        profile,
        [out],
        RunOptions(mode=RunMode.FAST, mapper_factory=CountedMapper),
    )
    rt.run()
    resting = [e for e in calls if e.resting]
    assert rt.stats.windows == 59 and len(calls) < 59 - 30  # most resting windows skipped
    assert resting[-1].t_us == 390_500  # the rest's last window, handed over when it ended
    published = [s for k, s in out.calls if k == "publish"]
    assert len(published) < 59 - 30

    whole = Mapper(profile)  # every window's estimate, in order
    fed = [whole.update(e) for e in WindowedPipeline(touch_us=400_000).process(join_all(times))]
    by_time = {s.t_us: s for s in fed}
    for state in published:
        assert state == by_time[state.t_us]


def join_all(times):
    from neurotouch_hid.sources import join_events

    return join_events([batch(t, n=1) for t in times])


def test_a_resting_gel_whose_next_window_is_late_polls_the_live_camera_every_ms_not_at_once():
    """While the gel rests, a poll that brings nothing once the next window's end + 1 ms has passed
    (the camera's data for it are late: it sends them at its own pace) waits 1 ms, not 0: in the
    test kernel the source's thread spun through 3,709 polls of no wait in 22 s of rest."""
    from neurotouch_hid.engine.rest import REST_WAKE_AFTER_END_US, RestHandover

    clock = ManualClock()
    pacer = Pacer(clock=lambda: clock.now_ns, sleep=clock.sleep)
    handover = RestHandover(pacer, threading.Event(), lambda item: None, paced=False, default_pause_s=0.0002)
    assert handover.live_pause() == 0.0002  # the gel moves: the source's own pause
    for end_us in (10_000, 20_000):  # the last window ended at 20 ms, at rest: the next ends at 30 ms
        handover.window_closed(GestureEstimate(t_us=end_us))
    assert handover.windows == (20_000, 10_000)
    handover.read(29_000)  # the last item read, camera time 29 ms, now
    assert handover.live_pause() == pytest.approx(0.002)  # camera time 29 ms: until 31 ms
    clock.now_ns = 5_000_000  # camera time about 34 ms, the next window's data not here yet
    assert handover.live_pause() == REST_WAKE_AFTER_END_US / 1e6 == 0.001


def test_a_resting_gel_polls_the_live_camera_once_per_window_and_a_touch_at_once():
    """A live source (its polls wait by a PollPause): while the gel rests, each poll's items are
    held and handed on (processed in the source's thread) when a poll brings nothing, and the
    next poll waits for the next window's end; from the touch on, the source's own pause."""
    from neurotouch_hid.sources import PausingStream, PollPause

    pipeline = WindowedPipeline(touch_us=60_000)
    times = [k * 1000 + 500 for k in range(100)]  # one event per 1 ms batch; windows end at 10 500 + 10 000 j
    pause = PollPause(0.0002)
    pauses: list[tuple[int, float]] = []  # (camera time, the pause asked) after each poll

    def camera():
        now_us, sent = 0, 0
        while sent < len(times):
            while sent < len(times) and times[sent] <= now_us:  # one poll: everything due
                yield batch(times[sent], n=1)
                sent += 1
            # a camera slower than the pipeline: what was handed on is processed (no race on the
            # rest); then the poll brought nothing new, and the camera's time goes on meanwhile
            assert wait_until(lambda n=sent: len(pipeline.seen) + rt.rest.held_events >= n)
            waited = pause()
            pauses.append((now_us, waited))
            now_us += max(200, round(waited * 1e6))
            clock.now_ns = now_us * 1000

    clock = ManualClock()  # the camera's time, moved on by the fake camera
    rt = Engine(
        RunParts(PausingStream(camera(), pause), pipeline),
        {"sign": 1},
        [RecordingOutput()],
        RunOptions(
            mode=RunMode.LIVE, mapper_factory=FakeMapper, pacer=Pacer(clock=lambda: clock.now_ns, sleep=clock.sleep)
        ),
    )
    rt.run()
    assert pipeline.seen == times and pause.decide is None  # everything, in order; the pause given back
    resting = [(t, p) for t, p in pauses if 21_500 <= t < 60_000]
    assert resting and all(p > 0.005 for _, p in resting)  # about a window each
    assert len(resting) <= 5  # one poll a window, not one per 1 ms batch
    assert all(p == 0.0002 for t, p in pauses if t >= 72_500)  # after the touch, the source's own
    at_rest = [n for n, thread in pipeline.threads if thread == "nt-source"]
    assert at_rest and all(n >= 9 for n in at_rest[1:])  # a window's batches at once, in the source's thread


class TimedOutput(RecordingOutput):
    """Remembers each changed state with its window's end and the paced clock when it came."""

    def __init__(self, clock: ManualClock):
        super().__init__()
        self.clock = clock
        self.timed: list[tuple[int, ControllerState, int]] = []
        self.closed: list[tuple[int, int]] = []  # every window: its end (us), the clock (ns)

    def publish(self, record):
        if record.state_changed:
            self.timed.append((record.estimate.t_us, record.state, self.clock.now_ns))


def _paced_run_of(recording, *, cut: bool) -> tuple[TimedOutput, list[int]]:
    """``recording`` through the real pipeline and default profile, paced on a manual clock, each
    item read once everything handed on is processed; the published states with the clock when
    they came, and the length of every item the source yielded (events; a frame counts 1)."""
    import contextlib

    from neurotouch_hid.engine.assembly import build_pipeline
    from neurotouch_hid.mapping.profile import load_profile
    from neurotouch_hid.sources.open import open_source

    def size(item) -> int:
        return len(item) if isinstance(item, np.ndarray) else 1

    clock = ManualClock()
    pacer = Pacer(clock=lambda: clock.now_ns, sleep=clock.sleep)
    output = TimedOutput(clock)
    read: list[int] = []
    with contextlib.ExitStack() as stack:
        opened = open_source(str(recording), stack, batch_us=1000)
        pipeline, _ = build_pipeline(opened.sensor, 10_000, resting_beside=False)
        stream = opened.stream
        rt = None

        def synchronised():
            for item in stream:
                deadline = time.monotonic() + 60  # (only ends a hang)
                while rt.busy and time.monotonic() < deadline:
                    time.sleep(0.0002)  # the pipeline's thread is at it: a short poll
                read.append(size(item))
                yield item

        source = synchronised()
        if cut:  # the stream's cut, handed on as the runtime finds it
            source = type(stream)(source, stream.batch_cut)
        process = pipeline.process

        def timed_process(item):  # every window's end, with the paced clock when it closed
            out = process(item)
            output.closed += [(estimate.t_us, clock.now_ns) for estimate in out]
            return out

        pipeline.process = timed_process
        rt = Engine(
            RunParts(source, pipeline), load_profile("default"), [output], RunOptions(mode=RunMode.PACED, pacer=pacer)
        )
        rt.run()
    return output, read


def test_a_resting_gel_s_batches_are_cut_at_its_window_ends_with_the_same_states_at_the_same_time(
    sim_push_only_recording,
):
    """While the gel rests, the paced recording's batches follow the windows (``BatchCut``): the
    same states, published at the same (paced) time, from about one batch a window instead of ten."""
    with_cut, read_cut = _paced_run_of(sim_push_only_recording, cut=True)
    without, read_plain = _paced_run_of(sim_push_only_recording, cut=False)
    assert with_cut.timed and any(state.axes != ControllerState.neutral().axes for _, state, _ in with_cut.timed)
    assert with_cut.timed == without.timed
    assert len(with_cut.closed) > 400 and with_cut.closed == without.closed  # every window closed as soon
    assert sum(read_cut) == sum(read_plain)  # every event and frame
    assert len(read_cut) < 0.6 * len(read_plain)
