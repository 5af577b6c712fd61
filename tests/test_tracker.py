"""The event-blob tracker (paper, section Marker Tracking) on hand-made event streams whose true
blob positions are known: a tiny ESIM-like generator renders white dots on black and emits an
event each time a pixel's log intensity crosses a contrast threshold."""

import numpy as np
import pytest

from neurotouch_hid.core.sensor import SensorGeometry
from neurotouch_hid.pipeline.contacts_plateau import rest_neighbours
from neurotouch_hid.pipeline.tracker import (
    SWAP_FOUND_PITCHES,
    SWAP_PITCHES,
    BlobTracker,
    TrackerConfig,
    _suspects,
    swapped_blobs,
)
from neurotouch_hid.sources import EVENT_DTYPE

SENSOR = SensorGeometry()


def render(centres, xs, ys, radius=1.25, background=0.05):
    """Intensity (0..1) of white discs with a 1 px linear edge on a dark background."""
    img = np.full(xs.shape, background)
    for cx, cy in centres:
        d = np.hypot(xs - cx, ys - cy)
        img = np.maximum(img, background + (1 - background) * np.clip(radius + 0.5 - d, 0, 1))
    return img


def esim(trajectory, t_end_us, box, step_us=20, contrast=0.25, seed=0):
    """Events (EVENT_DTYPE, time-ordered) of dots at ``trajectory(t_us) -> (N, 2)`` px, in the
    pixel box (x0, y0, x1, y1), from t = 0 to ``t_end_us``."""
    x0, y0, x1, y1 = box
    ys, xs = np.mgrid[y0:y1, x0:x1].astype(float)
    ref = np.log(render(trajectory(0), xs, ys))
    rng = np.random.default_rng(seed)
    out = []
    for t in range(step_us, t_end_us + 1, step_us):
        diff = np.log(render(trajectory(t), xs, ys)) - ref
        n = np.floor(np.abs(diff) / contrast).astype(int)
        iy, ix = np.nonzero(n)
        if not len(iy):
            continue
        cnt = n[iy, ix]
        ev = np.zeros(cnt.sum(), EVENT_DTYPE)
        ev["x"] = np.repeat(ix, cnt) + x0
        ev["y"] = np.repeat(iy, cnt) + y0
        ev["polarity"] = np.repeat(diff[iy, ix] > 0, cnt)
        ev["timestamp"] = t - step_us + rng.integers(0, step_us, len(ev))
        ref[iy, ix] += np.sign(diff[iy, ix]) * cnt * contrast
        out.append(ev)
    ev = np.concatenate(out)
    return ev[np.argsort(ev["timestamp"], kind="stable")]


def run(tracker, events, t_end_us, step_us=1000):
    """Feed events in ``step_us`` batches; positions (T, N, 2) after each batch and batch end times."""
    ends = np.arange(step_us, t_end_us + 1, step_us)
    cuts = np.searchsorted(events["timestamp"], ends)
    out, start = [], 0
    for cut in cuts:
        tracker.update(events[start:cut])
        start = cut
        out.append(tracker.positions_px)
    return np.array(out), ends


def linear(p0, v_px_per_ms):
    p0 = np.atleast_2d(np.asarray(p0, float))
    v = np.atleast_2d(np.asarray(v_px_per_ms, float))
    return lambda t: p0 + v * (t / 1000.0)


@pytest.mark.parametrize("velocity", [(0.05, 0.03), (0.1, 0.05)])
def test_dot_at_constant_velocity_is_tracked_within_half_a_pixel(velocity):
    # Speeds of the simulated gestures' markers (up to ~0.15 px/ms).
    p0 = (150.3, 120.6)
    truth = linear(p0, velocity)
    t_end = 100_000
    events = esim(truth, t_end, (120, 95, 180, 145))
    tracker = BlobTracker(np.array([p0]))
    positions, ends = run(tracker, events, t_end)
    err = np.linalg.norm(positions[:, 0] - np.array([truth(t)[0] for t in ends]), axis=1)
    assert np.linalg.norm(truth(t_end)[0] - p0) > 5  # it really moved
    assert np.median(err) < 0.5
    assert err.max() < 0.75
    assert tracker.valid.all()
    v = tracker.velocities_px_per_s[0] / 1000.0
    assert np.dot(v, velocity) > 0  # the velocity estimate points along the motion


