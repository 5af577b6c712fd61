"""GesturePipeline on a gel that is not where it was: a start on a pressed or moved gel against its
calibration, a closer camera, a gel sliding in its mount, a drifted tracker re-anchored, and
frames correcting lagging blobs (docs/method.md)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pipeline_helpers
import pytest
from pipeline_helpers import SENSOR, _WindowByWindow, events_at, gel_image

from neurotouch_hid.core.estimate import GestureType
from neurotouch_hid.core.sensor import SensorGeometry
from neurotouch_hid.pipeline.paper import PaperPipeline
from neurotouch_hid.pipeline.pipeline import GesturePipeline, PipelineConfig
from neurotouch_hid.sources import Frame

rest_image = pipeline_helpers.rest_image  # a shared fixture, found by pytest under this name


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
