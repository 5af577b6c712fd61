"""The whole gel's motion in its mount, read off the rim markers (not in the paper).

The paper's gesture step fits one similarity to the markers around the contacts and calls its
dominant term the gesture. When the whole dome slides or turns a little in its mount while a
finger presses (the ``drift`` physics family: up to 1.2 mm and 1.2 degrees), that rigid motion
adds to every marker's displacement: a pinch or a zoom, whose scale term at r is only a few
px, then reads as a push (on ``drift``: 151 of 772 pinch and 379 of 616 zoom windows,
docs/accuracy.md "Round 3"), and the contact homography's dynamic threshold (a times the mean
displacement) loosens.

The dome's rim is clamped in its mount, so a finger's deformation fades out towards it
(simulator: over >= 6 mm; a real gel likewise), while the mount's slip moves the rim with the
rest. The markers of the outer ring (rest distance from the gel centre >= ``rim_fraction`` of
the farthest marker's) therefore show the gel's rigid motion: a rotation theta about the gel
centre c and a translation t, fitted to them with least median of squares (robust to the few
rim markers a finger near the rim drags along; ``cv2.estimateAffinePartial2D`` with
``cv2.LMEDS``, whose scale is dropped: a rim that contracts or stretches is a pinch or a zoom,
not the mount)::

    current = c + R(theta) (p - c) + t        p: where the marker would be without the slip

A finger's deformation can still reach the rim (a wide multi-finger push, long-tailed fields):
then the rim's near side moves more than its far side, and removing the fitted motion would
remove part of the gesture (measured: on the ``fingers`` family, pushes read as pinches, gesture
accuracy -6.3 points). A slip moves every rim marker alike, so only the part that every rim
marker shares is taken: the translation's length is the :data:`SHARED_QUANTILE` quantile of
the rim markers' displacements along it (the rotation's share removed), the angle the same
quantile of their turns about c (the translation removed), each capped by the fit. A pure slip
keeps its whole motion; a push whose far rim barely moves keeps its translation.

With ``PipelineConfig.gel_motion`` the pipeline removes that motion (``remove``) before the
contact homography and the gesture's similarity, and puts it back on the contact points
(``apply``): the labels, like a user, see the contact points where they are. The intensity stays
the displacement of the markers as tracked (the labels' intensity includes the slip).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import cv2
import numpy as np

#: The outer ring: markers whose rest distance from the gel centre is at least this fraction of
#: the farthest marker's (on the simulated 177-marker gel: the outer ~60 markers).
RIM_FRACTION = 0.8
#: The shared part of the rim's motion: this quantile of the rim markers' displacements along the
#: fitted translation (and of their turns about the centre), capped by the fit (chosen, not
#: tuned: a fifth of the rim may lag behind the slip, e.g. where a finger pulls the other way).
SHARED_QUANTILE = 0.2
#: A rim whose markers' displacements are at most this (px) at the :data:`SHARED_QUANTILE` shares
#: no more motion than that (the tracker's noise): no motion, without a fit.
STILL_RIM_PX = 0.1
#: Fewer valid rim markers than this: no estimate (no motion).
MIN_RIM_MARKERS = 8


@dataclass(frozen=True)
class GelMotion:
    """A rigid motion of the whole gel, image frame.

    Attributes:
        centre_px: (2,) float64, the gel centre c (px), the rotation's origin.
        rotation_rad: theta (rad, as OpenCV measures it in the image: > 0 clockwise as displayed).
        translation_px: (2,) float64, t (px).
    """

    centre_px: np.ndarray
    rotation_rad: float = 0.0
    translation_px: np.ndarray = field(default_factory=lambda: np.zeros(2))

    def _matrix(self) -> np.ndarray:
        c, s = math.cos(self.rotation_rad), math.sin(self.rotation_rad)
        return np.array([[c, -s], [s, c]])

    def apply(self, points_px: np.ndarray) -> np.ndarray:
        """(..., 2) float64: ``points_px`` (..., 2) px moved with the gel, c + R (p - c) + t."""
        p = np.asarray(points_px, dtype=np.float64) - self.centre_px
        return p @ self._matrix().T + self.centre_px + self.translation_px

    def remove(self, points_px: np.ndarray) -> np.ndarray:
        """(..., 2) float64: the inverse of :meth:`apply` (NaN rows stay NaN)."""
        p = np.asarray(points_px, dtype=np.float64) - self.centre_px - self.translation_px
        return p @ self._matrix() + self.centre_px


def _low_quantile(values: np.ndarray) -> float:
    """The :data:`SHARED_QUANTILE` quantile of ``values`` (M,), M >= 1, as the order statistic
    below it (``np.partition``: ~10x cheaper than ``np.quantile`` on ~60 values)."""
    k = int(SHARED_QUANTILE * (len(values) - 1))
    return float(np.partition(values, k)[k])


def rim_markers(rest_px: np.ndarray, centre_px, rim_fraction: float = RIM_FRACTION) -> np.ndarray:
    """(N,) bool: the markers of the outer ring, from their rest positions (N, 2) px."""
    r = np.hypot(rest_px[:, 0] - centre_px[0], rest_px[:, 1] - centre_px[1])
    return r >= rim_fraction * r.max() if len(r) else np.zeros(0, dtype=bool)


def estimate_gel_motion(
    rest_px: np.ndarray, current_px: np.ndarray, valid: np.ndarray | None, rim: np.ndarray, centre_px
) -> GelMotion | None:
    """The gel's rigid motion from its rim markers (module docstring).

    Args:
        rest_px: (N, 2) float, rest positions (px, image frame).
        current_px: (N, 2) float, tracked positions (px); NaN rows are ignored.
        valid: (N,) bool or None, markers the tracker still follows.
        rim: (N,) bool, the rim markers (:func:`rim_markers`).
        centre_px: (2,) the gel centre (px).
    Returns:
        :class:`GelMotion`, or None (no motion: nothing to remove) when fewer than
        :data:`MIN_RIM_MARKERS` rim markers are valid, when the rim's shared displacement is at
        most :data:`STILL_RIM_PX` or when OpenCV finds no model.
    Source: ``cv2.estimateAffinePartial2D(..., method=cv2.LMEDS)``.
    """
    centre = np.asarray(centre_px, dtype=np.float64)
    use = rim & np.isfinite(current_px).all(axis=1)
    if valid is not None:
        use &= np.asarray(valid, dtype=bool)
    if int(use.sum()) < MIN_RIM_MARKERS:
        return None
    moved = current_px[use] - rest_px[use]
    if _low_quantile(np.hypot(moved[:, 0], moved[:, 1])) <= STILL_RIM_PX:
        return None  # the shared part of the rim's motion is below the tracker's noise
    src = np.ascontiguousarray(rest_px[use] - centre, dtype=np.float32)
    dst = np.ascontiguousarray(current_px[use] - centre, dtype=np.float32)
    matrix, _ = cv2.estimateAffinePartial2D(src, dst, method=cv2.LMEDS)
    if matrix is None:
        return None
    theta = math.atan2(matrix[1, 0], matrix[0, 0])
    t = matrix[:, 2].astype(np.float64)  # about the gel centre: dropping the scale leaves it as it is
    # only what every rim marker shares: a mount's slip moves the whole rim alike, a finger's
    # deformation reaching the rim moves its near side more than its far side
    src64, d = src.astype(np.float64), (dst - src).astype(np.float64)
    c, s = math.cos(theta), math.sin(theta)
    turned = src64 @ np.array([[c - 1.0, -s], [s, c - 1.0]]).T  # the fitted rotation's share of d
    norm = float(np.hypot(t[0], t[1]))
    if norm > 0:
        u = t / norm
        t = u * max(0.0, min(norm, _low_quantile((d - turned) @ u)))
    if theta != 0.0:
        sign = math.copysign(1.0, theta)
        rest = d - matrix[:, 2]  # without the fitted translation
        turn = (src64[:, 0] * rest[:, 1] - src64[:, 1] * rest[:, 0]) / np.maximum((src64 * src64).sum(axis=1), 1e-9)
        theta = sign * max(0.0, min(abs(theta), _low_quantile(sign * turn)))
    return GelMotion(centre, theta, t)
