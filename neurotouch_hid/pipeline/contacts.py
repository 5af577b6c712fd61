"""Contact point detection (paper, section "Contact Point Detection").

A finger deforms the gel locally; the rest of the displacement field follows a smooth global
motion. A RANSAC homography from the markers' rest positions to their current positions models
that global motion with a *dynamic* reprojection threshold ``a * mean_i ||v_i||`` (paper, first
equation of the section), so the number of outliers stays stable whatever the gesture's
intensity. The outliers are the candidate set S. A contact point is a candidate whose
displacement is the largest within radius r among the candidates (its neighbourhood N(i)), with
at least ``n_min`` candidates in that neighbourhood (paper, section "Results": N_min = 4).

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
        points_px: (K, 2) float64, their current positions, image frame (px).
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


def homography_outliers(rest_px: np.ndarray, current_px: np.ndarray, reproj_threshold_px: float) -> np.ndarray:
    """RANSAC homography rest -> current; the markers it rejects (paper, "Contact Point Detection").

    Args:
        rest_px: (M, 2) float, rest positions p_i(t0), image frame (px), M >= 4.
        current_px: (M, 2) float, current positions p_i(t_k), image frame (px).
        reproj_threshold_px: RANSAC reprojection threshold (px), > 0.
    Returns:
        (M,) bool, True for RANSAC's outliers. When OpenCV finds no homography (degenerate
        configuration: collinear or coincident points), there is no global model to separate
        local deformations from, so every marker is returned as a candidate.
    Source: ``cv2.findHomography(..., cv2.RANSAC, reprojThreshold)``.
    """
    src = np.ascontiguousarray(rest_px, dtype=np.float32)
    dst = np.ascontiguousarray(current_px, dtype=np.float32)
    homography, inliers = cv2.findHomography(src, dst, cv2.RANSAC, float(reproj_threshold_px))
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
    m = len(points_px)
    if m == 0:
        return np.zeros(0, dtype=np.int64)
    p = np.asarray(points_px, dtype=np.float64)
    mag = np.asarray(magnitudes, dtype=np.float64)
    diff = p[:, None, :] - p[None, :, :]
    near = np.einsum("ijk,ijk->ij", diff, diff) <= r_px * r_px  # (M, M), diagonal True
    enough = near.sum(axis=1) >= n_min
    neighbour_max = np.where(near, mag[None, :], -np.inf).max(axis=1)
    is_max = enough & (mag >= neighbour_max)
    order = [i for i in np.lexsort((np.arange(m), -mag)) if is_max[i]]
    kept: list[int] = []
    for i in order:  # tie-breaking: at most one maximum per neighbourhood
        if not any(near[i, k] for k in kept):
            kept.append(int(i))
    return np.asarray(kept, dtype=np.int64)


def detect_contacts(
    rest_px: np.ndarray,
    current_px: np.ndarray,
    valid: np.ndarray | None = None,
    *,
    r_px: float = 30.0,
    a: float = 0.6,
    n_min: int = 4,
    min_mean_displacement_px: float = 1e-3,
) -> Contacts:
    """The contact points of one window (paper, section "Contact Point Detection").

    Args:
        rest_px: (N, 2) float, rest positions p_i(t0), image frame (px).
        current_px: (N, 2) float, tracked positions p_i(t_k), image frame (px).
        valid: (N,) bool, False for markers the tracker lost (they take no part); None = all.
        r_px: neighbourhood radius r (px); paper: 30 px.
        a: dynamic reprojection threshold coefficient; paper: 0.6.
        n_min: minimum neighbourhood size N_min; paper: 4.
        min_mean_displacement_px: below this mean displacement (px) nothing moves and there is
            no contact (RANSAC needs a positive threshold).
    Returns:
        :class:`Contacts`. Degenerate inputs give no contact: fewer than 4 valid markers (a
        homography needs 4), or a mean displacement below ``min_mean_displacement_px``
        (e.g. all-zero). When ``cv2.findHomography`` returns None, all valid markers are
        candidates (see :func:`homography_outliers`).
    """
    rest = np.asarray(rest_px, dtype=np.float64)
    cur = np.asarray(current_px, dtype=np.float64)
    n = len(rest)
    ok = np.isfinite(cur).all(axis=1) & np.isfinite(rest).all(axis=1)
    if valid is not None:
        ok &= np.asarray(valid, dtype=bool)
    idx = np.flatnonzero(ok)
    if len(idx) < 4:
        return _no_contacts(n)
    magnitudes = np.linalg.norm(cur[idx] - rest[idx], axis=1)
    mean = float(magnitudes.mean())
    if mean < min_mean_displacement_px:
        return _no_contacts(n)
    threshold = a * mean
    outliers = homography_outliers(rest[idx], cur[idx], threshold)
    cand = idx[outliers]
    candidates = np.zeros(n, dtype=bool)
    candidates[cand] = True
    maxima = cand[local_maxima(cur[cand], magnitudes[outliers], r_px, n_min)]
    return Contacts(indices=maxima, points_px=cur[maxima].copy(), candidates=candidates, reproj_threshold_px=threshold)