def test_fast_dot_stays_locked():
    # 0.36 px/ms, faster than any simulated gesture: the blob lags a little but keeps its marker.
    p0 = (150.3, 120.6)
    truth = linear(p0, (-0.3, 0.2))
    t_end = 60_000
    events = esim(truth, t_end, (115, 95, 175, 150))
    tracker = BlobTracker(np.array([p0]))
    positions, ends = run(tracker, events, t_end)
    err = np.linalg.norm(positions[:, 0] - np.array([truth(t)[0] for t in ends]), axis=1)
    assert np.linalg.norm(truth(t_end)[0] - p0) > 20
    assert err.max() < 1.5
    assert tracker.valid.all()


def test_neighbouring_blobs_do_not_swap():
    # Two markers 9 px apart; the left one moves 4 px towards the right one and back, the right
    # one drifts down; a third stays still 9 px below the left one.
    a0, b0, c0 = np.array([150.2, 120.4]), np.array([159.1, 120.7]), np.array([150.6, 129.5])

    def truth(t):
        s = t / 1000.0
        a = a0 + np.array([4.0 * np.sin(np.pi * s / 100.0), 0.0])
        b = b0 + np.array([0.0, 0.04 * s])
        return np.array([a, b, c0])

    t_end = 100_000
    events = esim(truth, t_end, (135, 105, 175, 145))
    tracker = BlobTracker(truth(0))
    positions, ends = run(tracker, events, t_end)
    true = np.array([truth(t) for t in ends])
    err = np.linalg.norm(positions - true, axis=2)
    # Each blob stays with its own marker: nearer to it than half the spacing, every millisecond.
    assert err.max() < 2.0
    assert np.median(err) < 0.5
    assert tracker.valid.all()


def test_noise_far_from_blobs_does_not_move_them():
    rng = np.random.default_rng(1)
    start = np.array([[150.3, 120.6], [160.2, 120.1], [155.0, 131.4]])
    tracker = BlobTracker(start)
    n = 200_000
    noise = np.zeros(n, EVENT_DTYPE)
    noise["timestamp"] = np.sort(rng.integers(0, 1_000_000, n))
    noise["x"] = rng.integers(0, 346, n)
    noise["y"] = rng.integers(0, 260, n)
    noise["polarity"] = rng.integers(0, 2, n)
    d = np.min(np.hypot(noise["x"][:, None] - start[None, :, 0], noise["y"][:, None] - start[None, :, 1]), axis=1)
    far = noise[d > 6.0]
    tracker.update(far)
    assert np.array_equal(tracker.positions_px, start)
    assert tracker.counts["noise"] == len(far)
    assert tracker.counts["applied"] == 0


def test_isolated_noise_events_near_a_resting_blob_are_gated():
    # Background activity at ~20 Hz per pixel around a blob at rest: isolated in time per blob.
    start = np.array([[150.3, 120.6]])
    tracker = BlobTracker(start)
    rng = np.random.default_rng(2)
    n = 400
    ev = np.zeros(n, EVENT_DTYPE)
    ev["timestamp"] = np.arange(n) * 20_000 + rng.integers(0, 100, n)  # one every 20 ms
    ev["x"] = 150 + rng.integers(-3, 4, n)
    ev["y"] = 121 + rng.integers(-3, 4, n)
    ev["polarity"] = rng.integers(0, 2, n)
    tracker.update(ev)
    counts = tracker.counts
    assert counts["applied"] == 0 and counts["gated"] > 0.8 * n
    assert counts["gated"] + counts["noise"] == n
    assert np.array_equal(tracker.positions_px, start)


def test_each_event_goes_to_the_nearest_blob_through_the_owner_image():
    start = np.array([[100.0, 100.0], [108.0, 100.0]])
    tracker = BlobTracker(start, config=TrackerConfig(assoc_mm=1.4))
    owner = tracker.owner_image()
    assert owner[100, 103] == 0 and owner[100, 105] == 1  # each pixel to its nearest blob
    assert owner[100, 97] == 0 and owner[100, 111] == 1
    assert owner[100, 112] == -1 and owner[96, 100] == -1  # beyond the association threshold
    # A burst of events at (103, 100) pulls blob 0 only.
    ev = np.zeros(20, EVENT_DTYPE)
    ev["timestamp"] = np.arange(20) * 10
    ev["x"], ev["y"], ev["polarity"] = 103, 100, 1
    tracker.update(ev)
    pos = tracker.positions_px
    assert pos[0, 0] > 100.0
    assert np.array_equal(pos[1], start[1])


