"""Contact point detection (paper, section "Contact Point Detection").

A finger deforms the gel locally; the rest of the displacement field follows a smooth global
motion. A RANSAC homography from the markers' rest positions to their current positions models
that global motion with a *dynamic* reprojection threshold ``a * mean_i ||v_i||`` (paper, first
equation of the section), so the number of outliers stays stable whatever the gesture's
intensity. The outliers are the candidate set S. A contact point is a candidate whose
displacement is the largest within radius r among the candidates (its neighbourhood N(i)), with
at least ``n_min`` candidates in that neighbourhood (paper, section "Results": N_min = 4).

Field fallback (not in the paper, ``field_fallback``): a wide multi-finger push drags a large
part of the gel almost rigidly; the homography then models the fingers' motion itself, its
dynamic threshold (``a`` x the large mean displacement) is loose, and the few outliers left are
scattered, so no neighbourhood holds ``n_min`` of them and no contact is found although the gel
is strongly deformed (measured on the quick preset's 3-finger push, seed 0: ``none`` on ~65 %
of its windows above 2 mm). When the outliers give no contact, the rest model (no motion, the
identity) takes the homography's place: the candidates are the markers it rejects with the same
dynamic threshold, ``||v_i|| > a * mean_i ||v_i||``, and their local maxima are the contacts --
the contact point is, by the paper's definition, "the location where the silicone gel
experiences the greatest deformation".

Sub-marker refinement (not in the paper, ``refine_px``): the paper's contact point is the
position of the marker of peak displacement, so it is quantised to the 4 mm marker grid (the
paper's labels share that 4 mm uncertainty). :func:`refine_peak` instead fits a quadratic
surface to ||v|| and to v over the markers within ``refine_px`` of the peak marker (rest
positions), takes the surface's maximum (when it is one, near the peak marker) and returns where
that gel point is now (its rest position plus the fitted v there).

Everything here is in the image frame (px).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np


@dataclass(frozen=True)
class Contacts:
    """The contact points of one window.

    Attributes:
        indices: (K,) int64, indices of the markers that are contact points (ordered by
            decreasing displacement).
        points_px: (K, 2) float64, their current positions, image frame (px) (sub-marker
            refined ones with ``refine_px``, see :func:`refine_peak`).
        candidates: (N,) bool, the RANSAC outliers S (False for markers not valid).
        reproj_threshold_px: the dynamic reprojection threshold used (px); 0 when RANSAC did
            not run.
    """

    indices: np.ndarray
    points_px: np.ndarray
    candidates: np.ndarray
    reproj_threshold_px: float

    @property
    def count(self) -> int:
        """Number of contact points K."""
        return int(len(self.indices))


def _no_contacts(n: int, threshold: float = 0.0) -> Contacts:
    return Contacts(
        indices=np.zeros(0, dtype=np.int64),
        points_px=np.zeros((0, 2), dtype=np.float64),
        candidates=np.zeros(n, dtype=bool),
        reproj_threshold_px=threshold,
    )


#: RANSAC variants of ``cv2.findHomography`` by name: ``ransac`` is classic RANSAC (``cv2.RANSAC``,
#: the paper's reference [RANSAC]); ``usac_fast`` is OpenCV's USAC framework (RANSAC with local
#: optimisation, ``cv2.USAC_FAST``). On simulated gels (quick datasets, seeds 0 and 3) usac_fast
#: scored as well or better (gesture accuracy 92.5 vs 90.0 % and 94.7 vs 94.7 %, contact count
#: 84.7 vs 76.8 % and 84.9 vs 84.6 %) at ~2.5x less time (docs/performance.md, Pipeline).
HOMOGRAPHY_METHODS = {"ransac": cv2.RANSAC, "usac_fast": cv2.USAC_FAST}


def homography_outliers(
    rest_px: np.ndarray, current_px: np.ndarray, reproj_threshold_px: float, max_iters: int = 2000,
    method: str = "usac_fast",
) -> np.ndarray:
    """RANSAC homography rest -> current; the markers it rejects (paper, "Contact Point Detection").

    Args:
        rest_px: (M, 2) float, rest positions p_i(t0), image frame (px), M >= 4.
        current_px: (M, 2) float, current positions p_i(t_k), image frame (px).
        reproj_threshold_px: RANSAC reprojection threshold (px), > 0.
        max_iters: RANSAC's iteration cap (OpenCV's default 2000; OpenCV stops earlier once
            the 0.995 confidence is reached).
        method: a key of :data:`HOMOGRAPHY_METHODS`.
    Returns:
        (M,) bool, True for RANSAC's outliers. When OpenCV finds no homography (degenerate
        configuration: collinear or coincident points), there is no global model to separate
        local deformations from, so every marker is returned as a candidate.
    Source: ``cv2.findHomography(..., cv2.USAC_FAST or cv2.RANSAC, reprojThreshold)``.
    """
    src = np.ascontiguousarray(rest_px, dtype=np.float32)
    dst = np.ascontiguousarray(current_px, dtype=np.float32)
    homography, inliers = cv2.findHomography(
        src, dst, HOMOGRAPHY_METHODS[method], float(reproj_threshold_px), maxIters=int(max_iters)
    )
    if homography is None or inliers is None:
        return np.ones(len(src), dtype=bool)
    return inliers.ravel() == 0


def local_maxima(points_px: np.ndarray, magnitudes: np.ndarray, r_px: float, n_min: int) -> np.ndarray:
    """Local displacement maxima among candidate markers (paper, eqs. of N(i, t_k) and I_max).

    N(i) = {j in S : ||p_i - p_j|| <= r} (i itself included, as j ranges over all of S);
    i is kept when ||v_i|| >= ||v_j|| for every j in N(i) and |N(i)| >= n_min.
    Equal maxima within r of each other (ties) keep one per neighbourhood: the strongest first,
    then the lowest index.

    Args:
        points_px: (M, 2) float, candidate positions (px).
        magnitudes: (M,) float, their displacement norms ||v_i|| (px).
        r_px: neighbourhood radius r (px).
        n_min: minimum neighbourhood size N_min.
    Returns:
        (K,) int64 indices into the M candidates, by decreasing magnitude.
    """
    points_px = np.asarray(points_px, dtype=np.float64)
    magnitudes = np.asarray(magnitudes, dtype=np.float64)
    if len(points_px) == 0:
        return np.zeros(0, dtype=np.int64)
    x, y = points_px[:, 0], points_px[:, 1]
    dx, dy = x[:, None] - x[None, :], y[:, None] - y[None, :]
    near = dx * dx + dy * dy <= r_px * r_px  # (M, M), diagonal True
    enough = np.count_nonzero(near, axis=1) >= n_min
    neighbour_max = np.where(near, magnitudes[None, :], -np.inf).max(axis=1)
    maxima = np.flatnonzero(enough & (magnitudes >= neighbour_max))
    maxima = maxima[np.lexsort((maxima, -magnitudes[maxima]))]
    kept: list[int] = []
    for i in maxima:  # tie-breaking: at most one maximum per neighbourhood
        if not near[i, kept].any():
            kept.append(int(i))
    return np.asarray(kept, dtype=np.int64)


def refine_peak(rest_px: np.ndarray, displacement_px: np.ndarray, peak: int, radius_px: float) -> np.ndarray:
    """Sub-marker position of a displacement peak (see the module docstring).

    Args:
        rest_px: (M, 2) float, rest positions of valid markers (px, image frame).
        displacement_px: (M, 2) float, their displacements v (px).
        peak: index (into the M markers) of the peak marker.
        radius_px: markers whose rest position is within this of the peak's take part (px).
    Returns:
        (2,) float64, the current position (px) of the gel point of maximum ||v||: from the
        least-squares quadratic surfaces ``f(x, y) = c0 + c1 x + c2 y + c3 x^2 + c4 y^2 + c5 x y``
        of ||v|| and of v about the peak's rest position. The peak marker's own current position
        when fewer than 6 markers take part, the surface has no maximum, or its maximum lies
        further than half the radius from the peak marker.
    """
    rest = np.asarray(rest_px, dtype=np.float64)
    v = np.asarray(displacement_px, dtype=np.float64)
    fallback = rest[peak] + v[peak]
    rel = rest - rest[peak]
    near = rel[:, 0] * rel[:, 0] + rel[:, 1] * rel[:, 1] <= radius_px * radius_px
    if np.count_nonzero(near) < 6:
        return fallback
    x, y = rel[near, 0], rel[near, 1]
    design = np.stack([np.ones_like(x), x, y, x * x, y * y, x * y], axis=1)
    values = np.column_stack([np.hypot(v[near, 0], v[near, 1]), v[near]])
    coef, *_ = np.linalg.lstsq(design, values, rcond=None)
    c = coef[:, 0]
    hessian = np.array([[2 * c[3], c[5]], [c[5], 2 * c[4]]])
    if hessian[0, 0] >= 0 or np.linalg.det(hessian) <= 0:  # not a maximum
        return fallback
    top = np.linalg.solve(hessian, -c[1:3])
    if top @ top > (0.5 * radius_px) ** 2:
        return fallback
    basis = np.array([1.0, top[0], top[1], top[0] ** 2, top[1] ** 2, top[0] * top[1]])
    return rest[peak] + top + basis @ coef[:, 1:]


def detect_contacts(
    rest_px: np.ndarray,
    current_px: np.ndarray,
    valid: np.ndarray | None = None,
    *,
    r_px: float = 30.0,
    a: float = 0.6,
    n_min: int = 4,
    min_mean_displacement_px: float = 1e-3,
    max_iters: int = 2000,
    method: str = "usac_fast",
    field_fallback: bool = False,
    refine_px: float | None = None,
) -> Contacts:
    """The contact points of one window (paper, section "Contact Point Detection").

    Args:
        rest_px: (N, 2) float, rest positions p_i(t0), image frame (px), finite.
        current_px: (N, 2) float, tracked positions p_i(t_k), image frame (px); NaN rows count
            as lost.
        valid: (N,) bool, False for markers the tracker lost (they take no part); None = all.
        r_px: neighbourhood radius r (px); paper: 30 px.
        a: dynamic reprojection threshold coefficient; paper: 0.6.
        n_min: minimum neighbourhood size N_min; paper: 4.
        min_mean_displacement_px: below this mean displacement (px) nothing moves and there is
            no contact (RANSAC needs a positive threshold).
        max_iters, method: RANSAC's iteration cap and variant (see :func:`homography_outliers`).
        field_fallback: when the outliers give no contact, take the local maxima among the
            markers displaced by more than the threshold (the rest model's outliers, see the
            module docstring); ``candidates`` still holds the homography's outliers.
        refine_px: None: a contact point is its marker's position (paper); > 0: refined below
            the marker pitch with the markers within this radius (:func:`refine_peak`).
    Returns:
        :class:`Contacts`. Degenerate inputs give no contact: fewer than 4 valid markers (a
        homography needs 4), or a mean displacement below ``min_mean_displacement_px``
        (e.g. all-zero). When ``cv2.findHomography`` returns None, all valid markers are
        candidates (see :func:`homography_outliers`).
    """
    rest = np.asarray(rest_px, dtype=np.float64)
    cur = np.asarray(current_px, dtype=np.float64)
    n = len(rest)
    ok = np.isfinite(cur[:, 0]) & np.isfinite(cur[:, 1])
    if valid is not None:
        ok &= np.asarray(valid, dtype=bool)
    idx = np.flatnonzero(ok)
    if len(idx) < 4:
        return _no_contacts(n)
    rest_ok, cur_ok = rest[idx], cur[idx]
    magnitudes = np.hypot(cur_ok[:, 0] - rest_ok[:, 0], cur_ok[:, 1] - rest_ok[:, 1])
    mean = float(magnitudes.mean())
    if mean < min_mean_displacement_px:
        return _no_contacts(n)
    threshold = a * mean
    outliers = homography_outliers(rest_ok, cur_ok, threshold, max_iters, method)
    cand = idx[outliers]
    candidates = np.zeros(n, dtype=bool)
    candidates[cand] = True
    maxima = cand[local_maxima(cur_ok[outliers], magnitudes[outliers], r_px, n_min)]
    if len(maxima) == 0 and field_fallback:
        moved = magnitudes > threshold  # outliers of the rest model (identity), same threshold
        maxima = idx[moved][local_maxima(cur_ok[moved], magnitudes[moved], r_px, n_min)]
    points = cur[maxima].copy()
    if refine_px is not None and len(maxima):
        position = np.full(n, -1, dtype=np.int64)
        position[idx] = np.arange(len(idx))
        v_ok = cur_ok - rest_ok
        points = np.array([refine_peak(rest_ok, v_ok, int(position[i]), refine_px) for i in maxima])
    return Contacts(indices=maxima, points_px=points, candidates=candidates, reproj_threshold_px=threshold)
