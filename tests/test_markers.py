"""Marker detection on APS frames (paper, section Marker Tracking): synthetic frames whose dot
centres are known, and a real non-gel AEDAT4 recording."""

import cv2
import dv_processing as dv
import numpy as np
import pytest

from neurotouch_hid.core.errors import SensorError
from neurotouch_hid.core.sensor import SensorGeometry
from neurotouch_hid.pipeline.markers import Markers, detect_markers, looks_like_marker_grid

SENSOR = SensorGeometry()


def render_dots(centres, sensor=SENSOR, diameter_px=2.5, seed=0, noise=3.0):
    """uint8 frame of white discs (area-sampled, 8x8 subpixels, slightly blurred) on black."""
    ss = 8
    h, w = sensor.height, sensor.width
    frac = np.zeros((h, w))
    r = diameter_px / 2
    offs = (np.arange(ss) + 0.5) / ss - 0.5
    for cx, cy in centres:
        x0, y0 = int(np.floor(cx - r - 1)), int(np.floor(cy - r - 1))
        ys, xs = np.mgrid[y0 : y0 + int(2 * r) + 4, x0 : x0 + int(2 * r) + 4]
        sub_x = xs[..., None, None] + offs[None, None, None, :]
        sub_y = ys[..., None, None] + offs[None, None, :, None]
        cover = ((sub_x - cx) ** 2 + (sub_y - cy) ** 2 <= r * r).mean(axis=(2, 3))
        ok = (ys >= 0) & (ys < h) & (xs >= 0) & (xs < w)
        frac[ys[ok], xs[ok]] += cover[ok]
    img = 15 + 220 * cv2.GaussianBlur(frac, (0, 0), 0.5)
    img += np.random.default_rng(seed).normal(0, noise, img.shape)
    return np.clip(img, 0, 255).astype(np.uint8)


def grid_centres(spacing=10.0, jitter=0.0, seed=0, radius=70.0):
    rng = np.random.default_rng(seed)
    k = np.arange(-8, 9) * spacing
    gx, gy = np.meshgrid(k, k)
    pts = np.stack([gx.ravel(), gy.ravel()], axis=1)
    pts = pts[np.hypot(pts[:, 0], pts[:, 1]) <= radius]
    pts = pts + rng.uniform(-jitter, jitter, pts.shape) + rng.uniform(0, 1, 2)
    return pts + np.asarray(SENSOR.gel_center_px)


def match(found, truth):
    d = np.hypot(found[:, None, 0] - truth[None, :, 0], found[:, None, 1] - truth[None, :, 1])
    return d.min(axis=1), d.argmin(axis=1)


def test_fifty_dots_found_with_subpixel_centroids():
    rng = np.random.default_rng(3)
    truth = grid_centres(jitter=2.0, seed=3)
    truth = truth[rng.choice(len(truth), 50, replace=False)]
    markers = detect_markers(render_dots(truth), SENSOR)
    assert isinstance(markers, Markers)
    assert len(markers) == 50
    assert markers.centroids_px.dtype == np.float32 and markers.centroids_px.shape == (50, 2)
    err, idx = match(markers.centroids_px, truth)
    assert len(set(idx.tolist())) == 50
    assert err.max() < 0.2
    assert np.all((markers.sizes_px >= 2) & (markers.sizes_px <= 15))


def test_blobs_outside_the_gel_and_too_big_are_rejected():
    inside = grid_centres(spacing=20.0, seed=1, radius=60.0)
    cx, cy = SENSOR.gel_center_px
    outside = np.array([[cx - 120, cy], [cx + 110, cy - 20], [20.3, 20.7], [330.2, 240.6]])
    img = render_dots(np.concatenate([inside, outside]))
    img[int(cy) - 5 : int(cy) + 5, int(cx) + 5 : int(cx) + 15] = 230  # a 10x10 px white patch
    markers = detect_markers(img, SENSOR)
    assert len(markers) == len(inside)
    err, _ = match(markers.centroids_px, inside)
    assert err.max() < 0.2
    assert SENSOR.inside_gel(markers.centroids_px).all()


def test_fixed_threshold_is_used():
    truth = grid_centres(spacing=20.0, seed=2, radius=60.0)
    img = render_dots(truth)
    assert len(detect_markers(img, SENSOR, threshold=100)) == len(truth)
    assert len(detect_markers(img, SENSOR, threshold=254)) == 0


def test_marker_grid_is_recognised():
    truth = grid_centres(spacing=10.0, jitter=0.5, seed=4)
    markers = detect_markers(render_dots(truth), SENSOR)
    assert len(markers) == len(truth)
    assert looks_like_marker_grid(markers, SENSOR)


def test_not_a_grid_sparse_dots_or_noise():
    sparse = grid_centres(spacing=25.0, seed=5)  # regular but far too sparse
    assert not looks_like_marker_grid(detect_markers(render_dots(sparse), SENSOR), SENSOR)
    dark = np.random.default_rng(0).normal(20, 4, (SENSOR.height, SENSOR.width)).clip(0, 255).astype(np.uint8)
    assert not looks_like_marker_grid(detect_markers(dark, SENSOR), SENSOR)
    few = Markers(np.array([[170.0, 130.0], [180.0, 130.0]], np.float32), np.array([5.0, 5.0], np.float32))
    assert not looks_like_marker_grid(few, SENSOR)


def test_street_recording_is_not_a_gel(any_street):
    rec = dv.io.MonoCameraRecording(str(any_street.path))
    for _ in range(3):
        frame = rec.getNextFrame()
        image = frame.image if frame.image.ndim == 2 else frame.image[:, :, 0]
        markers = detect_markers(image, SENSOR)
        assert len(markers) > 0  # it finds something...
        assert not looks_like_marker_grid(markers, SENSOR)  # ...that is not a marker grid


def test_bad_image_raises_sensor_error():
    with pytest.raises(SensorError, match="346x260"):
        detect_markers(np.zeros((100, 100), np.uint8), SENSOR)
    with pytest.raises(SensorError, match="uint8"):
        detect_markers(np.zeros((260, 346), np.float32), SENSOR)


def test_simulated_gel_frame_is_a_grid_with_its_markers_found():
    from neurotouch_hid.sources import Frame
    from neurotouch_hid.sources.simulator import SimulatedSource

    source = SimulatedSource(seed=0)
    frame = next(item for item in source.stream(0.04) if isinstance(item, Frame))
    markers = detect_markers(frame.image, source.sensor)
    truth = source.rest_px
    assert len(markers) == len(truth)
    err, idx = match(markers.centroids_px, truth)
    assert len(set(idx.tolist())) == len(truth)
    assert err.max() < 0.2
    assert looks_like_marker_grid(markers, source.sensor)
