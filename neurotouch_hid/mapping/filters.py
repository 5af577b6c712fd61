"""The mapping's signal shaping: the 1-euro filter and the analogue response curve.

Both act on the profile's input quantities (mm, user frame) before they become axis values.
"""

from __future__ import annotations

import math

import numpy as np

#: Below this (input units, and units per second), a filter decaying towards a zero input holds
#: exactly zero: the exponential decay would otherwise take minutes to get there and then stick at
#: the smallest subnormal number; a mapper at rest needs the exact zero (``Mapper``'s fixed point).
ZERO_TAIL = 1e-12


class OneEuroFilter:
    """The 1-euro filter (Casiez, Roussel, Vogel: "1 Euro Filter: A Simple Speed-based Low-pass
    Filter for Noisy Input in Interactive Systems", CHI 2012), element-wise on a scalar or a short
    vector (e.g. a (2,) push vector, mm).

    An exponential low-pass whose cut-off rises with the (low-passed) speed:
    ``fc = min_cutoff_hz + beta * |dx/dt|`` with dx/dt in units/s, so ``beta`` is in Hz per
    (mm/s) for inputs in mm. Time is int64 microseconds (the camera clock).

    The arithmetic is Python's, element by element (the same IEEE double operations as NumPy's
    element-wise ones): the mapper runs once per window right after the pipeline's fit, on a
    core that slept since the last window, where each NumPy call on a 1- or 2-element array
    costs several microseconds (docs/performance.md, "Runtime latency").
    """

    def __init__(self, min_cutoff_hz: float = 1.0, beta: float = 0.0, d_cutoff_hz: float = 1.0) -> None:
        self.min_cutoff_hz = float(min_cutoff_hz)
        self.beta = float(beta)
        self.d_cutoff_hz = float(d_cutoff_hz)
        self.reset()

    def reset(self) -> None:
        """Forget the history: the next sample passes through unchanged."""
        self._x: list[float] | None = None
        self._dx: list[float] = []
        self._t_us: int | None = None

    def at_zero(self) -> bool:
        """True when the filter holds exactly 0 with no speed: a zero sample, whenever it comes,
        leaves the output at 0 and changes only the clock (:meth:`tick`). False before any sample."""
        return self._x is not None and not any(self._x) and not any(self._dx)

    def tick(self, t_us: int) -> None:
        """What a zero sample at ``t_us`` does to a filter :meth:`at_zero` that has a history:
        its clock moves on (the next sample's dt counts from here), nothing else changes."""
        self._t_us = max(int(t_us), self._t_us + 1)

    @staticmethod
    def _alpha(cutoff_hz: float, dt_s: float) -> float:
        tau = 1.0 / (2.0 * math.pi * cutoff_hz)
        return 1.0 / (1.0 + tau / dt_s)

    def __call__(self, value: np.ndarray | float, t_us: int) -> np.ndarray | float:
        """Filter one sample taken at ``t_us`` (us); returns the filtered value: a float for a
        scalar, a float64 array of the same shape for an array. A sample not later than the
        previous one is treated as 1 us later. A zero input whose filtered value and speed are
        below :data:`ZERO_TAIL` gives exactly 0.
        """
        scalar = isinstance(value, (float, int)) or np.ndim(value) == 0  # the mapper's scalars are floats
        x = [float(value)] if scalar else np.asarray(value, dtype=np.float64).ravel().tolist()
        if self._x is None or self._t_us is None:
            self._x, self._dx, self._t_us = x, [0.0] * len(x), int(t_us)
        else:
            dt_s = max(int(t_us) - self._t_us, 1) * 1e-6
            self._t_us = max(int(t_us), self._t_us + 1)
            alpha_d = self._alpha(self.d_cutoff_hz, dt_s)
            for i, (xi, last, dx_last) in enumerate(zip(x, self._x, self._dx)):
                dx = dx_last + alpha_d * ((xi - last) / dt_s - dx_last)
                cutoff = self.min_cutoff_hz + self.beta * abs(dx)
                xf = last + self._alpha(cutoff, dt_s) * (xi - last)
                if xi == 0.0 and abs(xf) < ZERO_TAIL and abs(dx) < ZERO_TAIL:
                    xf = dx = 0.0  # the decay's tail ends at zero, not stuck among subnormals
                self._dx[i] = dx
                self._x[i] = xf
        if scalar:
            return self._x[0]
        return np.array(self._x, dtype=np.float64).reshape(np.shape(value))


def response(
    magnitude_mm: float,
    deadzone_mm: float,
    saturation_mm: float,
    exponent: float = 1.0,
    expo: float = 0.0,
    gain: float = 1.0,
    anti_deadzone: float = 0.0,
) -> float:
    """The analogue response in [0, 1] to an input magnitude (mm, >= 0).

    0 up to the dead zone, 1 from the saturation on, in between
    ``t = (m - deadzone) / (saturation - deadzone)`` shaped by ``t ** exponent``, then the expo
    ``(1 - expo) t + expo t^3`` (finer control near the centre), then ``min(gain * t, 1)``, then
    the anti-deadzone ``a + (1 - a) t`` (any input past the dead zone gives at least ``a``, so a
    game's own inner dead zone does not swallow it; 0 stays 0) (the paper, section "Gesture
    Classification and Intensity Prediction", suggests non-linear intensity profiles for
    applications). Non-finite magnitudes give 0.
    """
    if not math.isfinite(magnitude_mm) or magnitude_mm <= deadzone_mm:
        return 0.0
    t = min((magnitude_mm - deadzone_mm) / (saturation_mm - deadzone_mm), 1.0)
    t = t**exponent
    t = (1.0 - expo) * t + expo * t**3
    t = min(gain * t, 1.0)
    return anti_deadzone + (1.0 - anti_deadzone) * t if t > 0 else 0.0
