"""GesturePipeline: windows, reference frame, resting, errors; predictions JSON lines; and the
whole pipeline on a simulated dataset (paper, section "Methodology")."""

from __future__ import annotations

import dataclasses
import json
import threading
import warnings

import numpy as np
import pytest
from helpers import run_cli

from neurotouch_hid.core.dataset import read_predictions, write_predictions
from neurotouch_hid.core.errors import DatasetError, NeurotouchError, SensorError
from neurotouch_hid.core.estimate import GestureEstimate, GestureType
from neurotouch_hid.core.sensor import SensorGeometry
from neurotouch_hid.pipeline.episode import EpisodeVote
from neurotouch_hid.pipeline.paper import PaperPipeline
from neurotouch_hid.pipeline.pipeline import GesturePipeline, PipelineConfig
from neurotouch_hid.pipeline.resting import RestingResult
from neurotouch_hid.sources import EVENT_DTYPE, Frame

SENSOR = SensorGeometry()


def gel_image(shift_px=(0.0, 0.0), region_px: float | None = None) -> np.ndarray:
    """A gel at rest as the camera sees it: 1 mm white dots on a 4 mm grid (10 px), Gaussian
    profile; markers within ``region_px`` of the centre (or all) moved by ``shift_px``."""
    k = np.arange(-7, 8) * 10.0
    pts = np.stack(np.meshgrid(k, k), axis=-1).reshape(-1, 2) + np.asarray(SENSOR.gel_center_px)
    pts = pts[SENSOR.inside_gel(pts, margin_px=-4.0)]
    if region_px is not None:
        near = np.hypot(*(pts - SENSOR.gel_center_px).T) <= region_px
        pts[near] += shift_px
    else:
        pts += shift_px
    img = np.full((SENSOR.height, SENSOR.width), 20.0)
    yy, xx = np.mgrid[-4:5, -4:5]
    for x, y in pts:
        ix, iy = int(round(x)), int(round(y))
        img[iy - 4 : iy + 5, ix - 4 : ix + 5] += 220 * np.exp(-((xx + ix - x) ** 2 + (yy + iy - y) ** 2) / (2 * 0.8**2))
    return np.clip(img, 0, 255).astype(np.uint8)


def events_at(*timestamps: int) -> np.ndarray:
    """Noise events (far from any marker) at the given times."""
    ev = np.zeros(len(timestamps), dtype=EVENT_DTYPE)
    ev["timestamp"] = timestamps
    ev["x"], ev["y"] = 2, 2
    return ev


@pytest.fixture(scope="module")
def rest_image() -> np.ndarray:
    return gel_image()


# --- windows -----------------------------------------------------------------------------------
def test_windows_are_aligned_on_the_first_event_and_none_is_skipped(rest_image):
    pipeline = GesturePipeline(SENSOR)
    assert pipeline.process(events_at(100, 200)) == []  # before the reference frame: dropped
    assert pipeline.process(Frame(500, rest_image)) == []
    out = pipeline.process(events_at(1234, 5000, 12000))
    assert [e.t_us for e in out] == [11234]
    out = pipeline.process(events_at(45000))  # crosses three window ends, two without events
    assert [e.t_us for e in out] == [21234, 31234, 41234]
    out = pipeline.process(Frame(60000, rest_image))  # a frame closes the windows before it
    assert [e.t_us for e in out] == [51234]
    assert pipeline.process(events_at(60001)) == []


def test_one_millisecond_windows(rest_image):
    pipeline = GesturePipeline(SENSOR, PipelineConfig(window_us=1000))
    pipeline.process(Frame(0, rest_image))
    out = pipeline.process(events_at(10, 20, 3500))
    assert [e.t_us for e in out] == [1010, 2010, 3010]
    assert all(e.resting and e.gesture is GestureType.NONE for e in out)


def test_windows_shorter_than_one_millisecond_are_refused():
    with pytest.raises(ValueError, match="1000"):
        PipelineConfig(window_us=999)


def test_on_window_sees_each_estimate_with_the_tracked_positions(rest_image):
    seen = []
    pipeline = GesturePipeline(SENSOR, on_window=lambda e: seen.append((e.t_us, pipeline.marker_positions())))
    pipeline.process(Frame(0, rest_image))
    out = pipeline.process(events_at(0, 25000))
    assert [t for t, _ in seen] == [e.t_us for e in out] == [10000, 20000]
    for _, positions in seen:
        np.testing.assert_allclose(positions, pipeline.rest_px, atol=1e-4)


# --- reference frame and errors ----------------------------------------------------------------
def test_the_first_frame_is_the_rest_reference(rest_image):
    pipeline = GesturePipeline(SENSOR)
    pipeline.process(Frame(0, rest_image))
    assert pipeline.rest_px.shape[1] == 2 and len(pipeline.rest_px) > 100
    assert pipeline.marker_positions().dtype == np.float32
    assert pipeline.resting.resting


def test_a_scene_without_gel_raises_no_gel_found():
    noise = np.random.default_rng(0).integers(0, 256, (SENSOR.height, SENSOR.width), dtype=np.uint8)
    pipeline = GesturePipeline(SENSOR, PipelineConfig(resting={"reference_attempts": 2}))
    assert pipeline.process(Frame(0, noise)) == []  # one bad first frame is tolerated
    with pytest.raises(SensorError, match="no gel found: the first 2 APS frame"):
        pipeline.process(Frame(40000, noise))


def test_an_under_exposed_first_frame_is_skipped(rest_image):
    pipeline = GesturePipeline(SENSOR)
    pipeline.process(Frame(0, np.zeros((SENSOR.height, SENSOR.width), np.uint8)))
    assert pipeline.rest_px is None
    pipeline.process(Frame(40000, rest_image))
    assert pipeline.rest_px is not None and len(pipeline.rest_px) > 100


def test_a_stream_without_frames_raises():
    with pytest.raises(SensorError, match="no APS frame"):
        list(GesturePipeline(SENSOR).run([events_at(0, 50000)]))


# --- resting -----------------------------------------------------------------------------------
def test_frames_decide_resting_and_rest_resets_the_tracker(rest_image):
    pipeline = GesturePipeline(SENSOR)
    pipeline.process(Frame(0, rest_image))
    pipeline.process(Frame(40000, gel_image((4.0, 0.0), region_px=30)))
    assert not pipeline.resting.resting and pipeline.resting.distance > 2.5
    out = pipeline.process(events_at(40001, 55000))
    assert [(e.resting, e.gesture) for e in out] == [(False, GestureType.NONE)]  # nothing tracked moved
    pipeline.tracker.reset(pipeline.rest_px + 3.0)  # tracker drift
    pipeline.process(Frame(80000, rest_image))
    assert pipeline.resting.resting
    np.testing.assert_allclose(pipeline.marker_positions(), pipeline.rest_px, atol=1e-4)


def test_moving_markers_overrule_a_stale_resting_verdict(rest_image):
    # each window's own type (the episode vote would hold a lone contact undecided)
    pipeline = _WindowByWindow(SENSOR, PipelineConfig(resting={"motion_override_mm": 0.4}))
    pipeline.process(Frame(0, rest_image))
    assert pipeline.resting.resting
    assert [e.resting for e in pipeline.process(events_at(1, 15000))] == [True]  # nothing moved
    # a finger pushed after the resting frame (a Gaussian field): the events moved the blobs
    w = np.exp(-np.sum((pipeline.rest_px - SENSOR.gel_center_px) ** 2, axis=1) / (2 * 12.0**2))
    moved = pipeline.rest_px + w[:, None] * [8.0, 0.0]
    pipeline.tracker.reset(moved)
    (estimate,) = pipeline.process(events_at(25000))
    assert not estimate.resting and estimate.gesture is GestureType.PUSH and estimate.n_contacts >= 1
    assert pipeline.resting.resting  # the APS verdict itself is unchanged ...
    pipeline.process(Frame(40000, rest_image))  # ... until the next frame judges (and resets)
    assert [e.resting for e in pipeline.process(events_at(45000))] == [True]


