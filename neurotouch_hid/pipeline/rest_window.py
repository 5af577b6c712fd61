"""A resting gel's window in one compiled call (docs/performance.md, "At rest"; docs/method.md,
"Resting").

While the resting verdict stands, a window's whole event path is the noise filter
(``noise.py``), the tracker (``tracker.py``, its lost-blob checks after each part of the batch)
and, at the window's end, the motion override's first test (``override.py``: do at least
``min_markers`` markers lie further than the threshold from rest?). :func:`rest_window` does all
of it in one numba call, in the order and with the kernels the general path
(``GesturePipeline._process_events``) calls one by one from Python: the same kept events, the
same tracker state, the same answer. When the override's first test passes (the first sign of a
touch), it stops at the window's end and hands the rest of the batch back, and the pipeline goes
on in Python, within the same window.
"""

from __future__ import annotations

import numba
import numpy as np

from neurotouch_hid.pipeline.noise import background_activity_keep
from neurotouch_hid.pipeline.tracker_kernels import _check_lost, _track

#: What :func:`rest_window` answers.
OPEN, RESTING, TOUCHED = 0, 1, 2


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
            (updated), as its ``update`` passes them to ``_track`` and ``_check_lost``.
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
    cut = np.searchsorted(kept["timestamp"], window_end_us)
    if cut > 0:
        _track(kept[:cut], state, cov, t_upd, t_seen, rate, valid, cell, label, offs, n_offs, neigh, prm, counts)
        _check_lost(cell, label, offs, n_offs, neigh, valid, state, prm)
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
        _track(kept[cut:], state, cov, t_upd, t_seen, rate, valid, cell, label, offs, n_offs, neigh, prm, counts)
        _check_lost(cell, label, offs, n_offs, neigh, valid, state, prm)
    return RESTING, kept, cut
