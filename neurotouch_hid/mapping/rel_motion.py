"""The pointer's and the wheels' relative counts on the camera clock: a velocity integrated over
the estimates' ``t_us`` (int us) into whole counts with the fraction kept (:class:`RelMotion`),
and a wheel's hi-res units (1/120 detent) with the legacy detents they make, counted as the
kernel's HID input driver counts them (drivers/hid/hid-input.c). Bounded per step
(:data:`MAX_MOTION_STEP_US`, :data:`MAX_REL_COUNTS_PER_STEP`; docs/limits.md).
"""

from __future__ import annotations

import math

#: Longest camera-time step (us) the pointer and wheels integrate over: a gap in the data (a
#: dropped batch, a pause) must not turn into one long jump.
MAX_MOTION_STEP_US = 100_000
#: Most counts a relative axis moves in one step (pointer px, or hi-res wheel units): a mouse
#: reports a few hundred at most; an event holds a signed 32-bit value, which a profile summing
#: many fast mappings would pass (python-evdev raises OverflowError).
MAX_REL_COUNTS_PER_STEP = 10_000
#: Hi-res wheel units per detent (the kernel's REL_WHEEL_HI_RES convention).
HI_RES_PER_DETENT = 120


class RelMotion:
    """Velocity -> integer relative counts on the camera clock, keeping the fraction left over.

    ``step(velocity, t_us)``: ``velocity`` in counts per second (pointer px/s, or wheel hi-res
    1/120 detents per second); returns the whole counts moved since the previous step (the step
    is capped at :data:`MAX_MOTION_STEP_US`, the counts at :data:`MAX_REL_COUNTS_PER_STEP`; the
    first step moves nothing). A zero velocity
    drops the remainder, so a stopped pointer never creeps.
    """

    def __init__(self) -> None:
        self._t_us: int | None = None
        self._rest = 0.0

    def step(self, velocity: float, t_us: int) -> int:
        t_us = int(t_us)
        dt_us = 0 if self._t_us is None else min(max(t_us - self._t_us, 0), MAX_MOTION_STEP_US)
        self._t_us = t_us
        if velocity == 0 or not math.isfinite(velocity):
            self._rest = 0.0
            return 0
        total = self._rest + velocity * dt_us * 1e-6
        counts = int(max(-MAX_REL_COUNTS_PER_STEP, min(MAX_REL_COUNTS_PER_STEP, total)))  # towards zero
        self._rest = max(-1.0, min(1.0, total - counts))  # what is clamped away is not owed later
        return counts


class Wheel:
    """One wheel: hi-res counts (1/120 detent) and the legacy detents they make, counted as the
    kernel's HID input driver counts them for a hi-res wheel (``hidinput_handle_scroll`` in
    drivers/hid/hid-input.c): the hi-res units accumulate, each whole 120 of them (towards zero)
    is a detent, the remainder is kept, through a pause and a turn back alike."""

    def __init__(self) -> None:
        self.motion = RelMotion()
        self._accumulated = 0  # hi-res units not yet reported as a detent (|x| < 120)

    def step(self, detents_per_s: float, t_us: int) -> tuple[int, int]:
        """(hi-res units, whole detents) moved since the previous step."""
        hi = self.motion.step(detents_per_s * HI_RES_PER_DETENT, t_us)
        if hi == 0:
            return 0, 0
        self._accumulated += hi
        detents = int(self._accumulated / HI_RES_PER_DETENT)  # towards zero, as C's division
        self._accumulated -= detents * HI_RES_PER_DETENT
        return hi, detents