def test_motion_override_counts_its_own_markers_not_the_contact_n_min(rest_image):
    """With the paper's N_min = 4, the old rule (n_min markers moved) let five markers' tracker
    jitter overrule a resting verdict; the override's own count (12) does not, and a real
    finger still does."""
    pipeline = GesturePipeline(SENSOR, PipelineConfig(contacts={"n_min": 4}))
    pipeline.process(Frame(0, rest_image))
    pipeline.process(events_at(1))
    jitter = pipeline.rest_px.copy()
    jitter[:5] += [0.4, 0.0]  # five scattered markers, 0.4 px off: noise, not a gesture
    pipeline.tracker.reset(jitter)
    assert [e.resting for e in pipeline.process(events_at(15000))] == [True]
    d = np.linalg.norm(jitter - pipeline.rest_px, axis=1)
    assert np.count_nonzero(d > 0.3) >= pipeline.config.n_min  # the old rule would have overruled
    w = np.exp(-np.sum((pipeline.rest_px - SENSOR.gel_center_px) ** 2, axis=1) / (2 * 12.0**2))
    pipeline.tracker.reset(pipeline.rest_px + w[:, None] * [5.0, 0.0])
    assert [e.resting for e in pipeline.process(events_at(25000))] == [False]


def test_smooth_override_ignores_scattered_jitter_but_not_a_finger(rest_image):
    """Under a flickering light every marker's edges fire events at rest and the tracker jitters
    in random directions: 60 scattered markers 0.5 px off would overrule a resting verdict by their
    own displacements, but not once median-filtered over their grid neighbours; a finger's smooth
    bump of 2 px (0.8 mm) still overrules it."""
    rng = np.random.default_rng(4)
    pipeline = GesturePipeline(SENSOR, PipelineConfig())
    pipeline.process(Frame(0, rest_image))
    pipeline.process(events_at(1))
    jitter = pipeline.rest_px.copy()
    pick = rng.choice(len(jitter), 60, replace=False)
    angle = rng.uniform(0, 2 * np.pi, 60)
    jitter[pick] += 0.5 * np.stack([np.cos(angle), np.sin(angle)], axis=1)
    assert np.count_nonzero(np.linalg.norm(jitter - pipeline.rest_px, axis=1) > 0.3) >= 12  # by their own: moved
    pipeline.tracker.reset(jitter)
    assert [e.resting for e in pipeline.process(events_at(15000))] == [True]
    w = np.exp(-np.sum((pipeline.rest_px - SENSOR.gel_center_px) ** 2, axis=1) / (2 * 12.0**2))
    pipeline.tracker.reset(pipeline.rest_px + w[:, None] * [2.0, 0.0])
    assert [e.resting for e in pipeline.process(events_at(25000))] == [False]


def test_override_ignores_a_whole_gel_walked_by_flicker_but_not_a_finger_on_it(rest_image):
    """When a flickering light has just come on, every marker's events walk its blob on its own:
    the whole gel's blobs 0.4 px off in random directions, so many that their neighbourhood
    medians pass the threshold too. The part of each displacement its neighbours do not share
    (the gel's jitter) is what the shared motion must exceed; a finger's smooth 3 px bump on the
    same walking gel still overrules the verdict."""
    rng = np.random.default_rng(5)
    pipeline = GesturePipeline(SENSOR, PipelineConfig())
    pipeline.process(Frame(0, rest_image))
    pipeline.process(events_at(1))
    rest = pipeline.rest_px
    angle = rng.uniform(0, 2 * np.pi, len(rest))
    walk = 0.4 * np.stack([np.cos(angle), np.sin(angle)], axis=1)
    pipeline.tracker.reset(rest + walk)
    assert pipeline.resting.resting
    # without the background, the smooth override's own count would overrule
    d = np.concatenate([walk, np.full((1, 2), np.nan)])[pipeline._grid_neighbours]
    moved = np.linalg.norm(np.nanmedian(d, axis=1), axis=1) > pipeline.config.motion_override_px
    assert np.count_nonzero(moved) >= pipeline.config.override_min_markers
    assert [e.resting for e in pipeline.process(events_at(15000))] == [True]
    w = np.exp(-np.sum((rest - SENSOR.gel_center_px) ** 2, axis=1) / (2 * 12.0**2))
    pipeline.tracker.reset(rest + walk + w[:, None] * [3.0, 0.0])
    assert [e.resting for e in pipeline.process(events_at(25000))] == [False]


def test_papers_resting_verdict_holds_until_the_next_frame(rest_image):
    pipeline = PaperPipeline(SENSOR)
    pipeline.process(Frame(0, rest_image))
    pipeline.process(events_at(1))
    pipeline.tracker.reset(pipeline.rest_px + [4.0, 0.0])
    assert [(e.resting, e.gesture) for e in pipeline.process(events_at(15000))] == [(True, GestureType.NONE)]


def test_the_papers_method_runs_on_a_gel_whose_creep_is_measured(rest_image):
    """A calibrated gel's sensor.yaml has a creep; the paper's method (elastic gel) ignores it
    and answers, as the product's method takes it."""
    sensor = dataclasses.replace(SENSOR, creep=(0.3, 0.3))
    for pipeline in (PaperPipeline(sensor), GesturePipeline(sensor)):
        pipeline.process(Frame(0, rest_image))
        pipeline.process(events_at(1))
        assert [e.resting for e in pipeline.process(events_at(15000))] == [True]


def test_set_resting_from_another_thread_is_applied_at_the_next_item(rest_image):
    pipeline = GesturePipeline(SENSOR, detect_resting=False)
    pipeline.process(Frame(0, rest_image))
    result = pipeline.resting_detector.update(gel_image((4.0, 0.0), region_px=30))
    worker = threading.Thread(target=pipeline.set_resting, args=(result, 40000))
    worker.start()
    worker.join()
    pipeline.process(Frame(40000, rest_image))  # detect_resting=False: this frame is not judged
    out = pipeline.process(events_at(40001, 55000))
    assert [e.resting for e in out] == [False]


def test_set_resting_ignores_no_verdict_and_stale_verdicts(rest_image):
    pipeline = GesturePipeline(SENSOR, detect_resting=False)
    pipeline.process(Frame(0, rest_image))
    pipeline.set_resting(RestingResult(False, 9.0), 80000)
    pipeline.set_resting(RestingResult(True, 0.1), 40000)  # older frame, computed late
    pipeline.set_resting(None, 120000)  # the detector had no verdict
    pipeline.process(Frame(80000, rest_image))
    assert not pipeline.resting.resting and pipeline.resting.distance == 9.0
    pipeline.set_resting(RestingResult(True, 0.2), 60000)  # older than the verdict in force
    pipeline.process(events_at(80001))
    assert not pipeline.resting.resting


def test_a_verdict_on_a_frame_the_pipeline_has_not_reached_waits_for_that_frame(rest_image):
    # a pipeline running behind its source (a cold start, a busy machine) while the resting thread
    # keeps up: the verdict on a frame after the release (at rest) was applied to the windows
    # of the press still queued, which re-anchored the markers and said rest in mid-press
    pipeline = GesturePipeline(SENSOR, detect_resting=False)
    pipeline.process(Frame(0, rest_image))
    pipeline.set_resting(RestingResult(False, 9.0), 40000)
    pipeline.process(Frame(40000, rest_image))
    w = np.exp(-np.sum((pipeline.rest_px - SENSOR.gel_center_px) ** 2, axis=1) / (2 * 12.0**2))
    pressed = pipeline.rest_px + w[:, None] * [3.0, 0.0]
    pipeline.tracker.reset(pressed)
    pipeline.set_resting(RestingResult(True, 0.0), 120000)  # the frame after the release
    during = pipeline.process(events_at(40001, 55000, 65000, 75000))
    assert during and not any(e.resting for e in during)
    np.testing.assert_array_equal(pipeline.tracker.positions_px, pressed)  # not re-anchored
    pipeline.process(Frame(120000, rest_image))
    assert pipeline.resting.resting
    np.testing.assert_array_equal(pipeline.tracker.positions_px, pipeline.rest_px)


