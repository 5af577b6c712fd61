"""Flat tops and lone markers of the contact step (not in the paper; docs/method.md, "Contacts").

Both read each marker's neighbours on the gel at rest (:func:`rest_neighbours`). A plateau of the
displacement field several markers wide (several fingers together, or a stuck contact disc) is
one flat top whose contacts are read off its area and shape (:func:`plateau_contacts`); a marker
displaced far more than all its neighbours is the tracker's error and takes their median
(``_despiked``).
Image frame (px).
"""

from __future__ import annotations

import math

import numba
import numpy as np

from neurotouch_hid.pipeline.order import median_head

#: Gaussian-like peak holds 2-5 markers above 90 % of its maximum on the development families).
PLATEAU_MARKERS = 6
#: Most fingers one plateau is read as (paper, "Creation of the Gesture Detection Dataset":
#: gestures with up to 3 fingers).
MAX_FINGERS = 3
#: A flat top at least this many times as long as wide is three fingertips side by side, whatever
#: its area (round fingertips in a row; two side by side are about twice as long as wide).
ROW_ELONGATION = 3.0
#: A flat top's area per finger, in fingertip footprints pi r^2: a deep fingertip's flat top is
#: wider than its footprint (1.1-1.25 footprints per finger where two or three press together).
FOOTPRINTS_PER_FINGER = 1.25
#: A flat top less than this many times as long as wide is round: one fingertip pressed deep
#: (1.01-1.04), or two pressed deep together once their flat tops have merged (1.00-1.07).
ROUND_ELONGATION = 1.05
#: A flat top of at least one footprint at least this many times as long as wide is fingertips
#: side by side (two: 1.3-3.1 up to 4 mm deep, before they press round; one fingertip: 1.05 at most).
LONG_ELONGATION = 1.3


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
def _plateau(
    table: np.ndarray, magnitudes: np.ndarray, seed: int, level: float, top: float, taken: np.ndarray
) -> np.ndarray:
    """(M,) bool: the markers connected to ``seed`` through neighbours (``table``, see
    :func:`rest_neighbours`) whose magnitude is at least ``level`` and at most ``top`` and that are
    not ``taken`` ((M,) bool: on a stronger maximum's flat top), breadth-first."""
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
            if j < 0 or inside[j] or taken[j] or magnitudes[j] < level or magnitudes[j] > top:
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
            median = median_head(near, k)  # of the (<= 8) neighbours
            if magnitudes[i] * fraction > median:
                out[i] = median
    return out


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _second_moments(points: np.ndarray, weights: np.ndarray):
    """``points`` (M, 2) with ``weights`` (M,): their weighted centre (mx, my), each point's offset
    from it (dx, dy: (M,) each) and the weighted sums a = sum w dx^2, b = sum w dx dy, c = sum w
    dy^2 (the 2x2 weighted covariance times the total weight)."""
    total = weights.sum()
    mx = (points[:, 0] * weights).sum() / total
    my = (points[:, 1] * weights).sum() / total
    dx = points[:, 0] - mx
    dy = points[:, 1] - my
    return mx, my, dx, dy, (weights * dx * dx).sum(), (weights * dx * dy).sum(), (weights * dy * dy).sum()


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _elongation(points: np.ndarray, weights: np.ndarray) -> float:
    """How many times as long as wide ``points`` (M, 2) are: the square root of the ratio of
    their ``weights``-weighted covariance's eigenvalues (closed form; inf for points on a line)."""
    _, _, _, _, a, b, c = _second_moments(points, weights)
    half = np.sqrt(0.25 * (a - c) ** 2 + b * b)
    small = 0.5 * (a + c) - half
    return np.sqrt((0.5 * (a + c) + half) / small) if small > 1e-12 * (a + c) else np.inf


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _split_along_axis(points: np.ndarray, weights: np.ndarray, n: int) -> np.ndarray:
    """(n, 2) weighted centroids of ``n`` parts of equal weight of ``points`` (M, 2), M >= n,
    taken in order along their weighted principal axis (equal numbers of points when one point
    outweighs a part). The axis is the 2x2 weighted covariance's leading eigenvector, in closed
    form."""
    total = weights.sum()
    mx, my, dx, dy, a, b, c = _second_moments(points, weights)
    out = np.empty((n, 2))
    if n == 1:
        out[0, 0], out[0, 1] = mx, my
        return out
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
    parts = 1  # distinct parts: group is non-decreasing (cumulative weights), so count its steps
    for k in range(1, len(group)):  # (np.unique would cost the first run ~1 s of compiling)
        parts += group[k] != group[k - 1]
    if parts < n:  # a marker outweighs a part: parts of equal marker counts
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
    long_before: bool = True,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, bool]:
    """Merge the displacement maxima that lie on one plateau; a wide plateau's contacts (see the
    module docstring, "Flat tops"). Each maximum's plateau (at ``fraction`` of its magnitude)
    stops at the plateaus of the stronger maxima before it and, but for the strongest's, holds no
    marker displaced more than its maximum: such a marker lies on a stronger finger's slope (the
    strongest maximum's own centre can be higher, where the homography explains it).

    A round flat top (less than :data:`ROUND_ELONGATION` times as long as wide) whose area reads
    two fingers is one fingertip pressed deep unless an earlier window of the press showed a long
    flat top (``long_before``): two fingertips pressed deep together are as round, but side by
    side (at least :data:`LONG_ELONGATION` times as long as wide) before.

    At most :data:`MAX_FINGERS` contacts come out: when the wide plateaus' fingers and the other
    maxima would make more, each plateau is one contact (placed by the caller) and only the
    :data:`MAX_FINGERS` strongest maxima are kept.

    Args:
        table: (M, K) int64, the valid markers' neighbours on the gel (:func:`rest_neighbours`
            renumbered among them, -1 padded).
        current_px: (M, 2) float64, their current positions (px, image frame).
        magnitudes: (M,) float64, their displacement norms ||v|| (px).
        peaks: (K,) int64, the maxima (indices into the M markers) by decreasing magnitude.
        fraction: plateau level as a fraction of its maximum's magnitude, in (0, 1).
        pitch_px: the marker pitch (px): each marker stands for pitch^2 of gel.
        finger_radius_px: a fingertip's radius (px, the paper's r): a plateau of area A holds
            ``min(3, ceil(A / (f pi r^2)))`` fingers, f = :data:`FOOTPRINTS_PER_FINGER` (the
            paper's gestures have up to 3), and 3 when it is at least :data:`ROW_ELONGATION`
            times as long as wide.
        long_before: whether an earlier window of the press had a long flat top (the
            ``long`` this function returned); True where there is no press (a single window)
            keeps the area's reading of a round flat top.

    Returns:
        (kept, fingers, points, long): the kept maxima (K' <= K, int64, by decreasing
        magnitude); for each, 0 (a plateau of at most :data:`PLATEAU_MARKERS` markers, or a
        round one read as one fingertip: the caller places its contact) or its number of fingers
        n (int64, K'); the fingers' contact points, (sum of n, 2) float64 (px, current positions)
        in the order of ``kept``: the weighted centroids of n equal-weight parts of each wide
        plateau along its principal axis; and whether a flat top of at least one footprint
        pi r^2 is at least :data:`LONG_ELONGATION` times as long as wide (bool).
    """
    covered = np.zeros(len(magnitudes), dtype=np.bool_)
    kept = np.empty(len(peaks), dtype=np.int64)
    fingers = np.zeros(len(peaks), dtype=np.int64)
    points = np.empty((MAX_FINGERS * len(peaks), 2))
    n_kept = n_points = 0
    footprint = math.pi * finger_radius_px**2
    long = False
    for p in peaks:
        if covered[p]:
            continue  # on a stronger maximum's plateau: the same flat top
        level = fraction * magnitudes[p]
        # a weaker one's level may reach a stronger's flat top, and the slope below it
        top = magnitudes[p] if n_kept else np.inf
        mask = _plateau(table, magnitudes, p, level, top, covered)
        covered |= mask
        kept[n_kept] = p
        size = np.count_nonzero(mask)
        if size > PLATEAU_MARKERS:
            weights = magnitudes[mask] - level + 1e-9
            area = size * pitch_px**2
            n = max(1, math.ceil(area / (FOOTPRINTS_PER_FINGER * footprint)))
            elongation = _elongation(current_px[mask], weights)
            long = long or (area >= footprint and elongation >= LONG_ELONGATION)
            if elongation >= ROW_ELONGATION:
                n = MAX_FINGERS
            elif n == 2 and elongation < ROUND_ELONGATION and not long_before:
                n = 0  # one fingertip pressed deep
            n = min(MAX_FINGERS, n)
            if n:
                parts = _split_along_axis(current_px[mask], weights, n)
                for q in range(n):  # (a slice assignment would cost the first run ~2 s of compiling)
                    points[n_points + q, 0], points[n_points + q, 1] = parts[q, 0], parts[q, 1]
            fingers[n_kept] = n
            n_points += n
        n_kept += 1
    kept, fingers, points = at_most_three(kept[:n_kept].copy(), fingers[:n_kept].copy(), points[:n_points].copy())
    return kept, fingers, points, long


@numba.njit(cache=True, nogil=True, error_model="numpy")
def at_most_three(
    kept: np.ndarray, fingers: np.ndarray, points: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The cap of :func:`plateau_contacts` on its (kept, fingers, points): as they are when they
    make at most :data:`MAX_FINGERS` contacts (a flat top of n fingers n, any other maximum 1);
    else each flat top is one contact (fingers 0, no points: the caller places it) and only the
    :data:`MAX_FINGERS` strongest maxima stay. More contacts than a gesture has fingers means
    the wide flat tops are deep single fingertips (a fingertip's footprint grows with its depth),
    and the weakest maxima the fingers' tails."""
    if np.maximum(fingers, 1).sum() > MAX_FINGERS:
        n = min(len(kept), MAX_FINGERS)
        return kept[:n].copy(), np.zeros(n, dtype=np.int64), points[:0].copy()
    return kept, fingers, points
