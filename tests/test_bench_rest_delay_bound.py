"""benchmarks/rest_delay_bound.py's model on hand-made windows: what is held while the gel rests
comes up to D late, the first window that does not rest too, and those after it only until the
source is back at 1 ms (S after it was delivered)."""

from __future__ import annotations

import numpy as np
import pytest
from helpers import load_benchmark

from neurotouch_hid.core.estimate import GestureEstimate, GestureType


@pytest.fixture(scope="module")
def bound():
    return load_benchmark("rest_delay_bound")


def windows(resting: list[bool]) -> list[GestureEstimate]:
    """10 ms windows ending at 10, 20, ... ms, resting or pushing as said."""
    return [
        GestureEstimate(t_us=10_000 * (k + 1))
        if rest
        else GestureEstimate(t_us=10_000 * (k + 1), gesture=GestureType.PUSH, resting=False, intensity_mm=1.0)
        for k, rest in enumerate(resting)
    ]


def test_the_camera_s_delay_makes_the_first_moving_windows_late_until_it_is_set_back(bound):
    predictions = windows([True, True, False, False, False, True])
    late = bound.lateness_ms(predictions, delay_ms=10.0, switch_ms=3.0)
    # at rest 9 ms later than today's 1 ms; the first moving window (ending at 30 ms) too; the
    # next, 10 ms on, only until 30 + 10 + 3 ms; then on time; at rest again 9 ms
    np.testing.assert_allclose(late, [9.0, 9.0, 9.0, 2.0, 0.0, 9.0])


def test_today_s_delay_makes_nothing_late_and_two_windows_a_hand_on_only_the_first_moving_one(bound):
    predictions = windows([True, False, False, False])
    np.testing.assert_allclose(bound.lateness_ms(predictions, 1.0, 0.0), 0.0)
    np.testing.assert_allclose(bound.lateness_ms(predictions, 11.0, 0.0), [10.0, 10.0, 0.0, 0.0])