def test_reset_reinitialises_positions_and_count():
    start = np.array([[150.3, 120.6]])
    truth = linear(start[0], (0.2, 0.0))
    events = esim(truth, 50_000, (130, 100, 180, 140))
    tracker = BlobTracker(start)
    tracker.update(events)
    assert tracker.positions_px[0, 0] > 155
    new = np.array([[100.5, 100.5], [110.5, 100.5], [120.5, 100.5]])
    tracker.reset(new)
    assert np.array_equal(tracker.positions_px, new)
    assert tracker.valid.all() and tracker.valid.shape == (3,)
    assert np.all(tracker.velocities_px_per_s == 0)
    owner = tracker.owner_image()
    assert owner[100, 110] == 1 and owner[120, 160] == -1  # old blob's pixels released

    # Tracking works after the reset: the middle dot moves right.
    def truth2(t):
        return new + np.array([[0.0, 0.0], [0.05 * t / 1000.0, 0.0], [0.0, 0.0]])

    events2 = esim(truth2, 40_000, (90, 90, 135, 112))
    events2["timestamp"] += 60_000
    tracker.update(events2)
    assert abs(tracker.positions_px[1, 0] - truth2(40_000)[1, 0]) < 0.5


def test_blob_leaving_the_gel_is_lost():
    cx, cy = SENSOR.gel_center_px
    start = np.array([[cx + SENSOR.gel_radius_px - 3.0, cy + 0.3], [cx, cy]])

    def truth(t):
        return start + np.array([[0.3 * t / 1000.0, 0.0], [0.0, 0.0]])

    events = esim(truth, 50_000, (int(cx) - 5, int(cy) - 10, 346, int(cy) + 10))
    tracker = BlobTracker(start, sensor=SENSOR)
    run(tracker, events, 50_000)  # lost is decided at the end of each (1 ms) batch
    assert not tracker.valid[0]
    assert tracker.valid[1]
    assert np.all(tracker.owner_image() != 0)
    assert tracker.positions_px[0, 0] < cx + SENSOR.gel_radius_px + tracker.pixels.gel_margin_px + 1.5


def test_blobs_that_merge_are_lost():
    # Two dots 7 px apart slide onto each other: both blobs are lost, a third one is not. (The
    # last ~2 px of an exact overlap make few distinguishable events: merge_mm 1.2, 3 px at 2.5 px/mm, here.)
    start = np.array([[150.2, 120.3], [157.2, 120.3], [150.2, 130.3]])

    def truth(t):
        return start + min(t / 30_000.0, 1.0) * np.array([[3.5, 0.0], [-3.5, 0.0], [0.0, 0.0]])

    events = esim(truth, 40_000, (140, 110, 168, 140))
    tracker = BlobTracker(start, config=TrackerConfig(merge_mm=1.2))
    tracker.update(events)
    assert not tracker.valid[:2].any()
    assert tracker.valid[2]


def test_update_rejects_wrong_dtype_and_accepts_empty():
    tracker = BlobTracker(np.array([[10.0, 10.0]]))
    tracker.update(np.zeros(0, EVENT_DTYPE))
    with pytest.raises(ValueError, match="EVENT_DTYPE"):
        tracker.update(np.zeros((5, 4)))
    with pytest.raises(ValueError, match="finite"):
        tracker.reset(np.array([[np.nan, 1.0]]))


def test_aps_frame_correction_pulls_blobs_to_unambiguous_detections():
    start = np.array([[100.0, 100.0], [120.0, 100.0], [140.0, 100.0], [142.5, 100.0]])
    tracker = BlobTracker(start)
    detections = np.array(
        [
            [100.6, 100.3],  # blob 0: within the gate -> corrected towards it
            [122.0, 100.0],  # blob 1: 2 px away, beyond the 1.5 px gate -> ignored
            [141.2, 100.0],  # blobs 2 and 3 both within 3 px: two markers seen as one -> ignored
        ]
    )
    assert tracker.correct(detections) == 1
    pos = tracker.positions_px
    assert np.linalg.norm(pos[0] - detections[0]) < 0.1  # the frame is far more precise
    assert np.array_equal(pos[1:], start[1:])
    assert tracker.correct(np.zeros((0, 2))) == 0


