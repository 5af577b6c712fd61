"""Windows that queue up behind the pipeline (a real-time run fell behind its source): every event
tracked, only the newest queued window decided (``GesturePipeline.process_newest``, the runtime's
``_handle``), on recordings made by the project's simulator."""

from __future__ import annotations

import numpy as np
import pytest

from neurotouch_hid.core.estimate import GestureEstimate, GestureType
from neurotouch_hid.core.sensor import SensorGeometry
from neurotouch_hid.engine.engine import Engine, RunParts
from neurotouch_hid.engine.mode import RunMode, RunOptions
from neurotouch_hid.mapping.profile import load_profile
from neurotouch_hid.pipeline.pipeline import GesturePipeline, PipelineConfig
from neurotouch_hid.sources import Frame, join_events
from neurotouch_hid.sources.batches import merge_stream
from neurotouch_hid.sources.recording import RecordingReader

WINDOW_US = 1_000
GROUP = 4  # batches joined, as a queue behind the pipeline hands them on (1 ms each: ~4 windows)


@pytest.fixture(scope="module")
def push(sim_push_only_recording):
    """The simulated push's sensor and its stream in 1 ms batches and APS frames."""
    return _stream(sim_push_only_recording)


def _stream(path):
    """A recording's sensor (sensor.yaml beside it) and its stream in 1 ms batches and APS frames."""
    sensor = SensorGeometry.load(path.parent / "sensor.yaml")
    with RecordingReader(path) as reader:
        events, frames = reader.read_all()
    return sensor, list(merge_stream([events], frames, 1_000))


def _pipeline(sensor, seen: dict[int, np.ndarray], window_us: int) -> GesturePipeline:
    """The product's pipeline (noise filter on, resting detection inline: deterministic), keeping
    the tracked markers at each window it decides."""
    pipeline: GesturePipeline

    def keep(estimate: GestureEstimate) -> None:
        seen[estimate.t_us] = pipeline.marker_positions()

    pipeline = GesturePipeline(sensor, PipelineConfig(window_us=window_us), on_window=keep)
    return pipeline


def _reference(push, window_us: int = WINDOW_US):
    sensor, items = push
    seen: dict[int, np.ndarray] = {}
    pipeline = _pipeline(sensor, seen, window_us)
    estimates = [e for item in items for e in pipeline.process(item)]
    return pipeline, estimates, seen


def _coalesced(push, window_us: int = WINDOW_US, group: int = GROUP):
    """The same stream with every run of ``group`` event batches joined and fed to ``process_newest``."""
    sensor, items = push
    seen: dict[int, np.ndarray] = {}
    pipeline = _pipeline(sensor, seen, window_us)
    estimates: list[GestureEstimate] = []
    skipped: list[int] = []
    run: list[np.ndarray] = []

    def flush() -> None:
        if run:
            out, ends = pipeline.process_newest(join_events(run))
            estimates.extend(out)
            skipped.extend(ends)
            run.clear()

    for item in items:
        if isinstance(item, Frame):
            flush()
            estimates.extend(pipeline.process(item))
            continue
        run.append(item)
        if len(run) == group:
            flush()
    flush()
    return pipeline, estimates, skipped, seen


def _episodes(estimates: list[GestureEstimate], gap_us: int) -> list[tuple[GestureType, int, int]]:
    """(type, first window end, last window end) of each run of windows answering one gesture,
    windows of a type at most ``gap_us`` apart in one run (the coalesced windows between them)."""
    out: list[tuple[GestureType, int, int]] = []
    for e in estimates:
        if e.gesture is GestureType.NONE:
            continue
        if out and out[-1][0] is e.gesture and e.t_us - out[-1][2] <= gap_us:
            out[-1] = (e.gesture, out[-1][1], e.t_us)
        else:
            out.append((e.gesture, e.t_us, e.t_us))
    return out


def test_joined_batches_track_every_event_and_decide_only_the_newest_window(push):
    ref_pipeline, ref, ref_seen = _reference(push)
    pipeline, out, skipped, seen = _coalesced(push)
    ends = [e.t_us for e in out]
    # every window closed once: decided or closed without a decision, none lost, none twice
    assert sorted(ends + skipped) == [e.t_us for e in ref]
    assert len(set(ends) & set(skipped)) == 0
    assert len(skipped) > len(ref) // 2  # most windows were joined with a newer one
    # every event went through the noise filter and the tracker: the markers at each decided
    # window's end are the uncoalesced run's, bit for bit
    assert pipeline.noise_filter.n_in == ref_pipeline.noise_filter.n_in
    assert pipeline.noise_filter.n_out == ref_pipeline.noise_filter.n_out
    moved = 0
    for t_us, positions in seen.items():
        np.testing.assert_array_equal(positions, ref_seen[t_us])
        moved += bool(np.nanmax(np.abs(positions - pipeline.rest_px)) > 1.0)
    assert moved > 100  # the push moved the markers in many of the decided windows


