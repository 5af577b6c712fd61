"""The simulated hand that follows an enrolment's prompts like a person does.

A person starts a prompted gesture a few hundred milliseconds after its cue
(:data:`REACTION_S`), holds it longer or shorter than asked (:data:`HOLD_FACTOR`), never before
the previous gesture has left the gel, and misses a prompt now and then (``miss_rate``). The
gesture itself is the simulator's (:func:`~neurotouch_hid.sources.hands.prompted_gesture`:
the user's fingers, strength and speed, a push towards the asked direction, a tap or a hold), on
the simulated gel of a physics family. :func:`simulate_enrolment` writes the recording of a whole
plan with the simulator's own labels (the ground truth that ``enrol --from`` is measured against).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from neurotouch_hid.core.sensor import SensorGeometry
from neurotouch_hid.enrolment.plan import DIRECTIONS, Plan, Prompt
from neurotouch_hid.sources.gel import SimGesture
from neurotouch_hid.sources.hands import USERS, prompted_gesture
from neurotouch_hid.sources.physics import physics_family
from neurotouch_hid.sources.sim_dataset import write_sequence
from neurotouch_hid.sources.simulator import START_US, GelSimulator

#: How late a person starts after the cue (s, uniform).
REACTION_S = (0.15, 0.6)
#: How much longer or shorter than asked a person holds (factor, uniform).
HOLD_FACTOR = (0.7, 1.4)
#: A person waits this long after the previous gesture has settled before starting the next (us).
SETTLE_GAP_US = 100_000
#: The default share of prompts the simulated hand misses.
MISS_RATE = 1 / 20


@dataclass(frozen=True)
class Performed:
    """What the hand did for one prompt: the gesture (None when the prompt was missed)."""

    prompt: Prompt
    gesture: SimGesture | None


class SimulatedHand:
    """A simulated user following prompts on a simulated gel.

    Args:
        seed: the hand's and the gel's seed (the same seed performs a plan the same way).
        user: the simulated user id (0-9; default ``seed % 10``).
        physics: the gel's family (:data:`~neurotouch_hid.sources.physics.PHYSICS`).
        miss_rate: the share of prompts missed (0..1).
        sensor: geometry (default docs/dataset.md's).
    Raises:
        NeurotouchError: an unknown physics family; ValueError: a user id or miss_rate out of range.
    """

    def __init__(
        self,
        seed: int = 0,
        *,
        user: int | None = None,
        physics: str = "default",
        miss_rate: float = MISS_RATE,
        sensor: SensorGeometry | None = None,
    ) -> None:
        uid = seed % len(USERS) if user is None else user
        if not 0 <= uid < len(USERS):
            raise ValueError(f"simulated users are 0 to {len(USERS) - 1}, got {uid}")
        if not 0.0 <= miss_rate <= 1.0:
            raise ValueError(f"miss_rate is a share in 0..1, got {miss_rate}")
        self.sensor = sensor or SensorGeometry()
        self.user = USERS[uid]
        self.physics = physics_family(physics)
        self.miss_rate = miss_rate
        hand_ss, gesture_ss, family_ss = np.random.SeedSequence([seed, 0xE4202]).spawn(3)
        self._hand = np.random.default_rng(hand_ss)
        self._draws = np.random.default_rng(gesture_ss)
        self._family = np.random.default_rng(family_ss)
        self.simulator = GelSimulator(
            self.sensor, self.user, seed=seed, stream_seed=(0xE42,), script=(), physics=self.physics
        )
        self._free_us = START_US

    def perform(self, prompt: Prompt, cue_us: int, missed: bool | None = None) -> Performed:
        """Do ``prompt``, cued at ``cue_us`` (camera clock, us, not before the simulator's time):
        start late, hold longer or shorter, or miss it (at ``miss_rate``, or as ``missed`` says
        when given). The gesture is added to the simulator."""
        reaction = self._hand.uniform(*REACTION_S)
        factor = self._hand.uniform(*HOLD_FACTOR)
        drawn_miss = self._hand.random() < self.miss_rate
        if drawn_miss if missed is None else missed:
            return Performed(prompt, None)
        start = max(int(cue_us + reaction * 1e6), self._free_us, self.simulator.t_us)
        direction = DIRECTIONS.get(prompt.direction or "")
        gesture = prompted_gesture(
            self._draws,
            self.user,
            prompt.gesture,
            start,
            prompt.seconds * factor,
            self.sensor,
            self.physics,
            self._family,
            direction=direction,
        )
        self.simulator.perform(gesture)
        self._free_us = gesture.t_settled_us + SETTLE_GAP_US
        return Performed(prompt, gesture)


def simulate_enrolment(
    plan: Plan,
    out_dir: str | Path,
    name: str = "enrolment",
    *,
    seed: int = 0,
    user: int | None = None,
    physics: str = "default",
    miss_rate: float = MISS_RATE,
    tail_s: float = 0.0,
) -> list[Performed]:
    """The simulated hand performs ``plan`` (cues from the first frame, :data:`START_US`), and the
    gel is recorded until the plan's end and ``tail_s`` more (s), then on until it rests; writes
    ``NAME.aedat4``, the simulator's own labels ``NAME.labels.csv`` and ``NAME.markers.npz``
    (:func:`~neurotouch_hid.sources.sim_dataset.write_sequence`) and ``sensor.yaml`` into
    ``out_dir`` (created). Returns what was done for each prompt, in the plan's order.

    Raises:
        NeurotouchError: unknown physics family; RecordingError: the folder cannot be written.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    hand = SimulatedHand(seed, user=user, physics=physics, miss_rate=miss_rate)
    hand.sensor.save(out / "sensor.yaml")
    performed = [hand.perform(p, START_US + int(round(p.cue_s * 1e6))) for p in plan.prompts]
    write_sequence(out, name, hand.simulator, plan.end_s + tail_s)
    return performed
