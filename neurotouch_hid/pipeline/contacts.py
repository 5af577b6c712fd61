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

Flat tops (not in the paper, ``plateau_fraction``): the paper's contact is a marker whose
displacement is the largest within r. Where several fingers push together, or a stuck contact
disc carries the gel under it rigidly (Cattaneo-Mindlin partial slip), the field's maximum is a
plateau several markers wide, flat to within the tracker's noise: any of its markers may be
the largest within r, so one plateau yields maxima at random places on it (measured on the
development families: a 3-finger push reads as 4-6 contacts, its contact distance 5-6.5 mm).
:func:`plateau_contacts` merges the maxima that lie on one plateau -- the markers connected to
the strongest maximum (neighbours within 1.5 marker pitches at rest) whose displacement is at
least ``plateau_fraction`` x its own, i.e. maxima whose topographic prominence is below
``1 - plateau_fraction`` of the peak. A plateau of more than :data:`PLATEAU_MARKERS` markers is
a flat top: it holds one finger per fingertip footprint (pi r^2, the paper's r being "the
typical radius of a fingertip") of its area, at most 3, placed at the weighted centroids of
equal parts of the plateau along its principal axis (weights: how far each marker rises above
the plateau's level); a smaller plateau is a finger's peak and keeps its contact as before.

Neighbourhoods on the gel (not in the paper, ``maxima_at_rest``): the paper's N(i) holds the
candidates within r of marker i's *current* position. A pinch brings two fingers, and the gel
under them, together: when their contact markers come within r of each other in the image,
the weaker one is no maximum any more and the pinch reads as one contact (measured on the
development families: most of the 2 -> 1 errors of ``strong`` and ``drift`` pinches, where the
markers between the fingers are squeezed together). With ``maxima_at_rest`` N(i) is taken over
the rest positions: markers within r on the gel, which a deformation does not bring together.

Lone markers (not in the paper, ``spike_fraction``): a finger's footprint is wider than the
4 mm marker pitch, so the markers next to a contact move nearly as much as it does. A single
marker far above all its neighbours is the tracker's error (a hot pixel or background activity
pulled its blob: the ``noise`` family), and the paper's rule makes it a contact, or lets it
suppress a real one within r. With ``spike_fraction`` a marker displaced more than
1 / spike_fraction times the median of its neighbours (rest positions within 1.5 pitches) takes
that median in this stage (maxima, plateaus, refinement; the intensity still reads its own).

Long tails (not in the paper, ``bump_span_px``; the pipeline's ``bump_fit``): the paper's
contact point is the marker of largest displacement within r, "the location where the silicone
gel experiences the greatest deformation". Where the fingers' fields have long tails (a power-law
falloff, or the a/r field outside a stuck contact disc), the fields of the fingers of one gesture
overlap: in a pinch, zoom or twist each finger's field is opposed on its inner side by the
others' tails, so the largest displacement lies one to two marker pitches *outside* the finger
(measured on the development families: 5-8 px outward, 2-3 mm, on ``powerlaw`` and
``stickslip``; ~1 px on the Gaussian ``default``). :func:`bump_fit` instead explains the whole
field as a sum of radial bumps, one per contact, v(x) = sum_k g(||x - c_k||) u_k, and moves
the centres c_k to the least-squares optimum. The profile g is not assumed (no Gaussian or power
law): it is measured on the window's own field, a piecewise-linear function of the distance with
knots one marker pitch apart up to the gel's radius (the only constants, both geometry); the
fit starts at the contacts found above, keeps their number, and a centre it moves further than
two pitches stays where it was. A contact point is then the fitted gel point where it is now (its
rest position plus the field there, :func:`field_at`). It runs only where there are at least two
contacts and no flat top holds several fingers: a single finger's peak is symmetric already, and
on a multi-finger flat top (a rigid plateau) the bumps' centres are not determined by the field
(measured: the 3-finger push of ``default`` 2.7 -> 3.7 mm with it, ``powerlaw`` 7.1 -> 6.3 mm).
The gesture step still takes A and the intensity about the maxima (``Contacts.peaks_px``): the
paper's intensity is the largest deformation, and the fitted centres moved the intensity MAE by
+0.02 to +0.06 mm on every family.

Everything here is in the image frame (px).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numba
import numpy as np

from neurotouch_hid.pipeline.contacts_bump import _at_rest, bump_fit, field_at
from neurotouch_hid.pipeline.contacts_plateau import _despiked, _valid_table, plateau_contacts, rest_neighbours
from neurotouch_hid.pipeline.contacts_refine import _refine_peak
from neurotouch_hid.pipeline.markers import marker_arrays


@dataclass(frozen=True)
class Contacts:
    """The contact points of one window.

    Attributes:
        indices: (K,) int64, indices of the markers that are contact points (ordered by
            decreasing displacement; the contacts of one plateau all give its maximum's marker).
        points_px: (K, 2) float64, their current positions, image frame (px) (sub-marker
            refined ones with ``refine_px``, see :func:`refine_peak`; the fitted fingers' centres
            with ``bump_span_px``, see :func:`bump_fit`).
        peaks_px: (K, 2) float64, the points of the field's maxima (px, image frame): the
            contact points as they are before :func:`bump_fit` (``points_px`` itself without
            it). The gesture step reads its set A and intensity around these: the largest
            deformation (paper, "Gesture Classification and Intensity Prediction").
        candidates: (N,) bool, the RANSAC outliers S (False for markers not valid).
        reproj_threshold_px: the dynamic reprojection threshold used (px); 0 when RANSAC did
            not run.
    """

    indices: np.ndarray
    points_px: np.ndarray
    peaks_px: np.ndarray
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
        peaks_px=np.zeros((0, 2), dtype=np.float64),
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
    where: np.ndarray,
    magnitudes: np.ndarray,
    outliers: np.ndarray,
    table: np.ndarray,
    spike_fraction: float,
    r2: float,
    n_min: int,
    fallback_threshold: float,
) -> tuple[np.ndarray, np.ndarray]:
    """The contact step after RANSAC, up to the plateaus (:func:`detect_contacts`).

    ``where`` (M, 2) float64 px: the positions whose neighbourhoods N(i) count (current, or rest
    with ``maxima_at_rest``); ``magnitudes`` (M,) ||v|| px; ``outliers`` (M,) bool, RANSAC's;
    ``table`` (M, K) int64, the valid markers' neighbour table (used when ``spike_fraction`` > 0);
    ``spike_fraction`` <= 0: no lone-marker median; ``r2`` = r^2 (px^2);
    ``fallback_threshold`` < 0: no field fallback, else the rest model's threshold (px).
    Returns the maxima (K,) int64 (indices into the M markers, by decreasing magnitude) and the
    magnitudes the later steps read (M,) float64 (lone markers at their neighbours' median)."""
    if spike_fraction > 0:
        magnitudes = _despiked(table, magnitudes, spike_fraction)
    chosen = np.flatnonzero(outliers)
    found = _local_maxima(where[chosen], magnitudes[chosen], r2, n_min)
    peaks = chosen[found]
    if len(peaks) == 0 and fallback_threshold >= 0:
        moved = np.flatnonzero(magnitudes > fallback_threshold)  # the rest model's outliers
        peaks = moved[_local_maxima(where[moved], magnitudes[moved], r2, n_min)]
    return peaks, magnitudes


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
    plateau_fraction: float | None = None,
    pitch_px: float = 10.0,
    maxima_at_rest: bool = False,
    spike_fraction: float | None = None,
    neighbours: np.ndarray | None = None,
    bump_span_px: float | None = None,
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
        plateau_fraction: None: every local maximum is a contact (paper); in (0, 1): maxima on
            one plateau at this fraction of the strongest are merged, and a wide plateau's
            contacts are read off its area and shape (:func:`plateau_contacts`, with ``r_px`` as
            the fingertip's radius).
        pitch_px: the marker pitch (px), for the plateaus.
        maxima_at_rest: False: N(i) = the candidates within r of marker i now (paper); True:
            within r at rest (module docstring, "Neighbourhoods on the gel").
        spike_fraction: None: the tracked ||v|| (paper); in (0, 1]: lone markers take their
            neighbours' median (module docstring, "Lone markers").
        neighbours: (N, K) int64, :func:`rest_neighbours` of ``rest_px`` with ``pitch_px``
            (computed once per rest reference by the pipeline); None: computed here when needed.
        bump_span_px: None: the contact points are the maxima's (paper); > 0: when there are
            at least two contacts and none is a flat top's, their centres are fitted as radial
            bumps with a profile of knots ``pitch_px`` apart up to this distance (px), e.g. the
            gel's radius (:func:`bump_fit`, module docstring "Long tails").
    Returns:
        :class:`Contacts`. Degenerate inputs give no contact: fewer than 4 valid markers (a
        homography needs 4), or a mean displacement below ``min_mean_displacement_px``
        (e.g. all-zero). When ``cv2.findHomography`` returns None, all valid markers are
        candidates (see :func:`homography_outliers`).
    Raises:
        ValueError: the arrays do not describe the same N markers (:func:`marker_arrays`).
    """
    rest, cur, usable = marker_arrays(rest_px, current_px, valid)
    n = len(rest)
    idx, rest_ok, cur_ok, v_ok, magnitudes = _usable(rest, cur, usable)
    if len(idx) < 4:
        return _no_contacts(n)
    mean = float(magnitudes.mean())
    if mean < min_mean_displacement_px:
        return _no_contacts(n)
    threshold = a * mean
    outliers = homography_outliers(rest_ok, cur_ok, threshold, max_iters, method)
    candidates = np.zeros(n, dtype=bool)
    candidates[idx[outliers]] = True
    if spike_fraction is None and plateau_fraction is None:
        table = np.zeros((len(idx), 1), dtype=np.int64)  # not read
    else:
        if neighbours is None:
            neighbours = rest_neighbours(rest, pitch_px)
        table = _valid_table(np.ascontiguousarray(neighbours, dtype=np.int64), idx, n)
    peaks, magnitudes = _maxima(
        rest_ok if maxima_at_rest else cur_ok,  # the neighbourhoods N(i): on the gel at rest, or now (paper)
        magnitudes,
        outliers,
        table,
        -1.0 if spike_fraction is None else float(spike_fraction),
        float(r_px) * float(r_px),
        int(n_min),
        threshold if field_fallback else -1.0,
    )
    if plateau_fraction is not None and len(peaks):
        peaks, fingers, flat = plateau_contacts(
            table, cur_ok, magnitudes, peaks, float(plateau_fraction), float(pitch_px), float(r_px)
        )
    else:
        fingers, flat = np.zeros(len(peaks), dtype=np.int64), np.zeros((0, 2))
    rows, points, used = [], [], 0
    for i, f in zip(peaks.tolist(), fingers.tolist()):
        if f:  # a flat top: its contacts, all on its maximum's marker
            rows += [i] * f
            points += list(flat[used : used + f])
            used += f
        else:
            rows.append(i)
            points.append(_refine_peak(rest_ok, v_ok, magnitudes, i, refine_px) if refine_px else cur_ok[i])
    maxima = idx[np.array(rows, dtype=np.int64)]
    points = peaks_px = np.array(points, dtype=np.float64).reshape(-1, 2)
    if bump_span_px is not None and len(points) >= 2 and fingers.max(initial=0) < 2:
        n_knots = max(2, math.ceil(bump_span_px / pitch_px) + 1)
        centres = bump_fit(rest_ok, v_ok, _at_rest(cur_ok, v_ok, points), float(pitch_px), n_knots)
        points = field_at(rest_ok, v_ok, centres)
    return Contacts(
        indices=maxima, points_px=points, peaks_px=peaks_px, candidates=candidates, reproj_threshold_px=threshold
    )
