"""The whole gel's motion in its mount, read off the rim markers (not in the paper; docs/method.md,
"Gel motion").

The paper's gesture step fits one similarity to the markers around the contacts and calls its
dominant term the gesture. When the whole dome slides or turns a little in its mount while a
finger presses (the ``drift`` physics family: up to 1.2 mm and 1.2 degrees), that rigid motion
adds to every marker's displacement: a pinch or a zoom, whose scale term at r is only a few
px, then reads as a push (on ``drift``: 151 of 772 pinch and 379 of 616 zoom windows,
docs/method.md "Gel motion"), and the contact homography's dynamic threshold (a times the mean
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

The product's pipeline (docs/method.md, "Gel motion") removes that motion (``remove``) before the
contact homography and the gesture's similarity, and puts it back on the contact points
(``apply``): the labels, like a user, see the contact points where they are. The intensity stays
the displacement of the markers as tracked (the labels' intensity includes the slip).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import cv2
import numba
import numpy as np

from neurotouch_hid.pipeline.markers import marker_arrays
from neurotouch_hid.pipeline.order import sort_head

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

    def apply(self, points_px: np.ndarray) -> np.ndarray:
        """(..., 2) float64: ``points_px`` (..., 2) px moved with the gel, c + R (p - c) + t."""
        return self._moved(points_px, False)

    def remove(self, points_px: np.ndarray) -> np.ndarray:
        """(..., 2) float64: the inverse of :meth:`apply` (NaN rows stay NaN)."""
        return self._moved(points_px, True)

    def _moved(self, points_px: np.ndarray, inverse: bool) -> np.ndarray:
        p = np.ascontiguousarray(points_px, dtype=np.float64)
        moved = _rigid_motion(p.reshape(-1, 2), self.centre_px, self.rotation_rad, self.translation_px, inverse)
        return moved.reshape(p.shape)


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _rigid_motion(
    points_px: np.ndarray, centre_px: np.ndarray, theta: float, translation_px: np.ndarray, inverse: bool
) -> np.ndarray:
    """(M, 2) float64: :meth:`GelMotion.apply` (c + R (p - c) + t) or, with ``inverse``,
    :meth:`GelMotion.remove` (c + R^T (p - c - t)) of ``points_px`` (M, 2) float64 px, image
    frame; ``centre_px`` c and ``translation_px`` t (2,) float64 px, ``theta`` rad."""
    c, s = math.cos(theta), math.sin(theta)
    cx, cy = centre_px[0], centre_px[1]
    tx, ty = translation_px[0], translation_px[1]
    m = len(points_px)
    out = np.empty((m, 2))
    for i in range(m):
        if inverse:  # R^T (p - c - t) + c
            x, y = points_px[i, 0] - cx - tx, points_px[i, 1] - cy - ty
            out[i, 0] = x * c + y * s + cx
            out[i, 1] = y * c - x * s + cy
        else:  # R (p - c) + c + t
            x, y = points_px[i, 0] - cx, points_px[i, 1] - cy
            out[i, 0] = x * c - y * s + cx + tx
            out[i, 1] = x * s + y * c + cy + ty
    return out


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _low_quantile(values: np.ndarray) -> float:
    """The :data:`SHARED_QUANTILE` quantile of ``values`` (M,) float64, M >= 1, as the order
    statistic below it (the k-th smallest, k = floor(SHARED_QUANTILE (M - 1))).

    A sorted copy (:func:`~neurotouch_hid.pipeline.order.sort_head`): M is the rim's few dozen
    markers, and numba's ``np.partition`` costs the first run ~4 s of compiling."""
    k = int(SHARED_QUANTILE * (len(values) - 1))
    ordered = values.copy()
    sort_head(ordered, len(ordered))
    return ordered[k]


