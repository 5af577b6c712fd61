"""Recognition failures reported on gels and cameras the project has not seen, replayed on the
simulated gel (docs/method.md, "Contacts" and "Episode vote")."""

from __future__ import annotations

import numpy as np
import pytest

from neurotouch_hid.core.dataset import labels_at
from neurotouch_hid.core.estimate import GestureEstimate, GestureType
from neurotouch_hid.core.sensor import SensorGeometry
from neurotouch_hid.evaluation.felt import DEFAULT_DEADZONE_MM
from neurotouch_hid.pipeline.pipeline import GesturePipeline
from neurotouch_hid.sources.batches import split_batches
from neurotouch_hid.sources.gel import SimGesture
from neurotouch_hid.sources.hands import USERS
from neurotouch_hid.sources.physics import PHYSICS
from neurotouch_hid.sources.simulator import START_US, GelSimulator

SENSOR = SensorGeometry()
G = GestureType


def _run(gestures: list[SimGesture], seconds: float, family: str = "default"):
    """The product's estimates of a scripted session on the simulated gel, and its labels."""
    sim = GelSimulator(SENSOR, USERS[0], seed=1, script=gestures, physics=PHYSICS[family])
    pipeline = GesturePipeline(SENSOR)
    estimates: list[GestureEstimate] = []
    labels = []
    for chunk in sim.run(seconds):
        labels.append(chunk.label)
        estimates += pipeline.process(chunk.frame)
        for batch in split_batches(chunk.events, 1000):
            estimates += pipeline.process(batch)
    return estimates, labels


def uneven_pinch() -> SimGesture:
    """Two fingers of contact radius 6 mm at (-4.3, -1.7) mm (near the apex) and (15.2, 1.4) mm,
    user frame, moving 4.1 mm and 2.3 mm towards each other, pressed firmly; attack 0.2 s, hold
    2.1 s, release 0.36 s."""
    return SimGesture(
        gesture=G.PINCH,
        t_start_us=START_US + 300_000,
        attack_us=200_000,
        hold_us=2_100_000,
        release_us=360_000,
        fingers_mm=np.array([[-4.3, -1.7], [15.2, 1.4]]),
        amplitude_mm=4.1,
        direction=np.zeros(2),
        finger_mm=6.0,
        press=0.9,
        tremor=(0.02, 5.0, 0.0),
        global_mm=np.zeros(2),
        global_rad=0.0,
        residual=0.03,
        creep_us=80_000,
        strengths=(1.0, 2.3 / 4.1),
    )


@pytest.mark.parametrize("family", ["default", "pasternak"])
def test_anuneven_pinch_with_one_finger_near_the_apex_reads_pinch_on_two_contacts_throughout(family):
    """Reported on a gel the project has not seen: this pinch read as a one-contact push near the
    apex in every window above the dead zone (the weaker finger's field lost after the tracker).
    On the simulated gel, with a Gaussian and with a Pasternak (long-tailed) falloff, where the
    gel under the weaker finger moves 1.6-2.2 mm, every window above the dead zone must answer
    pinch on two contacts, one on each finger."""
    estimates, labels = _run([uneven_pinch()], 3.3, family)
    truth = labels_at(labels, np.array([e.t_us for e in estimates], dtype=np.int64))
    felt = [(e, t) for e, t in zip(estimates, truth) if e.intensity_mm >= DEFAULT_DEADZONE_MM]
    assert len(felt) > 200  # the hold is above the dead zone
    assert {e.gesture for e, _ in felt} == {G.PINCH}
    assert {e.n_contacts for e, _ in felt} == {2}
    held = [e for e, t in felt if t is not None and t.gesture is G.PINCH and t.intensity_mm > 1.5]
    for e in held:
        first, second = sorted(SENSOR.image_to_user(e.contacts_px).tolist())
        assert np.hypot(first[0] + 4.3, first[1] + 1.7) < 7.0  # on each finger, where it has moved to
        assert np.hypot(second[0] - 15.2, second[1] - 1.4) < 7.0
