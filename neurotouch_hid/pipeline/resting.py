"""Resting position detection on APS frames (paper, section "Resting Position Detection").

The current APS frame is compared with the reference rest frame captured when the pipeline
starts, through the Chamfer distance between their marker pixels (white pixels after
thresholding, inside the gel disc). A static threshold on that distance (paper, section
"Results": 2.5) says whether the gel rests; at rest the pipeline re-initialises its tracker.

Normalisation: the paper's formula sums squared nearest distances over both point sets (marker
pixels). Raw sums grow with the number of marker pixels, so here the two sums are divided by
the number of markers in the reference (its connected components)::

    d = ( sum_{p in P} min_q ||p - q||^2  +  sum_{q in Q} min_p ||p - q||^2 ) / n_markers   (px^2)

the squared Chamfer distance *per marker*: a marker of k pixels shifted by delta px adds about
2 k delta^2. On the simulated gel (``SimulatedSource(seed=1)``, 40 s, 1000 frames) rest frames
give d <= 0.41 and the paper's threshold 2.5 gives resting precision 0.86, recall 1.00 against
the labels (a gel is labelled at rest when no marker moved more than 0.1 mm); the per-pixel mean
instead (d / pixels-per-marker, ~7 px per marker) would need a threshold near 0.1.

Nearest distances come from distance transforms (``cv2.distanceTransform`` of the inverted
marker mask, linear in pixels): the reference's is computed once, the current frame's once per
frame. :meth:`RestingDetector.update` only reads the detector's precomputed state, so it may
run in its own thread beside the event path (OpenCV releases the GIL).

Marker centroids (``centroids``, not in the paper): the marker pixels are those above a fixed
grey level, so a global change of the light (a flickering LED driver whose phase each 4 ms
exposure samples anew: the ``flicker`` physics family, +-25 % at 120 Hz) adds or removes a ring
of pixels round every marker and the pixel-set distance of a gel at rest jumps far above the
threshold (docs/method.md, "Resting": resting F1 33 % on ``flicker``). Scaling the grey level with the
frame's mean brightness does not undo it (on the simulated frames the background and the
markers do not brighten in proportion, and bright markers saturate at 255; measured: resting
F1 50 %). With ``centroids`` the same Chamfer formula is taken over the markers' centroids
instead of their pixels: each 8-connected region of marker pixels gives its grey-level-weighted
centroid, and::

    d = ( sum_{p in P} min_q ||p - q||^2  +  sum_{q in Q} min_p ||p - q||^2 ) / n_markers   (px^2)

over the current centroids P and the reference's Q. A symmetric blob's weighted centroid does
not move when the light scales it, saturates it or when the threshold takes one ring of pixels
more or less, so a resting gel gives d ~ 0 under any light; a marker shifted by delta px adds
2 delta^2 (not ~2 k delta^2 as with its k pixels), so the threshold is on another scale
(``PipelineConfig.resting.centroid_threshold_mm2``). A marker lost or split adds about its distance to the
nearest centroid squared (a pitch, ~100 px^2 at 2.5 px/mm) over n_markers. Cost per frame: one
connected-components pass over the gel's bounding box (OpenCV) and the centroid sums and the
(P x Q) nearest distances (~177^2) in numba, all without the GIL, so a resting thread does not
hold up the event path.

Press (``RestingResult.press_px``, not in the paper): the Chamfer distance is a mean over the
whole gel, so one fingertip starting to press moves it little (a dozen markers 0.1 mm from rest
add less than the near-rest threshold). Each reference marker's distance to the frame's nearest
centroid, the median over the marker and its grid neighbours (a finger moves them together, a
marker's noise does not), and the largest of these over the gel, say how far the gel is pressed
anywhere (docs/method.md, "Resting").
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numba
import numpy as np

from neurotouch_hid.core.errors import SensorError
from neurotouch_hid.core.sensor import SensorGeometry
from neurotouch_hid.pipeline.config import RestingConfig
from neurotouch_hid.pipeline.order import median_head
from neurotouch_hid.pipeline.override import grid_neighbours
from neurotouch_hid.sources import Frame


@dataclass(frozen=True)
class RestingResult:
    """One frame's verdict.

    Attributes:
        resting: True when ``distance`` <= the detector's threshold.
        distance: squared Chamfer distance per reference marker (px^2, see the module
            docstring), or the raw sum when the detector is not ``per_marker``; inf when the
            current frame has no marker pixel. From ``update(..., verdict_only=True)`` on a
            frame not at rest it may be the current-to-reference term alone (a lower bound).
        centroids_px: (M, 2) float64 the frame's marker centroids (x, y px, image frame) when
            the detector compared centroids (``centroids``), else None. The pipeline's
            frame correction fuses them into the tracker's blobs.
        press_px: the press the frame shows (px; centroids only, else 0): the largest, over the
            reference's markers, of the median over a marker and its grid neighbours of their
            distances to the frame's nearest centroid (module docstring, "Press").
    """

    resting: bool
    distance: float
    centroids_px: np.ndarray | None = field(default=None, compare=False, repr=False)
    press_px: float = 0.0


class RestingDetector:
    """Chamfer-distance resting detector (paper, section "Resting Position Detection";
    docs/method.md, "Resting"). Its defaults are the product's method: the distance over the
    markers' centroids, per marker, at the product's threshold; the paper's (the raw sum over
    marker pixels, threshold 2.5) is :class:`~neurotouch_hid.pipeline.paper.PaperPipeline`'s.

    Args:
        reference: uint8 (height, width) APS frame of the gel at rest, image frame.
        sensor: the geometry (image size, gel disc: pixels outside it are ignored; its px_per_mm
            converts the default threshold).
        threshold: Chamfer distance at or below which the gel rests (px^2); None: the product's,
            ``RestingConfig.centroid_threshold_mm2`` (mm^2) at the sensor's px_per_mm; the paper's
            raw sum over pixels: 2.5.
        binary_threshold: grey level above which a pixel is a marker pixel (0..255); None =
            Otsu's threshold over the reference's gel disc, computed once and kept.
        per_marker: True: the distance is divided by the reference's number of markers (module
            docstring); False: the paper's raw sum (px^2).
        centroids: True: the distance is taken over the markers' weighted centroids (module
            docstring, "Marker centroids"; not in the paper); False: over their pixels (the
            paper's); per marker whatever ``per_marker`` says.
    Attributes:
        n_markers: number of markers (8-connected marker-pixel regions) of the reference.
    Raises:
        SensorError: the reference is not a uint8 image of the sensor's size, or shows no
            marker pixel.
    """

    def __init__(
        self,
        reference: np.ndarray,
        sensor: SensorGeometry,
        threshold: float | None = None,
        binary_threshold: int | None = None,
        per_marker: bool = True,
        centroids: bool = True,
    ) -> None:
        self.sensor = sensor
        if threshold is None:
            s = sensor.px_per_mm
            threshold = RestingConfig().centroid_threshold_mm2 * s * s
        self.threshold = float(threshold)
        self.per_marker = bool(per_marker)
        self.centroids = bool(centroids)
        # Work on the gel disc's bounding box only: every marker pixel lies inside it, so the
        # distances there are the whole image's (4x fewer pixels on a DAVIS-346).
        cx, cy = sensor.gel_center_px
        r = sensor.gel_radius_px + 2.0
        self._roi = (
            slice(max(0, int(cy - r)), min(sensor.height, int(cy + r) + 2)),
            slice(max(0, int(cx - r)), min(sensor.width, int(cx + r) + 2)),
        )
        self._gel = np.ascontiguousarray(sensor.gel_mask()[self._roi])
        # 16-bit labels when the box cannot hold more regions (8-connected regions are a pixel
        # apart: at most one per 2 x 2 pixels; 6,241 in a DAVIS-346's gel box): half the memory
        # of 32-bit ones to write and read back once a frame, the same labels
        h, w = self._gel.shape
        self._label_type = cv2.CV_16U if -(-h // 2) * -(-w // 2) < 2**16 else cv2.CV_32S
        ref = self._check(reference)
        if binary_threshold is None:
            level, _ = cv2.threshold(
                ref[self._roi][self._gel > 0].reshape(-1, 1), 0, 255, cv2.THRESH_BINARY | cv2.THRESH_OTSU
            )
            binary_threshold = int(level)
        self.binary_threshold = int(binary_threshold)
        ref_mask = self.marker_mask(ref)
        self._ref_points = np.flatnonzero(ref_mask)
        if len(self._ref_points) == 0:
            raise SensorError("the reference APS frame shows no marker pixel inside the gel disc: no gel found")
        self._ref_dt2 = self._squared_distance_to(ref_mask).ravel()
        n_labels, _ = cv2.connectedComponents(ref_mask, connectivity=8)
        self.n_markers = n_labels - 1
        #: (n_markers, 2) float64 the reference's marker centroids (px, gel bounding box)
        self.reference_centroids = self.marker_centroids(ref)
        #: (n_markers, k) int64 each reference marker, then its grid neighbours, padded with n_markers
        self._neighbours = grid_neighbours(self.reference_centroids)

    def _check(self, image: np.ndarray) -> np.ndarray:
        img = np.asarray(image)
        if img.dtype != np.uint8 or img.shape != (self.sensor.height, self.sensor.width):
            raise SensorError(
                f"APS frame must be uint8 of shape ({self.sensor.height}, {self.sensor.width}) as sensor.yaml says, "
                f"got {img.dtype} {img.shape}"
            )
        return img

    def marker_mask(self, image: np.ndarray) -> np.ndarray:
        """uint8 mask of the gel's bounding box of ``image`` (uint8 (height, width)): 255 on
        marker pixels (grey > ``binary_threshold``) inside the gel disc, 0 elsewhere."""
        _, mask = cv2.threshold(image[self._roi], self.binary_threshold, 255, cv2.THRESH_BINARY)
        return cv2.bitwise_and(mask, self._gel)

    def marker_centroids(self, image: np.ndarray) -> np.ndarray:
        """(M, 2) float64 grey-level-weighted centroids (x, y px, relative to the gel's bounding
        box) of the 8-connected regions of marker pixels of ``image`` (uint8 (height, width));
        each pixel weighs its grey level above ``binary_threshold``. OpenCV labels the regions
        and a numba kernel sums them (both without the GIL)."""
        mask = self.marker_mask(image)
        n, labels = cv2.connectedComponents(mask, connectivity=8, ltype=self._label_type)
        rows, cols = self._roi
        image = image if image.flags.c_contiguous else np.ascontiguousarray(image)
        return _weighted_centroids(labels, image, rows.start, cols.start, n, float(self.binary_threshold))

    def _centroid_verdict(self, image: np.ndarray) -> RestingResult:
        """The verdict from the Chamfer distance between the centroids of ``image`` and the
        reference's (px^2) and the press it shows (px), with the centroids in the image frame."""
        p = self.marker_centroids(image)
        if len(p) == 0:
            return RestingResult(False, float("inf"), p)
        chamfer, press = _chamfer_and_press(p, self.reference_centroids, self._neighbours)
        distance = chamfer / (self.n_markers if self.per_marker else 1)
        p[:, 0] += self._roi[1].start
        p[:, 1] += self._roi[0].start
        return RestingResult(distance <= self.threshold, distance, p, press)

    @staticmethod
    def _squared_distance_to(mask: np.ndarray) -> np.ndarray:
        """float32, the mask's shape: squared distance (px^2) from every pixel to the nearest
        marker pixel of ``mask`` (``cv2.distanceTransform`` of the inverted mask)."""
        dt = cv2.distanceTransform(cv2.bitwise_not(mask), cv2.DIST_L2, cv2.DIST_MASK_5)
        return cv2.multiply(dt, dt)

    def update(self, frame: Frame | np.ndarray, *, verdict_only: bool = False) -> RestingResult:
        """The Chamfer distance of ``frame`` to the reference and the verdict.

        Args:
            frame: a :class:`~neurotouch_hid.sources.Frame` or a uint8 (height, width) image.
            verdict_only: stop as soon as the verdict is certain: both terms of the distance
                are >= 0, so when the current-to-reference term alone is above the threshold
                the gel is not at rest, and the frame's own distance transform (~2/3 of the
                cost; about half the frames of a session) is skipped. The verdict is the same
                as without; ``distance`` is then that term (a lower bound). Pixel sets only:
                with ``centroids`` the whole (cheaper) distance is always taken.
        Returns:
            :class:`RestingResult`. Thread-safe: reads only state fixed at construction.
        Raises:
            SensorError: the image is not uint8 of the sensor's size.
        """
        image = self._check(frame.image if isinstance(frame, Frame) else frame)
        if self.centroids:
            return self._centroid_verdict(image)
        mask = self.marker_mask(image)
        points = np.flatnonzero(mask)
        if len(points) == 0:
            return RestingResult(False, float("inf"))
        current_to_ref = float(self._ref_dt2[points].sum())
        scale = self.n_markers if self.per_marker else 1
        if verdict_only and current_to_ref / scale > self.threshold:
            return RestingResult(False, current_to_ref / scale)
        ref_to_current = float(self._squared_distance_to(mask).ravel()[self._ref_points].sum())
        distance = (current_to_ref + ref_to_current) / scale
        return RestingResult(distance <= self.threshold, distance)


def compile_resting_kernels() -> None:
    """Compile (or load from numba's cache) the centroid kernels now, for the array types
    :meth:`RestingDetector.marker_centroids` passes them, instead of at the first APS frame."""
    image = np.zeros((2, 2), np.uint8)
    _weighted_centroids(np.zeros((2, 2), np.int32), image, 0, 0, 2, 0.0)  # a box too large for 16 bits
    centroids = _weighted_centroids(np.zeros((2, 2), np.uint16), image, 0, 0, 2, 0.0)
    _chamfer_and_press(centroids, centroids, np.zeros((len(centroids), 1), np.int64))


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _weighted_centroids(labels: np.ndarray, image: np.ndarray, top: int, left: int, n: int, level: float) -> np.ndarray:
    """(n - 1, 2) float64: the centroids (x, y px, relative to ``labels``) of regions 1 .. n-1 of
    ``labels`` (uint16 or int32 (h, w), 0 = background, the box of ``image`` from row ``top`` and column
    ``left``), each pixel weighted by its grey level in ``image`` (uint8 (H, W), the whole
    frame: no copy of the box) minus ``level``; summed in row-major order."""
    total = np.zeros(n)
    sx = np.zeros(n)
    sy = np.zeros(n)
    for y in range(labels.shape[0]):
        for x in range(labels.shape[1]):
            k = labels[y, x]
            if k > 0:
                w = np.float64(image[top + y, left + x]) - level
                total[k] += w
                sx[k] += w * x
                sy[k] += w * y
    out = np.empty((max(n - 1, 0), 2))
    for k in range(1, n):
        t = max(total[k], 1e-9)
        out[k - 1, 0] = sx[k] / t
        out[k - 1, 1] = sy[k] / t
    return out


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _chamfer_and_press(p: np.ndarray, q: np.ndarray, neighbours: np.ndarray) -> tuple[float, float]:
    """The Chamfer sum of the frame's centroids ``p`` (P, 2) and the reference's ``q`` (Q, 2)
    float64 (px^2: sum over p of min_q ||p - q||^2 + sum over q of min_p ||p - q||^2, the paper's,
    section "Resting Position Detection") and the press the frame shows (px, :func:`_press`,
    ``neighbours`` (Q, k) int64 the reference's grid neighbours): one call, both from the same
    nearest distances (:func:`_nearest_sq`)."""
    reference_to_current = _nearest_sq(q, p)
    return _nearest_sq(p, q).sum() + reference_to_current.sum(), _press(reference_to_current, neighbours)


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _press(nearest_sq: np.ndarray, neighbours: np.ndarray) -> float:
    """The press a frame shows (px): over the reference's markers, the largest median of the
    distances ``sqrt(nearest_sq)`` ((N,) float64, each reference marker's squared distance to
    the frame's nearest centroid, px^2) over a marker and its grid neighbours (``neighbours``,
    (N, k) int64, :func:`~neurotouch_hid.pipeline.override.grid_neighbours`, padded with N).
    A finger moves a marker's neighbours with it; one marker's noise or a lost marker does not
    move the median. 0 when N = 0."""
    largest = 0.0
    near = np.empty(neighbours.shape[1])
    for i in range(len(nearest_sq)):
        k = 0
        for j in neighbours[i]:
            if j < len(nearest_sq):
                near[k] = np.sqrt(nearest_sq[j])
                k += 1
        largest = max(largest, median_head(near, k))  # of the (<= 5) distances
    return largest


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _nearest_sq(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """(P,) float64: each point of ``p`` (P, 2)'s squared distance (px^2) to its nearest point of
    ``q`` (Q, 2), inf when Q = 0. ``q`` is sorted by x once; from each point's place in that
    order the sweep goes outwards on both sides and stops where the gap in x alone is no
    shorter than the nearest distance found (the sweep of a sorted nearest-neighbour search)."""
    out = np.full(len(p), np.inf)
    order = np.argsort(q[:, 0])
    xs = q[order, 0]
    ys = q[order, 1]
    for i in range(len(p)):
        x = p[i, 0]
        y = p[i, 1]
        best = np.inf
        start = np.searchsorted(xs, x)
        for k in range(start, len(xs)):
            dx = xs[k] - x
            if dx * dx >= best:
                break
            dy = ys[k] - y
            best = min(best, dx * dx + dy * dy)
        for k in range(start - 1, -1, -1):
            dx = x - xs[k]
            if dx * dx >= best:
                break
            dy = y - ys[k]
            best = min(best, dx * dx + dy * dy)
        out[i] = best
    return out