# --- predictions JSON lines --------------------------------------------------------------------
def test_predictions_round_trip(tmp_path):
    estimates = [
        GestureEstimate(t_us=10000),
        GestureEstimate(
            t_us=20000,
            gesture=GestureType.TWIST_CW,
            resting=False,
            intensity_mm=2.5,
            contacts_px=np.array([[150.0, 120.0], [190.0, 125.0]]),
            contacts_mm=np.array([[-9.2, 4.0], [6.8, 2.0]]),
            rotation_rad=-0.2,
            scale=1.01,
        ),
    ]
    path = tmp_path / "pred.jsonl"
    assert write_predictions(path, estimates) == 2
    lines = path.read_text().splitlines()
    assert json.loads(lines[1])["contacts_mm"] == [[-9.2, 4.0], [6.8, 2.0]]
    back = read_predictions(path)
    assert [(e.t_us, e.gesture, e.resting, e.n_contacts) for e in back] == [
        (10000, GestureType.NONE, True, 0),
        (20000, GestureType.TWIST_CW, False, 2),
    ]
    assert back[1].rotation_rad == pytest.approx(-0.2)


@pytest.mark.parametrize(
    "line, message",
    [
        ("{not json", "pred.jsonl:2: not a JSON object"),
        ('{"t_us": 5, "gesture": "none", "resting": true}', "pred.jsonl:2: missing field(s) intensity_mm"),
        ('{"t_us": 5, "gesture": "wave", "resting": true, "intensity_mm": 0}', "pred.jsonl:2: bad value"),
        ('{"t_us": 1, "gesture": "none", "resting": true, "intensity_mm": 0}', "pred.jsonl:2: t_us 1 goes back"),
    ],
)
def test_bad_prediction_lines_name_file_and_line(tmp_path, line, message):
    path = tmp_path / "pred.jsonl"
    path.write_text('{"t_us": 2, "gesture": "none", "resting": true, "intensity_mm": 0}\n' + line + "\n")
    with pytest.raises(DatasetError) as err:
        read_predictions(path)
    assert message in str(err.value)


# --- end to end on a simulated recording ------------------------------------------------------
@pytest.fixture(scope="module")
def push_dataset(sim_push_recording):
    """A quick simulated push sequence (tests/conftest.py): AEDAT4 + labels + true markers."""
    return sim_push_recording


@pytest.fixture(scope="module")
def push_tracked(push_dataset, tmp_path_factory):
    from neurotouch_hid.core.sensor import find_sensor_file
    from neurotouch_hid.pipeline.track import track_recording

    out = tmp_path_factory.mktemp("track")
    summary = track_recording(
        push_dataset, out / "pred.jsonl", find_sensor_file(push_dataset), markers_out=out / "m.npz"
    )
    return summary, read_predictions(out / "pred.jsonl"), np.load(out / "m.npz")


def test_track_finds_the_push_on_most_windows(push_dataset, push_tracked):
    from neurotouch_hid.core.dataset import read_labels

    summary, predictions, _ = push_tracked
    labels = read_labels(push_dataset.with_name(push_dataset.name.replace(".aedat4", ".labels.csv")))
    times = np.array([row.t_us for row in labels])
    assert summary.windows == len(predictions) > 100
    assert np.all(np.diff([p.t_us for p in predictions]) == 10_000)
    pushed, rested = [], []
    for p in predictions:
        i = np.searchsorted(times, p.t_us, side="right") - 1
        if i < 0:
            continue
        row = labels[i]
        if row.gesture is GestureType.PUSH and row.intensity_mm > 2.0:
            pushed.append(p.gesture is GestureType.PUSH and p.n_contacts >= 1)
        elif row.resting:
            rested.append(p.gesture is GestureType.NONE)
    assert len(pushed) > 30 and np.mean(pushed) >= 0.8
    assert len(rested) > 30 and np.mean(rested) >= 0.9


def test_track_markers_npz_follow_the_true_markers(push_dataset, push_tracked):
    _, predictions, markers = push_tracked
    truth = np.load(push_dataset.with_name(push_dataset.name.replace(".aedat4", ".markers.npz")))
    assert markers["t_us"].dtype == np.int64 and markers["positions_px"].dtype == np.float32
    np.testing.assert_array_equal(markers["t_us"], [p.t_us for p in predictions])
    n = len(markers["rest_px"])
    assert markers["positions_px"].shape == (len(predictions), n, 2)
    # every detected rest marker is a true marker (within 0.5 px)
    d = np.linalg.norm(markers["rest_px"][:, None] - truth["rest_px"][None], axis=2)
    assert d.min(axis=1).max() < 0.5
    # tracked positions stay near the true ones (nearest true marker at the same time)
    k = len(predictions) // 2
    j = int(np.argmin(np.abs(truth["t_us"] - markers["t_us"][k])))
    tracked = markers["positions_px"][k]
    tracked = tracked[np.isfinite(tracked).all(axis=1)]
    err = np.linalg.norm(tracked[:, None] - truth["positions_px"][j][None], axis=2).min(axis=1)
    assert np.median(err) < 1.0


def test_the_answered_intensity_leads_its_change_within_a_gesture_and_nothing_else(push_dataset):
    """docs/method.md, "Intensity lead": each window's intensity goes ``intensity_lead_us`` ahead along its
    change since the window before when that one had a gesture; types, contacts and the first window of
    each gesture are those of the pipeline without a lead."""
    from neurotouch_hid.core.sensor import find_sensor_file
    from neurotouch_hid.sources.recording import RecordingReader

    sensor = find_sensor_file(push_dataset)
    runs = {}
    for lead_us in (0, 3000):
        with RecordingReader(push_dataset) as reader:
            config = PipelineConfig(gesture={"intensity_lead_us": lead_us})
            runs[lead_us] = list(GesturePipeline(sensor, config).run(reader.stream()))
    plain, led = runs[0], runs[3000]
    assert [(p.t_us, p.gesture, p.n_contacts) for p in plain] == [(p.t_us, p.gesture, p.n_contacts) for p in led]
    rising = falling = 0
    for before, now, answered in zip(plain, plain[1:], led[1:]):
        if before.intensity_mm > 0 and now.intensity_mm > 0:  # two windows of one gesture
            change = now.intensity_mm - before.intensity_mm
            assert answered.intensity_mm == pytest.approx(max(0.0, now.intensity_mm + change * 0.3), abs=1e-9)
            rising += change > 0.05
            falling += change < -0.05
        else:
            assert answered.intensity_mm == now.intensity_mm
    assert rising > 3 and falling > 3  # the push's attack and release were both led
    with pytest.raises(ValueError, match="intensity_lead_us"):
        PipelineConfig(gesture={"intensity_lead_us": -1})
    with pytest.raises(ValueError, match="intensity_lead_us"):
        PipelineConfig(gesture={"intensity_lead_us": 60_000})


class _AlwaysFits(GesturePipeline):
    """The pipeline computing contacts and gesture afresh for every window (no reuse)."""

    fits = 0

    def _contacts_and_gesture(self, rest_px, current, valid):
        self.fits += 1
        return self._fit(rest_px, current, valid)


def test_windows_whose_markers_did_not_move_reuse_the_fit_with_identical_estimates(push_dataset):
    from neurotouch_hid.core.sensor import find_sensor_file
    from neurotouch_hid.sources.recording import RecordingReader

    sensor = find_sensor_file(push_dataset)
    with RecordingReader(push_dataset) as reader:
        items = list(reader.stream(batch_us=1000))
    fitted = []
    reusing = GesturePipeline(sensor)
    real_fit = reusing._fit

    def counting_fit(*args):
        fitted.append(1)
        return real_fit(*args)

    reusing._fit = counting_fit
    fresh = _AlwaysFits(sensor)
    a, b = list(reusing.run(items)), list(fresh.run(items))
    assert [json.dumps(e.to_json_dict()) for e in a] == [json.dumps(e.to_json_dict()) for e in b]
    assert fresh.fits > 100  # moving windows
    assert 0 < len(fitted) < fresh.fits  # some windows had the same markers as the one before


