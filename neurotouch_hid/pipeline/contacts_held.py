"""A finger's peak where the homography fits it (docs/method.md, "Contacts", step 3): which of the
field's maxima are kept as a finger's peak, where the homography fails on or about them
(:data:`PEAK_OUTLIER_NEIGHBOURS`) or where the press held them in the window before
(:data:`HELD_PEAK_SHARE`), and the peaks a press holds from one window to the next
(:func:`_still_held`, :func:`_held_levels`; :attr:`~neurotouch_hid.pipeline.contacts.Contacts.held`).
numba kernels of the pipeline's group; :func:`~neurotouch_hid.pipeline.contacts.detect_contacts`
calls them. Everything here is in the image frame (px).
"""

from __future__ import annotations

import numba
import numpy as np

#: A maximum that the homography fits is still a finger's peak when at least this many of its grid
#: neighbours are outliers: under a rigid stick disc (Cattaneo-Mindlin) the homography can fit the
#: disc's centre but not the slip about it (docs/method.md, "Contacts").
PEAK_OUTLIER_NEIGHBOURS = 2

#: A maximum the homography fits is still a finger's peak when it or one of its grid neighbours
#: was one finger's peak (not a flat top of several) earlier in the same press, and it is displaced
#: at least this share of what it was when the homography last failed on or about it: a finger held
#: where, from one APS frame's correction to the next, the homography's consensus follows it (a held
#: 3-finger zoom or twist, docs/method.md, "Contacts"). The press keeps such a peak while its marker
#: stays displaced at least this share, through windows where it is no maximum (another finger's
#: flat top beside it, the maxima reshuffled by a correction); a finger easing off below it is left
#: to the homography.
HELD_PEAK_SHARE = 0.9


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _where_homography_fails(
    peaks: np.ndarray, outliers: np.ndarray, table: np.ndarray, magnitudes: np.ndarray, held: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Which maxima ``peaks`` (K,) int64 (into the M markers) are a finger's peak, and the ||v||
    (px) each is held at. A peak is where the homography fails, on the maximum itself or on
    :data:`PEAK_OUTLIER_NEIGHBOURS` of its grid neighbours (``table`` (M, K') int64, -1 for none;
    ``outliers`` (M,) bool), held at its ``magnitudes`` (M,) float64 px; or where it or a grid
    neighbour was held in the window before (``held`` (M,) float64 px, 0: not) and it is displaced
    at least :data:`HELD_PEAK_SHARE` of that, held at the same. Returns (K,) bool, (K,) float64."""
    keep = np.zeros(len(peaks), dtype=np.bool_)
    level = np.zeros(len(peaks))
    for q in range(len(peaks)):
        i = peaks[q]
        count = 0
        before = held[i]
        for j in table[i]:
            if j >= 0:
                count += outliers[j]
                before = max(before, held[j])
        if outliers[i] or count >= PEAK_OUTLIER_NEIGHBOURS:
            keep[q], level[q] = True, magnitudes[i]
        elif before > 0.0 and magnitudes[i] >= HELD_PEAK_SHARE * before:
            keep[q], level[q] = True, before
    return keep, level


def _still_held(
    held: tuple[np.ndarray, np.ndarray] | None,
    idx: np.ndarray,
    magnitudes: np.ndarray,
    now: tuple[np.ndarray, np.ndarray],
) -> tuple[np.ndarray, np.ndarray]:
    """The peaks the press holds after this window (:attr:`Contacts.held`): this window's one-finger
    peaks ``now`` ((K,) int64 marker indices into the N, (K,) float64 ||v|| px), and those of
    ``held`` (the window before's, the same form; None: none) not among them whose marker is one of
    this window's valid markers ``idx`` (M,) int64 (ascending) and displaced, by ``magnitudes`` (M,)
    float64 px, at least :data:`HELD_PEAK_SHARE` of what it is held at (docs/method.md, "Contacts")."""
    if held is None or not len(held[0]):
        return now
    return _still_held_kernel(
        np.ascontiguousarray(held[0], dtype=np.int64),
        np.ascontiguousarray(held[1], dtype=np.float64),
        idx,
        magnitudes,
        np.ascontiguousarray(now[0], dtype=np.int64),
        np.ascontiguousarray(now[1], dtype=np.float64),
    )


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _found_at(idx: np.ndarray, marker: int) -> int:
    """The row of ``marker`` among the ascending marker indices ``idx`` (M,) int64, M >= 1; -1
    when it is not among them."""
    at = min(np.searchsorted(idx, marker), len(idx) - 1)
    return at if idx[at] == marker else -1


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _still_held_kernel(
    held_at: np.ndarray,
    held_level: np.ndarray,
    idx: np.ndarray,
    magnitudes: np.ndarray,
    now_at: np.ndarray,
    now_level: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`_still_held` on a non-empty ``held`` (H,) int64 and (H,) float64: ``now``'s peaks,
    then the held ones still held, in ``held``'s order; (K + H',) int64 and float64."""
    k_n = len(now_at)
    out_at = np.empty(k_n + len(held_at), dtype=np.int64)
    out_level = np.empty(k_n + len(held_at))
    out_at[:k_n] = now_at
    out_level[:k_n] = now_level
    n = k_n
    for h in range(len(held_at)):
        again = False  # held again this window: ``now``'s level
        for q in range(k_n):
            if now_at[q] == held_at[h]:
                again = True
        at = _found_at(idx, held_at[h])
        if at >= 0 and not again and magnitudes[at] >= HELD_PEAK_SHARE * held_level[h]:
            out_at[n] = held_at[h]
            out_level[n] = held_level[h]
            n += 1
    return out_at[:n].copy(), out_level[:n].copy()


def _held_levels(held: tuple[np.ndarray, np.ndarray] | None, idx: np.ndarray) -> np.ndarray:
    """(M,) float64: the ||v|| (px) each of the valid markers ``idx`` (M,) int64 (ascending) is held at
    by ``held`` (:attr:`Contacts.held`), 0 where none."""
    if held is None or not len(held[0]):
        return np.zeros(len(idx))
    return _held_levels_kernel(
        np.ascontiguousarray(held[0], dtype=np.int64), np.ascontiguousarray(held[1], dtype=np.float64), idx
    )


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _held_levels_kernel(held_at: np.ndarray, held_level: np.ndarray, idx: np.ndarray) -> np.ndarray:
    """:func:`_held_levels` on a non-empty ``held`` (H,) int64 and (H,) float64 (a marker held twice:
    the later level)."""
    levels = np.zeros(len(idx))
    for h in range(len(held_at)):
        at = _found_at(idx, held_at[h])
        if at >= 0:
            levels[at] = held_level[h]
    return levels


def compile_held_kernels() -> None:
    """Compile (or load from numba's cache) the kernels of a press's held peaks
    (:func:`_held_levels`, :func:`_still_held`) now: the warm-up's synthetic windows hold none."""
    held = (np.array([1, 2], dtype=np.int64), np.array([1.0, 1.0]))
    idx = np.arange(4, dtype=np.int64)
    _held_levels(held, idx)
    _still_held(held, idx, np.ones(4), (held[0][:1], held[1][:1]))
