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
    rest = np.ascontiguousarray(rest_px, dtype=np.float64)
    v = np.ascontiguousarray(displacement_px, dtype=np.float64)
    return _refine_peak(rest, v, np.hypot(v[:, 0], v[:, 1]), peak, radius_px)


def _refine_peak(rest: np.ndarray, v: np.ndarray, norms: np.ndarray, peak: int, radius_px: float) -> np.ndarray:
    """:func:`refine_peak` on float64 arrays with the norms ||v|| (M,) computed once per window.
    The least-squares fit is ``cv2.solve(..., cv2.DECOMP_SVD)`` (minimum-norm like
    ``np.linalg.lstsq``, without its Python overhead); the 2x2 Hessian is solved in closed form."""
    design, values = _fit_inputs(rest, v, norms, peak, radius_px * radius_px)
    if len(design) < 6:
        return rest[peak] + v[peak]
    _, coef = cv2.solve(design, values, flags=cv2.DECOMP_SVD)
    c1, c2, c3, c4, c5 = coef[1:, 0]
    det = 4.0 * c3 * c4 - c5 * c5  # Hessian [[2 c3, c5], [c5, 2 c4]]
    if 2.0 * c3 >= 0 or det <= 0:  # not a maximum
        return rest[peak] + v[peak]
    tx = -(2.0 * c4 * c1 - c5 * c2) / det  # Hessian^-1 (-gradient at 0)
    ty = -(2.0 * c3 * c2 - c5 * c1) / det
    if tx * tx + ty * ty > (0.5 * radius_px) ** 2:
        return rest[peak] + v[peak]
    basis = np.array([1.0, tx, ty, tx * tx, ty * ty, tx * ty])
    return rest[peak] + (tx, ty) + basis @ coef[:, 1:]


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _fit_inputs(
    rest: np.ndarray, v: np.ndarray, norms: np.ndarray, peak: int, r2: float
) -> tuple[np.ndarray, np.ndarray]:
    """The least-squares system of :func:`_refine_peak`: for the markers whose rest position is
    within squared distance ``r2`` (px^2) of the peak's (in index order), the design rows
    ``(1, x, y, x^2, y^2, x y)`` (x, y relative to the peak's rest position, px) and the values
    ``(||v||, v_x, v_y)`` (px); (m, 6) and (m, 3) float64."""
    m = len(rest)
    design = np.empty((m, 6))
    values = np.empty((m, 3))
    k = 0
    for i in range(m):
        x = rest[i, 0] - rest[peak, 0]
        y = rest[i, 1] - rest[peak, 1]
        if x * x + y * y <= r2:
            design[k, 0] = 1.0
            design[k, 1] = x
            design[k, 2] = y
            design[k, 3] = x * x
            design[k, 4] = y * y
            design[k, 5] = x * y
            values[k, 0] = norms[i]
            values[k, 1] = v[i, 0]
            values[k, 2] = v[i, 1]
            k += 1
    return design[:k].copy(), values[:k].copy()


#: A plateau of more markers than this is a flat top: its contact is its centroid (a finger's
#: Gaussian-like peak holds 2-5 markers above 90 % of its maximum on the development families).
PLATEAU_MARKERS = 6
#: Most fingers one plateau is read as (paper, "Creation of the Gesture Detection Dataset":
#: gestures with up to 3 fingers).
MAX_FINGERS = 3


