"""The runtime: threads, queues, pacing, shutdown (unit tests with small fakes for the stages),
then the real stages end to end (simulated gel -> pipeline -> default profile -> JSON lines)."""

from __future__ import annotations

import os
import signal
import threading
import time

import numpy as np
import pytest
from helpers import read_states, run_cli, wait_until
from runtime_fakes import FakeMapper, FakePipeline, RecordingOutput, batch, endless, once, writes_of

from neurotouch_hid.core.controller import ControllerState
from neurotouch_hid.core.errors import ProfileError
from neurotouch_hid.core.estimate import GestureEstimate, GestureType
from neurotouch_hid.engine.engine import Engine, RunParts
from neurotouch_hid.engine.mode import RunMode, RunOptions
from neurotouch_hid.engine.queue import DropOldestQueue, item_end_us
from neurotouch_hid.sources import Frame, Pacer


def make_runtime(
    source, pipeline=None, output=None, *, resting=None, mode=RunMode.FAST, **options
) -> tuple[Engine, FakePipeline, RecordingOutput]:
    pipeline = pipeline or FakePipeline()
    output = output or RecordingOutput()
    options = RunOptions(mode=mode, mapper_factory=FakeMapper, **options)
    return Engine(RunParts(source, pipeline, resting=resting), {"sign": 1}, [output], options), pipeline, output


def writes(output: RecordingOutput) -> list[ControllerState]:
    return [s for kind, s in output.calls if kind == "write"]


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


# --- states, shutdown ---------------------------------------------------------------------------
def test_states_follow_the_estimates_and_end_neutral():
    rt, _, out = make_runtime(batch(i * 1000) for i in range(10))
    stats = rt.run()
    states = writes(out)
    xs = [s.axes["ABS_X"] for s in states]
    assert xs[:5] == [1000, 2000, 3000, 4000, 5000]  # one write per change
    assert states[5].is_neutral()
    assert len(states) == 6 == stats.states_written  # unchanged states are not written again
    assert out.calls[-1] == ("neutralise", None)
    assert stats.windows == 10 and len(stats.latency) == 10


def test_exception_in_the_pipeline_still_neutralises_the_output():
    rt, _, out = make_runtime((batch(i * 1000) for i in range(10)), pipeline=FakePipeline(fail_at=3))
    with pytest.raises(RuntimeError, match="pipeline failure"):
        rt.run()
    assert any(not s.is_neutral() for s in writes(out))  # a button was held when it failed
    assert out.calls[-1] == ("neutralise", None)


def test_error_in_the_source_processes_what_was_read_then_neutralises_and_raises():
    from neurotouch_hid.core.errors import RecordingError

    def truncated():
        for i in range(4):
            yield batch(i * 1000)
        raise RecordingError("rec.aedat4: truncated")

    rt, pipeline, out = make_runtime(truncated())
    with pytest.raises(RecordingError, match="truncated"):
        rt.run()
    assert len(pipeline.seen) == 4
    assert out.calls[-1] == ("neutralise", None)


def test_stop_from_another_thread_ends_a_paced_endless_source_neutral():
    rt, pipeline, out = make_runtime(endless(), mode=RunMode.PACED, pipeline=FakePipeline(push_batches=10**9))
    once(lambda: writes(out), rt.stop)
    rt.run()
    assert pipeline.seen and out.calls[-1] == ("neutralise", None)
    assert writes(out) and not writes(out)[-1].is_neutral()  # stopped in the middle of a push


def test_sigterm_is_a_clean_stop():
    rt, pipeline, out = make_runtime(endless(), mode=RunMode.PACED, pipeline=FakePipeline(push_batches=10**9))
    previous = signal.getsignal(signal.SIGTERM)
    once(lambda: writes(out), lambda: os.kill(os.getpid(), signal.SIGTERM))
    stats = rt.run()  # returns normally
    assert stats.windows > 0 and out.calls[-1] == ("neutralise", None)
    assert signal.getsignal(signal.SIGTERM) is previous  # handler restored


class ManualClock:
    """A clock (ns) that moves only when the pacer sleeps on it; remembers each sleep (s)."""

    def __init__(self):
        self.now_ns = 0
        self.slept: list[float] = []

    def sleep(self, stop: threading.Event, seconds: float) -> bool:
        self.slept.append(seconds)
        self.now_ns += round(seconds * 1e9)
        return stop.is_set()


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


