"""Gesture type and intensity on hand-made marker motions (paper, "Gesture Classification and
Intensity Prediction"). Motions are built in the USER frame with SensorGeometry's own
conversions, so the expected directions do not depend on the code under test."""

from __future__ import annotations

import math

import numpy as np
import pytest

from neurotouch_hid.core.estimate import GestureType
from neurotouch_hid.core.sensor import SensorGeometry
from neurotouch_hid.pipeline.gesture import (
    _area_mm,
    _area_motion,
    _centred,
    _mm_figures,
    estimate_gesture,
    fit_similarity,
    markers_near,
    points_to_user,
    weighted_intensity,
)

SENSORS = {
    "mirrored": SensorGeometry(),
    "not-mirrored-rotated": SensorGeometry(mirror=False, rotation_deg=90.0),
}


def grid(sensor) -> np.ndarray:
    k = np.arange(-8, 9) * 10.0
    pts = np.stack(np.meshgrid(k, k), axis=-1).reshape(-1, 2) + np.asarray(sensor.gel_center_px)
    return pts[sensor.inside_gel(pts, margin_px=-3.0)]


def move_in_user_frame(sensor, rest_px, centre_px, *, angle=0.0, scale=1.0, shift_mm=(0.0, 0.0)):
    """Apply p' = c + scale * R(angle) (p - c) + shift in the user frame (angle CCW > 0)."""
    user = sensor.image_to_user(rest_px)
    c = sensor.image_to_user(np.asarray(centre_px, dtype=float))
    rot = np.array([[math.cos(angle), -math.sin(angle)], [math.sin(angle), math.cos(angle)]])
    moved = c + scale * (user - c) @ rot.T + np.asarray(shift_mm)
    return sensor.user_to_image(moved)


CENTRE = np.array([173.0, 130.0])
#: The paper's gesture step (uniform mean intensity over A, the translation about the contacts'
#: mean) with r = 30 px and a 0.5 px minimum intensity, as these hand-made windows were set up.
UNIFORM = dict(r_px=30.0, min_intensity_px=0.5, intensity_sigma_px=0.0, origin_radius_px=0.0)


def uniform_gesture(*args, **kwargs):
    """:func:`estimate_gesture` with :data:`UNIFORM` unless ``kwargs`` say otherwise."""
    return estimate_gesture(*args, **{**UNIFORM, **kwargs})


@pytest.mark.parametrize("name", list(SENSORS))
def test_pure_translation_is_a_push_in_the_user_direction(name):
    sensor = SENSORS[name]
    rest = grid(sensor)
    cur = move_in_user_frame(sensor, rest, CENTRE, shift_mm=(2.0, 1.0))
    result = uniform_gesture(rest, cur, None, CENTRE[None], sensor)
    assert result.gesture is GestureType.PUSH
    np.testing.assert_allclose(result.translation_mm, [2.0, 1.0], atol=1e-3)
    assert result.intensity_mm == pytest.approx(math.hypot(2.0, 1.0), rel=1e-4)
    assert result.similarity.scale == pytest.approx(1.0, abs=1e-4)


@pytest.mark.parametrize("name", list(SENSORS))
@pytest.mark.parametrize("angle, expected", [(0.15, GestureType.TWIST_CCW), (-0.15, GestureType.TWIST_CW)])
def test_pure_rotation_is_a_twist_of_the_user_frame_sign(name, angle, expected):
    sensor = SENSORS[name]
    rest = grid(sensor)
    contacts = np.array([[158.0, 130.0], [188.0, 130.0]])  # two fingers about the centre
    cur = move_in_user_frame(sensor, rest, CENTRE, angle=angle)
    result = uniform_gesture(rest, cur, None, contacts, sensor)
    assert result.gesture is expected
    assert result.rotation_rad == pytest.approx(angle, abs=1e-4)
    assert result.similarity.scale == pytest.approx(1.0, abs=1e-4)


@pytest.mark.parametrize("scale, expected", [(0.85, GestureType.PINCH), (1.15, GestureType.ZOOM)])
def test_pure_scale_is_a_pinch_or_a_zoom(scale, expected):
    sensor = SENSORS["mirrored"]
    rest = grid(sensor)
    contacts = np.array([[153.0, 130.0], [193.0, 130.0]])
    cur = move_in_user_frame(sensor, rest, CENTRE, scale=scale)
    result = uniform_gesture(rest, cur, None, contacts, sensor)
    assert result.gesture is expected
    assert result.similarity.scale == pytest.approx(scale, abs=1e-4)
    np.testing.assert_allclose(result.translation_mm, [0.0, 0.0], atol=1e-3)


