"""The live simulated hand (``--source sim``) is steady: every gesture of a type as strong as the
next, so that ``profile test --source sim`` tries a profile's mappings both ways (it once twisted
counter-clockwise to ~1.8 mm against ~4 mm clockwise, and accessibility's twist toggle for A
never fired)."""

from __future__ import annotations

import itertools

import pytest

from neurotouch_hid.core.estimate import GestureType
from neurotouch_hid.engine.assembly import estimates_from_source
from neurotouch_hid.mapping.profile import load_profile
from neurotouch_hid.mapping.replay import deflection, reach, replay, summarise
from neurotouch_hid.sources.simulator import SimulatedSource

G = GestureType


@pytest.mark.parametrize("seed", range(10))
def test_every_gesture_of_a_type_is_as_strong(seed):
    script = SimulatedSource(seed=seed)._sim._script
    strengths: dict[GestureType, set[float]] = {}
    for g in itertools.islice(script, 15):
        strengths.setdefault(g.gesture, set()).add(round(g.amplitude_mm, 9))
    assert all(len(s) == 1 for s in strengths.values()), strengths
    assert strengths[G.TWIST_CW] == strengths[G.TWIST_CCW]


@pytest.fixture(scope="module")
def sim_estimates():
    """What ``profile test --source sim`` replays: one cycle of the simulated hand's gestures
    through the pipeline."""
    return list(estimates_from_source("sim"))


def test_both_twists_reach_the_same_strength_through_the_pipeline(sim_estimates):
    peak = {k: max(e.intensity_mm for e in sim_estimates if e.gesture is k) for k in (G.TWIST_CW, G.TWIST_CCW)}
    assert 0.75 <= peak[G.TWIST_CCW] / peak[G.TWIST_CW] <= 1.33, peak


def test_accessibility_toggles_both_ways_and_default_turns_both_ways(sim_estimates):
    presses = summarise(replay(load_profile("accessibility"), sim_estimates)).presses
    assert presses["BTN_SOUTH"] >= 1 and presses["BTN_EAST"] >= 1, presses  # twist_ccw -> A, twist_cw -> B
    rx = [deflection("ABS_RX", s.axes["ABS_RX"]) for s in replay(load_profile("default"), sim_estimates)]
    left, right = -min(rx), max(rx)
    assert left > 0.3 and right > 0.3 and 0.67 <= left / right <= 1.5, (left, right)


def test_one_cycle_pushes_all_four_ways_and_every_mapped_output_is_reached(sim_estimates):
    states = replay(load_profile("accessibility"), sim_estimates)
    presses = summarise(states).presses
    assert all(presses[f"dpad_{d}"] >= 1 for d in ("up", "right", "down", "left")), presses
    reached = {r.output: r.reached for r in reach(load_profile("accessibility"), states)}
    assert set(reached) == {"dpad_up", "dpad_down", "dpad_left", "dpad_right", "BTN_SOUTH", "BTN_EAST", "left_stick"}
    assert all(reached.values()), reached


def test_the_steady_hand_pushes_up_right_down_and_left_in_turn():
    script = SimulatedSource(seed=3)._sim._script
    pushes = [g.direction for g in itertools.islice(script, 8) if g.gesture is G.PUSH]
    assert [tuple(round(float(c), 6) for c in d) for d in pushes] == [(0, 1), (1, 0), (0, -1), (-1, 0)]
