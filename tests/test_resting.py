"""Resting detection by Chamfer distance (paper, "Resting Position Detection") on hand-drawn frames."""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest

from neurotouch_hid.core.errors import SensorError
from neurotouch_hid.core.sensor import SensorGeometry
from neurotouch_hid.pipeline.resting import RestingDetector
from neurotouch_hid.sources import Frame

SENSOR = SensorGeometry()


def dots(shift=(0, 0), region=None, value=220) -> np.ndarray:
    """Single-pixel markers every 10 px inside the gel; ``shift`` (dx, dy) px applied to the
    markers inside ``region`` (a radius around the centre) or to all of them."""
    img = np.full((SENSOR.height, SENSOR.width), 10, dtype=np.uint8)
    cx, cy = (int(c) for c in SENSOR.gel_center_px)
    for y in range(cy - 60, cy + 61, 10):
        for x in range(cx - 60, cx + 61, 10):
            if np.hypot(x - cx, y - cy) > 60:
                continue
            inside = region is None or np.hypot(x - cx, y - cy) <= region
            dx, dy = shift if inside else (0, 0)
            img[y + dy, x + dx] = value
    return img


@pytest.fixture(scope="module")
def detector() -> RestingDetector:
    """The distance over marker pixels (the paper's), per marker, at the paper's threshold."""
    return RestingDetector(dots(), SENSOR, threshold=2.5, centroids=False)


def test_identical_frame_rests_with_zero_distance(detector):
    result = detector.update(Frame(40_000, dots()))
    assert result.resting and result.distance == 0.0


@pytest.mark.parametrize("shift, expected", [((1, 0), 2.0), ((0, 3), 18.0), ((2, 2), 16.0)])
def test_a_global_shift_gives_twice_the_squared_shift(detector, shift, expected):
    """Every marker pixel is |shift| from its nearest match, both ways: d = 2 |shift|^2."""
    result = detector.update(dots(shift))
    assert result.distance == pytest.approx(expected, rel=0.05)
    assert result.resting is (expected <= 2.5)


def test_the_distance_is_per_reference_marker():
    """Markers of 3 pixels (a vertical bar) shifted 2 px sideways: every pixel is 2 px from its
    match both ways, so d = (3 * 4 + 3 * 4) / 1 marker = 24, whatever the marker count."""

    def bars(dx):
        img = np.zeros((SENSOR.height, SENSOR.width), np.uint8)
        for x in (150, 170, 190):
            img[129:132, x + dx] = 200
        return img

    result = RestingDetector(bars(0), SENSOR, centroids=False).update(bars(2))
    assert result.distance == pytest.approx(24.0, rel=0.02)


def test_a_local_deformation_is_not_rest(detector):
    result = detector.update(dots(shift=(4, 0), region=30))
    assert not result.resting and result.distance > 2.5


def test_a_frame_without_markers_is_not_rest(detector):
    result = detector.update(np.zeros((SENSOR.height, SENSOR.width), np.uint8))
    assert not result.resting and result.distance == float("inf")


def test_bad_frames_raise_sensor_error(detector):
    with pytest.raises(SensorError, match="260, 346"):
        detector.update(np.zeros((10, 10), np.uint8))
    with pytest.raises(SensorError, match="no marker pixel"):
        RestingDetector(np.zeros((SENSOR.height, SENSOR.width), np.uint8), SENSOR)


def test_update_is_safe_from_several_threads(detector):
    frames = [dots((k % 3, 0)) for k in range(24)]
    serial = [detector.update(f) for f in frames]
    with ThreadPoolExecutor(4) as pool:
        parallel = list(pool.map(detector.update, frames))
    assert parallel == serial


def test_the_paper_raw_sum_is_the_per_marker_distance_times_the_markers():
    """The paper's equation sums over every marker pixel: with 3 bars of 3 pixels shifted 2 px,
    3 * (3 * 4 + 3 * 4) = 72, so the paper's threshold 2.5 calls it moving; per marker it is 24."""

    def bars(dx):
        img = np.zeros((SENSOR.height, SENSOR.width), np.uint8)
        for x in (150, 170, 190):
            img[129:132, x + dx] = 200
        return img

    raw = RestingDetector(bars(0), SENSOR, threshold=2.5, per_marker=False, centroids=False)
    assert raw.update(bars(2)).distance == pytest.approx(72.0, rel=0.02)
    assert not raw.update(bars(2)).resting and raw.update(bars(0)).resting


