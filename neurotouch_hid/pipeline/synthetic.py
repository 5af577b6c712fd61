"""A synthetic marker grid and windows on which :meth:`GesturePipeline.compile_kernels` compiles
every path of the pipeline's numba code before the first real events."""

from __future__ import annotations

import numpy as np

from neurotouch_hid.core.sensor import SensorGeometry
from neurotouch_hid.sources import EVENT_DTYPE


def synthetic_windows(
    sensor: SensorGeometry,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(rest, moved, flat, pinch, three, events) about the gel's centre: a 13 x 13 grid at rest
    10 px apart (N, 2) float64 px; the grid under a finger-like bump of displacement; a flat top
    several fingers wide (the contacts' plateau) with a lone marker far above its neighbours (the
    lone-marker median); two fingers pinching (the fit of their centres and the search for a
    finger they missed); three fingers twisting 35 px from the centre (the fit of three centres);
    four EVENT_DTYPE events."""
    cx, cy = sensor.gel_center_px
    k = np.arange(-6, 7) * 10.0
    rest = np.stack(np.meshgrid(k + cx, k + cy), axis=-1).reshape(-1, 2)
    bump = np.exp(-((rest - (cx, cy)) ** 2).sum(axis=1) / (2 * 12.0**2))[:, None]
    moved = rest + bump * np.array([4.0, 1.0])
    wide = np.exp(-((rest - (cx, cy)) ** 2).sum(axis=1) / (2 * 25.0**2))
    flat = rest + np.minimum(1.0, 2.0 * wide)[:, None] * np.array([3.0, 0.0])
    flat[len(rest) // 3] += (6.0, 0.0)
    sides = [np.exp(-((rest - (cx + dx, cy)) ** 2).sum(axis=1) / (2 * 12.0**2))[:, None] for dx in (-30.0, 30.0)]
    pinch = rest + sides[0] * np.array([4.0, 0.0]) - sides[1] * np.array([4.0, 0.0])
    three = rest.copy()
    for angle in np.radians([90.0, 210.0, 330.0]):
        centre = (cx + 35.0 * np.cos(angle), cy + 35.0 * np.sin(angle))
        finger = np.exp(-((rest - centre) ** 2).sum(axis=1) / (2 * 10.0**2))[:, None]
        three += finger * 3.0 * np.array([-np.sin(angle), np.cos(angle)])
    events = np.zeros(4, dtype=EVENT_DTYPE)
    events["timestamp"] = np.arange(4) * 100
    events["x"], events["y"], events["polarity"] = int(cx), int(cy), 1
    return rest, moved, flat, pinch, three, events
