"""GesturePipeline: its windows, the first frame as the rest reference, the resting verdicts and the
motion override, a restart, and the errors it raises (paper, section "Methodology")."""

from __future__ import annotations

import dataclasses
import threading
import warnings

import numpy as np
import pipeline_helpers
import pytest
from pipeline_helpers import SENSOR, _WindowByWindow, events_at, gel_image

from neurotouch_hid.core.errors import SensorError
from neurotouch_hid.core.estimate import GestureType
from neurotouch_hid.pipeline.paper import PaperPipeline
from neurotouch_hid.pipeline.pipeline import GesturePipeline, PipelineConfig
from neurotouch_hid.pipeline.resting import RestingResult
from neurotouch_hid.sources import EVENT_DTYPE, Frame

rest_image = pipeline_helpers.rest_image  # a shared fixture, found by pytest under this name


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
