"""Contact point detection (paper, section "Contact Point Detection"; docs/method.md, "Contacts").

A RANSAC homography from the markers' rest positions to their current positions models the gel's
global motion with a dynamic reprojection threshold ``a * mean_i ||v_i||`` (paper, first equation
of the section); its outliers are the candidate set S (:func:`outlier_candidates`), and a contact
point is a candidate whose displacement is the largest within radius r among the candidates, with
at least ``n_min`` candidates there (:func:`local_maxima`). The paper's method stops there
(``paper.paper_contacts``). The product's :func:`detect_contacts` adds, each for a reason given in
docs/method.md, "Contacts": the markers moved beyond the threshold among the neighbours,
neighbourhoods on the gel at rest, lone markers at their neighbours' median and flat tops
(``contacts_plateau.py``), a finger's peak where the homography fits it and the peaks a press holds
(``contacts_held.py``), the rest model when the outliers give no contact, sub-marker refinement
(``contacts_refine.py``) and the fit of radial bumps on long-tailed fields (``contacts_bump.py``).

Everything here is in the image frame (px).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numba
import numpy as np

from neurotouch_hid.pipeline.contacts_bump import _at_rest, bump_fit, field_at, with_missed_finger
from neurotouch_hid.pipeline.contacts_held import _held_levels, _still_held, _where_homography_fails
from neurotouch_hid.pipeline.contacts_plateau import (
    MAX_FINGERS,
    _despiked,
    _valid_table,
    plateau_contacts,
    rest_neighbours,
)
from neurotouch_hid.pipeline.contacts_refine import _refine_peak
from neurotouch_hid.pipeline.markers import marker_arrays

#: :attr:`Contacts.held` of a window that holds no finger's peak.
NOTHING_HELD = (np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.float64))


@dataclass(frozen=True)
class Contacts:
    """The contact points of one window.

    Attributes:
        indices: (K,) int64, indices of the markers that are contact points (ordered by
            decreasing displacement; the contacts of one plateau all give its maximum's marker).
        points_px: (K, 2) float64, their current positions, image frame (px) (sub-marker
            refined ones, ``contacts_refine.refine_peak``; the fitted fingers' centres,
            ``contacts_bump.bump_fit``; the peak markers' positions by the paper's rule).
        peaks_px: (K, 2) float64, the points of the field's maxima (px, image frame): the
            contact points as they are before the bump fit (``points_px`` itself without it).
            The gesture step reads its set A and intensity around these: the largest deformation
            (paper, "Gesture Classification and Intensity Prediction").
        candidates: (N,) bool, the RANSAC outliers S (False for markers not valid).
        reproj_threshold_px: the dynamic reprojection threshold used (px); 0 when RANSAC did
            not run.
        long_flat_top: a flat top of the field, at least a fingertip's footprint, is long:
            fingertips side by side (``contacts_plateau.LONG_ELONGATION``). The pipeline keeps it
            over the press (:func:`detect_contacts`'s ``long_before``).
        held: the fingers' peaks the press holds, as the next window of the press hears them
            (:func:`detect_contacts`'s ``held``): this window's maxima that are one finger's peak
            (not a flat top of several), and the press's earlier ones whose marker is still displaced
            at least ``contacts_held.HELD_PEAK_SHARE`` of what it is held at; (H,) int64 marker indices and
            (H,) float64 their ||v|| (px) when the homography last failed on or about them.
    """

    indices: np.ndarray
    points_px: np.ndarray
    peaks_px: np.ndarray
    candidates: np.ndarray
    reproj_threshold_px: float
    long_flat_top: bool = False
    held: tuple[np.ndarray, np.ndarray] = NOTHING_HELD

    @property
    def count(self) -> int:
        """Number of contact points K."""
        return int(len(self.indices))


def _no_contacts(n: int, threshold: float = 0.0) -> Contacts:
    return Contacts(
        indices=np.zeros(0, dtype=np.int64),
        points_px=np.zeros((0, 2), dtype=np.float64),
        peaks_px=np.zeros((0, 2), dtype=np.float64),
        candidates=np.zeros(n, dtype=bool),
        reproj_threshold_px=threshold,
    )


#: RANSAC variants of ``cv2.findHomography`` by name: ``ransac`` is classic RANSAC (``cv2.RANSAC``,
#: the paper's reference [RANSAC]); ``usac_fast`` is OpenCV's USAC framework (RANSAC with local
#: optimisation, ``cv2.USAC_FAST``). On simulated gels (quick datasets, seeds 0 and 3) usac_fast
#: scored as well or better (gesture accuracy 92.5 vs 90.0 % and 94.7 vs 94.7 %, contact count
#: 84.7 vs 76.8 % and 84.9 vs 84.6 %) at ~2.5x less time (docs/method.md, "Contacts").
HOMOGRAPHY_METHODS = {"ransac": cv2.RANSAC, "usac_fast": cv2.USAC_FAST}


def homography_outliers(
    rest_px: np.ndarray,
    current_px: np.ndarray,
    reproj_threshold_px: float,
    max_iters: int = 2000,
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
    points_px = np.ascontiguousarray(points_px, dtype=np.float64)
    magnitudes = np.ascontiguousarray(magnitudes, dtype=np.float64)
    if len(points_px) == 0:
        return np.zeros(0, dtype=np.int64)
    return _local_maxima(points_px, magnitudes, float(r_px) * float(r_px), int(n_min))


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _local_maxima(points_px: np.ndarray, magnitudes: np.ndarray, r2: float, n_min: int) -> np.ndarray:
    """:func:`local_maxima` with ``r2`` = r^2 (px^2): one O(M^2) pass without NumPy's (M, M)
    temporaries."""
    m = len(points_px)
    maxima = np.empty(m, dtype=np.int64)
    k = 0
    for i in range(m):
        count = 0
        is_max = True
        for j in range(m):
            dx = points_px[i, 0] - points_px[j, 0]
            dy = points_px[i, 1] - points_px[j, 1]
            if dx * dx + dy * dy <= r2:
                count += 1
                if magnitudes[j] > magnitudes[i]:
                    is_max = False
                    break
        if is_max and count >= n_min:
            maxima[k] = i
            k += 1
    maxima = maxima[:k]
    maxima = maxima[np.argsort(-magnitudes[maxima], kind="mergesort")]  # stable: ties by index
    kept = np.empty(k, dtype=np.int64)
    n_kept = 0
    for i in maxima:  # tie-breaking: at most one maximum per neighbourhood
        alone = True
        for q in range(n_kept):
            dx = points_px[i, 0] - points_px[kept[q], 0]
            dy = points_px[i, 1] - points_px[kept[q], 1]
            if dx * dx + dy * dy <= r2:
                alone = False
                break
        if alone:
            kept[n_kept] = i
            n_kept += 1
    return kept[:n_kept].copy()


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _usable(
    rest: np.ndarray, current: np.ndarray, valid: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The markers that take part in one window: valid and finite. ``rest``, ``current`` (N, 2)
    float64 px, ``valid`` (N,) bool. Returns their indices idx (M,) int64, rest and current
    positions (M, 2), displacements v (M, 2) (px) and norms ||v|| (M,) float64."""
    idx = np.empty(len(rest), dtype=np.int64)
    m = 0
    for i in range(len(rest)):
        if valid[i] and np.isfinite(current[i, 0]) and np.isfinite(current[i, 1]):
            idx[m] = i
            m += 1
    idx = idx[:m].copy()
    rest_ok = np.empty((m, 2))
    cur_ok = np.empty((m, 2))
    v = np.empty((m, 2))
    norms = np.empty(m)
    for q in range(m):
        for d in range(2):
            rest_ok[q, d] = rest[idx[q], d]
            cur_ok[q, d] = current[idx[q], d]
            v[q, d] = cur_ok[q, d] - rest_ok[q, d]
        norms[q] = np.hypot(v[q, 0], v[q, 1])
    return idx, rest_ok, cur_ok, v, norms


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _maxima(
    rest: np.ndarray,
    magnitudes: np.ndarray,
    outliers: np.ndarray,
    table: np.ndarray,
    spike_fraction: float,
    r2: float,
    n_min: int,
    fallback_threshold: float,
    min_move: float,
    held: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The contact step after RANSAC, up to the plateaus (:func:`detect_contacts`).

    ``rest`` (M, 2) float64 px: the rest positions, whose neighbourhoods N(i) count;
    ``magnitudes`` (M,) ||v|| px; ``outliers`` (M,) bool, RANSAC's; ``table`` (M, K) int64, the
    valid markers' neighbour table; ``r2`` = r^2 (px^2); ``fallback_threshold``: the dynamic
    threshold a * mean ||v|| (px), the rest model's; ``min_move`` (px): the least displacement
    that counts as moved. The maxima are outliers whose ||v|| is the largest within r among the
    outliers and the markers moved more than both thresholds, with N_min of those there
    (docs/method.md, "Contacts", step 3); when that gives no contact, the outliers alone, then
    the rest model. Returns the maxima (K,) int64 (indices into the M markers, by decreasing
    magnitude), the ||v|| (px) each is held at (K,) float64, and the magnitudes the later steps
    read (M,) float64 (lone markers at their neighbours' median). A maximum is kept where the
    homography fails on it or about it, or where it was held in the window before (``held`` (M,)
    float64 px, 0: not; :func:`_where_homography_fails`)."""
    magnitudes = _despiked(table, magnitudes, spike_fraction)
    chosen = np.flatnonzero(outliers | (magnitudes > max(fallback_threshold, min_move)))
    peaks = chosen[_local_maxima(rest[chosen], magnitudes[chosen], r2, n_min)]
    keep, level = _where_homography_fails(peaks, outliers, table, magnitudes, held)
    peaks, level = peaks[keep], level[keep]
    if len(peaks) == 0:
        chosen = np.flatnonzero(outliers)
        peaks = chosen[_local_maxima(rest[chosen], magnitudes[chosen], r2, n_min)]
        level = magnitudes[peaks]
    if len(peaks) == 0:
        moved = np.flatnonzero(magnitudes > fallback_threshold)  # the rest model's outliers
        peaks = moved[_local_maxima(rest[moved], magnitudes[moved], r2, n_min)]
        level = magnitudes[peaks]
    return peaks, level, magnitudes


@dataclass(frozen=True)
class Candidates:
    """The markers that take part in one window and RANSAC's verdict on them (:func:`outlier_candidates`).

    Attributes:
        n: N, the number of markers.
        idx: (M,) int64, indices of the valid, finite markers.
        rest_px, current_px, v_px: (M, 2) float64, their rest and current positions and
            displacements (px, image frame).
        magnitudes: (M,) float64, ||v|| (px).
        outliers: (M,) bool, the homography's outliers S.
        threshold_px: the dynamic reprojection threshold ``a * mean ||v||`` (px).
    """

    n: int
    idx: np.ndarray
    rest_px: np.ndarray
    current_px: np.ndarray
    v_px: np.ndarray
    magnitudes: np.ndarray
    outliers: np.ndarray
    threshold_px: float

    def contacts(
        self,
        rows: np.ndarray,
        points_px: np.ndarray,
        peaks_px: np.ndarray,
        long_flat_top: bool = False,
        held: tuple[np.ndarray, np.ndarray] = NOTHING_HELD,
    ) -> Contacts:
        """The :class:`Contacts` of the markers ``rows`` (K,) int64 (into the M) at ``points_px``."""
        candidates = np.zeros(self.n, dtype=bool)
        candidates[self.idx[self.outliers]] = True
        return Contacts(
            indices=self.idx[rows],
            points_px=points_px,
            peaks_px=peaks_px,
            candidates=candidates,
            reproj_threshold_px=self.threshold_px,
            long_flat_top=long_flat_top,
            held=held,
        )


def outlier_candidates(
    rest_px: np.ndarray,
    current_px: np.ndarray,
    valid: np.ndarray | None,
    *,
    a: float,
    min_mean_displacement_px: float = 1e-3,
    max_iters: int = 2000,
    method: str = "usac_fast",
) -> Candidates | int:
    """The candidate set S of one window: RANSAC's outliers with the dynamic threshold (paper,
    "Contact Point Detection").

    Args: as :func:`detect_contacts`.
    Returns:
        :class:`Candidates`, or N (the number of markers) when the window has no contact: fewer
        than 4 valid markers (a homography needs 4) or a mean displacement below
        ``min_mean_displacement_px``.
    Raises:
        ValueError: the arrays do not describe the same N markers (:func:`marker_arrays`).
    """
    rest, cur, usable = marker_arrays(rest_px, current_px, valid)
    idx, rest_ok, cur_ok, v_ok, magnitudes = _usable(rest, cur, usable)
    if len(idx) < 4:
        return len(rest)
    mean = float(magnitudes.mean())
    if mean < min_mean_displacement_px:
        return len(rest)
    threshold = a * mean
    outliers = homography_outliers(rest_ok, cur_ok, threshold, max_iters, method)
    return Candidates(len(rest), idx, rest_ok, cur_ok, v_ok, magnitudes, outliers, threshold)


def detect_contacts(
    rest_px: np.ndarray,
    current_px: np.ndarray,
    valid: np.ndarray | None = None,
    *,
    r_px: float = 25.0,
    a: float = 0.6,
    n_min: int = 12,
    min_mean_displacement_px: float = 1e-3,
    max_iters: int = 2000,
    method: str = "usac_fast",
    refine_px: float = 20.0,
    plateau_fraction: float = 0.8,
    pitch_px: float = 10.0,
    spike_fraction: float = 0.6,
    bump_span_px: float = 75.0,
    min_move_px: float = 0.6,
    neighbours: np.ndarray | None = None,
    long_before: bool = True,
    held: tuple[np.ndarray, np.ndarray] | None = None,
) -> Contacts:
    """The contact points of one window, the product's method (docs/method.md, "Contacts").

    Args:
        rest_px: (N, 2) float, rest positions p_i(t0), image frame (px), finite.
        current_px: (N, 2) float, tracked positions p_i(t_k), image frame (px); NaN rows count
            as lost.
        valid: (N,) bool, False for markers the tracker lost (they take no part); None = all.
        r_px: neighbourhood radius r (px), taken over the rest positions (on the gel).
        a: dynamic reprojection threshold coefficient (paper's 0.6).
        n_min: minimum neighbourhood size N_min.
        min_mean_displacement_px: below this mean displacement (px) nothing moves and there is
            no contact (RANSAC needs a positive threshold).
        max_iters, method: RANSAC's iteration cap and variant (see :func:`homography_outliers`).
        refine_px: a peak is refined below the marker pitch with the markers within this
            radius (px, :func:`~neurotouch_hid.pipeline.contacts_refine.refine_peak`).
        plateau_fraction: in (0, 1): maxima on one plateau at this fraction of the strongest are
            merged, and a wide plateau's contacts are read off its area and shape
            (:func:`~neurotouch_hid.pipeline.contacts_plateau.plateau_contacts`).
        pitch_px: the marker pitch (px).
        spike_fraction: in (0, 1]: a marker displaced more than 1 / spike_fraction times the
            median of its neighbours takes that median.
        bump_span_px: with at least two contacts and no flat top of several fingers, their
            centres are fitted as radial bumps with a profile of knots ``pitch_px`` apart up to
            this distance (px), the gel's radius
            (:func:`~neurotouch_hid.pipeline.contacts_bump.bump_fit`); with two, a third finger
            the maxima missed is looked for in what their bumps leave
            (:func:`~neurotouch_hid.pipeline.contacts_bump.with_missed_finger`).
        min_move_px: a marker displaced more than this (px) and than the dynamic threshold
            counts among an outlier's neighbours (for N_min and its being the largest) even where
            the homography keeps it (``ContactsConfig.min_move_mm``).
        neighbours: (N, K) int64, :func:`rest_neighbours` of ``rest_px`` with ``pitch_px``
            (computed once per rest reference by the pipeline); None: computed here.
        long_before: whether an earlier window of the press had a long flat top
            (:attr:`Contacts.long_flat_top`); False: a round flat top whose area reads two
            fingers is one fingertip pressed deep. True (the default, a window without its
            press) keeps the area's reading.
        held: the window before's :attr:`Contacts.held`, of the same press and rest reference
            (marker indices into the N, ||v|| px); a maximum there, or beside it, displaced at
            least ``contacts_held.HELD_PEAK_SHARE`` of that stays a finger's peak where the homography
            fits it. None (a window without its press): none held.
    Returns:
        :class:`Contacts` (``peaks_px``: the maxima before the bump fit). Degenerate inputs give
        no contact (see :func:`outlier_candidates`).
    Raises:
        ValueError: the arrays do not describe the same N markers (:func:`marker_arrays`).
    """
    found = outlier_candidates(
        rest_px,
        current_px,
        valid,
        a=a,
        min_mean_displacement_px=min_mean_displacement_px,
        max_iters=max_iters,
        method=method,
    )
    if isinstance(found, int):
        return _no_contacts(found)
    if neighbours is None:
        neighbours = rest_neighbours(np.asarray(rest_px, dtype=np.float64), pitch_px)
    c = found
    table = _valid_table(np.ascontiguousarray(neighbours, dtype=np.int64), c.idx, c.n)
    r2 = float(r_px) * float(r_px)
    peaks, level, magnitudes = _maxima(
        c.rest_px,
        c.magnitudes,
        c.outliers,
        table,
        float(spike_fraction),
        r2,
        int(n_min),
        c.threshold_px,
        float(min_move_px),
        _held_levels(held, c.idx),
    )
    level_at = np.zeros(len(magnitudes))
    level_at[peaks] = level
    long_flat_top = False
    if len(peaks):
        peaks, fingers, flat, long_flat_top = plateau_contacts(
            table,
            c.current_px,
            magnitudes,
            peaks,
            float(plateau_fraction),
            float(pitch_px),
            float(r_px),
            bool(long_before),
        )
    else:
        fingers, flat = np.zeros(0, dtype=np.int64), np.zeros((0, 2))
    alone = fingers <= 1  # one finger's peak, not a flat top of several (whose maximum wanders over it)
    held_now = _still_held(held, c.idx, magnitudes, (c.idx[peaks[alone]], level_at[peaks[alone]]))
    rows, points, used = [], [], 0
    for i, f in zip(peaks.tolist(), fingers.tolist()):
        if f:  # a flat top: its contacts, all on its maximum's marker
            rows += [i] * f
            points += list(flat[used : used + f])
            used += f
        else:
            rows.append(i)
            points.append(_refine_peak(c.rest_px, c.v_px, magnitudes, i, refine_px))
    points = peaks_px = np.array(points, dtype=np.float64).reshape(-1, 2)
    if len(points) and fingers.max(initial=0) < 2:
        n_knots = max(2, math.ceil(bump_span_px / pitch_px) + 1)
        start = _at_rest(c.current_px, c.v_px, points)
        if len(points) < MAX_FINGERS:
            centres, missed = with_missed_finger(c.rest_px, c.v_px, start, table, float(pitch_px), n_knots, r_px)
            if missed >= 0:  # a finger the maxima missed: its marker, as the maxima's
                rows.append(missed)
                peaks_px = np.vstack([peaks_px, c.current_px[missed]])
        else:
            centres = bump_fit(c.rest_px, c.v_px, start, float(pitch_px), n_knots)
        if len(centres) >= 2:  # one finger alone keeps its refined peak
            points = field_at(c.rest_px, c.v_px, centres)
    return c.contacts(np.array(rows, dtype=np.int64), points, peaks_px, bool(long_flat_top), held_now)