# --- profiles -----------------------------------------------------------------------------------
def test_switch_profile_neutralises_then_maps_with_the_new_profile():
    rt, pipeline, out = make_runtime(endless(), mode=RunMode.PACED, pipeline=FakePipeline(push_batches=10**9))
    seen_switch = threading.Event()

    def switch():
        rt.switch_profile({"sign": -1})
        seen_switch.set()

    once(lambda: len(writes_of(out.calls)) >= 3, switch)

    def written_after_switch() -> int:
        calls = list(out.calls)
        kinds = [k for k, _ in calls]
        return len(writes_of(calls[kinds.index("neutralise") + 1 :])) if "neutralise" in kinds else 0

    once(lambda: seen_switch.is_set() and written_after_switch() >= 3, rt.stop)
    rt.run()
    assert seen_switch.is_set()
    kinds = [k for k, _ in out.calls]
    i = kinds.index("neutralise")
    before, after = writes_of(out.calls[:i]), writes_of(out.calls[i + 1 :])
    assert before and after
    assert all(s.axes["ABS_X"] > 0 for s in before)
    assert all(s.axes["ABS_X"] < 0 for s in after)


def test_reload_keeps_the_old_profile_when_the_new_one_is_bad():
    def bad_loader(ref):
        raise ProfileError(f"profile {ref} is invalid (1 problem): ...")

    rt, _, out = make_runtime([], profile_ref="mine.yaml", profile_loader=bad_loader)
    assert rt.reload_profile() is False
    assert rt.profile == {"sign": 1} and out.calls == []


def test_sighup_reloads_the_profile():
    loads = []

    def loader(ref):
        loads.append(ref)
        return {"sign": -1}

    rt, _, out = make_runtime(
        endless(),
        mode=RunMode.PACED,
        pipeline=FakePipeline(push_batches=10**9),
        profile_ref="mine.yaml",
        profile_loader=loader,
    )
    once(lambda: len(writes(out)) >= 3, lambda: os.kill(os.getpid(), signal.SIGHUP))
    once(lambda: loads and len(writes(out)) >= 3 and writes(out)[-1].axes["ABS_X"] < 0, rt.stop)
    rt.run()
    assert loads == ["mine.yaml"] and rt.profile == {"sign": -1}
    assert writes(out)[-1].axes["ABS_X"] < 0


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


# --- the real stages, through the CLI -----------------------------------------------------------
import json  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402

CLI = [sys.executable, "-c", "from neurotouch_hid.cli import main; main()"]
ENV = dict(os.environ, PYTHONUNBUFFERED="1", COLUMNS="160")


def is_neutral(line: dict) -> bool:
    from neurotouch_hid.core.controller import AXES

    return all(line["axes"][n] == AXES[n][2] for n in AXES) and not any(line["buttons"].values())


def test_run_on_a_recording_moves_the_stick_during_the_push_and_ends_neutral(sim_push_only_recording, tmp_path):
    out = tmp_path / "states.jsonl"
    proc = run_cli(
        "run", "--source", str(sim_push_only_recording), "--output", "jsonl", "--fast", "--out", str(out), columns=160
    )
    assert proc.returncode == 0, proc.stderr
    states = read_states(out.read_text())
    pushes = [s for s in states if s["gesture"] == "push"]
    assert pushes, "no push recognised"
    # the default profile puts a push on the left stick
    assert any(abs(s["axes"]["ABS_X"]) + abs(s["axes"]["ABS_Y"]) > 3000 for s in pushes)
    # after the release the pipeline itself brings the stick back (before the final neutralise)
    assert is_neutral(states[-2]) and is_neutral(states[-1])
    assert [s["t_us"] for s in states] == sorted(s["t_us"] for s in states)
    assert "dropped 0 items" in proc.stderr  # --fast drops nothing


