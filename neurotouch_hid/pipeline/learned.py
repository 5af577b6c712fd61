"""A learned gesture type (not in the paper; docs/method.md, "Gesture").

The paper's type is the largest of three similarity terms (``gesture.classify``). On gels the
rule was not tuned on it breaks where the terms mislead: a whole-gel drift adds a translation
to every pinch or zoom (``drift`` family), long-tailed fields let a twist's fingers drag each
other (``powerlaw``). A small learned classifier on the similarity terms and per-contact
motion, trained on the family mix, was kept because it wins on held-out families
(docs/method.md, "Gesture"). This is a multinomial logistic regression over :func:`gesture_features`,
trained by ``benchmarks/train_gesture_classifier.py`` (scikit-learn's ``LogisticRegression``)
on the tuning users of the development families; its coefficients are the constants of
:mod:`neurotouch_hid.pipeline.gesture_model`, evaluated here with NumPy (no scikit-learn at run
time). It only relabels windows the rule already calls a gesture (``none`` stays the rule's).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cache

import numba
import numpy as np

from neurotouch_hid.core.estimate import GestureType
from neurotouch_hid.core.sensor import SensorGeometry
from neurotouch_hid.pipeline import gesture_model
from neurotouch_hid.pipeline.gesture import GestureResult

#: The feature names, in order (:func:`gesture_features`).
FEATURES = (
    "scale_share",
    "rotation_share",
    "translation_share",
    "signed_scale_share",
    "signed_rotation_share",
    "contact_radial",
    "contact_tangential",
    "contact_count",
    "log_intensity_px",
)


def gesture_features(
    result: GestureResult,
    contacts_px: np.ndarray,
    rest_px: np.ndarray,
    current_px: np.ndarray,
    valid: np.ndarray,
    sensor: SensorGeometry,
    r_px: float,
    origin_radius_px: float,
) -> np.ndarray:
    """(9,) float64 features of one window (:data:`FEATURES`).

    The similarity's three terms (``Similarity.terms_px``: lengths at distance r, px) as shares
    of their sum, the scale's and the rotation's shares signed (scale up, rotation
    counter-clockwise in the user frame: positive); per contact, the displacement of the marker
    nearest to it less the mean of those displacements (the contacts' common motion, e.g. a
    drift of the whole gel), as the cosine of its angle with the outward direction from the
    contacts' mean at rest (radial: zoom > 0, pinch < 0) and with the counter-clockwise tangent
    (user frame), averaged over the contacts (0 for one contact); the contact count (at most
    4); log(1 + intensity px).

    Args:
        result: the rule's :class:`GestureResult` of the window (not ``NONE``).
        contacts_px: (K, 2) float, contact points (px, image frame), K >= 1.
        rest_px, current_px: (N, 2) float, marker positions at rest and now (px).
        valid: (N,) bool, markers the tracker still follows.
        sensor: the geometry (mirror and rotation: the user frame's orientation).
        r_px, origin_radius_px: as for ``gesture.classify``.
    """
    sim = result.similarity
    s_t, r_t, t_t = sim.terms_px(r_px, origin_radius_px)
    return _features(
        s_t,
        r_t,
        t_t,
        sim.scale,
        result.rotation_rad,
        result.intensity_px,
        np.ascontiguousarray(contacts_px, dtype=np.float64).reshape(-1, 2),
        np.ascontiguousarray(rest_px, dtype=np.float64),
        np.ascontiguousarray(current_px, dtype=np.float64),
        np.ascontiguousarray(valid, dtype=np.bool_),
        sensor.rotation_image_to_user(1.0),  # the user frame's sense of a turn: -1 mirrored, else 1
    )


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _features(
    scale_px: float,
    rotation_px: float,
    translation_px: float,
    scale: float,
    user_rotation_rad: float,
    intensity_px: float,
    contacts: np.ndarray,
    rest: np.ndarray,
    current: np.ndarray,
    valid: np.ndarray,
    sense: float,
) -> np.ndarray:
    """(9,) float64, :func:`gesture_features` from the similarity's terms (px), its scale, its
    user-frame rotation (rad) and the intensity (px); contacts (K, 2), rest and current (N, 2)
    px float64, valid (N,) bool; ``sense`` = +-1, a counter-clockwise turn as displayed in the
    user frame."""
    total = scale_px + rotation_px + translation_px + 1e-9
    radial, turning = _relative_motion(contacts, rest, current, valid)
    features = np.empty(9)
    features[0] = scale_px / total
    features[1] = rotation_px / total
    features[2] = translation_px / total
    features[3] = math.copysign(scale_px / total, scale - 1.0)
    features[4] = math.copysign(rotation_px / total, user_rotation_rad)  # counter-clockwise > 0
    features[5] = radial
    features[6] = turning * sense
    features[7] = float(min(len(contacts), 4))
    features[8] = math.log1p(intensity_px)
    return features


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _relative_motion(contacts: np.ndarray, rest: np.ndarray, current: np.ndarray, valid: np.ndarray):
    """(radial, tangential) of :func:`gesture_features`, the tangential one counter-clockwise as
    displayed (image frame); (0, 0) for fewer than 2 contacts. For each contact (K, 2) px, the
    valid marker nearest to it now; its displacement less the mean of those displacements,
    against its rest position less the mean of those rest positions."""
    k = len(contacts)
    if k < 2:
        return 0.0, 0.0
    nearest = np.empty(k, dtype=np.int64)
    for c in range(k):
        best, best_d = -1, np.inf
        for i in range(len(current)):
            if valid[i]:
                dx = current[i, 0] - contacts[c, 0]
                dy = current[i, 1] - contacts[c, 1]
                d = dx * dx + dy * dy
                if d < best_d:
                    best, best_d = i, d
        nearest[c] = best
    if nearest.min() < 0:
        return 0.0, 0.0
    mu = np.zeros(2)
    mv = np.zeros(2)
    for c in range(k):
        i = nearest[c]
        mu += rest[i]
        mv += current[i] - rest[i]
    mu /= k
    mv /= k
    radial = turning = 0.0
    for c in range(k):
        i = nearest[c]
        ux, uy = rest[i, 0] - mu[0], rest[i, 1] - mu[1]
        vx, vy = current[i, 0] - rest[i, 0] - mv[0], current[i, 1] - rest[i, 1] - mv[1]
        nu = np.sqrt(ux * ux + uy * uy) + 1e-9
        nv = np.sqrt(vx * vx + vy * vy) + 1e-9
        radial += (vx * ux + vy * uy) / (nu * nv)
        turning += (vx * uy - vy * ux) / (nu * nv)  # along the tangent (u_y, -u_x): counter-clockwise as displayed
    return radial / k, turning / k


#: The classes of :mod:`gesture_model`'s rows, in order.
CLASSES = (GestureType.PUSH, GestureType.PINCH, GestureType.ZOOM, GestureType.TWIST_CW, GestureType.TWIST_CCW)


@dataclass(frozen=True, eq=False)
class Classifier:
    """The logistic regression's parameters as float64 arrays: ``mean``, ``scale`` (9,) (the
    features' standardisation, :data:`FEATURES` order), ``weights`` (5, 9) and ``intercept`` (5,)
    (:data:`CLASSES` order). The shipped ones are :mod:`gesture_model`'s (:meth:`shipped`); an
    adapted model (``neurotouch-hid adapt``, docs/method.md, "Adaptation") brings its own."""

    mean: np.ndarray
    scale: np.ndarray
    weights: np.ndarray
    intercept: np.ndarray

    @classmethod
    def of(cls, mean, scale, weights, intercept) -> "Classifier":
        """From sequences (or arrays) of the shapes above, copied as float64 arrays."""
        return cls(*(np.array(a, dtype=np.float64) for a in (mean, scale, weights, intercept)))

    @staticmethod
    @cache
    def shipped() -> "Classifier":
        """The shipped parameters (:mod:`gesture_model`)."""
        m = gesture_model
        return Classifier.of(m.MEAN, m.SCALE, m.WEIGHTS, m.INTERCEPT)

    def logits(self, features: np.ndarray) -> np.ndarray:
        """(..., 5) float64 class scores ``W (x - mean) / scale + b`` of (..., 9) features."""
        x = (np.asarray(features, dtype=np.float64) - self.mean) / self.scale
        return x @ self.weights.T + self.intercept


def learned_gesture(features: np.ndarray, classifier: Classifier | None = None) -> GestureType:
    """The logistic regression's type for (9,) features: argmax of ``W (x - mean) / scale + b``
    with ``classifier``'s parameters (None: the shipped ones, :mod:`gesture_model`)."""
    logits = (classifier or Classifier.shipped()).logits(features)
    return CLASSES[int(np.argmax(logits))]
