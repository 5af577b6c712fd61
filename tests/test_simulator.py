"""The simulated NeuroTouch gel (sources/simulator.py, gel.py, hands.py, sim_dataset.py, esim.py).

The quick dataset is written once per session through the CLI and read back with csv, PyYAML,
numpy and dv-processing directly (not with our own readers), against docs/dataset.md.
"""

from __future__ import annotations

import csv
import filecmp
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml

from neurotouch_hid.core.estimate import GestureType
from neurotouch_hid.core.sensor import SensorGeometry
from neurotouch_hid.sources import EVENT_DTYPE, Frame
from neurotouch_hid.sources.esim import EventCamera, time_ordered
from neurotouch_hid.sources.gel import SimGesture, deform
from neurotouch_hid.sources.hands import SIM_GESTURES, USERS, draw_gesture, guided_gesture
from neurotouch_hid.sources.physics import PHYSICS
from neurotouch_hid.sources.sim_dataset import preset_users, write_dataset
from neurotouch_hid.sources.simulator import START_US, GelSimulator, SimulatedSource

# docs/dataset.md, written out here from the spec (not taken from the code under test)
DATASET_COLUMNS = [
    "t_us",
    "gesture",
    "resting",
    "intensity_mm",
    "n_contacts",
    "x1_px",
    "y1_px",
    "x2_px",
    "y2_px",
    "x3_px",
    "y3_px",
]
DATASET_GESTURES = {"none", "push", "pinch", "zoom", "twist_cw", "twist_ccw"}
SENSOR_KEYS = {"width", "height", "px_per_mm", "gel_center_px", "gel_radius_px", "mirror", "rotation_deg"}


def _read_dv(path: Path) -> tuple[np.ndarray, list[tuple[int, np.ndarray]], tuple[int, int]]:
    import dv_processing as dv

    rec = dv.io.MonoCameraRecording(str(path))
    assert rec.isEventStreamAvailable() and rec.isFrameStreamAvailable()
    resolution = tuple(rec.getEventResolution())
    parts = []
    while rec.isRunning():
        batch = rec.getNextEventBatch()
        if batch is None:
            break
        parts.append(batch.numpy())
    rec = dv.io.MonoCameraRecording(str(path))
    frames = []
    while True:
        frame = rec.getNextFrame()
        if frame is None:
            break
        frames.append((int(frame.timestamp), frame.image))
    events = np.concatenate(parts) if parts else np.zeros(0, dtype=EVENT_DTYPE)
    return events, frames, resolution


def _components(image: np.ndarray) -> np.ndarray:
    """Centroids (K, 2) px of the white blobs of an APS frame: connected components of the Otsu
    threshold (OpenCV), each centroid weighted by the grey levels above the background in the
    blob's box grown by 2 px (markers are >= 8 px apart, so no neighbour enters it)."""
    _, binary = cv2.threshold(image, 0, 255, cv2.THRESH_BINARY | cv2.THRESH_OTSU)
    n, _, stats, _ = cv2.connectedComponentsWithStats(binary)
    out = np.zeros((n - 1, 2))
    for k in range(1, n):
        x, y, w, h = stats[k, :4]
        x0, y0 = max(x - 2, 0), max(y - 2, 0)
        roi = np.clip(image[y0 : y + h + 2, x0 : x + w + 2].astype(float) - 30.0, 0.0, None)
        m = cv2.moments(roi)
        out[k - 1] = (x0 + m["m10"] / m["m00"], y0 + m["m01"] / m["m00"])
    return out