def test_sigterm_ends_a_live_run_with_a_neutral_state_and_exit_0():
    proc = subprocess.Popen(
        [*CLI, "run", "--source", "sim", "--output", "jsonl"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=ENV,
    )
    try:
        lines = []
        for line in proc.stdout:  # wait for the first gesture moving the pad
            lines.append(json.loads(line))
            if not is_neutral(lines[-1]):
                break
        assert lines and not is_neutral(lines[-1]), proc.stderr.read() if proc.poll() is not None else ""
        proc.send_signal(signal.SIGTERM)
        rest, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0, err
    final = read_states(rest)
    assert final and is_neutral(final[-1])


def test_demo_without_uinput_shows_the_terminal_view_and_says_why(tmp_path):
    if os.access("/dev/uinput", os.W_OK):
        pytest.skip(reason="/dev/uinput is writable here: the demo uses the real gamepad")
    proc = run_cli("demo", "--seconds", "3", columns=160)
    assert proc.returncode == 0, proc.stderr
    assert "no writable /dev/uinput (" in proc.stderr
    assert "showing the gamepad in the terminal instead; see `neurotouch-hid doctor`" in proc.stderr
    # no TTY: plain state lines, not escape codes
    assert "\x1b[" not in proc.stdout
    lines = [line for line in proc.stdout.splitlines() if line.strip()]
    assert lines and all(line.startswith("t ") and "L(" in line for line in lines)


def test_a_bad_profile_raises_before_any_output_or_source_exists(tmp_path, monkeypatch):
    import neurotouch_hid.engine.assembly as assembly
    import neurotouch_hid.engine.driver as driver

    opened = []
    monkeypatch.setattr(driver, "open_output", lambda *a, **k: opened.append("output"))
    monkeypatch.setattr(assembly, "open_source", lambda *a, **k: opened.append("source"))
    bad = tmp_path / "bad.yaml"
    bad.write_text("mappings:\n  push: {input: nonsense, output: left_stick}\n")
    with pytest.raises(ProfileError, match="bad.yaml"):
        driver.run_driver("sim", bad, "gamepad")
    assert opened == []


def test_fast_replays_are_deterministic(sim_push_only_recording, tmp_path):
    from neurotouch_hid.engine.driver import DriverOptions, run_driver

    runs = []
    for k in range(2):
        out = tmp_path / f"states{k}.jsonl"
        stats = run_driver(str(sim_push_only_recording), "default", "jsonl", DriverOptions(fast=True, out=out))
        assert stats.dropped_items == 0 and stats.windows > 0
        runs.append(out.read_text())
    assert runs[0] == runs[1] and runs[0]


def test_a_predictions_file_replays_through_the_mapper_state_for_state(tmp_path):
    """``--source FILE.jsonl`` (no pipeline): the states written are the Mapper's for the same
    estimates, one line per change, ending neutral."""
    from neurotouch_hid.core.dataset import read_predictions, write_predictions
    from neurotouch_hid.engine.driver import DriverOptions, run_driver
    from neurotouch_hid.mapping.profile import load_profile
    from neurotouch_hid.mapping.replay import replay

    estimates = []
    for k in range(120):
        level = 6.0 * np.sin(np.pi * k / 119)  # a push ramping up and back down
        estimates.append(
            GestureEstimate(
                t_us=1_000_000 + 10_000 * k,
                gesture=GestureType.PUSH,
                resting=False,
                intensity_mm=level,
                translation_mm=np.array([level, 0.0]),
            )
        )
    estimates += [GestureEstimate(t_us=2_200_000 + 10_000 * k) for k in range(20)]
    preds = tmp_path / "p.jsonl"
    write_predictions(preds, estimates)
    out = tmp_path / "states.jsonl"
    stats = run_driver(str(preds), "default", "jsonl", DriverOptions(fast=True, out=out))
    got = [(d["axes"], d["buttons"]) for d in read_states(out.read_text())]
    neutral = (ControllerState.neutral().axes, ControllerState.neutral().buttons)
    expected = [neutral]  # the runtime starts from the neutral state and writes changes only
    for s in replay(load_profile("default"), read_predictions(preds)):  # as stored (rounded)
        if expected[-1] != (s.axes, s.buttons):
            expected.append((s.axes, s.buttons))
    assert got[-1] == neutral  # the final neutralise
    # JSON lines are also written when only the gesture changes: compare the state changes
    changes = [neutral]
    for g in got:
        if changes[-1] != g:
            changes.append(g)
    assert changes == expected
    assert stats.windows == len(estimates) and stats.events == 0
    assert any(a["ABS_X"] > 0 for a, _ in got)


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


def test_the_run_s_pipeline_runs_opencv_without_its_thread_pool():
    """A run's pipeline calls OpenCV on one APS frame or a few hundred points at a time: its
    pool's thread, woken at every call, cost more than it shared out (25 times a second at rest)."""
    import cv2

    from neurotouch_hid.core.sensor import SensorGeometry
    from neurotouch_hid.engine.assembly import build_pipeline

    previous = cv2.getNumThreads()
    cv2.setNumThreads(2)
    try:
        build_pipeline(SensorGeometry(), 10_000)
        assert cv2.getNumThreads() == 1
    finally:
        cv2.setNumThreads(previous)


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