def test_aps_frame_correction_removes_the_lag_of_a_stopped_marker():
    # A dot moves 6 px and stops; the events leave the blob a little behind; the APS frame shows
    # where the dot is.
    p0 = np.array([150.3, 120.6])

    def truth(t):
        return np.array([p0 + np.array([0.1, 0.0]) * min(t, 60_000) / 1000.0])

    events = esim(truth, 80_000, (140, 110, 165, 132))
    tracker = BlobTracker(p0[None])
    tracker.update(events)
    before = np.linalg.norm(tracker.positions_px[0] - truth(80_000)[0])
    tracker.correct(truth(80_000) + 0.02, t_us=80_000)
    after = np.linalg.norm(tracker.positions_px[0] - truth(80_000)[0])
    assert after < 0.15
    assert after < before


@pytest.fixture(scope="module")
def held_large_twist():
    """A simulated large fast twist held 1.2 s (the gesture of the test set's u1_twist_cw,
    9.2-11.4 s, with a shorter hold: markers squeezed together, then a tremor of a few Hz):
    events, the 1 ms truth grid, true marker positions (T, N, 2) image px, the markers detected
    on the first APS frame, and the attack's and hold's end (us)."""
    from neurotouch_hid.core.estimate import GestureType
    from neurotouch_hid.pipeline.markers import detect_markers
    from neurotouch_hid.sources.gel import SimGesture
    from neurotouch_hid.sources.hands import USERS
    from neurotouch_hid.sources.simulator import GelSimulator

    twist = SimGesture(
        gesture=GestureType.TWIST_CW,
        t_start_us=1_100_000,
        attack_us=380_000,
        hold_us=1_200_000,
        release_us=150_000,
        fingers_mm=np.array([[-6.73, 12.21], [-1.84, -11.42]]),
        amplitude_mm=14.5,
        direction=np.zeros(2),
        finger_mm=5.7,
        press=0.67,
        tremor=(0.04, 6.0, 0.2),
        global_mm=np.array([0.02, 0.16]),
        global_rad=-0.004,
        residual=0.03,
        creep_us=100_000,
    )
    sim = GelSimulator(SENSOR, USERS[1], seed=0, script=[twist])
    hold_end = twist.t_start_us + twist.attack_us + twist.hold_us
    chunks = list(sim.run((hold_end - sim.t_us) / 1e6))
    events = np.concatenate([c.events for c in chunks])
    t_grid = np.concatenate([c.t_us for c in chunks])
    truth = np.concatenate([c.positions_px for c in chunks]).astype(np.float64)
    start = detect_markers(chunks[0].frame.image, SENSOR).centroids_px.astype(np.float64)
    return events, t_grid, truth, start, twist.t_start_us + twist.attack_us, hold_end


def test_markers_squeezed_by_a_held_large_fast_twist_stay_on_their_own_marker(held_large_twist):
    # Regression (test set u1_twist_cw, 9.17-11.36 s): during the hold, the first events after a
    # pause in a blob's events met a covariance grown over the pause and the polarity offset
    # drifted without bound; blobs slid onto a squeezed neighbour's marker, pairs merged and
    # were lost, and the gesture read as push or none.
    events, t_grid, truth, start, attack_end, hold_end = held_large_twist
    who = np.hypot(start[:, None, 0] - truth[0, None, :, 0], start[:, None, 1] - truth[0, None, :, 1]).argmin(axis=1)
    assert len(np.unique(who)) == len(start) == truth.shape[1]
    # The premise: a fast, large motion that squeezes markers from ~8 px to ~5 px apart.
    at_hold = truth[np.searchsorted(t_grid, attack_end)]
    gaps = np.hypot(at_hold[:, None, 0] - at_hold[None, :, 0], at_hold[:, None, 1] - at_hold[None, :, 1])
    np.fill_diagonal(gaps, np.inf)
    assert np.linalg.norm(at_hold - truth[0], axis=1).max() > 15.0
    assert gaps.min() < 5.5
    assert np.linalg.norm(np.diff(truth, axis=0), axis=2).max() > 0.1  # px per ms

    tracker = BlobTracker(start, SENSOR.width, SENSOR.height, sensor=SENSOR)
    ends = t_grid[10::10]
    cuts = np.searchsorted(events["timestamp"], ends)
    errors, begin = [], 0
    for end, cut in zip(ends, cuts):
        tracker.update(events[begin:cut])
        begin = cut
        assert tracker.valid.all(), f"blobs {np.flatnonzero(~tracker.valid)} lost at t = {end} us"
        true = truth[np.searchsorted(t_grid, end)][who]
        errors.append(np.linalg.norm(tracker.positions_px - true, axis=1))
    errors = np.array(errors)
    assert ends[-1] >= hold_end - 10_000
    # Every blob stays within 2 px of its own marker (half the squeezed spacing) all along.
    assert errors.max() < 2.0
    assert np.median(errors[ends > attack_end]) < 0.6