def test_track_on_a_street_recording_says_no_gel_and_exits_2(any_street, tmp_path):
    done = run_cli("track", str(any_street.path), "--out", str(tmp_path / "p.jsonl"))
    assert done.returncode == 2
    assert "no gel found" in done.stderr and "Traceback" not in done.stderr
    assert not (tmp_path / "p.jsonl").exists()


def test_track_command_writes_predictions_and_markers(push_dataset, push_tracked, tmp_path):
    done = run_cli(
        "track",
        str(push_dataset),
        "--out",
        str(tmp_path / "p.jsonl"),
        "--window-us",
        "5000",
        "--markers",
        str(tmp_path / "m.npz"),
    )
    assert done.returncode == 0, done.stderr
    predictions = read_predictions(tmp_path / "p.jsonl")
    assert np.all(np.diff([p.t_us for p in predictions]) == 5000)
    assert abs(len(predictions) - 2 * push_tracked[0].windows) <= 2  # twice the 10 ms windows
    assert len(np.load(tmp_path / "m.npz")["t_us"]) == len(predictions)
    assert "x real time" in done.stdout


def test_track_refuses_markers_and_predictions_under_one_name_before_it_writes(push_dataset, tmp_path):
    """Both were written to the one file: the predictions first, then the markers were refused as
    "the same file as the input", and the file held the predictions; an earlier file there was lost."""
    from neurotouch_hid.core.atomic import OutputError
    from neurotouch_hid.core.sensor import find_sensor_file
    from neurotouch_hid.pipeline.track import track_recording

    out = tmp_path / "both.npz"
    out.write_bytes(b"earlier markers")
    done = run_cli("track", str(push_dataset), "--out", str(out), "--markers", str(tmp_path / "." / "both.npz"))
    assert done.returncode == 2
    assert "the markers file is also the predictions file; give each its own name" in done.stderr, done.stderr
    assert out.read_bytes() == b"earlier markers"
    with pytest.raises(OutputError, match="the markers file is also the predictions file"):
        track_recording(
            push_dataset, tmp_path / "new.jsonl", find_sensor_file(push_dataset), markers_out=tmp_path / "new.jsonl"
        )
    assert sorted(p.name for p in tmp_path.iterdir()) == ["both.npz"]


@pytest.mark.parametrize("suffix, scale", [(".png", 2), (".gif", 1)])
def test_view_writes_a_picture_of_the_right_size(push_dataset, tmp_path, suffix, scale):
    import imageio.v3 as iio

    from neurotouch_hid.core.sensor import find_sensor_file
    from neurotouch_hid.views.pictures import render_view

    sensor = find_sensor_file(push_dataset)
    out = tmp_path / f"view{suffix}"
    drawn = render_view(push_dataset, out, sensor, scale=scale)
    assert drawn > 10 and out.stat().st_size > 1000
    pictures = iio.imread(out, index=None) if suffix == ".gif" else iio.imread(out)[None]
    assert pictures.shape[1:3] == (scale * sensor.height, scale * sensor.width)
    assert len(pictures) == (drawn if suffix == ".gif" else 1)
    assert pictures[..., :3].std() > 5  # not a blank picture


def test_a_gif_longer_than_its_bound_is_refused_and_what_was_there_is_kept(push_dataset, tmp_path, monkeypatch):
    from neurotouch_hid.core.sensor import find_sensor_file
    from neurotouch_hid.views import pictures as view

    sensor = find_sensor_file(push_dataset)
    out = tmp_path / "view.gif"
    out.write_bytes(b"an earlier view")
    monkeypatch.setattr(view, "MAX_GIF_PICTURES", 5)
    with pytest.raises(NeurotouchError, match=r"more than 5 \(0.2 s at 25 pictures a second\).*write a \.mp4"):
        view.render_view(push_dataset, out, sensor, scale=1)
    assert out.read_bytes() == b"an earlier view"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["view.gif"]


# --- a new session after the camera was lost (GesturePipeline.restart) -----------------------------
def some_events(t0_us: int, n: int = 50) -> np.ndarray:
    events = np.zeros(n, dtype=EVENT_DTYPE)
    events["timestamp"] = t0_us + np.arange(n) * 500
    events["x"], events["y"], events["polarity"] = 173, 130, 1
    return events


def test_restart_waits_for_a_frame_at_rest_then_initialises_on_it():
    pipeline = GesturePipeline(SENSOR)
    pipeline.process(Frame(0, gel_image()))
    rest = pipeline.rest_px.copy()
    assert pipeline.process(some_events(1_000))  # windows close: a running session
    pipeline.restart()
    pressed = gel_image(shift_px=(4.0, 0.0), region_px=30.0)  # the user still presses when the camera returns
    for k in range(3):
        assert pipeline.process(Frame(100_000 + 40_000 * k, pressed)) == []
        assert pipeline.tracker is None
        assert pipeline.process(some_events(110_000 + 40_000 * k)) == [], "no estimate before the markers are back"
    pipeline.process(Frame(300_000, gel_image()))  # released: at rest against the kept reference
    assert pipeline.tracker is not None
    np.testing.assert_allclose(pipeline.rest_px, rest, atol=0.05)
    estimates = pipeline.process(some_events(310_000))
    assert estimates and all(e.t_us > 310_000 for e in estimates)


def test_restart_falls_back_to_a_still_frame_when_the_old_reference_never_matches():
    from neurotouch_hid.pipeline.pipeline import RESUME_MATCH_FRAMES

    pipeline = GesturePipeline(SENSOR)
    pipeline.process(Frame(0, gel_image()))
    rest = pipeline.rest_px.copy()
    pipeline.restart()
    moved = gel_image(shift_px=(5.0, 5.0))  # e.g. the gel was re-seated while the camera was away
    for k in range(RESUME_MATCH_FRAMES):
        pipeline.process(Frame(40_000 * (k + 1), moved))
        assert pipeline.tracker is None, f"initialised on frame {k} before giving up on the reference"
    pipeline.process(Frame(40_000 * (RESUME_MATCH_FRAMES + 1), moved))  # still: unchanged from the frame before
    assert pipeline.tracker is not None
    # the new rest positions are the moved grid's (a few markers left the gel disc or entered it)
    to_moved = np.hypot(*(pipeline.rest_px[:, None, :] - (rest[None, :, :] + 5.0)).transpose(2, 0, 1)).min(axis=1)
    assert np.median(to_moved) < 0.1


def test_restart_before_any_reference_is_a_plain_start():
    pipeline = GesturePipeline(SENSOR)
    pipeline.restart()
    pipeline.process(Frame(0, gel_image(shift_px=(2.0, 0.0))))
    assert pipeline.tracker is not None


class _WindowByWindow(GesturePipeline):
    """The product's pipeline with the paper's gesture decision: each window's own type."""

    _vote = PaperPipeline._vote


def _push_then_pinch(config: PipelineConfig, rest_image, cls: type = GesturePipeline) -> list[GestureType]:
    """A two-finger pinch whose first finger leads: two weak windows where only one finger
    moved (a push), then six strong pinch windows, then a last weak window in which one finger
    lingers (a push again). Returns each window's gesture type."""
    pipeline = cls(SENSOR, config)
    pipeline.process(Frame(0, rest_image))
    pipeline.process(events_at(1))
    rest = pipeline.rest_px
    c = np.asarray(SENSOR.gel_center_px)
    f1, f2 = c + [-15.0, 0.0], c + [15.0, 0.0]
    w1 = np.exp(-np.sum((rest - f1) ** 2, axis=1) / (2 * 12.0**2))
    w2 = np.exp(-np.sum((rest - f2) ** 2, axis=1) / (2 * 12.0**2))
    frames = [rest + w1[:, None] * [3.0, 0.0]] * 2 + [rest + w1[:, None] * [8.0, 0.0] - w2[:, None] * [8.0, 0.0]] * 6
    frames += [rest + w1[:, None] * [3.0, 0.0]]
    types = []
    for k, moved in enumerate(frames):
        pipeline.tracker.reset(moved)
        (estimate,) = pipeline.process(events_at(15000 + 10000 * k))
        types.append(estimate.gesture)
    return types


