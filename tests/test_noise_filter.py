"""The optional noise filter before the tracker (pipeline/noise.py, PipelineConfig.noise)
and the simulator's background-activity rate (``simulate --noise-hz``)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from typer.testing import CliRunner

from neurotouch_hid.cli import app
from neurotouch_hid.core.errors import NeurotouchError
from neurotouch_hid.core.estimate import GestureType
from neurotouch_hid.core.sensor import SensorGeometry
from neurotouch_hid.evaluation.runner import pipeline_config
from neurotouch_hid.pipeline.noise import EventNoiseFilter
from neurotouch_hid.pipeline.pipeline import GesturePipeline, PipelineConfig
from neurotouch_hid.sources import EVENT_DTYPE, Frame
from neurotouch_hid.sources.batches import split_batches
from neurotouch_hid.sources.dv import events_from_store, store_from_events
from neurotouch_hid.sources.gel import SimGesture
from neurotouch_hid.sources.recording import RecordingReader, read_info
from neurotouch_hid.sources.simulator import START_US, GelSimulator

SENSOR = SensorGeometry()
W, H = SENSOR.width, SENSOR.height
PUSH_START_US = START_US + 200_000
ATTACK_US, HOLD_US = 300_000, 300_000


def _push() -> SimGesture:
    """A one-finger push of 4 mm, held, released: 0.2 s rest, then ~1 s of motion."""
    return SimGesture(
        gesture=GestureType.PUSH,
        t_start_us=PUSH_START_US,
        attack_us=ATTACK_US,
        hold_us=HOLD_US,
        release_us=200_000,
        fingers_mm=np.array([[3.0, -2.0]]),
        amplitude_mm=4.0,
        direction=np.array([0.6, -0.8]),
        finger_mm=7.0,
        press=0.8,
        tremor=(0.0, 5.0, 0.0),
        global_mm=np.array([0.2, -0.1]),
        global_rad=0.002,
        residual=0.03,
        creep_us=80_000,
    )


def uniform_noise(rate_hz: float, t0_us: int, t1_us: int, seed: int = 7) -> np.ndarray:
    """Background activity: Poisson, ``rate_hz`` per pixel, uniform over the array and the time
    span, random polarity (the simulator's model), time-ordered EVENT_DTYPE."""
    rng = np.random.default_rng(seed)
    n = rng.poisson(rate_hz * W * H * (t1_us - t0_us) * 1e-6)
    ev = np.zeros(n, dtype=EVENT_DTYPE)
    ev["timestamp"] = np.sort(rng.integers(t0_us, t1_us, n))
    ev["x"] = rng.integers(0, W, n)
    ev["y"] = rng.integers(0, H, n)
    ev["polarity"] = rng.integers(0, 2, n)
    return ev


def _key(ev: np.ndarray) -> np.ndarray:
    """One int64 per event (timestamp, x, y, polarity) to find an event among the kept ones."""
    return ((ev["timestamp"].astype(np.int64) * W + ev["x"]) * H + ev["y"]) * 2 + ev["polarity"]


@pytest.fixture(scope="module")
def marker_events() -> np.ndarray:
    """The markers' own events during the push (no background activity, hot pixels removed)."""
    sim = GelSimulator(SENSOR, seed=1, script=[_push()], noise_rate_hz=0.0)
    events = np.concatenate([chunk.events for chunk in sim.run(1.2)])
    hot = np.isin(
        events["y"].astype(np.int64) * W + events["x"], sim.camera.hot_y.astype(np.int64) * W + sim.camera.hot_x
    )
    events = events[~hot]
    assert len(events) > 20_000  # the push makes the markers fire
    return events


def mix(marker_events: np.ndarray, rate_hz: float) -> tuple[np.ndarray, np.ndarray]:
    """Marker events plus ``rate_hz`` per pixel of background activity over their time span,
    merged in time order, and which of them are markers' (bool)."""
    t0, t1 = int(marker_events["timestamp"][0]), int(marker_events["timestamp"][-1]) + 1
    noise = uniform_noise(rate_hz, t0, t1)
    events = np.concatenate([marker_events, noise])
    is_marker = np.r_[np.ones(len(marker_events), bool), np.zeros(len(noise), bool)]
    order = np.argsort(events["timestamp"], kind="stable")
    return events[order], is_marker[order]


@pytest.fixture(scope="module")
def noisy(marker_events) -> tuple[np.ndarray, np.ndarray]:
    """The push with 3 Hz/pixel background activity (a DAVIS-346 in dim light)."""
    events, is_marker = mix(marker_events, 3.0)
    assert np.count_nonzero(~is_marker) > 3 * np.count_nonzero(is_marker)  # the noise dominates
    return events, is_marker


def _filter_in_batches(name: str, time_us: int | None, events: np.ndarray, batch_us: int = 1000) -> np.ndarray:
    f = EventNoiseFilter(name, W, H, time_us)
    return np.concatenate([f(b) for b in split_batches(events, batch_us)])


def _kept(name: str, time_us: int | None, events: np.ndarray) -> np.ndarray:
    """(E,) bool: which of ``events`` the filter keeps (fed in 1 ms batches, as the runtime)."""
    return np.isin(_key(events), _key(_filter_in_batches(name, time_us, events)))


# --- the filter on simulated noise ------------------------------------------------------------
@pytest.mark.parametrize(
    "name, time_us, min_removed, min_marker_kept",
    [
        ("BackgroundActivityNoiseFilter", None, 0.55, 0.9),  # the default: 20 ms
        ("BackgroundActivityNoiseFilter", 2000, 0.9, 0.45),  # the library's default time
        ("FastDecayNoiseFilter", None, 0.8, 0.8),  # 50 ms
        ("KNoiseFilter", None, 0.95, 0.2),  # 1 ms: clean, but loses most marker events
    ],
)
def test_filters_remove_injected_background_activity_and_keep_marker_events(
    noisy, name, time_us, min_removed, min_marker_kept
):
    events, is_marker = noisy
    kept = _kept(name, time_us, events)
    removed, marker_kept = 1.0 - kept[~is_marker].mean(), kept[is_marker].mean()
    assert removed > min_removed and marker_kept > min_marker_kept, (removed, marker_kept)


def test_the_default_filter_removes_most_noise_at_1_hz_and_keeps_most_marker_events(marker_events):
    events, is_marker = mix(marker_events, 1.0)
    kept = _kept(PipelineConfig().noise.kind, PipelineConfig().noise.time_us, events)
    assert 1.0 - kept[~is_marker].mean() > 0.8
    assert kept[is_marker].mean() > 0.9


@pytest.mark.parametrize("rate_hz, time_us", [(1.0, 10_000), (1.0, 20_000), (3.0, 10_000), (3.0, 20_000)])
def test_background_activity_filter_passes_noise_as_often_as_a_neighbour_fired(marker_events, rate_hz, time_us):
    # an isolated event is kept when one of its 8 neighbours fired within time_us: with Poisson
    # noise of rate r per pixel, 1 - exp(-8 r T) of the time (pixels near markers a bit more)
    events, is_marker = mix(marker_events, rate_hz)
    kept = _kept("BackgroundActivityNoiseFilter", time_us, events)
    expected = 1.0 - np.exp(-8 * rate_hz * time_us * 1e-6)
    assert abs(kept[~is_marker].mean() - expected) < 0.03


def test_a_longer_time_keeps_more_marker_events_and_more_noise(noisy):
    events, is_marker = noisy
    short = _kept("BackgroundActivityNoiseFilter", 1000, events)
    long = _kept("BackgroundActivityNoiseFilter", 10_000, events)
    assert long[is_marker].mean() > short[is_marker].mean() + 0.1
    assert long[~is_marker].mean() > short[~is_marker].mean()


def test_the_filter_keeps_its_state_across_batches(noisy):
    events, _ = noisy
    events = events[:200_000]
    whole = EventNoiseFilter("BackgroundActivityNoiseFilter", W, H)(events)
    assert np.array_equal(_filter_in_batches("BackgroundActivityNoiseFilter", None, events, batch_us=1000), whole)
    fresh_each_batch = np.concatenate(
        [EventNoiseFilter("BackgroundActivityNoiseFilter", W, H)(b) for b in split_batches(events, 1000)]
    )
    assert len(fresh_each_batch) < len(whole)  # what forgetting between batches would lose


def test_the_filter_starts_afresh_when_the_clock_goes_back():
    f = EventNoiseFilter("BackgroundActivityNoiseFilter", W, H, 2000)
    pair = np.zeros(2, dtype=EVENT_DTYPE)
    pair["timestamp"], pair["x"], pair["y"] = [9_000_000, 9_000_100], [10, 11], [10, 10]
    assert len(f(pair)) == 1  # the second one is supported by the first
    isolated = uniform_noise(0.05, 1_000_000, 1_200_000)  # ~900 events, ~0.01 per pixel
    assert len(isolated) > 500
    kept = f(isolated)  # the camera's clock restarted: earlier than everything seen
    assert len(kept) < 0.1 * len(isolated)
    assert f.n_in == len(isolated) and f.n_out == len(kept)


# --- the numba background-activity filter against dv-processing's ----------------------------
def _library_ba(events: np.ndarray, time_us: int, batch_us: int, width: int = W, height: int = H) -> np.ndarray:
    """dv-processing's own BackgroundActivityNoiseFilter (accept + generateEvents on EventStores)."""
    f = EventNoiseFilter("BackgroundActivityNoiseFilter", width, height, time_us)
    return np.concatenate(
        [events_from_store(f.filter_store(store_from_events(b))) for b in split_batches(events, batch_us)]
    )


def _numba_ba(events: np.ndarray, time_us: int, batch_us: int, width: int = W, height: int = H) -> np.ndarray:
    f = EventNoiseFilter("BackgroundActivityNoiseFilter", width, height, time_us)
    return np.concatenate([f(b) for b in split_batches(events, batch_us)])


@pytest.mark.parametrize("time_us, batch_us", [(2000, 1000), (20_000, 1000), (20_000, 10_000), (500, 10_000)])
def test_numba_filter_keeps_exactly_what_dv_processing_keeps_on_a_street_recording(any_street, time_us, batch_us):
    with RecordingReader(any_street.path) as reader:
        events, _ = reader.read_all()
    library = _library_ba(events, time_us, batch_us)
    assert 0 < len(library) < len(events)  # the filter decides something on real sensor noise
    assert np.array_equal(_numba_ba(events, time_us, batch_us), library)


@pytest.mark.parametrize("rate_hz", [0.1, 1.0, 3.0])
@pytest.mark.parametrize("time_us", [2000, 20_000])
def test_numba_filter_keeps_exactly_what_dv_processing_keeps_on_a_noisy_simulated_gel(marker_events, rate_hz, time_us):
    events, _ = mix(marker_events, rate_hz)
    library = _library_ba(events, time_us, 1000)
    assert 0 < len(library) < len(events)
    assert np.array_equal(_numba_ba(events, time_us, 1000), library)


def test_numba_filter_matches_dv_processing_at_the_borders_early_times_and_clock_restarts():
    # every pixel of a small array, corners and edges included, from t = 0 (the library's time
    # surface starts at 0, so the first duration is "supported" everywhere), then a clock restart
    rng = np.random.default_rng(3)
    w, h = 7, 5
    parts = []
    for t0, n in ((0, 400), (50_000, 400), (10_000, 300)):  # the last batch goes back in time
        ev = np.zeros(n, dtype=EVENT_DTYPE)
        ev["timestamp"] = t0 + np.sort(rng.integers(0, 6000, n))
        ev["x"], ev["y"], ev["polarity"] = rng.integers(0, w, n), rng.integers(0, h, n), rng.integers(0, 2, n)
        parts.append(ev)
    library_filter = EventNoiseFilter("BackgroundActivityNoiseFilter", w, h, 700)
    numba_filter = EventNoiseFilter("BackgroundActivityNoiseFilter", w, h, 700)
    for part in parts:
        for batch in split_batches(part, 1000):
            library = events_from_store(library_filter.filter_store(store_from_events(batch)))
            assert np.array_equal(numba_filter(batch), library)
    assert (numba_filter.n_in, numba_filter.n_out) == (library_filter.n_in, library_filter.n_out)
    assert 0 < numba_filter.n_out < numba_filter.n_in


def test_an_empty_batch_passes_through():
    f = EventNoiseFilter("KNoiseFilter", W, H)
    assert len(f(np.zeros(0, dtype=EVENT_DTYPE))) == 0 and f.n_in == 0


# --- configuration ----------------------------------------------------------------------------
@pytest.mark.parametrize(
    "kwargs, message",
    [
        ({"kind": "MedianFilter"}, "noise.kind must be None or one of BackgroundActivityNoiseFilter"),
        ({"kind": "KNoiseFilter", "time_us": 0}, "noise.time_us must be a whole number of microseconds >= 1"),
        ({"kind": "KNoiseFilter", "time_us": 2.5}, "noise.time_us must be a whole number"),
        ({"kind": None, "time_us": 2000}, "noise.time_us=2000 is set but noise.kind is None"),
    ],
)
def test_bad_noise_filter_settings_are_clear_errors(kwargs, message):
    with pytest.raises(ValueError, match=message):
        PipelineConfig(noise=kwargs)


def test_set_reaches_the_noise_filter_fields():
    config = pipeline_config(["noise.kind=FastDecayNoiseFilter", "noise.time_us=20000"])
    assert config.noise.kind == "FastDecayNoiseFilter" and config.noise.time_us == 20_000
    assert pipeline_config(["noise.kind=none"]).noise.kind is None
    with pytest.raises(NeurotouchError, match="noise.kind must be None or one of"):
        pipeline_config(["noise.kind=bilateral"])
    with pytest.raises(NeurotouchError, match="noise.time_us"):
        pipeline_config(["noise.kind=KNoiseFilter", "noise.time_us=1.5"])


# --- in the pipeline --------------------------------------------------------------------------
def _push_chunks(rate_hz: float) -> list:
    return list(GelSimulator(SENSOR, seed=1, script=[_push()], noise_rate_hz=rate_hz).run(1.2))


def _stream(chunks: list) -> list:
    """As a source yields it: each APS frame, then its period's events in 1 ms batches."""
    items: list = []
    for chunk in chunks:
        items.append(chunk.frame)
        items.extend(split_batches(chunk.events, 1000))
    return items


@pytest.fixture(scope="module")
def noisy_push_chunks() -> list:
    """The push at 3 Hz/pixel background activity (frames, events, true marker positions)."""
    return _push_chunks(3.0)


@pytest.fixture(scope="module")
def noisy_push_stream(noisy_push_chunks) -> list:
    return _stream(noisy_push_chunks)


def _run(items: list, config: PipelineConfig) -> tuple[GesturePipeline, list]:
    pipeline = GesturePipeline(SENSOR, config)
    return pipeline, list(pipeline.run(items))


def test_the_default_pipeline_filters_finds_the_push_and_closes_the_same_windows(noisy_push_stream):
    filtered, with_filter = _run(noisy_push_stream, PipelineConfig())
    _, without = _run(noisy_push_stream, PipelineConfig(noise={"kind": None}))
    assert [e.t_us for e in with_filter] == [e.t_us for e in without]
    f = filtered.noise_filter
    assert f is not None and f.n_in == sum(len(i) for i in noisy_push_stream if not isinstance(i, Frame))
    assert f.n_out < 0.5 * f.n_in  # ~90 % of this stream is background activity
    held = [e for e in with_filter if PUSH_START_US + ATTACK_US <= e.t_us < PUSH_START_US + ATTACK_US + HOLD_US]
    assert len(held) >= 25
    assert np.mean([e.gesture is GestureType.PUSH for e in held]) > 0.9
    assert all(e.resting and e.gesture is GestureType.NONE for e in with_filter if e.t_us < PUSH_START_US)


class _EventsOnly(GesturePipeline):
    """The product's pipeline without the APS-frame correction: the event path alone."""

    def _correct(self, result, t_us: int) -> None:
        pass


def _tracking_errors(chunks: list, config: PipelineConfig) -> np.ndarray:
    """Distance (px) from each tracked marker to its true position at every window end, on the
    markers that moved more than 1 px (the simulator's 1 ms truth, interpolated; lost = inf)."""
    t_true = np.concatenate([c.t_us for c in chunks])
    p_true = np.concatenate([c.positions_px for c in chunks]).astype(np.float64)
    errors: list[np.ndarray] = []

    def on_window(estimate) -> None:
        k = int(np.clip(np.searchsorted(t_true, estimate.t_us), 1, len(t_true) - 1))
        a = (estimate.t_us - t_true[k - 1]) / (t_true[k] - t_true[k - 1])
        truth = (p_true[k - 1] + a * (p_true[k] - p_true[k - 1]))[match]
        d = np.linalg.norm(pipeline.marker_positions() - truth, axis=1)
        moved = np.linalg.norm(truth - p_true[0][match], axis=1) > 1.0
        errors.append(np.where(np.isfinite(d), d, np.inf)[moved])

    pipeline = _EventsOnly(SENSOR, config, on_window=on_window)
    items = _stream(chunks)
    pipeline.process(items[0])
    match = np.argmin(np.linalg.norm(pipeline.rest_px[:, None] - p_true[0][None], axis=2), axis=1)
    for item in items[1:]:
        pipeline.process(item)
    return np.concatenate(errors)


def test_under_3_hz_noise_the_default_filter_keeps_the_markers_tracked(noisy_push_chunks):
    # the event path alone: the APS-frame correction pulls held blobs onto the frame's markers
    # whatever the events did (p90 0.36 px with or without the filter)
    on = _tracking_errors(noisy_push_chunks, PipelineConfig())
    off = _tracking_errors(noisy_push_chunks, PipelineConfig(noise={"kind": None}))
    assert len(on) == len(off) > 1000
    # measured: p90 0.71 px with the filter, 1.07 px without; p99 1.06 against 1.85 px
    assert np.percentile(on, 90) < 0.8 * np.percentile(off, 90)
    assert np.percentile(on, 99) < 0.7 * np.percentile(off, 99)


def test_at_the_default_noise_the_filter_costs_no_tracking_accuracy():
    chunks = _push_chunks(0.1)
    on = _tracking_errors(chunks, PipelineConfig())
    off = _tracking_errors(chunks, PipelineConfig(noise={"kind": None}))
    # measured: p90 0.63 px either way
    assert np.percentile(on, 90) < 1.1 * np.percentile(off, 90)
    assert np.median(on) < 1.1 * np.median(off)


def _events(*rows: tuple[int, int, int]) -> np.ndarray:
    """Events at (t_us, x, y), ON."""
    ev = np.zeros(len(rows), dtype=EVENT_DTYPE)
    for k, (t, x, y) in enumerate(rows):
        ev[k] = (t, x, y, 1)
    return ev


def test_windows_start_and_close_on_the_unfiltered_events(noisy_push_stream):
    frame = noisy_push_stream[0]  # the rest reference
    t0 = int(frame.t_us)
    batches = [
        _events((t0 + 100, 5, 5), (t0 + 20_000, 300, 250), (t0 + 45_000, 150, 20)),  # isolated
        _events((t0 + 50_000, 40, 40), (t0 + 50_010, 41, 40)),  # the second is supported
        _events((t0 + 75_000, 200, 200)),  # isolated
    ]
    filtered = GesturePipeline(SENSOR, PipelineConfig())  # the default filter
    plain = GesturePipeline(SENSOR, PipelineConfig(noise={"kind": None}))
    for pipeline in (filtered, plain):
        pipeline.process(frame)
    ends = []
    for batch in batches:
        got = [e.t_us for e in filtered.process(batch)]
        assert got == [e.t_us for e in plain.process(batch)]
        ends += got
    assert ends == [t0 + 10_100, t0 + 20_100, t0 + 30_100, t0 + 40_100, t0 + 50_100, t0 + 60_100, t0 + 70_100]
    assert (filtered.noise_filter.n_in, filtered.noise_filter.n_out) == (6, 1)


# --- simulate --noise-hz ------------------------------------------------------------------------
def _rate_per_pixel(folder) -> float:
    info = read_info(folder / "u0_push.aedat4")
    return info.n_events / (W * H) / (info.duration_us * 1e-6)


def test_noise_hz_makes_a_noisier_recording_and_eval_runs_the_filter_on_it(tmp_path):
    runner = CliRunner()
    common = ["simulate", "--preset", "quick", "--minutes", "0.02"]
    assert runner.invoke(app, [*common, "--out", str(tmp_path / "default")]).exit_code == 0
    result = runner.invoke(app, [*common, "--out", str(tmp_path / "noisy"), "--noise-hz", "3"])
    assert result.exit_code == 0, result.output
    default, noisy = _rate_per_pixel(tmp_path / "default"), _rate_per_pixel(tmp_path / "noisy")
    assert 0.1 <= default < 0.2  # 0.1 Hz background activity + 4 hot pixels (the gel rests)
    assert 2.8 < noisy < 3.3
    out = tmp_path / "m.json"
    result = runner.invoke(
        app,
        [
            "eval",
            str(tmp_path / "noisy"),
            "--set",
            "noise.kind=BackgroundActivityNoiseFilter",
            "--set",
            "noise.time_us=5000",
            "--json",
            str(out),
        ],
    )
    assert result.exit_code == 0, result.output
    config = json.loads(out.read_text())["config"]
    assert config["noise"] == {"kind": "BackgroundActivityNoiseFilter", "time_us": 5000}


def test_negative_noise_hz_is_one_clear_error(tmp_path, monkeypatch, capsys):
    from neurotouch_hid.cli import main

    monkeypatch.setattr("sys.argv", ["neurotouch-hid", "simulate", "--out", str(tmp_path / "x"), "--noise-hz", "-1"])
    with pytest.raises(SystemExit) as exc:
        main()
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert "--noise-hz must be >= 0" in err and "Traceback" not in err