def blobs(gain=1.0, shift=(0.0, 0.0), region=None) -> np.ndarray:
    """Gaussian markers (sigma 1.2 px, peak 200 over a background of 20) every 10 px inside the
    gel, the whole image times ``gain`` (a brighter or darker light); ``shift`` (dx, dy) px moves
    the markers within ``region`` px of the centre (all when None)."""
    yy, xx = np.mgrid[0 : SENSOR.height, 0 : SENSOR.width].astype(np.float64)
    img = np.full(xx.shape, 20.0)
    cx, cy = SENSOR.gel_center_px
    for y in np.arange(cy - 60, cy + 61, 10):
        for x in np.arange(cx - 60, cx + 61, 10):
            if np.hypot(x - cx, y - cy) > 60:
                continue
            inside = region is None or np.hypot(x - cx, y - cy) <= region
            dx, dy = shift if inside else (0.0, 0.0)
            img += 180.0 * np.exp(-((xx - x - dx) ** 2 + (yy - y - dy) ** 2) / (2 * 1.2**2))
    return np.clip(img * gain, 0, 255).astype(np.uint8)


@pytest.mark.parametrize("gain", [0.75, 1.25])
def test_a_flickering_light_is_not_motion_when_centroids_are_compared(gain):
    """A gel at rest under a light 25 % brighter or darker (the ``flicker`` family's extremes):
    over marker pixels (paper) a ring of pixels round every marker passes or fails the fixed
    grey level and the Chamfer distance is far above the threshold (moving); over the markers'
    weighted centroids nothing moved and the gel rests. (Grey level 120: between the blobs'
    pixel values at every gain, so that rounding to uint8 decides nothing.)"""
    pixels = RestingDetector(blobs(), SENSOR, threshold=0.4, binary_threshold=120, centroids=False)
    centroids = RestingDetector(blobs(), SENSOR, threshold=0.02, binary_threshold=120, centroids=True)
    assert not pixels.update(blobs(gain)).resting
    assert pixels.update(blobs(gain)).distance > 2.0
    result = centroids.update(blobs(gain))
    assert result.resting and result.distance <= 0.001


def test_centroids_still_see_a_local_deformation_under_any_light():
    centroids = RestingDetector(blobs(), SENSOR, threshold=0.02, binary_threshold=120, centroids=True)
    assert centroids.update(blobs()).distance == pytest.approx(0.0, abs=1e-9)
    assert len(centroids.reference_centroids) == centroids.n_markers
    for gain in (0.8, 1.0, 1.2):
        result = centroids.update(blobs(gain, shift=(0.5, 0.0), region=30))
        assert not result.resting and result.distance > 0.05


def test_the_centroid_distance_of_a_global_shift_is_twice_its_square():
    """Every centroid is |shift| from its match both ways: d = 2 |shift|^2 per marker, however
    many pixels a marker has (the pixel-set distance grows with them)."""
    centroids = RestingDetector(blobs(), SENSOR, threshold=0.02, binary_threshold=120, centroids=True)
    assert centroids.update(blobs(shift=(1.0, 1.0))).distance == pytest.approx(4.0, rel=0.01)


def test_the_centroid_kernels_give_the_weighted_means_of_each_marker():
    """The numba sums (row-major, without the GIL) equal each region's grey-weighted mean
    position computed directly with numpy, and the Chamfer sum the brute-force one."""
    import cv2

    detector = RestingDetector(blobs(), SENSOR, threshold=0.02, binary_threshold=120, centroids=True)
    image = blobs(1.1, shift=(0.4, -0.3), region=30)
    got = detector.marker_centroids(image)
    _, labels = cv2.connectedComponents(detector.marker_mask(image), connectivity=8)
    roi = image[detector._roi].astype(np.float64) - 120.0
    expected = []
    for k in range(1, labels.max() + 1):
        y, x = np.nonzero(labels == k)
        w = roi[y, x]
        expected.append(((w * x).sum() / w.sum(), (w * y).sum() / w.sum()))
    assert got == pytest.approx(np.array(expected), abs=1e-9)
    q = detector.reference_centroids
    d2 = ((got[:, None, :] - q[None, :, :]) ** 2).sum(axis=2)
    brute = (d2.min(axis=1).sum() + d2.min(axis=0).sum()) / detector.n_markers
    assert detector.update(image).distance == pytest.approx(brute, rel=1e-12)


