"""Order statistics of a few values inside the pipeline's numba kernels: an insertion sort of an
array's head, and the median it gives.

The values are a marker's grid neighbours (at most a dozen) or the gel's rim markers (a few
dozen), where an insertion sort costs less than a call; numba's own ``np.sort`` and
``np.partition`` would each cost a first run seconds of compiling (docs/performance.md,
"Start-up"). Inlined into the kernels that call them (``inline="always"``: no code of their own).
"""

from __future__ import annotations

import numba
import numpy as np


@numba.njit(cache=True, nogil=True, error_model="numpy", inline="always")
def sort_head(values: np.ndarray, k: int) -> None:
    """Sort ``values[:k]`` ((N,) float64, k <= N) ascending in place (insertion sort; NaN-free
    values)."""
    for q in range(1, k):
        x = values[q]
        r = q - 1
        while r >= 0 and values[r] > x:
            values[r + 1] = values[r]
            r -= 1
        values[r + 1] = x


@numba.njit(cache=True, nogil=True, error_model="numpy", inline="always")
def median_head(values: np.ndarray, k: int) -> float:
    """The median of ``values[:k]`` ((N,) float64, 1 <= k <= N; NaN-free), the mean of the two
    middle values when k is even; sorts ``values[:k]`` in place (:func:`sort_head`)."""
    sort_head(values, k)
    return values[k // 2] if k % 2 else 0.5 * (values[k // 2 - 1] + values[k // 2])
