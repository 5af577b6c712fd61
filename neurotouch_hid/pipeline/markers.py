"""Marker detection on an APS frame: white dots on the black gel (paper, section Marker Tracking).

The paper initialises its event-blob tracker "on the APS frame received at t0, by thresholding
the image and extracting white connected regions". :func:`detect_markers` does exactly that with
OpenCV (Otsu threshold over the gel disc, ``cv2.connectedComponentsWithStats``), then refines
each region to an intensity-weighted, sub-pixel centroid. :func:`looks_like_marker_grid` tells
a marker grid from any other scene (a street, a dark frame) so the pipeline can say "no gel found".

Nothing here assumes a number of markers: the count is whatever the frame shows.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import cv2
import numpy as np

from neurotouch_hid.core.errors import SensorError
from neurotouch_hid.core.sensor import MARKER_SPACING_MM, SensorGeometry

#: The gel's markers (paper, section System Overview): 1 mm white dots on a 4 mm grid
#: (``sensor.MARKER_SPACING_MM``, imported here for the pipeline and calibrate).
MARKER_DIAMETER_MM = 1.0


@dataclass
class Markers:
    """Markers found on one APS frame.

    Attributes:
        centroids_px: (N, 2) float32, intensity-weighted centroids (x, y), image frame, px.
        sizes_px: (N,) float32, area of each thresholded blob, px (pixel count).
    """

    centroids_px: np.ndarray
    sizes_px: np.ndarray

    def __len__(self) -> int:
        return int(self.centroids_px.shape[0])


def expected_marker_area_px(sensor: SensorGeometry) -> float:
    """Area (px) of one 1 mm marker at the gel centre's scale: pi * (px_per_mm / 2)^2."""
    return math.pi * (MARKER_DIAMETER_MM * sensor.px_per_mm / 2.0) ** 2


def expected_marker_spacing_px(sensor: SensorGeometry) -> float:
    """Distance (px) between neighbouring markers at the gel centre's scale (4 mm grid)."""
    return MARKER_SPACING_MM * sensor.px_per_mm


def detect_markers(
    image: np.ndarray,
    sensor: SensorGeometry,
    threshold: int | None = None,
    *,
    min_area_px: float | None = None,
    max_area_px: float | None = None,
) -> Markers:
    """Detect the white markers on an APS frame (paper, section Marker Tracking).

    Steps: threshold (Otsu over the pixels of the gel disc unless ``threshold`` is given),
    ``cv2.connectedComponentsWithStats`` (8-connectivity), area filter, intensity-weighted
    centroid of each blob over the blob grown by one pixel (so the dot's dim rim counts too,
    which keeps the centroid sub-pixel accurate on a 2.5 px dot), background subtracted.
    Blobs whose centroid lies outside the gel circle (``sensor.inside_gel``) are rejected.

    Args:
        image: uint8 (height, width) grey APS frame, image frame.
        sensor: the sensor geometry (gel circle, px_per_mm).
        threshold: fixed grey-level threshold (0..255; pixels > threshold are white), or None
            for Otsu's threshold over the gel disc.
        min_area_px, max_area_px: accepted blob area (px). Defaults: 0.2x and 6x the area of
            a 1 mm dot at ``sensor.px_per_mm``, and at least 1 px.
    Returns:
        :class:`Markers`, ordered by the blobs' labels (raster order of their first pixel).
    Raises:
        SensorError: the image is not a 2-D uint8 array of the sensor's size.
    """
    img = np.asarray(image)
    if img.ndim == 3 and img.shape[2] == 1:
        img = img[:, :, 0]
    if img.ndim != 2 or img.dtype != np.uint8:
        raise SensorError(f"APS frame must be a 2-D uint8 grey image, got shape {img.shape} dtype {img.dtype}")
    if img.shape != (sensor.height, sensor.width):
        raise SensorError(
            f"APS frame is {img.shape[1]}x{img.shape[0]} px but sensor.yaml says {sensor.width}x{sensor.height}"
        )
    area = expected_marker_area_px(sensor)
    lo = max(1.0, 0.2 * area) if min_area_px is None else float(min_area_px)
    hi = max(4.0, 6.0 * area) if max_area_px is None else float(max_area_px)

    gel = _gel_mask(sensor)
    if threshold is None:
        level, _ = cv2.threshold(img[gel > 0].reshape(-1, 1), 0, 255, cv2.THRESH_BINARY | cv2.THRESH_OTSU)
    else:
        level = float(threshold)
    _, binary = cv2.threshold(img, level, 1, cv2.THRESH_BINARY)
    n, labels, stats, _ = cv2.connectedComponentsWithStats(binary, connectivity=8, ltype=cv2.CV_32S)
    if n <= 1:
        return Markers(np.zeros((0, 2), np.float32), np.zeros(0, np.float32))

    # Background: the mean grey level of the dark pixels of the gel.
    background = cv2.mean(img, mask=cv2.bitwise_and(gel, 1 - binary))[0]

    # Grow each blob by one pixel (labels are far apart: markers are ~10 px apart) and take the
    # background-subtracted intensity-weighted centroid over the grown region.
    grown = cv2.dilate(labels.astype(np.float32), np.ones((3, 3), np.uint8))
    grown = np.where(labels > 0, labels, grown.astype(np.int32)).ravel()
    pixels = np.flatnonzero(grown)
    owner = grown[pixels]
    ys, xs = np.divmod(pixels, img.shape[1])
    weights = np.clip(img.ravel()[pixels] - background, 0.0, None)
    w_sum = np.bincount(owner, weights, minlength=n)[1:]
    wx = np.bincount(owner, weights * xs, minlength=n)[1:]
    wy = np.bincount(owner, weights * ys, minlength=n)[1:]

    sizes = stats[1:, cv2.CC_STAT_AREA].astype(np.float32)
    ok = w_sum > 0
    centroids = np.stack([wx, wy], axis=1) / np.where(ok, w_sum, 1.0)[:, None]
    keep = (sizes >= lo) & (sizes <= hi) & ok & sensor.inside_gel(centroids)
    return Markers(centroids[keep].astype(np.float32), sizes[keep])


