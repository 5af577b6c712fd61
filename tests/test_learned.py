"""The learned gesture type (``pipeline/learned.py``): features of hand-made windows and what the
trained model (``gesture_model.py``) reads where the paper's rule misreads."""

from __future__ import annotations

import math

import numpy as np
import pytest

from neurotouch_hid.core.estimate import GestureType
from neurotouch_hid.core.sensor import SensorGeometry
from neurotouch_hid.pipeline.gesture import estimate_gesture
from neurotouch_hid.pipeline.learned import FEATURES, _relative_motion, gesture_features, learned_gesture

SENSOR = SensorGeometry()
OPTIONS = dict(r_px=25.0, reproj_factor=2.0, min_intensity_px=0.3, intensity_sigma_px=3.0, origin_radius_px=10.0)


def grid() -> np.ndarray:
    k = np.arange(-8, 9) * 10.0
    pts = np.stack(np.meshgrid(k, k), axis=-1).reshape(-1, 2) + np.asarray(SENSOR.gel_center_px)
    return pts[SENSOR.inside_gel(pts, margin_px=-3.0)]


def two_finger_window(radial_px: float, tangential_px: float, drift_px=(0.0, 0.0)):
    """Two fingers 40 px apart on a horizontal line moving apart (radial > 0), together (< 0) or
    round their middle (tangential), each dragging a Gaussian patch; plus a whole-gel drift."""
    rest = grid()
    c = np.asarray(SENSOR.gel_center_px, dtype=float)
    fingers = np.array([c + [-20.0, 0.0], c + [20.0, 0.0]])
    out = np.array([[-1.0, 0.0], [1.0, 0.0]])
    tangent = np.array([[0.0, 1.0], [0.0, -1.0]])  # image frame, y down
    cur = rest + np.asarray(drift_px, dtype=float)
    for f, o, t in zip(fingers, out, tangent):
        w = np.exp(-np.sum((rest - f) ** 2, axis=1) / (2 * 8.0**2))
        cur = cur + w[:, None] * (radial_px * o + tangential_px * t)
    contacts = fingers + radial_px * out + tangential_px * tangent + drift_px
    return rest, cur, contacts


def features(rest, cur, contacts):
    result = estimate_gesture(rest, cur, None, contacts, SENSOR, **OPTIONS)
    valid = np.ones(len(rest), dtype=bool)
    return result, gesture_features(result, contacts, rest, cur, valid, SENSOR, 25.0, 10.0)


def test_the_features_read_the_contacts_motion():
    _, zoom = features(*two_finger_window(5.0, 0.0))
    _, pinch = features(*two_finger_window(-5.0, 0.0))
    _, twist = features(*two_finger_window(0.0, 5.0))
    i = {name: k for k, name in enumerate(FEATURES)}
    assert zoom[i["contact_radial"]] == pytest.approx(1.0, abs=0.05)
    assert pinch[i["contact_radial"]] == pytest.approx(-1.0, abs=0.05)
    assert abs(twist[i["contact_radial"]]) < 0.05 and abs(twist[i["contact_tangential"]]) > 0.95
    assert zoom[i["contact_count"]] == 2.0 and zoom[i["signed_scale_share"]] > 0 > pinch[i["signed_scale_share"]]
    assert twist[i["signed_rotation_share"]] * twist[i["contact_tangential"]] > 0  # one sense of turning


@pytest.mark.parametrize("radial, tangential", [(4.0, 0.0), (-4.0, 0.0), (0.0, 4.0), (0.0, -4.0)])
def test_two_fingers_on_a_drifting_gel_read_their_gesture_learned_and_push_by_the_rule(radial, tangential):
    # the whole gel slides 1 px while two fingers move 4 px apart, together or round their
    # middle: the similarity's translation term wins (the rule says push); the contacts' motion
    # relative to each other still shows the gesture the rule reads without the drift
    clean, _ = features(*two_finger_window(radial, tangential))
    drifted, x = features(*two_finger_window(radial, tangential, drift_px=(1.0, 0.0)))
    assert clean.gesture is not GestureType.PUSH
    assert drifted.gesture is GestureType.PUSH
    assert learned_gesture(x) is clean.gesture


@pytest.mark.parametrize("radial, tangential, expected", [(5.0, 0.0, GestureType.ZOOM), (-5.0, 0.0, GestureType.PINCH)])
def test_clean_two_finger_gestures_read_the_same_learned(radial, tangential, expected):
    result, x = features(*two_finger_window(radial, tangential))
    assert result.gesture is expected
    assert learned_gesture(x) is expected


@pytest.mark.parametrize("seed", range(8))
def test_the_features_kernel_is_the_formula_written_out(seed):
    # gesture_features' numba kernel against its formula in Python (bit for bit), on random
    # windows: one or several contacts, lost markers, mirrored or not
    rng = np.random.default_rng(seed)
    rest, cur, contacts = two_finger_window(*rng.normal(scale=4.0, size=2), drift_px=tuple(rng.normal(size=2)))
    contacts = contacts[: 1 + seed % 2]
    valid = rng.random(len(rest)) > 0.2
    sensor = SensorGeometry(mirror=bool(seed % 3))
    result = estimate_gesture(rest, cur, valid, contacts, sensor, **OPTIONS)
    got = gesture_features(result, contacts, rest, cur, valid, sensor, 25.0, 10.0)
    s_t, r_t, t_t = result.similarity.terms_px(25.0, 10.0)
    total = s_t + r_t + t_t + 1e-9
    radial, turning = _relative_motion(contacts, rest, cur, valid)
    if len(contacts) == 1:
        assert radial == turning == 0.0
    expected = [
        s_t / total,
        r_t / total,
        t_t / total,
        math.copysign(s_t / total, result.similarity.scale - 1.0),
        math.copysign(r_t / total, result.rotation_rad),
        radial,
        -turning if sensor.mirror else turning,
        float(len(contacts)),
        math.log1p(result.intensity_px),
    ]
    assert got.dtype == np.float64 and got.tobytes() == np.array(expected).tobytes()