def _signed_angle(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Counter-clockwise angle (rad) from vectors a to b (..., 2), y up."""
    return np.arctan2(a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0], (a * b).sum(axis=-1))


# --- the gel at rest --------------------------------------------------------------------------
def test_rest_frame_shows_177_markers_inside_the_gel_circle(sim_quick_dataset):
    sensor_file = sim_quick_dataset / "sensor.yaml"
    data = yaml.safe_load(sensor_file.read_text())
    cx, cy = data["gel_center_px"]
    _, frames, _ = _read_dv(sim_quick_dataset / "u0_push.aedat4")
    t0, image = frames[0]
    centroids = _components(image)
    assert len(centroids) == 177
    r = np.hypot(centroids[:, 0] - cx, centroids[:, 1] - cy)
    assert r.max() < data["gel_radius_px"]
    # sub-pixel rendering: weighted blob centroids agree with the true rest positions of
    # markers.npz (the read noise moves a centroid by a few hundredths of a pixel)
    rest = np.load(sim_quick_dataset / "u0_push.markers.npz")["rest_px"]
    d = np.linalg.norm(centroids[:, None, :] - rest[None], axis=-1)
    assert np.all(d.min(axis=1) < 0.1)
    assert len(set(d.argmin(axis=1))) == 177


# --- events -----------------------------------------------------------------------------------
def one_marker_camera(sigma_px: float = 1.0, **settings) -> EventCamera:
    """An event camera over a 60 x 40 px dark background with one bright marker at (20, 20),
    without noise events or hot pixels."""
    return EventCamera(
        np.full((40, 60), 20.0),
        np.array([[20.0, 20.0]]),
        np.array([200.0]),
        np.array([sigma_px]),
        np.random.default_rng(3),
        noise_rate_hz=0.0,
        n_hot=0,
        **settings,
    )


def test_moving_bright_marker_makes_on_events_ahead_and_off_events_behind():
    cam = one_marker_camera()
    t = np.arange(0, 20_001, 1000, dtype=np.int64)
    x = 20.0 + 1e-3 * t  # 1000 px/s to the right
    pos = np.stack([x, np.full_like(x, 20.0)], axis=1)[:, None, :]
    events = cam.events(t, pos, np.full((len(t), 1), 200.0), np.random.default_rng(4))
    assert len(events) > 100
    assert np.all(np.diff(events["timestamp"]) >= 0)
    centre_at_event = 20.0 + 1e-3 * events["timestamp"]
    ahead = events["x"] > centre_at_event
    on = events["polarity"] == 1
    assert np.mean(ahead[on]) > 0.95
    assert np.mean(~ahead[~on]) > 0.95
    assert 0.3 < on.mean() < 0.7


def test_events_stay_in_their_interval_when_a_pixel_starts_beyond_its_off_threshold():
    """Each pixel's reference starts at a random phase within its ON threshold; with a large
    threshold spread (the ``contrast`` family's kind) some pixels' OFF threshold is below half
    their ON threshold, so the first darkening fires at once. Those events must come at the
    interval's start, not before it (they did: a recording's events out of time order)."""
    cam = one_marker_camera(2.0, contrast=0.45, contrast_sigma=0.2)
    assert np.any(cam.c_off < 0.5 * cam.c_on)  # such pixels exist; make every pixel one, its
    # reference as high in its band as the constructor may draw it
    cam.c_on[:], cam.c_off[:] = 0.6, 0.225
    cam.log_ref[:] = cam.log_prev + 0.45 * cam.c_on
    rng = np.random.default_rng(4)
    last = -1
    for start in range(0, 40_000, 10_000):
        t = np.arange(start, start + 10_001, 1000, dtype=np.int64)
        x = 20.0 + 1e-3 * t  # a bright marker passing at 1000 px/s
        pos = np.stack([x, np.full_like(x, 20.0)], axis=1)[:, None, :]
        events = cam.events(t, pos, np.full((len(t), 1), 200.0), rng)
        assert len(events) and events["timestamp"].min() >= start and events["timestamp"].max() <= start + 10_000
        assert events["timestamp"][0] >= last
        last = events["timestamp"][-1]


def test_the_camera_left_out_while_the_marker_holds_still_makes_the_events_of_esim():
    """A marker that moves, holds still, jumps (a still state away from where it is rendered),
    dims and holds still again: a camera that leaves ESIM out while it holds still where it is
    rendered makes the same events, and ends in the same state, as one that runs ESIM on every call."""
    cams = [one_marker_camera(skip_still=skip) for skip in (True, False)]
    t0, still = 0, []
    for x, amp in [((20.0, 23.0), 200.0), (23.0, 200.0), (23.0, 200.0), (23.02, 200.0), (25.0, 200.0),
                   (25.0, 200.0), (25.0, 100.0), (25.0, 100.0), (25.0, 100.0)]:  # fmt: skip
        t = np.arange(t0, t0 + 10_001, 1000, dtype=np.int64)
        xs = np.linspace(*x, len(t)) if isinstance(x, tuple) else np.full(len(t), x)
        pos = np.stack([xs, np.full_like(xs, 20.0)], axis=1)[:, None, :]
        amps = np.full((len(t), 1), amp)
        a, b = (cam.events(t, pos, amps, np.random.default_rng(t0)) for cam in cams)
        assert a.tobytes() == b.tobytes()
        still.append(len(a) == 0)
        t0 = int(t[-1])
    for name in ("img", "lin_prev", "log_prev", "log_ref", "last_t", "rend_pos", "rend_amp", "rend_sigma"):
        assert np.array_equal(getattr(cams[0], name), getattr(cams[1], name)), name
    assert still == [False, True, True, True, False, True, False, True, True]


def test_events_in_time_order_are_numpys_stable_sort_of_esims_then_the_noise():
    rng = np.random.default_rng(7)
    first = np.zeros(300, dtype=EVENT_DTYPE)
    for name, high in (("timestamp", 50), ("x", 346), ("y", 260), ("polarity", 2)):
        first[name] = rng.integers(0, high, len(first))
    hot_n = np.array([3, 0, 5])
    hot_x, hot_y = np.array([7, 8, 9], dtype=np.int16), np.array([1, 2, 3], dtype=np.int16)
    ba_x, ba_y = rng.integers(0, 346, 200), rng.integers(0, 260, 200)
    t, p = rng.integers(0, 50, 208), rng.integers(0, 2, 208)  # few timestamps: many ties
    noise = np.zeros(208, dtype=EVENT_DTYPE)
    noise["timestamp"], noise["polarity"] = t, p
    noise["x"], noise["y"] = np.r_[ba_x, np.repeat(hot_x, hot_n)], np.r_[ba_y, np.repeat(hot_y, hot_n)]
    joined = np.concatenate([first, noise])
    expected = joined[np.argsort(joined["timestamp"], kind="stable")]
    got = time_ordered(first, t, ba_x, ba_y, p, hot_n, hot_x, hot_y)
    assert got.dtype == EVENT_DTYPE and got.tobytes() == expected.tobytes()
    with pytest.raises(ValueError, match="counts"):  # a hot pixel's count that does not add up
        time_ordered(first, t, ba_x, ba_y, p, hot_n + 1, hot_x, hot_y)


def test_gel_at_rest_makes_only_sparse_noise_events():
    sim = GelSimulator(seed=5)
    chunk = sim.step()  # the first 40 ms are a rest
    assert chunk.label.resting
    rate_per_pixel = len(chunk.events) / (346 * 260) / 0.04
    assert rate_per_pixel < 2.0  # Hz per pixel: background activity and hot pixels only


def _same_chunks(reused: GelSimulator, scratch: GelSimulator, seconds: float) -> int:
    """Step both simulators over ``seconds`` and assert every chunk is the same; the number of
    chunks labelled resting."""
    resting = 0
    for a, b in zip(reused.run(seconds), scratch.run(seconds), strict=True):
        assert a.frame.t_us == b.frame.t_us and np.array_equal(a.frame.image, b.frame.image)
        assert a.events.dtype == b.events.dtype and a.events.tobytes() == b.events.tobytes()
        assert (a.label.t_us, a.label.gesture, a.label.resting, a.label.intensity_mm) == (
            b.label.t_us,
            b.label.gesture,
            b.label.resting,
            b.label.intensity_mm,
        )
        assert a.label.contacts_px.tobytes() == b.label.contacts_px.tobytes()
        assert np.array_equal(a.t_us, b.t_us) and a.positions_px.tobytes() == b.positions_px.tobytes()
        resting += a.label.resting
    return resting


@pytest.mark.parametrize(
    "physics, script, seconds",
    [
        ("default", (), 1.0),
        ("default", None, 4.0),  # a drawn script: rests, gestures, their creep, rests again
        ("markers", None, 3.0),
        ("exposure", None, 3.0),
    ],
)
def test_a_resting_gel_reused_gives_the_chunks_computed_from_scratch(physics, script, seconds):
    def sim(reuse: bool) -> GelSimulator:
        return GelSimulator(user=USERS[3], seed=4, script=script, physics=PHYSICS[physics], reuse_rest=reuse)

    reused = sim(True)
    resting = _same_chunks(reused, sim(False), seconds)
    assert resting >= 5 and reused._rest is not None  # the rest was reused, and more than once


def test_a_guided_gesture_after_a_reused_rest_gives_the_chunks_computed_from_scratch():
    sims = [GelSimulator(seed=2, script=(), reuse_rest=reuse) for reuse in (True, False)]
    assert _same_chunks(*sims, 0.4) == 10
    gesture = guided_gesture(GestureType.TWIST_CW, sims[0].t_us + 3_000)
    for sim in sims:  # told as it goes, as a calibration does
        sim.perform(gesture)
    assert _same_chunks(*sims, (gesture.t_settled_us - sims[0].t_us) / 1e6 + 0.4) >= 10  # and at rest again


# --- motion and labels ------------------------------------------------------------------------
def _single_gesture(kind: GestureType, fingers_mm, amplitude_mm: float, direction=(0.0, 0.0)) -> SimGesture:
    return SimGesture(
        gesture=kind,
        t_start_us=START_US + 200_000,
        attack_us=300_000,
        hold_us=200_000,
        release_us=200_000,
        fingers_mm=np.asarray(fingers_mm, dtype=float),
        amplitude_mm=amplitude_mm,
        direction=np.asarray(direction, dtype=float),
        finger_mm=7.0,
        press=0.8,
        tremor=(0.0, 5.0, 0.0),
        global_mm=np.array([0.2, -0.1]),
        global_rad=0.002,
        residual=0.03,
        creep_us=80_000,
    )


def _run(gesture: SimGesture, seconds: float):
    sim = GelSimulator(seed=1, script=[gesture])
    return sim, list(sim.run(seconds))


def test_ccw_twist_in_user_frame_is_clockwise_in_the_image():
    sensor = SensorGeometry()
    twist = _single_gesture(GestureType.TWIST_CCW, [[-8.0, 3.0], [8.0, -3.0]], 8.0)
    _, chunks = _run(twist, 0.8)
    rows = [c.label for c in chunks if c.label.gesture is GestureType.TWIST_CCW]
    first, hold = rows[0], max(rows, key=lambda r: r.intensity_mm)
    assert first.n_contacts == hold.n_contacts == 2

    def rotation(points_a, points_b, y_up_flip):
        a = points_a - points_a.mean(axis=0)
        b = points_b - points_b.mean(axis=0)
        if y_up_flip:  # image as displayed: v grows downwards, so use (u, -v) to measure y up
            a, b = a * [1, -1], b * [1, -1]
        return float(np.mean(_signed_angle(a, b)))

    # as displayed, the contacts turn clockwise (negative angle, y up) ...
    assert rotation(first.contacts_px, hold.contacts_px, y_up_flip=True) < -0.2
    # ... and converted with docs/dataset.md's formula they turn counter-clockwise for the user
    user_a, user_b = sensor.image_to_user(first.contacts_px), sensor.image_to_user(hold.contacts_px)
    assert rotation(user_a, user_b, y_up_flip=False) > 0.2
    # the true markers near the fingers turn the same way as the labels
    pos0 = chunks[0].positions_px[0]
    hold_chunk = next(c for c in chunks if c.label.t_us == hold.t_us)
    pos1 = hold_chunk.positions_px[0]
    near = np.linalg.norm(pos0[:, None] - first.contacts_px[None], axis=-1).min(axis=1) < 8.0
    um0, um1 = sensor.image_to_user(pos0[near]), sensor.image_to_user(pos1[near])
    assert np.mean(_signed_angle(um0, um1)) > 0.05


def test_push_intensity_equals_contact_displacement_from_true_markers_and_aps_frames():
    sensor = SensorGeometry()
    rest_mm = GelSimulator(seed=1).gel.rest_mm
    marker = int(np.argmin(np.linalg.norm(rest_mm - [4.0, -8.0], axis=1)))
    finger = rest_mm[marker] + [0.6, 0.8]  # the finger centre 1 mm off a marker
    push = _single_gesture(GestureType.PUSH, finger[None], 9.0, direction=(0.6, -0.8))
    sim, chunks = _run(push, 1.6)
    rest_px = sim.gel.rest_px
    rows = [(c, c.label) for c in chunks if c.label.gesture is GestureType.PUSH]
    assert max(r.intensity_mm for _, r in rows) > 7.0
    for chunk, row in rows:
        moved_px = chunk.positions_px[0, marker] - rest_px[marker]
        moved_mm = float(np.linalg.norm(moved_px)) / sensor.px_per_mm
        # The marker sits 1 mm from the finger centre: the Gaussian falloff (sigma >= 7 mm)
        # keeps exp(-1 / 98) > 99 % of the finger's motion there, and pressing spreads it
        # radially by <= 0.35 mm * press * 1 mm / 7 mm = 0.04 mm.
        assert abs(row.intensity_mm - moved_mm) < 0.01 * row.intensity_mm + 0.06
        # the labelled contact point is where the surface under the finger is: ~1 mm from it
        gap_mm = np.linalg.norm(row.contacts_px[0] - chunk.positions_px[0, marker]) / sensor.px_per_mm
        assert gap_mm < 1.0 + 0.01 * row.intensity_mm + 0.06
    # independently of the simulator's state: the marker's blob centroid in the APS frames
    rest_blobs = _components(chunks[0].frame.image)
    chunk, row = max(rows, key=lambda cr: cr[1].intensity_mm)
    blobs = _components(chunk.frame.image)
    b0 = rest_blobs[np.argmin(np.linalg.norm(rest_blobs - rest_px[marker], axis=1))]
    b1 = blobs[np.argmin(np.linalg.norm(blobs - chunk.positions_px[0, marker], axis=1))]
    # at the hold (no tremor here) the 4 ms exposure is still, so only the falloff above and
    # the blob centroid error (< 0.3 px = 0.12 mm) separate the two
    blob_mm = float(np.linalg.norm(b1 - b0)) / sensor.px_per_mm
    assert abs(blob_mm - row.intensity_mm) < 0.01 * row.intensity_mm + 0.2
    # after the release the gel creeps back and the labels say resting again
    last = chunks[-1].label
    assert last.gesture is GestureType.NONE and last.resting


def test_gel_never_folds_and_markers_stay_apart_and_inside():
    sensor = SensorGeometry()
    rest = GelSimulator(seed=0).gel.rest_mm
    h = 0.2  # mm, finite-difference step of the Jacobian
    for uid, user in enumerate(USERS):
        rng = np.random.default_rng(100 + uid)
        for kind in SIM_GESTURES:
            g = draw_gesture(rng, user, kind, 0, sensor)
            t = np.array([g.attack_us + g.hold_us // 2])  # the hold: the largest deformation
            pos = deform([g], rest, t, sensor.gel_radius_mm)[0][0]
            gaps = np.linalg.norm(pos[:, None] - pos[None], axis=-1) + np.eye(len(pos)) * 1e9
            assert gaps.min() > 0.5, (kind, uid)  # 1.25 px: two blobs never merge into one
            assert np.hypot(pos[:, 0], pos[:, 1]).max() < sensor.gel_radius_mm
            jac = [
                (
                    deform([g], rest + dx, t, sensor.gel_radius_mm)[0][0]
                    - deform([g], rest - dx, t, sensor.gel_radius_mm)[0][0]
                )
                / (2 * h)
                for dx in (np.array([h, 0.0]), np.array([0.0, h]))
            ]
            det = jac[0][:, 0] * jac[1][:, 1] - jac[1][:, 0] * jac[0][:, 1]
            assert det.min() > 0.0, (kind, uid)  # orientation kept: no fold


def test_simulated_source_streams_frames_then_events_cycling_gestures():
    source = SimulatedSource(seed=2, gestures=["pinch", "zoom"])
    last_frame_us = None
    last_ts = -1
    n_frames = 0
    for item in source.stream(seconds=0.4, batch_us=1000):
        if isinstance(item, Frame):
            assert item.image.shape == (260, 346) and item.image.dtype == np.uint8
            last_frame_us = item.t_us
            n_frames += 1
        else:
            assert item.dtype == EVENT_DTYPE and len(item)
            ts = item["timestamp"]
            assert ts[0] >= last_frame_us and ts[-1] < last_frame_us + 40_000
            assert ts[-1] // 1000 == ts[0] // 1000  # 1 ms batches
            assert ts[0] >= last_ts
            last_ts = ts[-1]
    assert n_frames == 10
    kinds = [c.label.gesture for c in SimulatedSource(seed=2, gestures=["pinch", "zoom"]).chunks(9.0)]
    assert GestureType.PINCH in kinds and GestureType.ZOOM in kinds


def test_paper_preset_users_keep_tuning_apart_from_testing():
    assert set(preset_users("paper", 0)).isdisjoint(preset_users("paper", 1))
    assert len(preset_users("paper", 4)) == 5


# --- the written dataset ----------------------------------------------------------------------
def test_quick_dataset_follows_dataset_md(sim_quick_dataset):
    data = yaml.safe_load((sim_quick_dataset / "sensor.yaml").read_text())
    assert SENSOR_KEYS <= set(data)
    assert (data["width"], data["height"]) == (346, 260) and data["mirror"] is True
    names = sorted(p.name[: -len(".aedat4")] for p in sim_quick_dataset.glob("*.aedat4"))
    assert names == sorted(f"u0_{g.value}" for g in SIM_GESTURES)
    cx, cy = data["gel_center_px"]
    for name in names:
        with open(sim_quick_dataset / f"{name}.labels.csv", newline="") as fh:
            reader = csv.reader(fh)
            assert next(reader) == DATASET_COLUMNS
            rows = list(reader)
        events, frames, resolution = _read_dv(sim_quick_dataset / f"{name}.aedat4")
        assert resolution == (346, 260)
        assert [t for t, _ in frames] == [int(r[0]) for r in rows]  # one label per APS frame
        assert all(img.shape[:2] == (260, 346) and img.dtype == np.uint8 for _, img in frames)
        ts = events["timestamp"]
        assert len(events) and np.all(np.diff(ts) >= 0)
        assert set(np.unique(events["polarity"]).astype(int)) <= {0, 1}
        assert events["x"].min() >= 0 and events["x"].max() < 346 and events["y"].max() < 260
        gestures = set()
        for r in rows:
            gesture, resting, intensity, n = r[1], r[2], float(r[3]), int(r[4])
            assert gesture in DATASET_GESTURES and resting in ("0", "1") and 0 <= n <= 3
            gestures.add(gesture)
            cells = r[5:]
            assert all(c != "" for c in cells[: 2 * n]) and all(c == "" for c in cells[2 * n :])
            pts = np.array([float(c) for c in cells[: 2 * n]]).reshape(n, 2)
            assert np.all(np.hypot(pts[:, 0] - cx, pts[:, 1] - cy) < data["gel_radius_px"])
            if gesture == "none":
                assert intensity == 0.0 and n == 0
            else:
                assert resting == "0" and n >= 1 and intensity >= 0.0
        assert gestures == {"none", name.split("_", 1)[1]}
        assert rows[0][1:3] == ["none", "1"] and rows[-1][1:3] == ["none", "1"]
        markers = np.load(sim_quick_dataset / f"{name}.markers.npz")
        assert markers["t_us"].dtype == np.int64 and markers["positions_px"].dtype == np.float32
        assert markers["positions_px"].shape == (len(markers["t_us"]), 177, 2)
        assert markers["rest_px"].shape == (177, 2)
        assert set(int(r[0]) for r in rows) <= set(markers["t_us"].tolist())
        assert np.all(np.diff(markers["t_us"]) == 1000)


def test_same_seed_same_files_other_seed_other_files(sim_quick_dataset, tmp_path):
    again = write_dataset(tmp_path / "again", preset="quick", seed=0, gestures=["push"], progress=False)
    assert filecmp.cmp(again / "u0_push.labels.csv", sim_quick_dataset / "u0_push.labels.csv", shallow=False)
    ev_a, fr_a, _ = _read_dv(again / "u0_push.aedat4")
    ev_b, fr_b, _ = _read_dv(sim_quick_dataset / "u0_push.aedat4")
    assert np.array_equal(ev_a, ev_b)
    assert all(ta == tb and np.array_equal(a, b) for (ta, a), (tb, b) in zip(fr_a, fr_b))
    other = write_dataset(tmp_path / "other", preset="quick", seed=1, users=[0], gestures=["push"], progress=False)
    assert not filecmp.cmp(other / "u0_push.labels.csv", sim_quick_dataset / "u0_push.labels.csv", shallow=False)
    ev_c, _, _ = _read_dv(other / "u0_push.aedat4")
    assert len(ev_c) != len(ev_b) or not np.array_equal(ev_c, ev_b)


@pytest.mark.parametrize(
    "args, message",
    [
        (["--preset", "huge"], "unknown simulation preset 'huge'"),
        (["--users", "3,12"], "simulated users are 0 to 9"),
        (["--minutes", "-1"], "--minutes must be positive"),
    ],
)
def test_bad_simulate_options_are_one_clear_error(tmp_path, monkeypatch, capsys, args, message):
    from neurotouch_hid.cli import main

    monkeypatch.setattr("sys.argv", ["neurotouch-hid", "simulate", "--out", str(tmp_path / "x"), *args])
    with pytest.raises(SystemExit) as exc:
        main()
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err