def test_intensity_is_the_mean_displacement_of_a_in_mm():
    sensor = SENSORS["mirrored"]
    rest = grid(sensor)
    disp = np.zeros_like(rest)
    near = markers_near(rest, CENTRE[None], 30.0)
    disp[near] = [5.0, 0.0]
    away = rest[~near] - CENTRE
    disp[~near] = 20.0 * away / np.linalg.norm(away, axis=1, keepdims=True)  # outside A: not counted
    result = uniform_gesture(rest, rest + disp, None, CENTRE[None], sensor, r_px=30.0)
    assert result.gesture is GestureType.PUSH
    assert result.intensity_mm == pytest.approx(5.0 / sensor.px_per_mm)
    # A is taken at the current positions (paper: distance at t_k)
    assert np.array_equal(result.area, markers_near(rest + disp, CENTRE[None], 30.0))


def test_nothing_moves_gives_none():
    sensor = SENSORS["mirrored"]
    rest = grid(sensor)
    result = uniform_gesture(rest, rest + 0.2, None, CENTRE[None], sensor, min_intensity_px=0.5)
    assert result.gesture is GestureType.NONE and result.intensity_mm == 0.0


def test_no_contact_gives_none():
    sensor = SENSORS["mirrored"]
    rest = grid(sensor)
    result = uniform_gesture(rest, rest + 3.0, None, np.zeros((0, 2)), sensor)
    assert result.gesture is GestureType.NONE and not result.area.any()


def test_markers_near_is_strictly_within_r():
    pts = np.array([[0.0, 0.0], [29.9, 0.0], [30.0, 0.0], [np.nan, np.nan]])
    assert list(markers_near(pts, np.zeros((1, 2)), 30.0)) == [True, True, False, False]


def test_similarity_is_fitted_about_the_origin():
    rest = np.array([[10.0, 0.0], [0.0, 10.0], [-10.0, 0.0], [0.0, -10.0]]) + 100.0
    cur = (rest - 100.0) * 1.2 + 100.0  # scaled about (100, 100): no translation about there
    sim = fit_similarity(rest, cur, np.array([100.0, 100.0]), 1.0)
    assert sim.scale == pytest.approx(1.2, abs=1e-5)
    np.testing.assert_allclose(sim.translation_px, 0.0, atol=1e-4)


def test_proximity_weighted_intensity_reads_the_contact_points_displacement():
    # a finger's Gaussian field: the contact marker moves 8 px, its neighbours less
    sensor = SENSORS["mirrored"]
    rest = grid(sensor)
    centre = rest[np.argmin(np.sum((rest - CENTRE) ** 2, axis=1))]
    w = np.exp(-np.sum((rest - centre) ** 2, axis=1) / (2 * 12.0**2))
    cur = rest + w[:, None] * np.array([8.0, 0.0])
    contact = (centre + [8.0, 0.0])[None]
    paper = uniform_gesture(rest, cur, None, contact, sensor, r_px=30.0)
    peak = uniform_gesture(rest, cur, None, contact, sensor, r_px=30.0, intensity_sigma_px=0.5)
    assert peak.intensity_mm == pytest.approx(8.0 / sensor.px_per_mm, rel=1e-6)
    assert paper.intensity_mm < 0.8 * peak.intensity_mm  # the uniform mean reads the falloff too
    assert peak.gesture is paper.gesture is GestureType.PUSH


def test_weighted_intensity_is_the_paper_mean_without_sigma_and_weights_by_distance():
    rest = np.array([[0.0, 0.0], [10.0, 0.0], [20.0, 0.0]])
    cur = rest + [[4.0, 0.0], [0.0, 2.0], [1.0, 0.0]]
    contacts = np.array([[4.0, 0.0]])
    assert weighted_intensity(rest, cur, contacts, 0.0) == pytest.approx(7.0 / 3.0)
    d2 = np.array([0.0, 6.0**2 + 2.0**2, 17.0**2])
    weights = np.exp(-d2 / (2 * 5.0**2))
    assert weighted_intensity(rest, cur, contacts, 5.0) == pytest.approx((weights * [4, 2, 1]).sum() / weights.sum())


