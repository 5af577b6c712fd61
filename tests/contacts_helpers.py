"""What the contact detection tests share (tests/test_contacts_*.py): the default sensor, markers on a
square grid inside the gel disc, a finger's Gaussian displacement, three fingers pushing together,
and the check that each finger got one contact."""

from __future__ import annotations

import numpy as np

from neurotouch_hid.core.sensor import SensorGeometry

SENSOR = SensorGeometry()


#: A lone-marker fraction that takes no marker for a mistracked one (a marker would have to be
#: displaced 100 times its neighbours' median): these narrow hand-made bumps' peak markers stand
#: well above their neighbours, and the lone-marker rule is not what their tests test.
NO_SPIKES = 0.01


def grid(spacing: float = 10.0) -> np.ndarray:
    """Markers on a square grid (4 mm at 2.5 px/mm) inside the gel disc, image px."""
    k = np.arange(-8, 9) * spacing
    pts = np.stack(np.meshgrid(k, k), axis=-1).reshape(-1, 2) + np.asarray(SENSOR.gel_center_px)
    return pts[SENSOR.inside_gel(pts, margin_px=-3.0)]


def bump(rest: np.ndarray, centre, direction, sigma: float = 12.0) -> np.ndarray:
    """A finger's local deformation: a Gaussian displacement centred on ``centre``."""
    w = np.exp(-np.sum((rest - np.asarray(centre)) ** 2, axis=1) / (2 * sigma**2))
    return w[:, None] * np.asarray(direction, dtype=float)


def three_finger_push(noise_px: float = 0.15, seed: int = 0):
    """Three fingers on a line, 35 px (14 mm) apart, pushing hard together: their blended
    falloffs carry the gel between them as one flat top (the displacement saturates at the
    fingers'), ~3.3 fingertip footprints pi (25 px)^2 wide, as deep 3-finger flat tops are on the
    simulated gels (1.1 a finger), with tracker noise on it. Returns rest, current, the fingers'
    current positions."""
    rest = grid()
    c = np.asarray(SENSOR.gel_center_px, dtype=float)
    fingers = c + np.array([[-25.0, -25.0], [0.0, 0.0], [25.0, 25.0]])
    reach = 1.5 * sum(np.exp(-np.sum((rest - f) ** 2, axis=1) / (2 * 22.0**2)) for f in fingers)
    direction = np.array([8.0, -6.0])
    rng = np.random.default_rng(seed)
    cur = rest + np.minimum(reach, 1.0)[:, None] * direction + rng.normal(0.0, noise_px, rest.shape)
    return rest, cur, fingers + direction


def assert_one_contact_on_each(found, fingers_px, within_px):
    """As many contacts as fingers, one on each, every one within ``within_px`` of its finger."""
    assert found.count == len(fingers_px)
    nearest = np.linalg.norm(np.asarray(fingers_px)[None] - found.points_px[:, None], axis=2)
    assert sorted(np.argmin(nearest, axis=1)) == list(range(len(fingers_px)))
    assert nearest.min(axis=1).max() < within_px