def test_frame_matches_follow_the_gated_mutual_nearest_rule_written_with_numpy():
    """``_frame_matches`` (numba) against the rule written out with NumPy: each valid blob takes
    its nearest detection within the gate when it is that detection's nearest valid blob and no
    second valid blob lies within twice the gate; on random blobs and detections, some squeezed
    together, some invalid; and on whole-pixel positions, where equal distances are common (the
    kernel measures only the pairs in neighbouring cells, so its ties must still go to the lower
    index); and on a gate far smaller than the detections' spread (cells coarser than the gate)."""
    from neurotouch_hid.pipeline.tracker import _frame_matches

    rng = np.random.default_rng(11)
    for trial in range(100):
        n, m = int(rng.integers(1, 40)), int(rng.integers(1, 40))
        state = np.zeros((n, 6))
        state[:, :2] = rng.uniform(0, 30, (n, 2))
        state[: n // 4, :2] = state[n // 4 : 2 * (n // 4), :2] + rng.normal(0, 0.8, (n // 4, 2))  # squeezed pairs
        valid = rng.random(n) > 0.15
        det = np.concatenate([state[:, :2] + rng.normal(0, 0.7, (n, 2)), rng.uniform(0, 30, (m, 2))])
        if trial % 2:  # ties
            state[:, :2] = np.round(state[:, :2] / 2.0)
            det = np.round(det / 2.0)
        gate2 = 1.5**2 if trial % 3 else 0.05**2
        d2 = (state[:, None, 0] - det[None, :, 0]) ** 2 + (state[:, None, 1] - det[None, :, 1]) ** 2
        d2[~valid] = np.inf
        nearest = d2.argmin(axis=1)
        rows = np.arange(n)
        ok = valid & (d2[rows, nearest] <= gate2) & (d2.argmin(axis=0)[nearest] == rows)
        if n > 1:
            ok &= np.partition(d2, 1, axis=0)[1][nearest] > 4.0 * gate2
        expected = np.where(ok, nearest, -1)
        np.testing.assert_array_equal(_frame_matches(state, valid, det, gate2), expected)


PITCH = 10.0


def gel_grid(n=9):
    """(n * n, 2) rest positions of a square marker grid, PITCH px apart, and a smooth drag: a
    Gaussian bump of 19 px along +x about the grid's centre (a deep push, sigma 2 pitches)."""
    xs, ys = np.meshgrid(np.arange(n) * PITCH + 100.0, np.arange(n) * PITCH + 100.0)
    rest = np.column_stack([xs.ravel(), ys.ravel()])
    centre = rest.mean(axis=0)
    bump = 19.0 * np.exp(-np.sum((rest - centre) ** 2, axis=1) / (2 * (2 * PITCH) ** 2))
    return rest, rest + np.column_stack([bump, np.zeros(len(rest))])


def test_a_chain_of_blobs_left_one_marker_along_is_put_back_on_its_own_markers():
    rest, truth = gel_grid()
    neighbours = rest_neighbours(rest, PITCH)
    # a released press left three blobs of the third row each on the next marker of the row
    blobs = truth.copy()
    chain = [20, 21, 22]
    blobs[chain] = truth[[21, 22, 23]]
    blobs[23] = truth[23] + [0.4, 0.0]  # the last one's marker holds its own blob too, nearly
    moved, where = swapped_blobs(blobs, np.ones(len(rest), bool), rest, neighbours, truth, PITCH)
    assert sorted(moved.tolist()) == chain
    assert np.allclose(where[np.argsort(moved)], truth[chain])
    # the tracker takes them there, at rest speed, and owns their pixels again
    tracker = BlobTracker(blobs)
    tracker.relocate(moved, where)
    assert np.allclose(tracker.positions_px, np.where(np.isin(np.arange(len(rest)), chain)[:, None], truth, blobs))
    assert np.all(tracker.velocities_px_per_s == 0)
    x, y = np.round(truth[20]).astype(int)
    assert tracker.owner_image()[y, x] == 20


def test_a_cluster_of_blobs_left_between_markers_is_put_back_on_its_own_markers():
    """After a deep press's quick lift four blobs under the finger sat 0.5-0.7 pitch off their
    markers, between two of them, for 0.6 s (a simulated viscoelastic gel). Each other's
    neighbours, they lean their neighbours' median towards them: each reads less than
    SWAP_PITCHES from it, but sits on no marker of the frame while its own marker, where the
    median puts it, holds no blob."""
    rest, truth = gel_grid()
    neighbours = rest_neighbours(rest, PITCH)
    valid = np.ones(len(rest), bool)
    blobs = truth.copy()
    cluster = [10, 11, 19, 20]  # on the drag's flank
    blobs[cluster] += [0.0, 0.5 * PITCH]  # half a pitch across the drag: between two markers
    shared = np.full((len(rest), 2), np.nan)
    _suspects(blobs, valid, rest, neighbours, 0.0, shared)
    off = np.hypot(*(blobs[cluster] - rest[cluster] - shared[cluster]).T)
    assert np.all(off < SWAP_PITCHES * PITCH) and np.all(off > SWAP_FOUND_PITCHES * PITCH)
    # as far off, but on a marker of the frame (a strained hold: the frame shows it there), it stays
    moved, _ = swapped_blobs(blobs, valid, rest, neighbours, blobs, PITCH)
    assert len(moved) == 0
    # within two frames (those whose median leans least first) every one is on its own marker
    back = []
    for _frame in range(2):
        moved, where = swapped_blobs(blobs, valid, rest, neighbours, truth, PITCH)
        assert np.allclose(where, truth[moved])
        blobs[moved] = where
        back += moved.tolist()
    assert sorted(back) == cluster and np.allclose(blobs, truth)


def test_a_smooth_deep_drag_and_a_frame_without_the_marker_move_no_blob():
    rest, truth = gel_grid()
    neighbours = rest_neighbours(rest, PITCH)
    valid = np.ones(len(rest), bool)
    # the steepest part of the drag differs from its neighbours' median by less than the limit
    moved, _ = swapped_blobs(truth, valid, rest, neighbours, truth, PITCH)
    assert len(moved) == 0
    # a blob one pitch off whose own marker the frame does not show stays where it is
    blobs = truth.copy()
    blobs[40] = truth[41]
    frame = np.delete(truth, 40, axis=0)
    moved, _ = swapped_blobs(blobs, valid, rest, neighbours, frame, PITCH)
    assert len(moved) == 0
    # a blob off by less than the limit is not a suspect, whatever the frame shows
    blobs = truth.copy()
    blobs[40] += [0.9 * SWAP_PITCHES * PITCH, 0.0]
    moved, _ = swapped_blobs(blobs, valid, rest, neighbours, truth, PITCH)
    assert len(moved) == 0
    # a lost blob is neither moved nor counted among its neighbours
    blobs = truth.copy()
    blobs[40] = truth[41]
    lost = valid.copy()
    lost[40] = False
    moved, _ = swapped_blobs(blobs, lost, rest, neighbours, truth, PITCH)
    assert len(moved) == 0


def test_relocate_rejects_mismatched_or_non_finite_positions():
    tracker = BlobTracker(np.array([[100.0, 100.0], [110.0, 100.0]]))
    with pytest.raises(ValueError):
        tracker.relocate(np.array([0, 1]), np.array([[1.0, 2.0]]))
    with pytest.raises(ValueError):
        tracker.relocate(np.array([0]), np.array([[np.nan, 2.0]]))
    tracker.relocate(np.zeros(0, np.int64), np.zeros((0, 2)))  # nothing to move
    assert np.array_equal(tracker.positions_px, [[100.0, 100.0], [110.0, 100.0]])