def test_a_twist_about_a_missed_centre_is_still_a_twist_with_the_origin_radius():
    # a twist about CENTRE, but the only contact found lies 13 px off it (a finger missed):
    # about that wrong origin the rotation shows as a translation of ~ theta * 13 px, more than
    # the rotation term theta * r (r = 12 px)
    sensor = SENSORS["mirrored"]
    rest = grid(sensor)
    cur = move_in_user_frame(sensor, rest, CENTRE, angle=0.15)
    contact = (CENTRE + [13.0, 0.0])[None]
    kwargs = dict(r_px=12.0, min_intensity_px=0.1)
    paper = uniform_gesture(rest, cur, None, contact, sensor, **kwargs)
    ours = uniform_gesture(rest, cur, None, contact, sensor, origin_radius_px=10.0, **kwargs)
    assert paper.gesture is GestureType.PUSH
    assert ours.gesture is GestureType.TWIST_CCW


def test_the_origin_radius_leaves_a_push_a_push():
    sensor = SENSORS["mirrored"]
    rest = grid(sensor)
    cur = move_in_user_frame(sensor, rest, CENTRE, angle=0.02, shift_mm=(2.0, 1.0))
    result = uniform_gesture(rest, cur, None, CENTRE[None], sensor, r_px=30.0, origin_radius_px=10.0)
    assert result.gesture is GestureType.PUSH
    s = result.similarity
    m = math.hypot(s.scale * math.cos(s.rotation_rad) - 1, s.scale * math.sin(s.rotation_rad))
    assert s.terms_px(30.0, 10.0)[2] == pytest.approx(np.hypot(*s.translation_px) - 10.0 * m)


def test_the_type_is_read_about_the_type_centres_and_the_intensity_about_the_contacts():
    # the gel turns within 40 px of CENTRE and spreads beyond: about the maxima found 65 px out
    # (a field pushed outward) A holds the spread, about the fingers' fitted centres the turn
    sensor = SENSORS["mirrored"]
    rest = grid(sensor)
    turned = move_in_user_frame(sensor, rest, CENTRE, angle=0.1)
    spread = move_in_user_frame(sensor, rest, CENTRE, scale=1.08)
    cur = np.where((np.linalg.norm(rest - CENTRE, axis=1) < 40.0)[:, None], turned, spread)
    maxima = CENTRE + np.array([[-65.0, 0.0], [65.0, 0.0]])
    centres = CENTRE + np.array([[-15.0, 0.0], [15.0, 0.0]])
    about_maxima = uniform_gesture(rest, cur, None, maxima, sensor)
    result = uniform_gesture(rest, cur, None, maxima, sensor, type_centres_px=centres)
    assert about_maxima.gesture is GestureType.ZOOM
    assert result.gesture is GestureType.TWIST_CCW
    assert result.intensity_mm == about_maxima.intensity_mm
    assert np.array_equal(result.area, about_maxima.area)
    alone = uniform_gesture(rest, cur, None, centres, sensor).similarity
    assert (result.similarity.scale, result.similarity.rotation_rad) == (alone.scale, alone.rotation_rad)


# --- the numba kernels against NumPy written out (bit for bit where the kernel promises it) ---


def random_window(rng, n: int, k: int):
    """n markers (some lost: NaN rows, some not valid), k contacts, moved a few px."""
    rest = rng.uniform(100.0, 250.0, size=(n, 2))
    cur = rest + rng.normal(scale=3.0, size=(n, 2))
    cur[rng.random(n) < 0.1] = np.nan
    valid = rng.random(n) > 0.1
    contacts = rng.uniform(120.0, 230.0, size=(k, 2))
    return rest, cur, valid, contacts