def test_episode_vote_keeps_one_type_over_a_gesture_where_windows_flip(rest_image):
    """The window-by-window rule (paper) reads the lingering finger at the end as push; the
    episode vote answers pinch once the pinch outweighs the push, and keeps it."""
    base = dict(resting={"centroid_threshold_mm2": -1.0})  # never resting: only the events decide
    plain = _push_then_pinch(PipelineConfig(**base), rest_image, _WindowByWindow)
    voted = _push_then_pinch(PipelineConfig(**base), rest_image)
    P, Q = GestureType.PUSH, GestureType.PINCH
    assert plain[:2] == [P, P] and plain[2:8] == [Q] * 6 and plain[8] is P
    assert voted[:2] == [GestureType.NONE] * 2  # one contact for 10 ms: undecided
    assert voted[2:] == [Q] * 7  # committed on two contacts; the weak push at the end does not outweigh


def _lagging_pinch(
    config: PipelineConfig, rest_image: np.ndarray, cls: type = GesturePipeline
) -> list[tuple[GestureType, int]]:
    """A pinch whose first finger leads: six windows of that finger alone (a one-contact push),
    then the second finger moves towards it for five. Returns each window's (type, contacts)."""
    pipeline = cls(SENSOR, config)
    pipeline.process(Frame(0, rest_image))
    pipeline.process(events_at(1))
    rest = pipeline.rest_px
    c = np.asarray(SENSOR.gel_center_px)
    w1 = np.exp(-np.sum((rest - (c + [-15.0, 0.0])) ** 2, axis=1) / (2 * 12.0**2))[:, None]
    w2 = np.exp(-np.sum((rest - (c + [15.0, 0.0])) ** 2, axis=1) / (2 * 12.0**2))[:, None]
    frames = [rest + w1 * [k, 0.0] for k in (2.0, 4.0, 6.0, 8.0, 8.0)]
    frames += [rest + w1 * [8.0, 0.0] - w2 * [m, 0.0] for m in (4.0, 6.0, 8.0, 8.0, 8.0, 8.0)]
    out = []
    for k, moved in enumerate(frames):
        pipeline.tracker.reset(moved)
        (estimate,) = pipeline.process(events_at(15000 + 10000 * k))
        out.append((estimate.gesture, len(estimate.contacts_px)))
    return out


def test_a_lagging_finger_is_waited_for_and_the_pinch_committed_once_its_second_contact_is_seen(rest_image):
    """The first finger alone for 40 ms leaves the episode undecided (``none``); the pinch is
    answered from the window that sees the second contact on, as the window-by-window rule does."""
    base = dict(resting={"centroid_threshold_mm2": -1.0})
    plain = _lagging_pinch(PipelineConfig(**base), rest_image, _WindowByWindow)
    first_pinch = next(k for k, (g, _) in enumerate(plain) if g is GestureType.PINCH)
    assert {g for g, _ in plain[:first_pinch]} == {GestureType.PUSH}
    assert {n for _, n in plain[:first_pinch]} == {1} and plain[first_pinch][1] == 2
    assert {g for g, _ in plain[first_pinch:]} == {GestureType.PINCH}
    voted = _lagging_pinch(PipelineConfig(**base), rest_image)
    assert [g for g, _ in voted] == [GestureType.NONE] * first_pinch + [g for g, _ in plain[first_pinch:]]


def test_the_one_correction_needs_more_contacts_than_before_and_comes_once():
    """Correction rule of ``EpisodeVote``: a push committed on two contacts is kept against a
    pinch window with two; a third contact, within the correction time, is answered at once; a
    second correction is not taken, nor one after the correction time."""
    P, Q, Z, T = GestureType.PUSH, GestureType.PINCH, GestureType.ZOOM, GestureType.TWIST_CW
    vote = EpisodeVote()
    # (push on two contacts commits from the second window that sees them: test_type_commitment.py)
    got = [vote.update(P, 5.0, 2, 10_000), vote.update(P, 5.0, 2, 20_000), vote.update(Q, 1.0, 2, 30_000)]
    assert got == [GestureType.NONE, P, P]
    assert vote.update(Q, 1.0, 3, 40_000) is Q and vote.update(P, 0.5, 3, 50_000) is Q  # the 10 mm of push are gone
    assert vote.update(T, 0.5, 4, 60_000) is Q  # a second correction is not taken
    vote.update(GestureType.NONE, 0.0, 0, 70_000)
    assert vote.update(Z, 5.0, 2, 200_000) is Z
    assert vote.update(T, 1.0, 3, 200_000 + vote.correction_us + 10_000) is Z  # too late to correct


def _calibrated(points_px) -> SensorGeometry:
    return dataclasses.replace(SENSOR, extra={"rest_markers_px": np.asarray(points_px).tolist()})


def test_a_run_that_starts_pressed_waits_for_the_calibrated_rest_layout(rest_image):
    """The paper's rule takes the first frame as rest even when the gel is pressed; then the real
    rest reads as a gesture. With the calibrated layout the pressed frames are refused and the
    first frame at rest becomes the reference."""
    from neurotouch_hid.pipeline.markers import detect_markers

    layout = detect_markers(rest_image, SENSOR, None).centroids_px
    pressed = gel_image(shift_px=(4.0, 0.0), region_px=30.0)
    old = PaperPipeline(_calibrated(layout))
    old.process(Frame(0, pressed))
    assert old.rest_px is not None and np.abs(old.rest_px[:, None] - layout[None]).sum(-1).min(1).max() > 3.0
    new = GesturePipeline(_calibrated(layout))
    for k in range(3):
        assert new.process(Frame(40_000 * k, pressed)) == [] and new.rest_px is None
    assert new.pressed_frames == 3
    new.process(Frame(120_000, rest_image))
    assert new.rest_px is not None
    np.testing.assert_allclose(np.sort(new.rest_px, axis=0), np.sort(layout, axis=0), atol=0.05)


def test_a_gel_still_off_its_calibration_is_taken_after_a_while(rest_image):
    """A gel that moved since calibration (every marker 3 px off) must not stop the driver: once
    RESUME_MATCH_FRAMES frames were refused, an unchanged frame is taken."""
    from neurotouch_hid.pipeline.markers import detect_markers
    from neurotouch_hid.pipeline.pipeline import RESUME_MATCH_FRAMES

    layout = detect_markers(rest_image, SENSOR, None).centroids_px + [3.0, 0.0]
    pipeline = GesturePipeline(_calibrated(layout))
    k = 0
    while pipeline.rest_px is None and k < RESUME_MATCH_FRAMES + 5:
        pipeline.process(Frame(40_000 * k, rest_image))
        k += 1
    assert (
        pipeline.rest_px is not None and k == RESUME_MATCH_FRAMES + 1 and pipeline.pressed_frames == RESUME_MATCH_FRAMES
    )


