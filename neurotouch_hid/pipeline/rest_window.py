"""A resting gel's window in one compiled call (docs/performance.md, "At rest"; docs/method.md,
"Resting").

While the resting verdict stands, a window's whole event path is the noise filter
(``noise.py``), the tracker (``tracker.py``, its lost-blob checks after each part of the batch)
and, at the window's end, the motion override's first test (``override.py``: do at least
``min_markers`` markers lie further than the threshold from rest?). :func:`rest_window` does all
of it in one numba call, in the order and with the kernels the general path
(``WindowPath._process_events``, ``window_path.py``) calls one by one from Python: the same kept
events, the same tracker state, the same answer. When the override's first test passes (the first sign of a
touch), it stops at the window's end and hands the rest of the batch back, and the pipeline goes
on in Python, within the same window.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numba
import numpy as np

from neurotouch_hid.pipeline.noise import background_activity_keep
from neurotouch_hid.pipeline.tracker_kernels import check_lost, track_events
from neurotouch_hid.sources import EVENT_DTYPE

if TYPE_CHECKING:
    from neurotouch_hid.pipeline.noise import EventNoiseFilter
    from neurotouch_hid.pipeline.tracker import BlobTracker

#: What :func:`rest_window` answers.
OPEN, RESTING, TOUCHED = 0, 1, 2
#: The time surface :func:`rest_window` takes for "no noise filter".
NO_SURFACE = np.zeros((0, 0), dtype=np.int64)


def rest_batch(
    events: np.ndarray,
    noise: EventNoiseFilter | None,
    tracker: BlobTracker,
    rest_px: np.ndarray,
    end_us: int,
    window_us: int,
    threshold_sq: float,
    min_markers: int,
) -> tuple[int, np.ndarray, int] | None:
    """A resting gel's batch through :func:`rest_window`, on the noise filter's and the tracker's
    own state (both updated, the filter's counts too).

    Args:
        events: (E,) EVENT_DTYPE, time-ordered, E >= 1.
        noise: the pipeline's noise filter, or None; tracker: its blob tracker.
        rest_px: (N, 2) float64 the markers at rest (px). end_us: the open window's end (us);
            window_us: the window's length (us). threshold_sq, min_markers: the motion
            override's first test (px^2, markers).
    Returns:
        :func:`rest_window`'s ``(answer, kept, cut)``, or None (nothing done) for a batch it does
        not take: another layout, more than one window end reached, a clock gone back, no blob,
        a noise filter of the library's.
    """
    ts = events["timestamp"]
    first_us, last_us = int(ts[0]), int(ts[-1])
    if last_us >= end_us + window_us or events.dtype != EVENT_DTYPE or not events.flags.c_contiguous:
        return None
    state = tracker.kernel_state()
    if len(state[0]) == 0:
        return None
    surface = NO_SURFACE if noise is None else noise.kernel_surface(first_us)
    if surface is None:
        return None
    answer, kept, cut = rest_window(
        events,
        surface,
        0 if noise is None else noise.time_us,
        end_us,
        last_us >= end_us,
        *state,
        rest_px,
        threshold_sq,
        min_markers,
    )
    if noise is not None:
        noise.count(last_us, len(events), len(kept))
    return answer, kept, cut


@numba.njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _first_at_or_after(timestamps, t_us):
    """The index of the first of the time-ordered ``timestamps`` (int64, us) at or after ``t_us``
    (``len`` when none): ``np.searchsorted(timestamps, t_us)``'s binary search, written out:
    numba's generic ``searchsorted`` cost the per-event kernels' first-run compile ~0.25 s of
    CPU, which a first run's first gesture waits for."""
    lo, hi = 0, len(timestamps)
    while lo < hi:
        mid = (lo + hi) // 2
        if timestamps[mid] < t_us:
            lo = mid + 1
        else:
            hi = mid
    return lo


@numba.njit(cache=True, nogil=True, error_model="numpy")
def rest_window(
    events,
    surface,
    duration_us,
    window_end_us,
    closes,
    state,
    cov,
    t_upd,
    t_seen,
    rate,
    valid,
    cell,
    label,
    offs,
    n_offs,
    neigh,
    prm,
    counts,
    rest,
    threshold_sq,
    min_markers,
):
    """One batch of a resting gel's events: noise filter, tracker, and the override's first test
    at the window end ``window_end_us`` (us) when ``closes`` (the batch reaches it; it reaches no
    later window end).

    Args:
        events: (E,) EVENT_DTYPE, time-ordered, E >= 1.
        surface, duration_us: the background-activity filter's time surface (updated) and
            duration (:func:`~neurotouch_hid.pipeline.noise.background_activity_keep`); a (0, 0)
            surface: no noise filter.
        state ... counts: the :class:`~neurotouch_hid.pipeline.tracker.BlobTracker`'s arrays
            (updated), as its ``update`` passes them to the event kernels (``track_events``, ``check_lost``).
        rest: (N, 2) float64 the markers at rest (px); ``threshold_sq`` the override's threshold
            squared (px^2); ``min_markers`` how many markers beyond it overrule the verdict.
    Returns:
        (answer, kept, cut): :data:`OPEN` (no window closed), :data:`RESTING` (the window closed,
        the override's first test failed: the window is at rest; every kept event tracked) or
        :data:`TOUCHED` (it passed: the events ``kept[cut:]``, after the window end, are not
        tracked yet); ``kept`` (K,) EVENT_DTYPE the events the filter kept, ``cut`` the first of
        them at or after the window end.
    """
    if surface.shape[0] > 0:
        keep = np.empty(len(events), dtype=np.bool_)
        background_activity_keep(events, surface, duration_us, keep)
        kept = events[keep]
    else:
        kept = events[:]
    cut = _first_at_or_after(kept["timestamp"], window_end_us)
    if cut > 0:
        track_events(kept[:cut], state, cov, t_upd, t_seen, rate, valid, cell, label, offs, n_offs, neigh, prm, counts)
        check_lost(cell, label, offs, n_offs, neigh, valid, state, prm)
    if not closes:
        return OPEN, kept, cut
    moved = 0
    for i in range(len(rest)):
        if valid[i]:
            dx = state[i, 0] - rest[i, 0]
            dy = state[i, 1] - rest[i, 1]
            if dx * dx + dy * dy > threshold_sq:
                moved += 1
    if moved >= min_markers:
        return TOUCHED, kept, cut
    if cut < len(kept):
        track_events(kept[cut:], state, cov, t_upd, t_seen, rate, valid, cell, label, offs, n_offs, neigh, prm, counts)
        check_lost(cell, label, offs, n_offs, neigh, valid, state, prm)
    return RESTING, kept, cut
