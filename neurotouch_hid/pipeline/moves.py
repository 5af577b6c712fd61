"""How far the markers moved: the window path's checks before a fit, and the check of a
candidate rest reference against the calibrated layout (docs/method.md, "Overview", "Markers")."""

from __future__ import annotations

import numba
import numpy as np


def _off_layout(layout_px: np.ndarray, points_px: np.ndarray, tol_px: float) -> float:
    """Fraction of the layout's markers (N, 2) px without a point of ``points_px`` (M, 2) within
    ``tol_px`` (all pairs: only candidate reference frames are checked)."""
    d2 = ((layout_px[:, None, :] - points_px[None, :, :]) ** 2).sum(axis=-1).min(axis=1)
    return float(np.mean(d2 > tol_px * tol_px))


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _largest_move_sq(current: np.ndarray, valid: np.ndarray, rest: np.ndarray) -> float:
    """The largest squared displacement from rest (px^2) among the ``valid`` (N,) bool markers,
    ``current`` and ``rest`` (N, 2) float64 px: -1.0 when none is valid, NaN when one of theirs
    is NaN (as NumPy's ``max`` propagates it). One pass, no temporaries: every window runs it."""
    largest = -1.0
    for i in range(len(current)):
        if valid[i]:
            dx = current[i, 0] - rest[i, 0]
            dy = current[i, 1] - rest[i, 1]
            d2 = dx * dx + dy * dy
            if d2 != d2:
                return d2
            largest = max(largest, d2)
    return largest


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _unchanged(last_current: np.ndarray, current: np.ndarray, last_valid: np.ndarray, valid: np.ndarray) -> bool:
    """Whether the window's tracked positions (N, 2) float64 px and lost markers (N,) bool are
    those of the last fit, bit for bit (``np.array_equal``: a NaN position never equals)."""
    return np.array_equal(last_current, current) and np.array_equal(last_valid, valid)