def test_pixel_settings_follow_px_per_mm_on_a_closer_camera():
    """A camera at 4 px/mm (a 4 mm pitch is 16 px): in fixed pixels the contact radius of 25 px
    would be 6 mm, whose neighbourhood never holds n_min markers; following px_per_mm, r is
    40 px = 10 mm on the gel again, and a clear push is found."""
    from neurotouch_hid.pipeline.config import scaled_to_sensor
    from neurotouch_hid.pipeline.tracker import BlobTracker

    sensor = SensorGeometry(px_per_mm=4.0, gel_radius_px=120.0)
    c = np.asarray(sensor.gel_center_px)
    k = np.arange(-7, 8) * 16.0
    rest = np.stack(np.meshgrid(k, k), axis=-1).reshape(-1, 2) + c
    rest = rest[np.hypot(*(rest - c).T) <= 7.2 * 16.0]
    img = np.full((sensor.height, sensor.width), 20.0)
    yy, xx = np.mgrid[-6:7, -6:7]
    for x, y in rest:
        ix, iy = int(round(x)), int(round(y))
        img[iy - 6 : iy + 7, ix - 6 : ix + 7] += 220 * np.exp(-((xx + ix - x) ** 2 + (yy + iy - y) ** 2) / (2 * 1.4**2))
    image = np.clip(img, 0, 255).astype(np.uint8)
    pipeline = _WindowByWindow(sensor, PipelineConfig(resting={"centroid_threshold_mm2": -1.0}))  # own types
    pipeline.process(Frame(0, image))
    pipeline.process(events_at(1))
    assert len(pipeline.rest_px) == len(rest)
    w = np.exp(-np.sum((pipeline.rest_px - c) ** 2, axis=1) / (2 * 28.0**2))  # a 7 mm finger, 5 mm push
    pipeline.tracker.reset(pipeline.rest_px + (w * 20.0)[:, None] * [1.0, 0.0])
    (estimate,) = pipeline.process(events_at(15000))
    assert estimate.gesture is GestureType.PUSH and estimate.n_contacts == 1
    assert scaled_to_sensor(PipelineConfig(), sensor).r_px == pytest.approx(25.0 * 4.0 / 2.5)
    assert scaled_to_sensor(PipelineConfig(), SENSOR).r_px == 25.0  # 10 mm at 2.5 px/mm
    # the tracker's gates follow it too: 1.6 mm association radius = 6.4 px here, 4 px at 2.5
    assert pipeline.tracker.pixels.assoc_px == pytest.approx(1.6 * pipeline.sensor.px_per_mm)
    assert BlobTracker(rest, sensor=SENSOR).pixels.assoc_px == 4.0


def pinch_with_slip(rest_px: np.ndarray, slip_px=(3.0, 0.0), turn_rad=0.0) -> np.ndarray:
    """Two fingers 16 px either side of the gel centre closing by 2.5 px each (Gaussian falloff,
    sigma 8 px: the rim stays), then the whole gel slid by ``slip_px`` and turned by
    ``turn_rad`` about its centre in its mount."""
    c = np.asarray(SENSOR.gel_center_px)
    moved = rest_px.copy()
    for side in (-1.0, 1.0):
        finger = c + [side * 16.0, 0.0]
        w = np.exp(-np.sum((rest_px - finger) ** 2, axis=1) / (2 * 8.0**2))
        moved += w[:, None] * [-side * 2.5, 0.0]
    cos, sin = np.cos(turn_rad), np.sin(turn_rad)
    return (moved - c) @ np.array([[cos, -sin], [sin, cos]]).T + c + slip_px


@pytest.mark.parametrize("slip, turn", [((3.0, 0.0), 0.0), ((-2.0, 2.0), 0.02)])
def test_a_pinch_on_a_gel_that_slid_in_its_mount_stays_a_pinch(rest_image, slip, turn):
    """The ``drift`` family: the whole gel slides 1.2 mm (3 px) with a pinch. The paper's rule
    fits one similarity to the markers round the contacts: the slide would be its largest term, a
    push. With the rim's rigid motion removed first the pinch is what is left; the contact
    points stay where the markers are (the slide included) and the intensity is their tracked
    displacement (the slide included, as the labels count it)."""
    answers = {}
    # this finger field (sigma 8 px) is narrower than a marker pitch: its peak marker stands
    # alone above its neighbours, which the lone-marker rule takes for a mistracked marker
    # unless its fraction is tiny; that rule is not what is tested here
    pipeline = GesturePipeline(SENSOR, PipelineConfig(contacts={"spike_fraction": 0.01}))
    pipeline.process(Frame(0, rest_image))
    pipeline.process(events_at(1))
    pipeline.tracker.reset(pinch_with_slip(pipeline.rest_px, slip, turn))
    (answers[True],) = pipeline.process(events_at(15000))
    assert answers[True].gesture is GestureType.PINCH
    c = np.asarray(SENSOR.gel_center_px)
    rest_fingers = np.array([c - [16.0, 0.0], c + [16.0, 0.0]])
    truth = pinch_with_slip(rest_fingers, slip, turn)  # the fingers' markers, the slide included
    label_mm = np.hypot(*(truth - rest_fingers).T).mean() / SENSOR.px_per_mm  # as the labels count it
    assert answers[True].intensity_mm == pytest.approx(label_mm, abs=0.1)
    assert answers[True].n_contacts == 2
    for point in answers[True].contacts_px:  # the fingers lie between markers: within 0.4 pitch
        assert min(np.hypot(*(point - t)) for t in truth) < 4.0


def test_gel_motion_is_read_off_the_rim_and_undone():
    from neurotouch_hid.pipeline.gel_motion import estimate_gel_motion, rim_markers

    k = np.arange(-7, 8) * 10.0
    rest = np.stack(np.meshgrid(k, k), axis=-1).reshape(-1, 2) + SENSOR.gel_center_px
    rest = rest[SENSOR.inside_gel(rest, margin_px=-4.0)]
    moved = pinch_with_slip(rest, (2.0, -1.0), 0.015)
    rim = rim_markers(rest, SENSOR.gel_center_px)
    assert 30 <= rim.sum() <= 90
    motion = estimate_gel_motion(rest, moved, None, rim, SENSOR.gel_center_px)
    assert motion.rotation_rad == pytest.approx(0.015, abs=2e-3)
    np.testing.assert_allclose(motion.translation_px, [2.0, -1.0], atol=0.1)
    np.testing.assert_allclose(motion.apply(motion.remove(moved)), moved, atol=1e-9)
    # far from the fingers, the gel is back at rest once the slide is removed
    far = np.hypot(*(rest - SENSOR.gel_center_px).T) > 50
    np.testing.assert_allclose(motion.remove(moved)[far], rest[far], atol=0.15)


def test_a_push_whose_field_reaches_the_rim_is_not_taken_for_a_slip():
    """A wide push (sigma 30 px) drags the near rim by ~1.2 px and the far rim by ~0.1 px: the
    rim's fitted motion is mostly the push's own tail, of which only the part every rim marker
    shares is removed; a slip moves every rim marker alike and is removed whole."""
    from neurotouch_hid.pipeline.gel_motion import estimate_gel_motion, rim_markers

    k = np.arange(-7, 8) * 10.0
    rest = np.stack(np.meshgrid(k, k), axis=-1).reshape(-1, 2) + SENSOR.gel_center_px
    rest = rest[SENSOR.inside_gel(rest, margin_px=-4.0)]
    finger = np.asarray(SENSOR.gel_center_px) + [20.0, 0.0]
    w = np.exp(-np.sum((rest - finger) ** 2, axis=1) / (2 * 30.0**2))
    pushed = rest + w[:, None] * [6.0, 0.0]
    rim = rim_markers(rest, SENSOR.gel_center_px)
    assert np.ptp(np.hypot(*(pushed - rest)[rim].T)) > 1.0  # the rim moves unevenly
    motion = estimate_gel_motion(rest, pushed, None, rim, SENSOR.gel_center_px)
    assert motion is not None  # the rim moved: a fit, of which little is shared
    assert np.hypot(*motion.translation_px) <= 0.3 and abs(motion.rotation_rad) < 2e-3  # <= 5 % of the push
    assert estimate_gel_motion(rest, rest + 0.05, None, rim, SENSOR.gel_center_px) is None  # below the noise
    slid = estimate_gel_motion(rest, pushed + [0.0, 2.0], None, rim, SENSOR.gel_center_px)
    assert slid.translation_px[1] == pytest.approx(2.0, abs=0.1)


