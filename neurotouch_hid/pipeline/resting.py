"""Resting position detection on APS frames (paper, section "Resting Position Detection").

The current APS frame is compared with the reference rest frame captured when the pipeline
starts, through the Chamfer distance between their marker pixels (white pixels after
thresholding, inside the gel disc). A static threshold on that distance (paper, section
"Results": 2.5) says whether the gel rests; at rest the pipeline re-initialises its tracker.

Normalisation: the paper's formula sums squared nearest distances over both point sets; a raw
sum grows with the number of marker pixels, so here each sum is divided by its set's size::

    d = mean_{p in P} min_q ||p - q||^2  +  mean_{q in Q} min_p ||p - q||^2      (px^2)

i.e. the symmetric sum of the two mean squared nearest distances. With it the paper's 2.5
separates rest (d ~ 0-1 px^2 from sensor noise) from gestures on the simulated gel (a finger
moving markers by a few px lifts d well above 2.5); ``benchmarks/bench_pipeline.py`` prints the
distances seen on rest and gesture frames.

Nearest distances come from distance transforms (``cv2.distanceTransform`` of the inverted
marker mask, linear in pixels): the reference's is computed once, the current frame's once per
frame. :meth:`RestingDetector.update` only reads the detector's precomputed state, so it may
run in its own thread beside the event path (OpenCV releases the GIL).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from neurotouch_hid.errors import SensorError
from neurotouch_hid.sensor import SensorGeometry
from neurotouch_hid.sources import Frame


@dataclass(frozen=True)
class RestingResult:
    """One frame's verdict.

    Attributes:
        resting: True when ``distance`` <= the detector's threshold.
        distance: symmetric mean squared Chamfer distance to the reference (px^2); inf when
            either frame has no marker pixel.
    """

    resting: bool
    distance: float


class RestingDetector:
    """Chamfer-distance resting detector (paper, section "Resting Position Detection").

    Args:
        reference: uint8 (height, width) APS frame of the gel at rest, image frame.
        sensor: the geometry (image size, gel disc: pixels outside it are ignored).
        threshold: Chamfer distance at or below which the gel rests (px^2); paper: 2.5.
        binary_threshold: grey level above which a pixel is a marker pixel (0..255); None =
            Otsu's threshold over the reference's gel disc, computed once and kept.
    Raises:
        SensorError: the reference is not a uint8 image of the sensor's size, or shows no
            marker pixel.
    """

    def __init__(
        self,
        reference: np.ndarray,
        sensor: SensorGeometry,
        threshold: float = 2.5,
        binary_threshold: int | None = None,
    ) -> None:
        self.sensor = sensor
        self.threshold = float(threshold)
        self._gel = sensor.gel_mask()
        ref = self._check(reference)
        if binary_threshold is None:
            level, _ = cv2.threshold(ref[self._gel > 0].reshape(-1, 1), 0, 255, cv2.THRESH_BINARY | cv2.THRESH_OTSU)
            binary_threshold = int(level)
        self.binary_threshold = int(binary_threshold)
        ref_mask = self.marker_mask(ref)
        self._ref_points = np.flatnonzero(ref_mask)
        if len(self._ref_points) == 0:
            raise SensorError("the reference APS frame shows no marker pixel inside the gel disc: no gel found")
        self._ref_dt2 = self._squared_distance_to(ref_mask).ravel()

    def _check(self, image: np.ndarray) -> np.ndarray:
        img = np.asarray(image)
        if img.dtype != np.uint8 or img.shape != (self.sensor.height, self.sensor.width):
            raise SensorError(
                f"APS frame must be uint8 of shape ({self.sensor.height}, {self.sensor.width}) as sensor.yaml says, "
                f"got {img.dtype} {img.shape}"
            )
        return img

    def marker_mask(self, image: np.ndarray) -> np.ndarray:
        """uint8 (height, width) mask: 255 on marker pixels (grey > ``binary_threshold``) inside
        the gel disc, 0 elsewhere."""
        _, mask = cv2.threshold(image, self.binary_threshold, 255, cv2.THRESH_BINARY)
        return cv2.bitwise_and(mask, self._gel)

    @staticmethod
    def _squared_distance_to(mask: np.ndarray) -> np.ndarray:
        """float32 (height, width): squared distance (px^2) from every pixel to the nearest
        marker pixel of ``mask`` (``cv2.distanceTransform`` of the inverted mask)."""
        dt = cv2.distanceTransform(cv2.bitwise_not(mask), cv2.DIST_L2, cv2.DIST_MASK_5)
        return cv2.multiply(dt, dt)

    def update(self, frame: Frame | np.ndarray) -> RestingResult:
        """The Chamfer distance of ``frame`` to the reference and the verdict.

        Args:
            frame: a :class:`~neurotouch_hid.sources.Frame` or a uint8 (height, width) image.
        Returns:
            :class:`RestingResult`. Thread-safe: reads only state fixed at construction.
        Raises:
            SensorError: the image is not uint8 of the sensor's size.
        """
        image = self._check(frame.image if isinstance(frame, Frame) else frame)
        mask = self.marker_mask(image)
        points = np.flatnonzero(mask)
        if len(points) == 0:
            return RestingResult(False, float("inf"))
        current_to_ref = float(self._ref_dt2[points].mean())
        ref_to_current = float(self._squared_distance_to(mask).ravel()[self._ref_points].mean())
        distance = current_to_ref + ref_to_current
        return RestingResult(distance <= self.threshold, distance)