@functools.lru_cache(maxsize=8)
def _gel_mask(sensor: SensorGeometry) -> np.ndarray:
    """uint8 (height, width) mask of the gel disc, 1 inside (cached per geometry)."""
    mask = (sensor.gel_mask() > 0).astype(np.uint8)
    mask.setflags(write=False)
    return mask


def nearest_neighbour_distances(points_px: np.ndarray) -> np.ndarray:
    """(N,) float64 distance (px) from each point of (N, 2) ``points_px`` to its nearest other point
    (inf when N < 2)."""
    p = np.asarray(points_px, dtype=np.float64)
    if len(p) < 2:
        return np.full(len(p), np.inf)
    d = np.hypot(p[:, None, 0] - p[None, :, 0], p[:, None, 1] - p[None, :, 1])
    np.fill_diagonal(d, np.inf)
    return d.min(axis=1)


def looks_like_marker_grid(markers: Markers, sensor: SensorGeometry, *, min_markers: int = 20) -> bool:
    """Whether detected blobs look like the gel's marker grid rather than some other scene.

    A marker grid (paper, section System Overview: 1 mm dots on a 4 mm grid) has: at least
    ``min_markers`` blobs; blobs of consistent small size (median area within 0.25x..4x that of a
    1 mm dot, and 80 % of blobs within 0.3x..3x the median); a regular nearest-neighbour spacing
    (median nearest-neighbour distance within 0.6x..1.6x the 4 mm grid's spacing in px, and
    75 % of blobs within 0.6x..1.4x that median); and blobs spread over the gel disc (their
    bounding box at least half the gel's diameter wide and high).

    Args:
        markers: output of :func:`detect_markers`.
        sensor: geometry (px_per_mm, gel circle).
        min_markers: fewest blobs accepted as a grid.
    Returns:
        True when the blobs look like a marker grid.
    """
    n = len(markers)
    if n < max(min_markers, 3):
        return False
    sizes = markers.sizes_px.astype(np.float64)
    med_size = float(np.median(sizes))
    area = expected_marker_area_px(sensor)
    if not 0.25 * area <= med_size <= 4.0 * area:
        return False
    if np.mean((sizes >= 0.3 * med_size) & (sizes <= 3.0 * med_size)) < 0.8:
        return False
    nn = nearest_neighbour_distances(markers.centroids_px)
    med_nn = float(np.median(nn))
    spacing = expected_marker_spacing_px(sensor)
    if not 0.6 * spacing <= med_nn <= 1.6 * spacing:
        return False
    if np.mean((nn >= 0.6 * med_nn) & (nn <= 1.4 * med_nn)) < 0.75:
        return False
    extent = markers.centroids_px.max(axis=0) - markers.centroids_px.min(axis=0)
    return bool(np.all(extent >= sensor.gel_radius_px))


def marker_arrays(
    rest_px: np.ndarray, current_px: np.ndarray, valid: np.ndarray | None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One window's markers as the pipeline's numba kernels take them: rest and current positions
    (N, 2) float64 px (image frame, C order) and the markers the tracker follows (N,) bool (all
    when ``valid`` is None). The kernels index the three arrays together without bounds checks.

    Raises:
        ValueError: the arrays do not describe the same N markers (shapes (N, 2), (N, 2), (N,)).
    """
    rest = np.ascontiguousarray(rest_px, dtype=np.float64)
    current = np.ascontiguousarray(current_px, dtype=np.float64)
    followed = np.ones(len(current), dtype=bool) if valid is None else np.ascontiguousarray(valid, dtype=bool)
    if rest.ndim != 2 or rest.shape[1:] != (2,) or current.shape != rest.shape or followed.shape != rest.shape[:1]:
        raise ValueError(
            f"rest_px {rest.shape}, current_px {current.shape} and valid {followed.shape} must describe the same "
            "N markers: (N, 2), (N, 2) and (N,)"
        )
    return rest, current, followed