@pytest.mark.parametrize("radius", [75.0, 300.0])
def test_the_centroids_are_the_same_whatever_the_labels_width_and_the_frames_layout(radius):
    """16-bit labels where the gel's box cannot hold more regions (a DAVIS-346's), 32-bit ones
    where it could (a 700 x 620 sensor's): the centroids of every region as with OpenCV's 32-bit
    labels and the frame copied; a frame that is a view of a larger array (not contiguous) too."""
    import cv2

    sensor = SensorGeometry(width=700, height=620, gel_center_px=(350.0, 310.0), gel_radius_px=radius)
    image = np.full((sensor.height, sensor.width), 10, dtype=np.uint8)
    rng = np.random.default_rng(3)
    ys, xs = np.nonzero(sensor.gel_mask())
    pick = rng.choice(len(ys), size=400, replace=False)
    image[ys[pick], xs[pick]] = rng.integers(130, 255, size=400)  # lone pixels and small clusters
    detector = RestingDetector(image, sensor, binary_threshold=120)
    assert detector._label_type == (cv2.CV_16U if radius == 75.0 else cv2.CV_32S)
    _, labels = cv2.connectedComponents(detector.marker_mask(image), connectivity=8, ltype=cv2.CV_32S)
    roi = image[detector._roi].astype(np.float64) - 120.0
    expected = []
    for k in range(1, labels.max() + 1):
        y, x = np.nonzero(labels == k)
        w = roi[y, x]
        expected.append(((w * x).sum() / w.sum(), (w * y).sum() / w.sum()))
    wide = np.zeros((sensor.height, sensor.width + 5), dtype=np.uint8)
    wide[:, : sensor.width] = image
    view = wide[:, : sensor.width]
    assert not view.flags.c_contiguous
    for frame in (image, view):
        assert detector.marker_centroids(frame) == pytest.approx(np.array(expected), abs=1e-9)


def test_the_chamfer_sweep_finds_every_nearest_neighbour_of_the_brute_force():
    """``_nearest_sq`` (a sweep in x that stops early) gives, for every point, exactly the minimum
    over all pairs: on random sets of different sizes, on whole-pixel points with many equal x
    and distances, and with an empty set (inf)."""
    from neurotouch_hid.pipeline.resting import _nearest_sq

    rng = np.random.default_rng(5)
    for trial in range(60):
        p = rng.uniform(0, 200, (int(rng.integers(1, 250)), 2))
        q = rng.uniform(0, 200, (int(rng.integers(1, 250)), 2))
        if trial % 2:
            p, q = np.round(p / 8.0), np.round(q / 8.0)
        d2 = ((p[:, None, :] - q[None, :, :]) ** 2).sum(axis=2)
        np.testing.assert_array_equal(_nearest_sq(p, q), d2.min(axis=1))
        np.testing.assert_array_equal(_nearest_sq(q, p), d2.min(axis=0))
    assert np.all(np.isinf(_nearest_sq(np.ones((3, 2)), np.zeros((0, 2)))))


def test_the_press_is_how_far_a_patch_of_markers_moved_not_one_marker():
    """The press (``press_px``): the largest median, over a marker and its grid neighbours, of
    their distances to the frame's nearest centroid. A patch of markers moved 0.4 px shows
    0.4 px whatever the light, while the Chamfer distance, a mean over the gel, stays below the
    near-rest threshold (0.05 px^2); one marker moved 2 px alone shows no press; at rest 0."""
    detector = RestingDetector(blobs(), SENSOR, threshold=0.01, binary_threshold=120, centroids=True)
    assert detector.update(blobs()).press_px == pytest.approx(0.0, abs=1e-6)
    for gain in (0.8, 1.0, 1.2):
        patch = detector.update(blobs(gain, shift=(0.4, 0.0), region=15))
        assert patch.press_px == pytest.approx(0.4, abs=0.03)
        assert patch.distance < 0.05
    one = detector.update(blobs(shift=(2.0, 0.0), region=1))
    assert one.distance > 0.0 and one.press_px < 0.01


def test_the_press_kernel_is_the_largest_neighbourhood_median():
    """``_press`` (numba, insertion sort) equals NumPy's median over each marker's row of
    :func:`grid_neighbours` (padding ignored), then the largest, on random distances."""
    from neurotouch_hid.pipeline.override import grid_neighbours
    from neurotouch_hid.pipeline.resting import _press

    rng = np.random.default_rng(3)
    k = np.arange(-6, 7) * 10.0
    rest = np.stack(np.meshgrid(k, k), axis=-1).reshape(-1, 2)
    rest = rest[np.hypot(*rest.T) <= 60]
    neighbours = grid_neighbours(rest)
    for _ in range(20):
        nearest_sq = rng.exponential(0.1, len(rest))
        d = np.append(np.sqrt(nearest_sq), np.nan)[neighbours]
        assert _press(nearest_sq, neighbours) == pytest.approx(np.nanmax(np.nanmedian(d, axis=1)), rel=1e-12)
    assert _press(np.zeros(0), np.zeros((0, 1), np.int64)) == 0.0