def _same_episodes(ref: list[GestureEstimate], out: list[GestureEstimate], joined_us: int) -> list:
    """The uncoalesced run's episodes, asserted to be the coalesced run's: the same types in the
    same order, each beginning and ending within the time joined of the other's."""
    expected, got = _episodes(ref, joined_us), _episodes(out, joined_us)
    assert [g for g, _, _ in got] == [g for g, _, _ in expected]
    for (_, start, end), (_, got_start, got_end) in zip(expected, got):
        assert abs(got_start - start) <= joined_us and abs(got_end - end) <= joined_us
    return expected


def test_deciding_only_the_newest_window_keeps_the_gesture_episodes(push):
    """The episode vote and the creep filter key on camera time: told every fourth window or so,
    they give the same episodes, each within the windows joined of the uncoalesced run's."""
    _, ref, _ = _reference(push)
    _, out, _, _ = _coalesced(push)
    expected = _same_episodes(ref, out, GROUP * 1_000)
    assert {g for g, _, _ in expected} == {GestureType.PUSH}  # the recording's push: held over a second
    assert any(end - start > 1_000_000 for _, start, end in expected)


@pytest.mark.parametrize("gesture", ["push", "pinch", "twist_cw", "twist_ccw", "zoom"])
def test_every_gesture_keeps_its_type_when_four_10_ms_windows_are_joined(sim_quick_dataset, gesture):
    """The quick dataset's sequences (one user, 3 s each), the product's 10 ms windows, 40 ms of
    batches a call: the same gesture episodes, of the sequence's own type."""
    stream = _stream(sim_quick_dataset / f"u0_{gesture}.aedat4")
    _, ref, _ = _reference(stream, 10_000)
    _, out, skipped, _ = _coalesced(stream, 10_000, 40)
    assert len(skipped) > len(ref) // 2
    expected = _same_episodes(ref, out, 40_000)
    longest = max(expected, key=lambda episode: episode[2] - episode[1])
    assert longest[0] is GestureType(gesture) and longest[2] - longest[1] > 1_000_000


class _Estimates:
    """A subscriber that keeps every record's estimate."""

    wants_markers = False

    def __init__(self) -> None:
        self.estimates: list[GestureEstimate] = []

    def publish(self, record) -> None:
        self.estimates.append(record.estimate)

    def neutralise(self) -> None:
        pass

    def prepare(self, profile) -> None:
        pass


def test_a_run_behind_its_source_coalesces_queued_windows_and_drops_nothing(push):
    """A live source that delivers far faster than the pipeline works (the recording read at
    once): the batches queue up, each call takes all of them, every event is tracked, nothing is
    dropped, and the windows published and coalesced are every window of the stream."""
    sensor, items = push
    _, ref, _ = _reference(push)
    out = _Estimates()
    pipeline = GesturePipeline(sensor, PipelineConfig(window_us=WINDOW_US))
    runtime = Engine(
        RunParts(iter(items), pipeline),
        load_profile("default"),
        [out],
        RunOptions(mode=RunMode.LIVE, max_lag_us=10**12),
    )
    stats = runtime.run()
    assert stats.dropped_items == 0
    assert stats.events == sum(len(i) for i in items if not isinstance(i, Frame))
    assert stats.coalesced_windows > 0
    assert stats.windows + stats.coalesced_windows == len(ref)
    ends = [e.t_us for e in out.estimates]  # (those published: a resting gel's unchanged windows are not)
    assert ends == sorted(set(ends)) and set(ends) <= {e.t_us for e in ref}
    assert GestureType.PUSH in {e.gesture for e in out.estimates}


def test_a_fast_replay_never_coalesces(push):
    """``--fast`` (neither paced nor live): the source waits for the pipeline, no batch is joined,
    every window is decided as the pipeline alone decides it."""
    sensor, items = push
    _, ref, _ = _reference(push)
    out = _Estimates()
    pipeline = GesturePipeline(sensor, PipelineConfig(window_us=WINDOW_US))
    stats = Engine(RunParts(iter(items), pipeline), load_profile("default"), [out], RunOptions(mode=RunMode.FAST)).run()
    assert stats.coalesced_windows == 0 and stats.windows == len(ref)
    published = {e.t_us: e.gesture for e in out.estimates}
    assert published == {e.t_us: e.gesture for e in ref if e.t_us in published}
    assert GestureType.PUSH in published.values()