@pytest.mark.parametrize("seed", range(12))
def test_area_motion_is_the_selection_its_means_and_the_centred_sets(seed):
    rng = np.random.default_rng(seed)
    n, k = [(0, 1), (1, 1), (3, 2), (40, 1), (177, 3), (177, 12)][seed % 6]
    rest, cur, valid, contacts = random_window(rng, n, k)
    r = 25.0
    sigma = 0.0 if seed % 2 else 3.0
    area, rest_a, cur_a, intensity, mean, origin = _area_motion(rest, cur, valid, contacts, r * r, sigma)
    d2 = ((cur[:, None, :] - contacts[None, :, :]) ** 2).sum(axis=2)
    expected = (d2 < r * r).any(axis=1) & valid  # NaN rows compare False
    assert np.array_equal(area, expected)
    assert np.array_equal(rest_a, rest[expected]) and np.array_equal(cur_a, cur[expected])
    assert np.array_equal(origin, contacts.mean(axis=0))
    if not expected.any():
        assert intensity == mean == 0.0
        return
    norms = np.hypot(cur_a[:, 0] - rest_a[:, 0], cur_a[:, 1] - rest_a[:, 1])
    assert mean == pytest.approx(norms.mean(), rel=1e-12)
    if sigma == 0.0:
        assert intensity == mean
    else:
        nearest = ((cur_a[:, None, :] - contacts[None, :, :]) ** 2).sum(axis=2).min(axis=1)
        weights = np.exp(-nearest / (2 * sigma**2))
        assert intensity == pytest.approx((weights * norms).sum() / weights.sum(), rel=1e-12)
    src, dst = _centred(rest_a, cur_a, origin)
    assert src.dtype == dst.dtype == np.float32
    assert np.array_equal(src, (rest_a - origin).astype(np.float32))
    assert np.array_equal(dst, (cur_a - origin).astype(np.float32))


@pytest.mark.parametrize("seed", range(8))
def test_camera_model_kernels_are_image_to_user_bit_for_bit(seed):
    rng = np.random.default_rng(100 + seed)
    sensor = SensorGeometry(
        gel_center_px=tuple(rng.uniform(160.0, 190.0, size=2)),
        px_per_mm=float(rng.uniform(2.0, 3.0)),
        mirror=bool(seed % 2),
        rotation_deg=[0.0, 0.0, 37.0, -90.0][seed % 4],
        radial_k=(float(rng.uniform(-0.3, 0.3)), float(rng.uniform(-0.1, 0.1))),
    )
    m = [1, 2, 5, 40, 177][seed % 5]
    cur_a = rng.uniform(100.0, 250.0, size=(m, 2))
    rest_a = cur_a + rng.normal(scale=2.0, size=(m, 2))
    origin, translation = rng.uniform(150.0, 200.0, size=2), rng.normal(size=2)
    contacts = rng.uniform(120.0, 230.0, size=(2, 2))
    cx, cy = sensor.gel_center_px
    k1, k2 = sensor.radial_k
    camera = (cx, cy, sensor.gel_radius_px, k1, k2, sensor.px_per_mm, sensor.mirror)
    mm = _area_mm(cur_a, rest_a, origin, translation, camera)
    if sensor.rotation_deg:
        mm = mm @ sensor.rotation_matrix().T
    expected = sensor.image_to_user(np.vstack([cur_a, rest_a, origin, origin + translation]))
    assert np.array_equal(mm, expected)
    v = expected[:m] - expected[m : 2 * m]
    intensity, translation_mm = _mm_figures(mm, cur_a, contacts, 0.0)
    assert intensity == pytest.approx(np.hypot(v[:, 0], v[:, 1]).mean(), rel=1e-12)
    assert np.array_equal(translation_mm, expected[-1] - expected[-2])


@pytest.mark.parametrize("seed", range(8))
def test_contact_points_in_mm_are_image_to_user_bit_for_bit(seed):
    rng = np.random.default_rng(200 + seed)
    radial_k = None if seed == 0 else (float(rng.uniform(-0.3, 0.3)), float(rng.uniform(-0.1, 0.1)))
    sensor = SensorGeometry(
        px_per_mm=float(rng.uniform(2.0, 3.0)),
        mirror=bool(seed % 2),
        rotation_deg=[0.0, 0.0, 37.0, -90.0][seed % 4],
        radial_k=radial_k,
    )
    for k in (0, 1, 3):
        points = rng.uniform(60.0, 290.0, size=(k, 2))
        converted = points_to_user(points, sensor)
        assert converted.shape == (k, 2) and converted.dtype == np.float64
        assert np.array_equal(converted, sensor.image_to_user(points))
