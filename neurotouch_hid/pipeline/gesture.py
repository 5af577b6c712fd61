"""Gesture type and intensity (paper, section "Gesture Classification and Intensity Prediction";
docs/method.md, "Gesture").

The markers within r of a contact point form the set A. A 4-DoF similarity (scale s, rotation
theta, translation t) is fitted with RANSAC to their motion from rest to now, about the contact
points' mean (the paper's transformation origin). The dominant term gives the type: a
translation is a push, a scale below 1 a pinch, above 1 a zoom, a rotation a twist. Each term is
made a length, the displacement it causes at distance r from the origin (``|s - 1| r``,
``|theta| r``, ``||t||``, px), so that they compare.

The product departs from the paper (docs/method.md, "Gesture"): the translation term is taken at
the best origin within ``origin_radius_px`` of the contacts' mean, ``max(0, ||t|| - m rho)`` with
``m = |s e^{i theta} - 1|``; the intensity is a proximity-weighted mean of ||v_i|| over A
(:func:`weighted_intensity`, sigma ``intensity_sigma_px``) instead of the paper's uniform mean.

Orientation: OpenCV's angle is measured in the image frame (y down), so a positive cv2 angle
turns clockwise as displayed; :meth:`SensorGeometry.rotation_image_to_user` turns ``-theta`` into
the user frame, where clockwise/counter-clockwise are decided. Intensities are converted to mm
with ``sensor.px_per_mm``, or with the camera model (``SensorGeometry.radial_k``) where each
displacement lies on the gel (docs/method.md, "Camera model").
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import cv2
import numba
import numpy as np

from neurotouch_hid.core.estimate import GestureType
from neurotouch_hid.core.sensor import SensorGeometry
from neurotouch_hid.pipeline.gel_motion import GelMotion
from neurotouch_hid.pipeline.markers import marker_arrays


@dataclass(frozen=True)
class Similarity:
    """A 4-DoF similarity p' = s R(theta) p + t about an origin, image frame.

    Attributes:
        scale: s (1 = unchanged).
        rotation_rad: theta as OpenCV reports it in the image frame (y down): > 0 turns
            clockwise as displayed.
        translation_px: (2,) float64, t in image px (x right, y down).
    """

    scale: float = 1.0
    rotation_rad: float = 0.0
    translation_px: np.ndarray = field(default_factory=lambda: np.zeros(2))

    def terms_px(self, r_px: float, origin_radius_px: float = 10.0) -> tuple[float, float, float]:
        """(scale, rotation, translation) as displacements at distance r (px): the quantities
        compared to pick the gesture type (see the module docstring).

        ``origin_radius_px`` (px): the smallest translation over origins within that distance of
        the fitted one, ``max(0, ||t|| - m rho)`` with ``m = |s e^{i theta} - 1|`` (moving the
        origin by o changes t by (sR - I) o, a scaled rotation of norm m); 0 = about the fitted
        origin (paper)."""
        translation = math.hypot(self.translation_px[0], self.translation_px[1])
        m = math.hypot(self.scale * math.cos(self.rotation_rad) - 1.0, self.scale * math.sin(self.rotation_rad))
        translation = max(0.0, translation - m * origin_radius_px)
        return abs(self.scale - 1.0) * r_px, abs(self.rotation_rad) * r_px, translation


@dataclass(frozen=True)
class GestureResult:
    """One window's gesture.

    Attributes:
        gesture: the dominant type (``NONE`` when nothing moves or there is no contact).
        intensity_px: the intensity (px): mean ||v_i|| over A, or its proximity-weighted
            profile (:func:`weighted_intensity`); 0 when there is no A.
        intensity_mm: the same in mm: px / sensor.px_per_mm, or, with the sensor's camera model
            (``radial_k``), the same profile of the displacements converted to mm where they are.
        similarity: the fitted similarity (image frame).
        area: (N,) bool, the markers of A.
        translation_mm: (2,) float64, the translation in the user frame (mm; with the camera
            model, as moved at the contacts' mean).
        rotation_rad: the rotation in the user frame (rad, counter-clockwise > 0).
    """

    gesture: GestureType
    intensity_px: float
    intensity_mm: float
    similarity: Similarity
    area: np.ndarray
    translation_mm: np.ndarray
    rotation_rad: float


def markers_near(points_px: np.ndarray, centres_px: np.ndarray, r_px: float) -> np.ndarray:
    """The set A: markers whose distance to at least one centre is < r (paper).

    Args:
        points_px: (N, 2) float, marker positions (px); NaN rows are never in A.
        centres_px: (K, 2) float, contact points (px).
        r_px: radius r (px).
    Returns:
        (N,) bool.
    """
    p = np.ascontiguousarray(points_px, dtype=np.float64)
    c = np.ascontiguousarray(centres_px, dtype=np.float64).reshape(-1, 2)
    return _near(p, c, float(r_px) * float(r_px))


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _near(points_px: np.ndarray, centres_px: np.ndarray, r2: float) -> np.ndarray:
    """:func:`markers_near` with r2 = r^2 (px^2), without NumPy's (N, K) temporaries."""
    near = np.zeros(len(points_px), dtype=np.bool_)
    for i in range(len(points_px)):
        for k in range(len(centres_px)):
            dx = points_px[i, 0] - centres_px[k, 0]
            dy = points_px[i, 1] - centres_px[k, 1]
            if dx * dx + dy * dy < r2:  # False for NaN rows
                near[i] = True
                break
    return near


def weighted_intensity(
    rest_px: np.ndarray, current_px: np.ndarray, contacts_px: np.ndarray, sigma_px: float = 3.0
) -> float:
    """Gesture intensity (px) of the markers of A (paper, eq. "Gesture Intensity", or a
    proximity-weighted profile, see the module docstring).

    Args:
        rest_px: (M, 2) float, rest positions of A's markers (px).
        current_px: (M, 2) float, their current positions (px), finite.
        contacts_px: (K, 2) float, contact points (px), K >= 1.
        sigma_px: > 0: the mean weighted by ``exp(-d_i^2 / (2 sigma^2))``, d_i = distance (px) of
            marker i to its nearest contact; 0: the paper's uniform mean of ||v_i||.
    Returns:
        the intensity (px); 0 when M = 0.
    """
    rest = np.asarray(rest_px, dtype=np.float64)
    cur = np.ascontiguousarray(current_px, dtype=np.float64)
    if len(cur) == 0:
        return 0.0
    norms = np.hypot(cur[:, 0] - rest[:, 0], cur[:, 1] - rest[:, 1])
    contacts = np.ascontiguousarray(contacts_px, dtype=np.float64).reshape(-1, 2)
    return _profile(norms, cur, contacts, float(sigma_px))


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _profile(norms: np.ndarray, current_px: np.ndarray, contacts_px: np.ndarray, sigma_px: float) -> float:
    """:func:`weighted_intensity` from the norms ||v_i|| (M,) float64, M >= 1, of the markers at
    ``current_px`` (M, 2) px; ``sigma_px`` 0.0 = the uniform mean."""
    if sigma_px == 0.0:
        return norms.sum() / len(norms)
    return _weighted_mean(norms, current_px, contacts_px, sigma_px)


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _weighted_mean(norms: np.ndarray, current_px: np.ndarray, contacts_px: np.ndarray, sigma_px: float) -> float:
    """The proximity-weighted mean of :func:`weighted_intensity` in one pass over the markers."""
    m = len(norms)
    d2 = np.empty(m)
    for i in range(m):
        best = np.inf
        for k in range(len(contacts_px)):
            dx = current_px[i, 0] - contacts_px[k, 0]
            dy = current_px[i, 1] - contacts_px[k, 1]
            best = min(best, dx * dx + dy * dy)
        d2[i] = best
    lowest = d2.min()
    total = 0.0
    weight_sum = 0.0
    for i in range(m):
        weight = np.exp(-(d2[i] - lowest) / (2.0 * sigma_px * sigma_px))  # shifted: never all 0
        total += weight * norms[i]
        weight_sum += weight
    return total / weight_sum


def fit_similarity(
    rest_px: np.ndarray, current_px: np.ndarray, origin_px: np.ndarray, reproj_threshold_px: float
) -> Similarity:
    """Fit a 4-DoF similarity rest -> current about ``origin_px`` with RANSAC.

    Args:
        rest_px: (M, 2) float, rest positions of A (px).
        current_px: (M, 2) float, current positions of A (px).
        origin_px: (2,) float, the transformation origin (px), subtracted from both sets.
        reproj_threshold_px: RANSAC reprojection threshold (px), > 0.
    Returns:
        :class:`Similarity`. With fewer than 2 markers, or when OpenCV finds no model, the
        least-squares translation (mean displacement) with s = 1 and theta = 0.
    Source: ``cv2.estimateAffinePartial2D(..., method=cv2.RANSAC)``.
    """
    src, dst = _centred(
        np.ascontiguousarray(rest_px, dtype=np.float64),
        np.ascontiguousarray(current_px, dtype=np.float64),
        np.ascontiguousarray(origin_px, dtype=np.float64),
    )
    return _ransac_similarity(src, dst, reproj_threshold_px)


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _centred(rest_px: np.ndarray, current_px: np.ndarray, origin_px: np.ndarray):
    """(src, dst), each (M, 2) float32: ``rest_px`` and ``current_px`` (M, 2) float64 px less
    ``origin_px`` (2,) px, subtracted in float64 and then rounded, as OpenCV takes them."""
    src = np.empty(rest_px.shape, dtype=np.float32)
    dst = np.empty(current_px.shape, dtype=np.float32)
    for i in range(len(rest_px)):
        for j in range(2):
            src[i, j] = rest_px[i, j] - origin_px[j]
            dst[i, j] = current_px[i, j] - origin_px[j]
    return src, dst


def _ransac_similarity(src: np.ndarray, dst: np.ndarray, reproj_threshold_px: float) -> Similarity:
    """:func:`fit_similarity` on the centred (M, 2) float32 point sets of :func:`_centred`."""
    matrix = None
    if len(src) >= 2:
        matrix, _ = cv2.estimateAffinePartial2D(
            src, dst, method=cv2.RANSAC, ransacReprojThreshold=float(reproj_threshold_px)
        )
    if matrix is None:
        mean = (dst.astype(np.float64) - src).mean(axis=0) if len(src) else np.zeros(2)
        return Similarity(translation_px=mean)
    scale = math.hypot(matrix[0, 0], matrix[1, 0])
    theta = math.atan2(matrix[1, 0], matrix[0, 0])
    return Similarity(scale=scale, rotation_rad=theta, translation_px=matrix[:, 2].copy())


def classify(
    similarity: Similarity, r_px: float, sensor: SensorGeometry, origin_radius_px: float = 10.0
) -> GestureType:
    """The dominant term of the similarity (paper, eq. "Gesture Type"), terms in px at radius r
    (``origin_radius_px``: see :meth:`Similarity.terms_px`).

    A rotation's direction is taken in the user frame (see the module docstring): user angle
    > 0 is counter-clockwise (``TWIST_CCW``), < 0 clockwise (``TWIST_CW``).
    """
    scale_px, rotation_px, translation_px = similarity.terms_px(r_px, origin_radius_px)
    if scale_px >= rotation_px and scale_px >= translation_px:  # the first maximum wins ties
        return GestureType.ZOOM if similarity.scale > 1.0 else GestureType.PINCH
    if rotation_px >= translation_px:
        user = user_rotation(similarity.rotation_rad, sensor)
        return GestureType.TWIST_CCW if user > 0 else GestureType.TWIST_CW
    return GestureType.PUSH


def user_rotation(image_rotation_rad: float, sensor: SensorGeometry) -> float:
    """An OpenCV angle in the image frame (y down, > 0 clockwise as displayed) in the user
    frame (rad, counter-clockwise > 0)."""
    return float(sensor.rotation_image_to_user(-image_rotation_rad))


def _nothing(area: np.ndarray) -> GestureResult:
    return GestureResult(GestureType.NONE, 0.0, 0.0, Similarity(), area, np.zeros(2), 0.0)


def estimate_gesture(
    rest_px: np.ndarray,
    current_px: np.ndarray,
    valid: np.ndarray | None,
    contacts_px: np.ndarray,
    sensor: SensorGeometry,
    *,
    r_px: float = 25.0,
    reproj_factor: float = 2.0,
    min_reproj_px: float = 0.5,
    min_intensity_px: float = 0.3,
    intensity_sigma_px: float = 3.0,
    origin_radius_px: float = 10.0,
    gel_motion: GelMotion | None = None,
    type_centres_px: np.ndarray | None = None,
) -> GestureResult:
    """Gesture type and intensity from the markers around the contact points (the product's
    defaults; the paper's method passes its own, ``paper.py``).

    Args:
        rest_px: (N, 2) float, rest positions (px, image frame).
        current_px: (N, 2) float, tracked positions (px, image frame).
        valid: (N,) bool or None, markers the tracker still follows.
        contacts_px: (K, 2) float, contact points (px, image frame).
        sensor: the geometry (px/mm, image -> user frame).
        r_px: radius r defining A (px).
        reproj_factor: the similarity's RANSAC threshold is ``reproj_factor`` x the mean
            ||v_i|| over A (dynamic, like the contact stage's), at least ``min_reproj_px``.
        min_reproj_px: floor of that threshold (px).
        min_intensity_px: below this intensity (px), nothing moves: ``NONE``.
        intensity_sigma_px: the intensity profile (:func:`weighted_intensity`): > 0 = weighted by
            proximity to the contacts (px); 0 = the paper's mean ||v_i|| over A.
        origin_radius_px: the translation term at the best origin within this distance (px) of
            the contacts' mean; 0 = about the contacts' mean (paper).
        gel_motion: None (paper), or the whole gel's rigid motion in its mount
            (:mod:`~neurotouch_hid.pipeline.gel_motion`): removed from A's current positions and
            from the origin before the similarity is fitted, so that the type and the
            similarity's terms are the fingers' own; A and the intensity stay as tracked.
        type_centres_px: None, or (K', 2) float px: the centres about which the type is read
            (the similarity's set A' of the markers within r of them and its origin, their mean)
            while A, the intensity and ``NONE`` stay about ``contacts_px`` (the field's maxima):
            the fitted fingers' centres where neighbouring fingers' fields push the maxima
            outward (docs/method.md, "Gesture"). A' empty: about ``contacts_px``.
    Returns:
        :class:`GestureResult`; ``NONE`` with zero intensity when there is no contact, A is
        empty or the intensity is below ``min_intensity_px``.
    Raises:
        ValueError: the arrays do not describe the same N markers (:func:`marker_arrays`).
    """
    rest, cur, valid = marker_arrays(rest_px, current_px, valid)
    contacts = np.ascontiguousarray(contacts_px, dtype=np.float64).reshape(-1, 2)
    sigma = float(intensity_sigma_px)
    area, rest_a, cur_a, intensity_px, mean_px, origin = _area_motion(
        rest, cur, valid, contacts, float(r_px) * float(r_px), sigma
    )
    if len(cur_a) == 0 or intensity_px < min_intensity_px:
        return _nothing(area)
    rest_t, cur_t = rest_a, cur_a  # the similarity's set: A, or A' about type_centres_px
    if type_centres_px is not None:
        centres = np.ascontiguousarray(type_centres_px, dtype=np.float64).reshape(-1, 2)
        _, rest_c, cur_c, _, mean_c, origin_c = _area_motion(rest, cur, valid, centres, float(r_px) ** 2, 0.0)
        if len(cur_c):
            rest_t, cur_t, mean_px, origin = rest_c, cur_c, mean_c, origin_c
    threshold = max(reproj_factor * mean_px, min_reproj_px)
    if gel_motion is None:
        src, dst = _centred(rest_t, cur_t, origin)
    else:
        origin = gel_motion.remove(origin)
        src, dst = _centred(rest_t, gel_motion.remove(cur_t), origin)
    similarity = _ransac_similarity(src, dst, threshold)
    if sensor.radial_k is None:
        intensity_mm = intensity_px / sensor.px_per_mm
        translation_mm = sensor.vectors_image_to_user(similarity.translation_px)
    else:  # the camera model: each displacement and the translation in mm where they are
        mm = _rotated(_area_mm(cur_a, rest_a, origin, similarity.translation_px, _camera(sensor)), sensor)
        intensity_mm, translation_mm = _mm_figures(mm, cur_a, contacts, sigma)
    return GestureResult(
        gesture=classify(similarity, r_px, sensor, origin_radius_px),
        intensity_px=intensity_px,
        intensity_mm=intensity_mm,
        similarity=similarity,
        area=area,
        translation_mm=translation_mm,
        rotation_rad=user_rotation(similarity.rotation_rad, sensor),
    )


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _area_motion(
    rest_px: np.ndarray, current_px: np.ndarray, valid: np.ndarray, contacts_px: np.ndarray, r2: float, sigma_px: float
):
    """The set A and its motion, for :func:`estimate_gesture`.

    Args:
        rest_px, current_px: (N, 2) float64, marker positions at rest and now (px, image frame).
        valid: (N,) bool, markers the tracker still follows.
        contacts_px: (K, 2) float64, contact points (px).
        r2: r^2 (px^2) of :func:`markers_near`.
        sigma_px: the intensity profile (:func:`_profile`; 0.0 = the paper's uniform mean).
    Returns:
        area (N,) bool; A's rest and current positions, each (M, 2) float64 px; the intensity
        (px) and the uniform mean ||v_i|| (px), both 0.0 when M = 0; the contacts' mean (2,)
        float64 px (the transformation origin).
    """
    area = _near(current_px, contacts_px, r2)  # NaN rows (lost markers) are never near
    m = 0
    for i in range(len(area)):
        area[i] = area[i] and valid[i]
        m += area[i]
    rest_a = np.empty((m, 2))
    cur_a = np.empty((m, 2))
    norms = np.empty(m)
    j = 0
    for i in range(len(area)):
        if area[i]:  # element by element: a row assignment costs the first run ~2 s of compiling
            rest_a[j, 0], rest_a[j, 1] = rest_px[i, 0], rest_px[i, 1]
            cur_a[j, 0], cur_a[j, 1] = current_px[i, 0], current_px[i, 1]
            norms[j] = np.hypot(current_px[i, 0] - rest_px[i, 0], current_px[i, 1] - rest_px[i, 1])
            j += 1
    origin = np.zeros(2)
    for k in range(len(contacts_px)):  # NumPy's mean over axis 0: row after row
        origin += contacts_px[k]
    origin /= len(contacts_px)
    if m == 0:
        return area, rest_a, cur_a, 0.0, 0.0, origin
    mean = norms.sum() / m
    intensity = mean if sigma_px == 0.0 else _weighted_mean(norms, cur_a, contacts_px, sigma_px)
    return area, rest_a, cur_a, intensity, mean, origin


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _point_mm(u: float, v: float, camera: tuple) -> tuple[float, float]:
    """One image point (u, v) px in user-frame mm by the camera model of
    :meth:`SensorGeometry.image_to_user` (``radial_k`` = (k1, k2)), all but its final rotation
    (``rotation_deg``), in the same operations as there, so bit for bit. ``camera``: the
    sensor's numbers (:func:`_camera`)."""
    centre_x, centre_y, gel_radius_px, k1, k2, px_per_mm, mirror = camera
    x, y = u - centre_x, v - centre_y
    x2 = np.hypot(x, y) / gel_radius_px
    x2 = x2 * x2
    gain = 1.0 + k1 * x2 + k2 * x2 * x2
    x, y = x * gain, y * gain
    return (-(x / px_per_mm) if mirror else x / px_per_mm), -y / px_per_mm


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _points_mm(points_px: np.ndarray, camera: tuple) -> np.ndarray:
    """(K, 2) float64: :func:`_point_mm` of each row of ``points_px`` (K, 2) float64 px."""
    mm = np.empty((len(points_px), 2))
    for row in range(len(points_px)):
        mm[row, 0], mm[row, 1] = _point_mm(points_px[row, 0], points_px[row, 1], camera)
    return mm


def points_to_user(points_px: np.ndarray, sensor: SensorGeometry) -> np.ndarray:
    """(K, 2) float64 user-frame mm of the image points ``points_px`` (K, 2) px: exactly
    :meth:`SensorGeometry.image_to_user`, whose camera model (``radial_k``) runs here in one
    numba kernel instead of a dozen NumPy calls (the pipeline converts each window's contact
    points right after its fit, on a core that slept since the window before)."""
    if sensor.radial_k is None:
        return sensor.image_to_user(points_px)
    return _rotated(
        _points_mm(np.ascontiguousarray(points_px, dtype=np.float64).reshape(-1, 2), _camera(sensor)), sensor
    )


def _camera(sensor: SensorGeometry) -> tuple[float, float, float, float, float, float, bool]:
    """The sensor's camera model (``radial_k`` set) as the kernels take it: (centre_x, centre_y,
    gel_radius_px, k1, k2, px_per_mm, mirror)."""
    k1, k2 = sensor.radial_k
    cx, cy = sensor.gel_center_px
    return (
        float(cx),
        float(cy),
        float(sensor.gel_radius_px),
        float(k1),
        float(k2),
        float(sensor.px_per_mm),
        bool(sensor.mirror),
    )


def _rotated(mm: np.ndarray, sensor: SensorGeometry) -> np.ndarray:
    """(K, 2) user mm of the kernels, turned by the sensor's ``rotation_deg``: the last step of
    :meth:`SensorGeometry.vectors_image_to_user`."""
    return mm @ sensor.rotation_matrix().T if sensor.rotation_deg else mm


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _area_mm(
    current_px: np.ndarray,
    rest_px: np.ndarray,
    origin_px: np.ndarray,
    translation_px: np.ndarray,
    camera: tuple,
) -> np.ndarray:
    """(2M + 2, 2) float64: the points ``current_px``, ``rest_px`` (each (M, 2) px), ``origin_px``
    and ``origin_px + translation_px`` ((2,) px) in mm by :func:`_point_mm` (the camera model of
    :meth:`SensorGeometry.image_to_user` but its final rotation); ``camera`` of :func:`_camera`."""
    m = len(current_px)
    mm = np.empty((2 * m + 2, 2))
    for row in range(2 * m + 2):
        if row < m:
            u, v = current_px[row, 0], current_px[row, 1]
        elif row < 2 * m:
            u, v = rest_px[row - m, 0], rest_px[row - m, 1]
        elif row == 2 * m:
            u, v = origin_px[0], origin_px[1]
        else:
            u, v = origin_px[0] + translation_px[0], origin_px[1] + translation_px[1]
        mm[row, 0], mm[row, 1] = _point_mm(u, v, camera)
    return mm


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _mm_figures(mm: np.ndarray, current_px: np.ndarray, contacts_px: np.ndarray, sigma_px: float):
    """(intensity_mm, translation_mm (2,) float64) from the user-frame points of
    :func:`_area_mm` (rotated): the profile (:func:`_profile`) of A's displacements in mm,
    at A's markers ``current_px`` (M, 2) px, M >= 1; and the translation as moved at the origin."""
    m = len(current_px)
    norms = np.empty(m)
    for i in range(m):
        norms[i] = np.hypot(mm[i, 0] - mm[m + i, 0], mm[i, 1] - mm[m + i, 1])
    translation = mm[2 * m + 1] - mm[2 * m]
    return _profile(norms, current_px, contacts_px, sigma_px), translation


def compile_camera_model_kernels() -> None:
    """Compile (or load from numba's cache) the camera model's kernels of :func:`estimate_gesture`
    and :func:`points_to_user` now, for the types they are passed: a pipeline's sensor gets its
    camera model at the first rest frame (docs/method.md, "Camera model"), after
    ``GesturePipeline.compile_kernels``."""
    points = np.zeros((1, 2))
    camera = (0.0, 0.0, 1.0, 0.0, 0.0, 1.0, True)
    mm = _area_mm(points, points, np.zeros(2), np.zeros(2), camera)
    _mm_figures(mm, points, points, 1.0)
    _points_mm(points, camera)