def rest_neighbours(rest_px: np.ndarray, pitch_px: float) -> np.ndarray:
    """Each marker's neighbours on the gel: the markers whose rest positions are closer than 1.5
    marker pitches (a square grid's 8 nearest), for the plateaus and the lone markers.

    Args:
        rest_px: (M, 2) float, rest positions (px, image frame).
        pitch_px: the marker pitch (px).
    Returns:
        (M, K) int64, row i the indices of marker i's neighbours (itself excluded), padded
        with -1; K is the largest neighbour count (at least 1).
    """
    rest = np.ascontiguousarray(rest_px, dtype=np.float64)
    return _neighbour_table(rest, (1.5 * float(pitch_px)) ** 2)


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _neighbour_table(rest: np.ndarray, link2: float) -> np.ndarray:
    """:func:`rest_neighbours` with ``link2`` = (1.5 pitch)^2 (px^2)."""
    m = len(rest)
    counts = np.zeros(m, dtype=np.int64)
    for i in range(m):
        for j in range(m):
            if j != i:
                dx = rest[i, 0] - rest[j, 0]
                dy = rest[i, 1] - rest[j, 1]
                if dx * dx + dy * dy <= link2:
                    counts[i] += 1
    width = max(1, counts.max()) if m else 1
    table = np.full((m, width), -1, dtype=np.int64)
    for i in range(m):
        k = 0
        for j in range(m):
            if j != i:
                dx = rest[i, 0] - rest[j, 0]
                dy = rest[i, 1] - rest[j, 1]
                if dx * dx + dy * dy <= link2:
                    table[i, k] = j
                    k += 1
    return table


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _valid_table(neighbours: np.ndarray, idx: np.ndarray, n: int) -> np.ndarray:
    """``neighbours`` (N, K) int64 over all N markers restricted to the valid ones ``idx`` (M,):
    (M, K) int64, rows of the valid markers, entries renumbered among them, lost neighbours -1."""
    position = np.full(n, -1, dtype=np.int64)
    for q in range(len(idx)):
        position[idx[q]] = q
    table = np.empty((len(idx), neighbours.shape[1]), dtype=np.int64)
    for q in range(len(idx)):
        for k in range(neighbours.shape[1]):
            j = neighbours[idx[q], k]
            table[q, k] = position[j] if j >= 0 else -1
    return table


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _plateau(table: np.ndarray, magnitudes: np.ndarray, seed: int, level: float) -> np.ndarray:
    """(M,) bool: the markers connected to ``seed`` through neighbours (``table``, see
    :func:`rest_neighbours`) whose magnitude is at least ``level`` (breadth-first)."""
    m = len(magnitudes)
    inside = np.zeros(m, dtype=np.bool_)
    queue = np.empty(m, dtype=np.int64)
    inside[seed] = True
    queue[0] = seed
    head, tail = 0, 1
    while head < tail:
        i = queue[head]
        head += 1
        for j in table[i]:
            if j < 0 or inside[j] or magnitudes[j] < level:
                continue
            inside[j] = True
            queue[tail] = j
            tail += 1
    return inside


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _despiked(table: np.ndarray, magnitudes: np.ndarray, fraction: float) -> np.ndarray:
    """(M,) magnitudes where a marker displaced more than 1 / ``fraction`` times the median of its
    neighbours (``table``, see :func:`rest_neighbours`; at least 2 of them) takes that median."""
    out = magnitudes.copy()
    near = np.empty(table.shape[1])
    for i in range(len(magnitudes)):
        k = 0
        for j in table[i]:
            if j >= 0:
                near[k] = magnitudes[j]
                k += 1
        if k >= 2:
            for q in range(1, k):  # insertion sort of the (<= 8) neighbours
                x = near[q]
                r = q - 1
                while r >= 0 and near[r] > x:
                    near[r + 1] = near[r]
                    r -= 1
                near[r + 1] = x
            median = near[k // 2] if k % 2 else 0.5 * (near[k // 2 - 1] + near[k // 2])
            if magnitudes[i] * fraction > median:
                out[i] = median
    return out


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _split_along_axis(points: np.ndarray, weights: np.ndarray, n: int) -> np.ndarray:
    """(n, 2) weighted centroids of ``n`` parts of equal weight of ``points`` (M, 2), M >= n,
    taken in order along their weighted principal axis (equal numbers of points when one point
    outweighs a part). The axis is the 2x2 weighted covariance's leading eigenvector, in closed
    form."""
    total = weights.sum()
    mx = (points[:, 0] * weights).sum() / total
    my = (points[:, 1] * weights).sum() / total
    out = np.empty((n, 2))
    if n == 1:
        out[0, 0], out[0, 1] = mx, my
        return out
    dx = points[:, 0] - mx
    dy = points[:, 1] - my
    a = (weights * dx * dx).sum()
    b = (weights * dx * dy).sum()
    c = (weights * dy * dy).sum()
    top = 0.5 * (a + c) + np.sqrt(0.25 * (a - c) ** 2 + b * b)
    if abs(b) > 1e-12 * (a + c + 1e-300):
        ax, ay = top - c, b
    elif a >= c:
        ax, ay = 1.0, 0.0
    else:
        ax, ay = 0.0, 1.0
    order = np.argsort(dx * ax + dy * ay, kind="mergesort")
    w = weights[order]
    middle = (np.cumsum(w) - 0.5 * w) / total  # each marker's place along the axis, by weight
    group = np.minimum((middle * n).astype(np.int64), n - 1)
    if len(np.unique(group)) < n:  # a marker outweighs a part: parts of equal marker counts
        group = np.arange(len(order)) * n // len(order)
    for g in range(n):
        sx = sy = sw = 0.0
        for q in range(len(order)):
            if group[q] == g:
                i = order[q]
                sx += points[i, 0] * weights[i]
                sy += points[i, 1] * weights[i]
                sw += weights[i]
        out[g, 0], out[g, 1] = sx / sw, sy / sw
    return out


@numba.njit(cache=True, nogil=True, error_model="numpy")
def plateau_contacts(
    table: np.ndarray,
    current_px: np.ndarray,
    magnitudes: np.ndarray,
    peaks: np.ndarray,
    fraction: float,
    pitch_px: float,
    finger_radius_px: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Merge the displacement maxima that lie on one plateau; a wide plateau's contacts (see the
    module docstring, "Flat tops").

    Args:
        table: (M, K) int64, the valid markers' neighbours on the gel (:func:`rest_neighbours`
            renumbered among them, -1 padded).
        current_px: (M, 2) float64, their current positions (px, image frame).
        magnitudes: (M,) float64, their displacement norms ||v|| (px).
        peaks: (K,) int64, the maxima (indices into the M markers) by decreasing magnitude.
        fraction: plateau level as a fraction of its maximum's magnitude, in (0, 1).
        pitch_px: the marker pitch (px): each marker stands for pitch^2 of gel.
        finger_radius_px: a fingertip's radius (px, the paper's r): a plateau of area A holds
            ``min(3, ceil(A / (pi r^2)))`` fingers (the paper's gestures have up to 3).
    Returns:
        (kept, fingers, points): the kept maxima (K' <= K, int64, by decreasing magnitude); for
        each, 0 (a plateau of at most :data:`PLATEAU_MARKERS` markers: the caller places its
        contact) or its number of fingers n (int64, K'); and the fingers' contact points, (sum
        of n, 2) float64 (px, current positions) in the order of ``kept``: the weighted
        centroids of n equal-weight parts of each wide plateau along its principal axis.
    """
    covered = np.zeros(len(magnitudes), dtype=np.bool_)
    kept = np.empty(len(peaks), dtype=np.int64)
    fingers = np.zeros(len(peaks), dtype=np.int64)
    points = np.empty((MAX_FINGERS * len(peaks), 2))
    n_kept = n_points = 0
    for p in peaks:
        if covered[p]:
            continue  # on a stronger maximum's plateau: the same flat top
        level = fraction * magnitudes[p]
        mask = _plateau(table, magnitudes, p, level)
        covered |= mask
        kept[n_kept] = p
        size = np.count_nonzero(mask)
        if size > PLATEAU_MARKERS:
            n = min(MAX_FINGERS, max(1, math.ceil(size * pitch_px**2 / (math.pi * finger_radius_px**2))))
            points[n_points : n_points + n] = _split_along_axis(current_px[mask], magnitudes[mask] - level + 1e-9, n)
            fingers[n_kept] = n
            n_points += n
        n_kept += 1
    return kept[:n_kept].copy(), fingers[:n_kept].copy(), points[:n_points].copy()


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _solve(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, bool]:
    """x of ``a x = b`` for a small square ``a`` (n, n) and ``b`` (n, m), float64, by Gaussian
    elimination with partial pivoting (numba's ``np.linalg`` needs SciPy's LAPACK, which the
    runtime does not install). Returns (x (n, m), False) when ``a`` is singular to working
    precision (a pivot below 1e-12 x its largest entry, or not finite)."""
    n = a.shape[0]
    a = a.copy()
    x = b.copy()
    scale = 0.0
    for i in range(n):
        for j in range(n):
            scale = max(scale, abs(a[i, j]))
    if not scale > 0.0 or not np.isfinite(scale):
        return x, False
    for col in range(n):
        pivot = col
        for row in range(col + 1, n):
            if abs(a[row, col]) > abs(a[pivot, col]):
                pivot = row
        if not abs(a[pivot, col]) > 1e-12 * scale:
            return x, False
        if pivot != col:
            for j in range(n):
                a[col, j], a[pivot, j] = a[pivot, j], a[col, j]
            for j in range(x.shape[1]):
                x[col, j], x[pivot, j] = x[pivot, j], x[col, j]
        for row in range(col + 1, n):
            f = a[row, col] / a[col, col]
            if f != 0.0:
                for j in range(col, n):
                    a[row, j] -= f * a[col, j]
                for j in range(x.shape[1]):
                    x[row, j] -= f * x[col, j]
    for col in range(n - 1, -1, -1):
        for j in range(x.shape[1]):
            acc = x[col, j]
            for k in range(col + 1, n):
                acc -= a[col, k] * x[k, j]
            x[col, j] = acc / a[col, col]
    return x, True


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _hat(r: float, knot: float, n_knots: int) -> tuple[int, float]:
    """The piecewise-linear profile's segment of a distance ``r`` (px): knot index j and the
    fraction f in [0, 1) towards knot j + 1, knots at 0, knot, ..., (n_knots - 1) knot; beyond the
    last knot, the last segment's end (the profile stays at its last value)."""
    t = r / knot
    top = n_knots - 1.0
    if t >= top:
        return n_knots - 2, 1.0
    j = int(t)
    return j, t - j


#: Rounds of the bump fit (:func:`bump_fit`): its centres move by at most half a knot per round.
#: 3: on the development families' windows, 2-8 rounds are within 0.1 mm of each other on every
#: family, 3 within 0.04 mm of the best; each round costs ~15 us (K = 2, 177 markers, hot).
BUMP_ITERATIONS = 3


@numba.njit(cache=True, nogil=True, error_model="numpy")
def bump_fit(
    rest: np.ndarray, v: np.ndarray, centres: np.ndarray, knot: float, n_knots: int, rounds: int = BUMP_ITERATIONS
) -> np.ndarray:
    """Centres of the fingers' radial bumps that best explain a displacement field (see the
    module docstring, "Long tails").

    Model: v(x) = sum_k g(||x - c_k||) u_k, one radial profile g shared by the K fingers (g(0) = 1,
    piecewise linear with ``n_knots`` knots ``knot`` px apart, constant beyond the last), each
    finger's displacement u_k (2,) and centre c_k (2,). Least squares over the M markers, by
    ``rounds`` rounds of: u given g and c (K x K normal equations), g given u and c (n_knots x
    n_knots, with a curvature penalty and ridge of 1e-6 of its mean diagonal), one Gauss-Newton
    step of c given g and u (2K x 2K; each centre moves by at most knot / 2 a round). No
    profile is assumed: g starts as a Gaussian over the knots' span and is measured on the
    window's field. The systems are solved by :func:`_solve` (no LAPACK at run time).

    Args:
        rest: (M, 2) float64, the markers' rest positions (px, image frame).
        v: (M, 2) float64, their displacements (px).
        centres: (K, 2) float64, K >= 1, initial centres at rest (px), e.g. the maxima's markers.
        knot: the profile's knot spacing (px), > 0.
        n_knots: its number of knots, >= 2.
        rounds: the number of rounds (:data:`BUMP_ITERATIONS`).
    Returns:
        (K, 2) float64, the fitted centres at rest (px); a centre whose fit is not finite or
        moved further than 2 knots is its initial one; all are when the u or g system is
        singular or the profile's g(0) vanishes (e.g. no displacement), and a singular
        Gauss-Newton system ends the rounds where they are.
    """
    m = len(rest)
    k_n = len(centres)
    c = centres.copy()
    g = np.empty(n_knots)
    for q in range(n_knots):  # start: a Gaussian of the knot span's width
        t = q / (n_knots - 1.0)
        g[q] = math.exp(-4.5 * t * t)
    seg = np.empty((m, k_n), dtype=np.int64)
    frac = np.empty((m, k_n))
    dist = np.empty((m, k_n))
    a = np.empty((m, k_n))
    uu = np.empty((k_n, k_n))
    geo = np.empty(2 * k_n)
    end = (n_knots - 1) * knot
    for _ in range(rounds):
        for i in range(m):
            for k in range(k_n):
                r = math.sqrt((rest[i, 0] - c[k, 0]) ** 2 + (rest[i, 1] - c[k, 1]) ** 2)
                dist[i, k] = r
                seg[i, k], frac[i, k] = _hat(r, knot, n_knots)
        # the fingers' displacements u given g and c
        for i in range(m):
            for k in range(k_n):
                j, f = seg[i, k], frac[i, k]
                a[i, k] = g[j] * (1.0 - f) + g[j + 1] * f
        normal = np.zeros((k_n, k_n))
        rhs = np.zeros((k_n, 2))
        for i in range(m):  # a^T a and a^T v, written out (numba's @ needs SciPy's BLAS)
            for k in range(k_n):
                rhs[k, 0] += a[i, k] * v[i, 0]
                rhs[k, 1] += a[i, k] * v[i, 1]
                for q in range(k_n):
                    normal[k, q] += a[i, k] * a[i, q]
        for k in range(k_n):
            normal[k, k] += 1e-9 * (normal[k, k] + 1e-12)
        u, ok = _solve(normal, rhs)
        if not ok:
            return centres.copy()
        # the profile g given u and c: rows (i, d) = sum_k b_k u_kd, b_k the hat basis at r_ik
        # (2 nonzero knots), so the normal matrix gains sum_kl (u_k . u_l) b_k b_l^T per marker
        normal = np.zeros((n_knots, n_knots))
        rhs = np.zeros((n_knots, 1))
        for k in range(k_n):
            for q in range(k_n):
                uu[k, q] = u[k, 0] * u[q, 0] + u[k, 1] * u[q, 1]
        for i in range(m):
            for k in range(k_n):
                j, f = seg[i, k], frac[i, k]
                uv = u[k, 0] * v[i, 0] + u[k, 1] * v[i, 1]
                rhs[j, 0] += (1.0 - f) * uv
                rhs[j + 1, 0] += f * uv
                for q in range(k_n):
                    jq, fq = seg[i, q], frac[i, q]
                    w = uu[k, q]
                    normal[j, jq] += w * (1.0 - f) * (1.0 - fq)
                    normal[j, jq + 1] += w * (1.0 - f) * fq
                    normal[j + 1, jq] += w * f * (1.0 - fq)
                    normal[j + 1, jq + 1] += w * f * fq
        # a faint curvature penalty and ridge (1e-6 of the mean diagonal): a knot no marker's
        # distance reaches follows its neighbours, and when the fingers' displacements cancel
        # (sum_k u_k = 0, a pinch) a constant added to g, which changes no model value, is 0
        level = 0.0
        for p in range(n_knots):
            level += normal[p, p]
        level *= 1e-6 / n_knots
        for p in range(n_knots):
            normal[p, p] += level
        for p in range(1, n_knots - 1):
            for a_, wa in ((p - 1, 1.0), (p, -2.0), (p + 1, 1.0)):
                for b_, wb in ((p - 1, 1.0), (p, -2.0), (p + 1, 1.0)):
                    normal[a_, b_] += level * wa * wb
        sol, ok = _solve(normal, rhs)
        if not ok or not abs(sol[0, 0]) > 1e-9:
            return centres.copy()
        g0 = sol[0, 0]
        for p in range(n_knots):
            g[p] = sol[p, 0] / g0
        u *= g0
        for k in range(k_n):
            for q in range(k_n):
                uu[k, q] = u[k, 0] * u[q, 0] + u[k, 1] * u[q, 1]
        # one Gauss-Newton step of the centres given g and u
        normal = np.zeros((2 * k_n, 2 * k_n))
        rhs = np.zeros((2 * k_n, 1))
        for i in range(m):
            model_x = 0.0
            model_y = 0.0
            for k in range(k_n):
                j, f, r = seg[i, k], frac[i, k], dist[i, k]
                w = g[j] * (1.0 - f) + g[j + 1] * f
                model_x += w * u[k, 0]
                model_y += w * u[k, 1]
                # d model_d / d c_ke = -g'(r) (x_e - c_ke) / r u_kd: its part without u
                slope = (g[j + 1] - g[j]) / knot / r if end > r > 1e-9 else 0.0
                geo[2 * k] = -slope * (rest[i, 0] - c[k, 0])
                geo[2 * k + 1] = -slope * (rest[i, 1] - c[k, 1])
            # summed over the two components d: J^T J gains geo_ke geo_lf (u_k . u_l), J^T res
            # gains geo_ke (u_k . res_i)
            res_x, res_y = v[i, 0] - model_x, v[i, 1] - model_y
            for p in range(2 * k_n):
                k = p // 2
                rhs[p, 0] += geo[p] * (u[k, 0] * res_x + u[k, 1] * res_y)
                for q in range(p, 2 * k_n):
                    normal[p, q] += geo[p] * geo[q] * uu[k, q // 2]
        for p in range(2 * k_n):
            for q in range(p):
                normal[p, q] = normal[q, p]
            normal[p, p] += 1e-6 * (normal[p, p] + 1e-12)
        step, ok = _solve(normal, rhs)
        if not ok:
            break
        for k in range(k_n):
            sx, sy = step[2 * k, 0], step[2 * k + 1, 0]
            n = math.sqrt(sx * sx + sy * sy)
            shrink = min(1.0, 0.5 * knot / n) if n > 0 else 1.0
            c[k, 0] += sx * shrink
            c[k, 1] += sy * shrink
    for k in range(k_n):
        moved = math.hypot(c[k, 0] - centres[k, 0], c[k, 1] - centres[k, 1])
        if not moved <= 2.0 * knot:  # also NaN
            c[k, 0], c[k, 1] = centres[k, 0], centres[k, 1]
    return c


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _at_rest(current: np.ndarray, v: np.ndarray, points: np.ndarray) -> np.ndarray:
    """(K, 2) where the gel points now at ``points`` (K, 2) px were at rest: each less the
    displacement of the marker nearest to it now (``current``, ``v`` (M, 2) px, M >= 1)."""
    out = np.empty_like(points)
    for k in range(len(points)):
        best = 0
        best_d2 = np.inf
        for i in range(len(current)):
            d2 = (current[i, 0] - points[k, 0]) ** 2 + (current[i, 1] - points[k, 1]) ** 2
            if d2 < best_d2:
                best, best_d2 = i, d2
        out[k, 0] = points[k, 0] - v[best, 0]
        out[k, 1] = points[k, 1] - v[best, 1]
    return out


@numba.njit(cache=True, nogil=True, error_model="numpy")
def field_at(rest: np.ndarray, v: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Where gel points are now: (K, 2) ``points`` (rest positions, px) plus the displacement
    there, the inverse-square-distance mean of the displacements ``v`` (M, 2) of the 4 markers
    nearest at rest (``rest`` (M, 2), M >= 1; a marker's own when a point is on it)."""
    out = np.empty_like(points)
    near = min(4, len(rest))
    best = np.empty(near, dtype=np.int64)
    best_d2 = np.empty(near)
    for k in range(len(points)):
        n_best = 0  # the nearest markers so far, by increasing distance (insertion)
        for i in range(len(rest)):
            d2 = (rest[i, 0] - points[k, 0]) ** 2 + (rest[i, 1] - points[k, 1]) ** 2
            if n_best < near or d2 < best_d2[n_best - 1]:
                q = n_best if n_best < near else near - 1
                while q > 0 and best_d2[q - 1] > d2:
                    best[q], best_d2[q] = best[q - 1], best_d2[q - 1]
                    q -= 1
                best[q], best_d2[q] = i, d2
                n_best = min(n_best + 1, near)
        sx = sy = sw = 0.0
        for q in range(near):
            w = 1.0 / (best_d2[q] + 1e-6)
            sx += w * v[best[q], 0]
            sy += w * v[best[q], 1]
            sw += w
        out[k, 0] = points[k, 0] + sx / sw
        out[k, 1] = points[k, 1] + sy / sw
    return out


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
