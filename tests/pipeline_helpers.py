"""What the GesturePipeline's tests share (tests/test_pipeline_*.py, test_type_commitment.py,
test_counter_drag.py): the default sensor, a gel at rest as the camera sees it, noise events at
given times, and the paper's window-by-window gesture decision."""

from __future__ import annotations

import numpy as np
import pytest

from neurotouch_hid.core.sensor import SensorGeometry
from neurotouch_hid.pipeline.paper import PaperPipeline
from neurotouch_hid.pipeline.pipeline import GesturePipeline
from neurotouch_hid.sources import EVENT_DTYPE

SENSOR = SensorGeometry()


def gel_image(shift_px=(0.0, 0.0), region_px: float | None = None) -> np.ndarray:
    """A gel at rest as the camera sees it: 1 mm white dots on a 4 mm grid (10 px), Gaussian
    profile; markers within ``region_px`` of the centre (or all) moved by ``shift_px``."""
    k = np.arange(-7, 8) * 10.0
    pts = np.stack(np.meshgrid(k, k), axis=-1).reshape(-1, 2) + np.asarray(SENSOR.gel_center_px)
    pts = pts[SENSOR.inside_gel(pts, margin_px=-4.0)]
    if region_px is not None:
        near = np.hypot(*(pts - SENSOR.gel_center_px).T) <= region_px
        pts[near] += shift_px
    else:
        pts += shift_px
    img = np.full((SENSOR.height, SENSOR.width), 20.0)
    yy, xx = np.mgrid[-4:5, -4:5]
    for x, y in pts:
        ix, iy = int(round(x)), int(round(y))
        img[iy - 4 : iy + 5, ix - 4 : ix + 5] += 220 * np.exp(-((xx + ix - x) ** 2 + (yy + iy - y) ** 2) / (2 * 0.8**2))
    return np.clip(img, 0, 255).astype(np.uint8)


def events_at(*timestamps: int) -> np.ndarray:
    """Noise events (far from any marker) at the given times."""
    ev = np.zeros(len(timestamps), dtype=EVENT_DTYPE)
    ev["timestamp"] = timestamps
    ev["x"], ev["y"] = 2, 2
    return ev


@pytest.fixture(scope="module")
def rest_image() -> np.ndarray:
    return gel_image()


class _WindowByWindow(GesturePipeline):
    """The product's pipeline with the paper's gesture decision: each window's own type."""

    _vote = PaperPipeline._vote
