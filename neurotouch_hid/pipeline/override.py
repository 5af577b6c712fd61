"""The event path overruling a stale resting verdict (not in the paper; docs/method.md, "Resting").

A resting verdict comes from an APS frame, up to 40 ms old at 25 Hz. When, at a window's end,
enough tracked markers have moved further than a threshold from rest, the window is processed as
a gesture window. A marker counts as moved by the median of its and its nearest neighbours'
displacements at rest (a finger moves a marker's neighbours with it; tracker jitter under a
flickering light does not), and only beyond the threshold plus the gel's jitter: the median, over
the gel's markers, of the part of each marker's displacement that its neighbourhood does not share
(its distance from that median). A finger's field is smooth over the 4 mm grid, so near it and
far from it a marker moves as its neighbours do; a flickering light changes every marker's
brightness at once, and the events of each change walk every blob of the gel on its own, so much
just after the light comes on that the neighbourhood medians of a whole gel of walking blobs pass
the threshold. On a gel whose untouched markers make no events (a steady light) the jitter is 0
and the threshold is as given (docs/method.md, "Resting").
"""

from __future__ import annotations

import numba
import numpy as np


def overrules_rest(
    current: np.ndarray,
    valid: np.ndarray,
    rest: np.ndarray,
    neighbours: np.ndarray,
    threshold_px: float,
    min_markers: int,
) -> bool:
    """Whether at least ``min_markers`` ``valid`` (N,) bool markers moved further than
    ``threshold_px`` plus the gel's jitter from rest, each by the median displacement over itself
    and its ``neighbours`` (:func:`grid_neighbours`); the jitter is the median over the valid
    markers of their distances (px) from their neighbourhood's median displacement (module
    docstring); ``current``, ``rest`` (N, 2) float64 px. The medians are taken only when the
    markers' own displacements would overrule (at rest nearly always not, so their cost is spent
    on the few windows that need it)."""
    threshold_sq = threshold_px * threshold_px
    if _count_moved(current, valid, rest, threshold_sq) < min_markers:
        return False
    shared, jitter = _shared_and_jitter(current, valid, rest, neighbours)
    if jitter > 0.0:  # (exactly as given otherwise)
        threshold_sq = (threshold_px + jitter) ** 2
    moved = int(np.count_nonzero(shared[:, 0] * shared[:, 0] + shared[:, 1] * shared[:, 1] > threshold_sq))
    return moved >= min_markers


def shared_distances(
    current: np.ndarray, valid: np.ndarray, rest: np.ndarray, neighbours: np.ndarray
) -> tuple[np.ndarray, float]:
    """Each marker's distance from rest as its neighbourhood shares it, and the gel's jitter.

    Args:
        current, rest: (N, 2) float64 positions (px).
        valid: (N,) bool, the tracked markers.
        neighbours: (N, k) int64, :func:`grid_neighbours` of ``rest``.
    Returns:
        ((N,) float64 px, the length of the median over each marker and its ``neighbours`` of their
        displacements from rest, NaN for a lost marker; the jitter (px) of :func:`overrules_rest`).
    """
    shared, jitter = _shared_and_jitter(current, valid, rest, neighbours)
    return np.where(valid, np.hypot(shared[:, 0], shared[:, 1]), np.nan), jitter


def _shared_and_jitter(
    current: np.ndarray, valid: np.ndarray, rest: np.ndarray, neighbours: np.ndarray
) -> tuple[np.ndarray, float]:
    """(N, 2) float64 px each marker's median displacement over itself and its ``neighbours``
    (NaN rows where none is tracked), and the gel's jitter (px; 0 with no valid marker)."""
    d = np.where(valid[:, None], current - rest, np.nan)
    shared = _median_of_sorted(np.sort(np.concatenate([d, np.full((1, 2), np.nan)])[neighbours], axis=1))
    own = d[valid] - shared[valid]
    return shared, float(np.median(np.hypot(own[:, 0], own[:, 1]))) if len(own) else 0.0


#: The smooth override's neighbours of a marker: the markers within this many times the median
#: nearest-neighbour distance at rest (on the square 4 mm grid: its four nearest, not the diagonals).
OVERRIDE_NEIGHBOUR_GAP = 1.25


def _median_of_sorted(values: np.ndarray) -> np.ndarray:
    """(N, 2) the median over axis 1 of ``values`` (N, k, 2) sorted along it with NaN last
    (NaN ignored, as ``np.nanmedian``, ~7x faster here); 0 where a row has no finite value (a
    marker whose neighbours are all lost has not moved)."""
    n = np.isfinite(values).sum(axis=1)  # (N, 2)
    lo = np.take_along_axis(values, np.maximum((n - 1) // 2, 0)[:, None, :], axis=1)[:, 0]
    hi = np.take_along_axis(values, np.maximum(n // 2, 0)[:, None, :], axis=1)[:, 0]
    return np.where(n > 0, 0.5 * (lo + hi), 0.0)


def grid_neighbours(rest_px: np.ndarray) -> np.ndarray:
    """(N, k) int64: each marker of ``rest_px`` (N, 2) px, then its neighbours at rest (within
    :data:`OVERRIDE_NEIGHBOUR_GAP` times the median nearest-neighbour distance), padded with N
    (a row of NaN is appended to the displacements it indexes)."""
    n = len(rest_px)
    gap = np.sqrt(((rest_px[:, None, :] - rest_px[None, :, :]) ** 2).sum(axis=-1))
    np.fill_diagonal(gap, np.inf)
    near = gap <= OVERRIDE_NEIGHBOUR_GAP * np.median(gap.min(axis=1)) if n > 1 else np.zeros((n, n), bool)
    k = int(near.sum(axis=1).max()) if n else 0
    out = np.full((n, k + 1), n, dtype=np.int64)
    out[:, 0] = np.arange(n)
    for i in range(n):
        idx = np.flatnonzero(near[i])
        out[i, 1 : 1 + len(idx)] = idx
    return out


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _count_moved(current: np.ndarray, valid: np.ndarray, rest: np.ndarray, threshold_sq: float) -> int:
    """How many ``valid`` (N,) bool markers are more than sqrt(``threshold_sq``) (px^2) from rest,
    ``current`` and ``rest`` (N, 2) float64 px (a NaN position is not). One pass, no
    temporaries: every resting window runs it (the motion override)."""
    moved = 0
    for i in range(len(current)):
        if valid[i]:
            dx = current[i, 0] - rest[i, 0]
            dy = current[i, 1] - rest[i, 1]
            if dx * dx + dy * dy > threshold_sq:
                moved += 1
    return moved