def rim_markers(rest_px: np.ndarray, centre_px, rim_fraction: float = RIM_FRACTION) -> np.ndarray:
    """(N,) bool: the markers of the outer ring, from their rest positions (N, 2) px."""
    r = np.hypot(rest_px[:, 0] - centre_px[0], rest_px[:, 1] - centre_px[1])
    return r >= rim_fraction * r.max() if len(r) else np.zeros(0, dtype=bool)


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _rim_pairs(
    rest_px: np.ndarray, current_px: np.ndarray, valid: np.ndarray, rim: np.ndarray, centre_px: np.ndarray
) -> tuple[np.ndarray, np.ndarray, float]:
    """The rim markers to fit: those of ``rim`` that are ``valid`` and have a finite position.

    Args:
        rest_px, current_px: (N, 2) float64 px; valid, rim: (N,) bool (:func:`marker_arrays`).
        centre_px: (2,) float64 px, the gel centre c.
    Returns:
        (src, dst, shared_px): the M markers' rest and current positions about c, (M, 2)
        float32 px (OpenCV's input), and the :data:`SHARED_QUANTILE` quantile of their
        displacements' lengths (px), or -1.0 when M < :data:`MIN_RIM_MARKERS`.
    """
    n = len(rest_px)
    rows = np.empty(n, dtype=np.int64)
    m = 0
    for i in range(n):
        if rim[i] and valid[i] and np.isfinite(current_px[i, 0]) and np.isfinite(current_px[i, 1]):
            rows[m] = i
            m += 1
    src = np.empty((m, 2), dtype=np.float32)
    dst = np.empty((m, 2), dtype=np.float32)
    if m < MIN_RIM_MARKERS:
        return src, dst, -1.0
    lengths = np.empty(m)
    for j in range(m):
        i = rows[j]
        lengths[j] = math.hypot(current_px[i, 0] - rest_px[i, 0], current_px[i, 1] - rest_px[i, 1])
        src[j, 0] = rest_px[i, 0] - centre_px[0]
        src[j, 1] = rest_px[i, 1] - centre_px[1]
        dst[j, 0] = current_px[i, 0] - centre_px[0]
        dst[j, 1] = current_px[i, 1] - centre_px[1]
    return src, dst, _low_quantile(lengths)


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _shared_part(src: np.ndarray, dst: np.ndarray, matrix: np.ndarray) -> tuple[float, np.ndarray]:
    """The part of the fitted motion that every rim marker shares (module docstring).

    Args:
        src, dst: (M, 2) float32, M >= 2, the rim markers' rest and current positions about the
            gel centre (px, image frame), as fitted.
        matrix: (2, 3) float64, OpenCV's fit src -> dst: a rotation theta, a scale (dropped)
            and a translation (px).
    Returns:
        (theta, t): the rotation (rad) and the translation ((2,) float64 px) capped at the
        :data:`SHARED_QUANTILE` quantile of the markers' turns about the centre (the fitted
        translation removed) and of their displacements along the translation (the fitted
        rotation's share removed).
    """
    theta = math.atan2(matrix[1, 0], matrix[0, 0])
    tx, ty = matrix[0, 2], matrix[1, 2]  # about the gel centre: dropping the scale leaves it as it is
    c, s = math.cos(theta), math.sin(theta)
    norm = math.hypot(tx, ty)
    ux, uy = (tx / norm, ty / norm) if norm > 0 else (0.0, 0.0)
    sign = math.copysign(1.0, theta)
    m = len(src)
    along = np.empty(m)
    turns = np.empty(m)
    for i in range(m):
        x, y = np.float64(src[i, 0]), np.float64(src[i, 1])
        dx, dy = np.float64(dst[i, 0] - src[i, 0]), np.float64(dst[i, 1] - src[i, 1])
        # the displacement d without the fitted rotation's share, (R - I) src
        ex = dx - (x * (c - 1.0) - y * s)
        ey = dy - (x * s + y * (c - 1.0))
        along[i] = ex * ux + ey * uy
        # without the fitted translation, its turn about the centre: cross(src, d - t) / |src|^2
        rx, ry = dx - tx, dy - ty
        turns[i] = sign * ((x * ry - y * rx) / max(x * x + y * y, 1e-9))
    if norm > 0:
        shared = _low_quantile(along)
        length = norm if shared >= norm else shared  # min(norm, shared), as Python takes it
        length = 0.0 if not length > 0.0 else length  # max(0.0, length)
        tx, ty = ux * length, uy * length
    if theta != 0.0:
        shared = _low_quantile(turns)
        angle = abs(theta) if shared >= abs(theta) else shared
        theta = sign * (0.0 if not angle > 0.0 else angle)
    return theta, np.array([tx, ty])


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
    Raises:
        ValueError: the arrays do not describe the same N markers.
    Source: ``cv2.estimateAffinePartial2D(..., method=cv2.LMEDS)``.
    """
    centre = np.asarray(centre_px, dtype=np.float64)
    rest, current, valid = marker_arrays(rest_px, current_px, valid)
    if len(rim) != len(rest):
        raise ValueError(f"rim ({len(rim)},) must flag the same {len(rest)} markers as rest_px")
    src, dst, shared_px = _rim_pairs(rest, current, valid, np.ascontiguousarray(rim, dtype=bool), centre)
    if shared_px < 0.0:
        return None  # too few rim markers
    if shared_px <= STILL_RIM_PX:
        return None  # the shared part of the rim's motion is below the tracker's noise
    matrix, _ = cv2.estimateAffinePartial2D(src, dst, method=cv2.LMEDS)
    if matrix is None:
        return None
    # only what every rim marker shares: a mount's slip moves the whole rim alike, a finger's
    # deformation reaching the rim moves its near side more than its far side
    theta, translation = _shared_part(src, dst, matrix)
    return GelMotion(centre, theta, translation)


def compile_gel_motion_kernels() -> None:
    """Compile (or load from numba's cache) the kernels of :func:`estimate_gel_motion` and
    :class:`GelMotion` now, for the array types the pipeline passes them, instead of at the
    first window whose rim moves."""
    rest = np.zeros((MIN_RIM_MARKERS, 2))
    markers = np.ones(MIN_RIM_MARKERS, dtype=bool)
    src, dst, _ = _rim_pairs(rest, rest, markers, markers, np.zeros(2))
    _shared_part(src, dst, np.eye(2, 3))
    motion = GelMotion(np.zeros(2), 0.1, np.ones(2))
    motion.apply(motion.remove(rest))