def test_a_frame_near_rest_re_anchors_a_drifted_tracker_without_calling_it_rest(rest_image):
    """After a long gesture the tracker carries its own error (here a bump of up to 2 px round
    the centre) while the gel creeps back: a frame 0.5 px off rest on a few markers
    (centroid distance 0.03: above the resting threshold 0.01, so not at rest, as the labels say)
    left that error standing and the windows after it read a gesture; re-anchoring the tracker
    near rest (centroid_reset_threshold 0.05) reads them as none, still not resting; with the
    re-anchoring threshold below that frame's distance (0.02) they read a gesture. The frame
    before shows the gel further pressed: the press is relaxing, not growing from rest."""
    near = gel_image((0.5, 0.0), region_px=15)
    answers = {}
    for reset in (0.02, 0.05):
        config = PipelineConfig(resting={"centroid_reset_threshold_mm2": reset / 6.25})
        pipeline = _WindowByWindow(SENSOR, config)  # each window's own type: no undecided start
        pipeline.process(Frame(0, rest_image))
        pipeline.process(events_at(1))
        pipeline.process(Frame(20_000, gel_image((1.0, 0.0), region_px=15)))
        pipeline.process(events_at(21_000))
        w = np.exp(-np.sum((pipeline.rest_px - SENSOR.gel_center_px) ** 2, axis=1) / (2 * 12.0**2))
        pipeline.tracker.reset(pipeline.rest_px + w[:, None] * [2.0, 0.0])
        pipeline.process(Frame(40_000, near))
        assert not pipeline.resting.resting and 0.02 < pipeline.resting.distance <= 0.05
        answers[reset] = pipeline.process(events_at(45_000))
    assert [(e.resting, e.gesture) for e in answers[0.05]] == [(False, GestureType.NONE)]
    assert answers[0.02][0].gesture is not GestureType.NONE and not answers[0.02][0].resting


