"""The gel's rigid motion read off the rim markers (``gel_motion.py``): its numba kernels against
straightforward NumPy references written here (random rims, NaN rows, lost markers, too few
markers, a still rim). The behaviour on whole gestures is tested in test_pipeline_gel_motion.py."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from neurotouch_hid.pipeline.gel_motion import (
    MIN_RIM_MARKERS,
    SHARED_QUANTILE,
    STILL_RIM_PX,
    GelMotion,
    estimate_gel_motion,
    rim_markers,
)

CENTRE = (173.0, 130.0)


def gel(rng: np.random.Generator) -> np.ndarray:
    """(N, 2) rest positions (px): a jittered 10 px grid inside a 72 px radius round CENTRE."""
    k = np.arange(-7, 8) * 10.0
    grid = np.stack(np.meshgrid(k, k), axis=-1).reshape(-1, 2)
    grid = grid[np.hypot(grid[:, 0], grid[:, 1]) < 72.0] + CENTRE
    return grid + rng.normal(0.0, 0.3, grid.shape)


def low(values: np.ndarray) -> float:
    return float(np.sort(values)[int(SHARED_QUANTILE * (len(values) - 1))])


def reference_estimate(rest, current, valid, rim, centre):
    """(theta, t) or None, as the module docstring describes it, in plain NumPy."""
    centre = np.asarray(centre, dtype=np.float64)
    use = rim & np.isfinite(current).all(axis=1)
    if valid is not None:
        use &= valid
    if use.sum() < MIN_RIM_MARKERS:
        return None
    moved = current[use] - rest[use]
    if low(np.hypot(moved[:, 0], moved[:, 1])) <= STILL_RIM_PX:
        return None
    src = (rest[use] - centre).astype(np.float32)
    dst = (current[use] - centre).astype(np.float32)
    matrix, _ = cv2.estimateAffinePartial2D(src, dst, method=cv2.LMEDS)
    if matrix is None:
        return None
    theta = math.atan2(matrix[1, 0], matrix[0, 0])
    fitted_t = matrix[:, 2].copy()
    p, d = src.astype(np.float64), (dst - src).astype(np.float64)
    c, s = math.cos(theta), math.sin(theta)
    rotation_share = p @ (np.array([[c, -s], [s, c]]) - np.eye(2)).T
    t = fitted_t
    norm = np.hypot(*fitted_t)
    if norm > 0:
        u = fitted_t / norm
        t = u * np.clip(low((d - rotation_share) @ u), 0.0, norm)
    if theta != 0.0:
        r = d - fitted_t
        turns = (p[:, 0] * r[:, 1] - p[:, 1] * r[:, 0]) / np.maximum((p * p).sum(axis=1), 1e-9)
        sign = math.copysign(1.0, theta)
        theta = sign * np.clip(low(sign * turns), 0.0, abs(theta))
    return theta, t


def random_case(rng: np.random.Generator, rest: np.ndarray):
    """A slip and turn of the whole gel, a finger's field, tracker noise, NaN rows, lost markers."""
    theta = rng.choice([0.0, rng.normal(0.0, 0.02)])
    c, s = math.cos(theta), math.sin(theta)
    current = (rest - CENTRE) @ np.array([[c, -s], [s, c]]).T + CENTRE + rng.choice([0.0, 1.0]) * rng.normal(0, 2, 2)
    finger = rest[rng.integers(len(rest))]
    field = np.exp(-np.sum((rest - finger) ** 2, axis=1) / (2 * rng.uniform(5.0, 40.0) ** 2))
    current += field[:, None] * rng.normal(0.0, 5.0, 2) + rng.normal(0.0, rng.choice([0.01, 0.3]), rest.shape)
    current[rng.random(len(rest)) < 0.05] = np.nan
    valid = None if rng.random() < 0.3 else rng.random(len(rest)) > rng.choice([0.0, 0.2, 0.95])
    return current, valid


def test_the_estimate_is_the_numpy_reference_on_random_rims():
    rng = np.random.default_rng(11)
    outcomes = {"motion": 0, "none": 0}
    for _ in range(300):
        rest = gel(rng)
        rim = rim_markers(rest, CENTRE)
        current, valid = random_case(rng, rest)
        expected = reference_estimate(rest, current, valid, rim, CENTRE)
        motion = estimate_gel_motion(rest, current, valid, rim, CENTRE)
        if expected is None:
            assert motion is None
            outcomes["none"] += 1
            continue
        assert motion is not None
        assert motion.rotation_rad == pytest.approx(expected[0], abs=1e-12)
        np.testing.assert_allclose(motion.translation_px, expected[1], rtol=0, atol=1e-12)
        np.testing.assert_array_equal(motion.centre_px, CENTRE)
        outcomes["motion"] += 1
    assert outcomes["motion"] > 100 and outcomes["none"] > 10  # both branches exercised


@pytest.mark.parametrize("followed", [MIN_RIM_MARKERS - 1, MIN_RIM_MARKERS])
def test_too_few_rim_markers_give_no_motion(followed):
    """Rim markers lost to the tracker or NaN do not count: below MIN_RIM_MARKERS, no estimate."""
    rng = np.random.default_rng(followed)
    rest = gel(rng)
    rim = rim_markers(rest, CENTRE)
    current = rest + (2.0, -1.0)
    rows = np.flatnonzero(rim)
    valid = np.zeros(len(rest), dtype=bool)
    valid[rows[: followed + 2]] = True
    current[rows[:2]] = np.nan  # followed, but NaN
    motion = estimate_gel_motion(rest, current, valid, rim, CENTRE)
    if followed < MIN_RIM_MARKERS:
        assert motion is None
    else:
        np.testing.assert_allclose(motion.translation_px, (2.0, -1.0), atol=1e-4)
        assert motion.rotation_rad == pytest.approx(0.0, abs=1e-6)
    assert estimate_gel_motion(rest, rest + 0.05, None, rim, CENTRE) is None  # a still rim: no fit


def reference_apply(motion: GelMotion, points: np.ndarray) -> np.ndarray:
    c, s = math.cos(motion.rotation_rad), math.sin(motion.rotation_rad)
    return (points - motion.centre_px) @ np.array([[c, -s], [s, c]]).T + motion.centre_px + motion.translation_px


@pytest.mark.parametrize("shape", [(2,), (0, 2), (1, 2), (2, 2), (9, 2), (177, 2)])
def test_remove_and_apply_are_the_rigid_motion_and_its_inverse(shape):
    rng = np.random.default_rng(len(shape) + shape[0])
    for _ in range(20):
        motion = GelMotion(np.asarray(CENTRE), rng.normal(0.0, 0.05), rng.normal(0.0, 3.0, 2))
        points = rng.uniform(80.0, 260.0, shape)
        if points.ndim == 2 and len(points) > 1:
            points[rng.integers(len(points))] = np.nan
        moved = motion.apply(points)
        assert moved.shape == points.shape and moved.dtype == np.float64
        np.testing.assert_allclose(moved, reference_apply(motion, points), rtol=0, atol=1e-12)
        np.testing.assert_allclose(motion.remove(moved), points, rtol=0, atol=1e-9)  # NaN rows stay NaN
        np.testing.assert_array_equal(np.isnan(motion.remove(points)), np.isnan(points))
