"""Sub-marker refinement of a contact point (not in the paper; docs/method.md, "Contacts").

The paper's contact point is the position of the marker of peak displacement, so it is quantised
to the 4 mm marker grid. :func:`refine_peak` fits a quadratic surface to ||v|| and to v over the
markers near the peak marker (rest positions), takes the surface's maximum (when it is one, near
the peak marker) and returns where that gel point is now. Image frame (px).
"""

from __future__ import annotations

import cv2
import numba
import numpy as np


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