def test_the_smooth_override_median_ignores_lost_markers_as_nanmedian_does():
    from neurotouch_hid.pipeline.override import _median_of_sorted

    rng = np.random.default_rng(7)
    values = rng.normal(size=(60, 5, 2))
    values[rng.random(values.shape) < 0.3] = np.nan
    values[4] = np.nan  # every neighbour lost: not moved
    with np.errstate(all="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        expected = np.nan_to_num(np.nanmedian(values, axis=1))
    np.testing.assert_allclose(_median_of_sorted(np.sort(values, axis=1)), expected)


def test_a_window_where_nothing_moved_min_intensity_skips_the_fits(rest_image):
    """Not at rest, but no tracked marker 0.3 px (min_intensity_px) from rest: the intensity is
    below the minimum whatever the contacts, so the window answers none (not resting) without a
    homography; once a finger moves the markers the fits run again."""
    pipeline = _WindowByWindow(SENSOR)  # each window's own type: no undecided start
    pipeline.process(Frame(0, rest_image))
    pipeline.process(Frame(40_000, gel_image((4.0, 0.0), region_px=30)))
    assert not pipeline.resting.resting
    pipeline.process(events_at(41_000))  # the windows start
    pipeline.tracker.reset(pipeline.rest_px + [0.2, 0.0])
    assert [(e.resting, e.gesture) for e in pipeline.process(events_at(51_000))] == [(False, GestureType.NONE)]
    assert pipeline._last_fit is None  # no contact or gesture fit was made
    w = np.exp(-np.sum((pipeline.rest_px - SENSOR.gel_center_px) ** 2, axis=1) / (2 * 12.0**2))
    pipeline.tracker.reset(pipeline.rest_px + w[:, None] * [5.0, 0.0])
    (estimate,) = pipeline.process(events_at(61_000))
    assert estimate.gesture is GestureType.PUSH and pipeline._last_fit is not None


def test_a_press_remembers_a_long_flat_top_until_it_ends(rest_image):
    """Two fingertips side by side make a long flat top, then pressed deep a round one that reads
    as one fingertip alone: the press keeps them two. A window without a gesture ends the press,
    and the next press's round flat top is one fingertip (docs/method.md, "Contacts")."""
    pipeline = _WindowByWindow(SENSOR)
    pipeline.process(Frame(0, rest_image))
    pipeline.process(Frame(40_000, gel_image((4.0, 0.0), region_px=30)))
    pipeline.process(events_at(41_000))  # the windows start
    rest, c = pipeline.rest_px, np.asarray(SENSOR.gel_center_px, dtype=float)

    def flat_top(radius_px: float, long: float = 1.0) -> np.ndarray:
        d = np.hypot((rest[:, 0] - c[0]) / long, rest[:, 1] - c[1])
        fall = np.where(d <= radius_px, 1.0 - 0.05 * d / radius_px, 0.95 * np.exp(-((d - radius_px) ** 2) / 200.0))
        return rest + fall[:, None] * [6.0, 0.0]

    counts = []
    for t_us, current in enumerate((flat_top(24.0, 1.6), flat_top(26.0), rest + 0.1, flat_top(26.0))):
        pipeline.tracker.reset(current)
        (estimate,) = pipeline.process(events_at(51_000 + 10_000 * t_us))
        counts.append((estimate.gesture is GestureType.NONE, len(estimate.contacts_px)))
    assert counts == [(False, 2), (False, 2), (True, 0), (False, 1)]


def test_a_press_hands_each_window_s_held_maxima_to_the_next_until_it_ends(rest_image, monkeypatch):
    """The maxima a window holds (:attr:`Contacts.held`) reach the next window of the same press,
    whether its fit is computed or reused, and no window after the press ends (docs/method.md,
    "Contacts": a finger held where the homography follows it)."""
    from neurotouch_hid.pipeline import fit_path

    heard, said, real = [], [], fit_path.detect_contacts

    def detect(*args, **kwargs):
        heard.append(kwargs["held"])
        contacts = real(*args, **kwargs)
        said.append(contacts.held)
        return contacts

    monkeypatch.setattr(fit_path, "detect_contacts", detect)
    pipeline = _WindowByWindow(SENSOR)
    pipeline.process(Frame(0, rest_image))
    pipeline.process(Frame(40_000, gel_image((4.0, 0.0), region_px=30)))
    pipeline.process(events_at(41_000))  # the windows start
    rest, c = pipeline.rest_px, np.asarray(SENSOR.gel_center_px, dtype=float)
    push = rest + np.exp(-np.sum((rest - c) ** 2, axis=1) / 300.0)[:, None] * [6.0, 0.0]
    for k, current in enumerate((push, push + [0.02, 0.0], rest + 0.1, push)):
        pipeline.tracker.reset(current)
        pipeline.process(events_at(51_000 + 10_000 * k))
    assert len(heard) == 3  # the window at rest is no fit
    assert heard[0] is None and heard[2] is None  # a press's first window holds nothing
    assert len(said[0][0]) == 1 and heard[1] is said[0]


def _numba_signatures() -> dict[str, int]:
    """Compiled signatures per numba function of the pipeline's modules."""
    import numba

    from neurotouch_hid.pipeline import contacts, contacts_held, gesture, learned, noise, resting, tracker

    return {
        f"{m.__name__}.{name}": len(f.signatures)
        for m in (contacts, contacts_held, gesture, learned, noise, resting, tracker)
        for name, f in vars(m).items()
        if isinstance(f, numba.core.registry.CPUDispatcher)
    }


def test_compile_kernels_leaves_nothing_to_compile_on_real_gestures(rest_image):
    """A run compiles while it starts, not mid-gesture (where it would drop events): after
    compile_kernels, a push, a wide flat top, a lone mistracked marker, a pinch and a three-finger
    twist compile nothing."""
    pipeline = GesturePipeline(SENSOR)
    pipeline.compile_kernels()
    compiled = _numba_signatures()
    pipeline.process(Frame(0, rest_image))
    pipeline.process(events_at(1))
    rest = pipeline.rest_px
    c = np.asarray(SENSOR.gel_center_px)
    for width_px, peak_px in ((8.0, 3.0), (30.0, 4.0), (12.0, 5.0)):
        w = np.exp(-np.sum((rest - c) ** 2, axis=1) / (2 * width_px**2))
        moved = rest + np.minimum(1.0, 1.5 * w)[:, None] * [peak_px, 1.0]
        moved[7] += (6.0, 0.0)
        pipeline.tracker.reset(moved)
        pipeline.process(events_at(15000 * int(peak_px)))
    sides = [np.exp(-np.sum((rest - c - (dx, 0.0)) ** 2, axis=1) / (2 * 10.0**2))[:, None] for dx in (-25.0, 25.0)]
    pipeline.tracker.reset(rest + (sides[0] - sides[1]) * [5.0, 1.0])  # a pinch: the bump fit of its centres
    pipeline.process(events_at(90_000))
    assert pipeline._last_fit[4].count == 2
    twist = rest.copy()
    for angle in np.radians([30.0, 150.0, 270.0]):  # three fingers: the fit of their centres
        finger = np.exp(-np.sum((rest - c - 40.0 * np.array([np.cos(angle), np.sin(angle)])) ** 2, axis=1) / 242.0)
        twist += finger[:, None] * 4.0 * np.array([-np.sin(angle), np.cos(angle)])
    pipeline.tracker.reset(twist)
    pipeline.process(events_at(95_000))
    assert pipeline._last_fit[4].count == 3
    pipeline.process(Frame(100_000, rest_image))  # the resting detector's kernels
    assert _numba_signatures() == compiled


def test_the_window_checks_before_a_fit_match_numpy():
    from neurotouch_hid.pipeline.pipeline import _largest_move_sq, _unchanged

    rng = np.random.default_rng(9)
    rest = rng.uniform(50.0, 300.0, size=(177, 2))
    for trial in range(20):
        current = rest + rng.normal(scale=[0.01, 0.3, 3.0, 30.0][trial % 4], size=rest.shape)
        valid = rng.random(177) > [0.0, 0.2, 0.9, 1.0][trial % 4]
        if trial % 5 == 4:
            current[rng.integers(177)] = np.nan
        d = current[valid] - rest[valid]
        moved_sq = d[:, 0] * d[:, 0] + d[:, 1] * d[:, 1]
        largest = _largest_move_sq(current, valid, rest)
        if not valid.any():
            assert largest == -1.0
        elif np.isnan(moved_sq).any():
            assert np.isnan(largest)
        else:
            assert largest == moved_sq.max()
        same = current.copy()
        assert _unchanged(same, current, valid.copy(), valid) == (not np.isnan(current).any())
        same[trial % 177, trial % 2] += 1e-9
        assert not _unchanged(same, current, valid, valid)
        flipped = valid.copy()
        flipped[0] = not flipped[0]
        assert not _unchanged(current.copy(), current, flipped, valid)  # a marker lost or found


def _held_and_lagging(
    config: PipelineConfig, rest_image: np.ndarray, frame_image: np.ndarray, before: np.ndarray | None = None
) -> tuple:
    """A pipeline whose blobs lag: the markers within 30 px of the centre are held 3 px right,
    the blobs still 0.6 px short of them (a held gesture makes no events that would move them
    on); then the APS frame ``frame_image`` arrives, after the frame ``before`` when given.
    Returns (rest, the markers within 30 px, blobs after the frame)."""
    pipeline = GesturePipeline(SENSOR, config)
    pipeline.process(Frame(0, rest_image))
    pipeline.process(events_at(1))
    if before is not None:
        pipeline.process(Frame(20_000, before))
        pipeline.process(events_at(21_000))
    rest = pipeline.rest_px
    near = np.hypot(*(rest - SENSOR.gel_center_px).T) <= 30.0
    pipeline.tracker.reset(rest + near[:, None] * [2.4, 0.0])
    pipeline.process(events_at(30_000))
    pipeline.process(Frame(40_000, frame_image))
    return rest, near, pipeline.tracker.positions_px.copy()


def test_frame_correction_brings_lagging_blobs_onto_the_markers_the_frame_shows(rest_image):
    """Events only (paper), a held marker's blob stays where its last events left it (0.6 px
    short here); the APS frame's centroids (the resting detector's) pull it onto the marker:
    the error falls under 0.2 px, and the still markers stay put."""
    held = gel_image(shift_px=(3.0, 0.0), region_px=30.0)
    rest, near, fused = _held_and_lagging(PipelineConfig(), rest_image, held)
    truth = rest + near[:, None] * [3.0, 0.0]
    assert np.abs(fused[near] - truth[near]).max() < 0.2
    assert np.abs(fused[~near] - rest[~near]).max() < 0.05


def test_a_frame_near_rest_re_anchors_the_blobs_and_is_not_fused_back(rest_image):
    """A frame near rest (``centroid_reset_threshold``) after a deeper one (a release) re-anchors
    the tracker at the rest positions; its own centroids, a few tenths of a pixel off, must not
    then pull the blobs away again (the frame correction is for frames that are not near rest)."""
    almost = gel_image(shift_px=(0.3, 0.0), region_px=30.0)  # Chamfer ~0.03 px^2: not resting, near rest
    deeper = gel_image(shift_px=(1.0, 0.0), region_px=30.0)
    rest, _, after = _held_and_lagging(PipelineConfig(), rest_image, almost, before=deeper)
    assert np.array_equal(after, rest)


def test_a_frame_near_rest_whose_press_grows_from_rest_corrects_the_blobs(rest_image):
    """A frame near rest straight after the gel rested: a press growing from rest, 0.3 px
    (0.12 mm) on a patch of markers, beyond ``press_mm`` (0.1 mm), whose blobs the events have
    moved 0.1 px so far. Re-anchored, the attack's first displacement would be wiped at every
    frame; the frame corrects the blobs instead, towards the markers it shows, and the verdict
    stays "not at rest". With ``press_mm`` 0.2 mm the same frame re-anchors them."""
    almost = gel_image(shift_px=(0.3, 0.0), region_px=30.0)
    after = {}
    for press_mm in (0.1, 0.2):
        pipeline = GesturePipeline(SENSOR, PipelineConfig(resting={"press_mm": press_mm}))
        pipeline.process(Frame(0, rest_image))
        pipeline.process(events_at(1))
        rest = pipeline.rest_px
        near = np.hypot(*(rest - SENSOR.gel_center_px).T) <= 30.0
        pipeline.tracker.reset(rest + near[:, None] * [0.1, 0.0])
        pipeline.process(events_at(30_000))
        pipeline.process(Frame(40_000, almost))
        pipeline.process(events_at(41_000))
        assert not pipeline.resting.resting
        after[press_mm] = pipeline.tracker.positions_px - rest
    assert np.all(after[0.1][near, 0] > 0.2) and np.abs(after[0.1][~near]).max() < 0.05
    assert np.array_equal(after[0.2], np.zeros_like(rest))


def test_the_resting_verdict_carries_the_frames_marker_centroids_in_the_image_frame(rest_image):
    from neurotouch_hid.pipeline.markers import detect_markers
    from neurotouch_hid.pipeline.resting import RestingDetector

    moved = gel_image(shift_px=(2.0, 1.0), region_px=30.0)
    verdict = RestingDetector(rest_image, SENSOR).update(moved)  # the product's: centroids
    markers = detect_markers(moved, SENSOR).centroids_px
    assert not verdict.resting and len(verdict.centroids_px) == len(markers)
    d = np.hypot(*(verdict.centroids_px[:, None] - markers[None]).transpose(2, 0, 1)).min(axis=1)
    assert d.max() < 0.1
    pixel_sets = RestingDetector(rest_image, SENSOR, 2.5, centroids=False)
    assert pixel_sets.update(moved).centroids_px is None


def test_a_frame_puts_blobs_left_on_their_neighbours_markers_back_on_their_own(rest_image):
    pipeline = GesturePipeline(SENSOR)
    pipeline.process(Frame(0, rest_image))
    pressed = gel_image((4.0, 0.0), region_px=30)
    pipeline.process(Frame(40000, pressed))
    assert not pipeline.resting.resting  # the frame corrects the blobs, it does not re-anchor them
    rest = pipeline.rest_px
    shifted = rest + np.where((np.hypot(*(rest - SENSOR.gel_center_px).T) <= 30)[:, None], [4.0, 0.0], 0.0)
    # a chain of three blobs in a row near the centre, each on the next marker along (+x, 10 px)
    centre = np.argmin(np.hypot(*(rest - SENSOR.gel_center_px).T))
    row = [int(np.argmin(np.hypot(*(rest - rest[centre] - [10.0 * k, 0.0]).T))) for k in range(-1, 3)]
    left = shifted.copy()
    left[row[:3]] = shifted[row[1:]]
    pipeline.tracker.reset(left)
    pipeline.process(Frame(80000, pressed))
    np.testing.assert_allclose(pipeline.marker_positions()[row[:3]], shifted[row[:3]], atol=0.5)
