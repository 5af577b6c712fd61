"""The mapper, table by table: estimate in -> axes / buttons out."""

from __future__ import annotations

import math

import numpy as np
import pytest

from neurotouch_hid.core.controller import AXES
from neurotouch_hid.core.estimate import GestureEstimate, GestureType
from neurotouch_hid.mapping.filters import OneEuroFilter, response
from neurotouch_hid.mapping.inputs import gesture_inputs
from neurotouch_hid.mapping.mapper import Mapper
from neurotouch_hid.mapping.profile import Profile, load_profile, shipped_profiles_dir
from neurotouch_hid.mapping.replay import replay, summarise, tuned_saturations

G = GestureType
STICK_MAX, STICK_MIN = AXES["ABS_X"][1], AXES["ABS_X"][0]


def profile(**mappings) -> Profile:
    return Profile.model_validate({"mappings": mappings})


def est(gesture=G.NONE, mm=0.0, t_us=0, direction=(1.0, 0.0), contact=None, resting=None) -> GestureEstimate:
    contacts = np.zeros((0, 2)) if contact is None else np.array([contact], dtype=float)
    return GestureEstimate(
        t_us=t_us,
        gesture=gesture,
        resting=(gesture == G.NONE) if resting is None else resting,
        intensity_mm=mm,
        contacts_px=contacts.copy(),
        contacts_mm=contacts,
        translation_mm=np.array(direction, dtype=float),
    )


def stick_value(fraction: float) -> int:
    return round(fraction * STICK_MAX) if fraction >= 0 else round(fraction * -STICK_MIN)


# --- analogue axes: dead zone, saturation, curve, gain, invert ------------------------------------
TWIST_AXIS = dict(input="twist", output="ABS_RX", deadzone_mm=1.0, saturation_mm=5.0)


@pytest.mark.parametrize(
    "extra, gesture, mm, fraction",
    [
        ({}, G.TWIST_CCW, 0.5, 0.0),  # inside the dead zone
        ({}, G.TWIST_CCW, 1.0, 0.0),  # at the dead zone
        ({}, G.TWIST_CCW, 3.0, 0.5),  # halfway between dead zone and saturation
        ({}, G.TWIST_CCW, 5.0, 1.0),  # saturation: full deflection
        ({}, G.TWIST_CCW, 12.0, 1.0),  # beyond saturation: still full
        ({}, G.TWIST_CW, 5.0, -1.0),  # clockwise: the other side, full
        ({}, G.TWIST_CW, 2.0, -0.25),
        ({"exponent": 2.0}, G.TWIST_CCW, 3.0, 0.25),
        ({"exponent": 0.5}, G.TWIST_CCW, 2.0, 0.5),
        ({"expo": 0.5}, G.TWIST_CCW, 3.0, 0.5 * 0.5 + 0.5 * 0.125),
        ({"gain": 2.0}, G.TWIST_CCW, 2.0, 0.5),
        ({"gain": 2.0}, G.TWIST_CCW, 4.0, 1.0),  # gain clips at full deflection
        ({"invert": True}, G.TWIST_CCW, 3.0, -0.5),
        ({"invert": True}, G.TWIST_CW, 5.0, 1.0),
        ({}, G.PUSH, 5.0, 0.0),  # another gesture does not move a twist axis
        ({}, G.NONE, 5.0, 0.0),
    ],
)
def test_axis_response(extra, gesture, mm, fraction):
    state = Mapper(profile(m={**TWIST_AXIS, **extra})).update(est(gesture, mm))
    assert state.axes["ABS_RX"] == stick_value(fraction)
    assert all(v == 0 for k, v in state.axes.items() if k != "ABS_RX")


@pytest.mark.parametrize(
    "input_name, output, gesture, mm, expected",
    [
        ("zoom", "ABS_RZ", G.ZOOM, 0.0, 0),
        ("zoom", "ABS_RZ", G.ZOOM, 2.5, round(0.5 * 255)),  # dead zone 0, saturation 5
        ("zoom", "ABS_RZ", G.ZOOM, 9.0, 255),
        ("pinch", "ABS_Z", G.PINCH, 5.0, 255),
        ("pinch", "ABS_Z", G.ZOOM, 5.0, 0),
        ("pinch_zoom", "ABS_RZ", G.PINCH, 5.0, 0),  # a trigger only takes the positive side
        ("pinch_zoom", "ABS_RZ", G.ZOOM, 5.0, 255),
        ("pinch_zoom", "ABS_RX", G.PINCH, 5.0, STICK_MIN),  # a stick axis takes both
        ("pinch_zoom", "ABS_RY", G.ZOOM, 5.0, STICK_MIN),  # a positive value on a y axis is up
        ("pinch_zoom", "ABS_RY", G.PINCH, 5.0, 32767),
    ],
)
def test_triggers_and_signed_scalars(input_name, output, gesture, mm, expected):
    m = dict(input=input_name, output=output, deadzone_mm=0.0, saturation_mm=5.0)
    assert Mapper(profile(m=m)).update(est(gesture, mm)).axes[output] == expected


@pytest.mark.parametrize("output", ["ABS_Y", "ABS_RY", "l_stick_y", "r_stick_y", "REL_Y"])
def test_a_scalar_on_a_y_axis_goes_the_way_a_stick_mapping_goes(output):
    """push_y on one stick axis moves it as ``push`` on the stick does: a push up is up (evdev's
    negative ABS_Y / ABS_RY, as the pointer's negative REL_Y)."""
    scalar = dict(input="push_y", output=output, deadzone_mm=1.0, saturation_mm=5.0)
    stick = dict(input="push", output="left_stick", deadzone_mm=1.0, saturation_mm=5.0)
    up = est(G.PUSH, 5.0, direction=(0.0, 1.0))
    mapper = Mapper(profile(m=scalar))
    mapper.update(up)
    state = mapper.update(est(G.PUSH, 5.0, t_us=10_000, direction=(0.0, 1.0)))  # the pointer moves from the second
    moved = state.rel.get("REL_Y", 0) if output == "REL_Y" else min(state.axes["ABS_Y"], state.axes["ABS_RY"])
    assert moved < 0 and Mapper(profile(m=stick)).update(up).axes["ABS_Y"] < 0


# --- sticks: direction in the user frame, y flipped to evdev ------------------------------------
PUSH_STICK = dict(input="push", output="left_stick", deadzone_mm=1.0, saturation_mm=5.0)


@pytest.mark.parametrize(
    "extra, direction, mm, x, y",
    [
        ({}, (0, 1), 5.0, 0.0, -1.0),  # push up (user +y) -> evdev ABS_Y negative (up)
        ({}, (0, -1), 5.0, 0.0, 1.0),
        ({}, (1, 0), 5.0, 1.0, 0.0),
        ({}, (-3, 0), 5.0, -1.0, 0.0),  # only the direction of translation_mm counts
        ({}, (1, 1), 3.0, 0.5 / math.sqrt(2), -0.5 / math.sqrt(2)),  # radial: direction kept
        ({}, (0, 1), 0.9, 0.0, 0.0),  # dead zone
        ({"invert_y": True}, (0, 1), 5.0, 0.0, 1.0),
        ({"invert_x": True}, (1, 0), 3.0, -0.5, 0.0),
        ({}, (0, 0), 5.0, 0.0, 0.0),  # no direction: no deflection
    ],
)
def test_push_to_stick(extra, direction, mm, x, y):
    state = Mapper(profile(m={**PUSH_STICK, **extra})).update(est(G.PUSH, mm, direction=direction))
    assert state.axes["ABS_X"] == stick_value(x) and state.axes["ABS_Y"] == stick_value(y)


@pytest.mark.parametrize(
    "contact, gesture, x, y",
    [
        ((15.0, 0.0), G.PUSH, 0.5, 0.0),  # position / gel radius (30 mm)
        ((0.0, 30.0), G.ZOOM, 0.0, -1.0),  # at the rim, up -> full evdev up
        ((-45.0, 0.0), G.PINCH, -1.0, 0.0),  # beyond the rim clips
        ((15.0, 0.0), G.NONE, 0.0, 0.0),  # no gesture: centred
    ],
)
def test_contact_to_stick(contact, gesture, x, y):
    m = dict(input="contact", output="right_stick", deadzone_mm=0.0)
    state = Mapper(profile(m=m)).update(est(gesture, 3.0, contact=contact))
    assert state.axes["ABS_RX"] == stick_value(x) and state.axes["ABS_RY"] == stick_value(y)


def test_contributions_to_one_axis_add_up_and_clamp():
    p = profile(
        a=dict(input="push_x", output="ABS_X", deadzone_mm=0.0, saturation_mm=10.0),
        b=dict(input="push_x", output="ABS_X", deadzone_mm=0.0, saturation_mm=10.0),
    )
    assert Mapper(p).update(est(G.PUSH, 3.0)).axes["ABS_X"] == stick_value(0.6)
    assert Mapper(p).update(est(G.PUSH, 8.0)).axes["ABS_X"] == STICK_MAX


# --- buttons: hysteresis, hold, toggle, d-pad ----------------------------------------------------
BUTTON = dict(input="zoom", output="BTN_SOUTH", press_mm=2.0, release_mm=1.0)


@pytest.mark.parametrize(
    "mode, intensities, expected",
    [
        ("hold", [0, 1.9, 2.0, 1.5, 1.0, 0.99, 1.5, 2.5, 0], [0, 0, 1, 1, 1, 0, 0, 1, 0]),
        ("toggle", [0, 2.0, 1.5, 0.5, 1.5, 3.0, 0.0, 0.0, 2.2], [0, 1, 1, 1, 1, 0, 0, 0, 1]),
    ],
)
def test_button_hysteresis_and_modes(mode, intensities, expected):
    mapper = Mapper(profile(b={**BUTTON, "mode": mode}))
    pressed = [
        mapper.update(est(G.ZOOM if mm else G.NONE, mm, t_us=10_000 * i)).buttons["BTN_SOUTH"]
        for i, mm in enumerate(intensities)
    ]
    assert pressed == [bool(e) for e in expected]


@pytest.mark.parametrize(
    "direction, hat_x, hat_y",
    [
        ((0, 1), 0, -1),
        ((0, -1), 0, 1),
        ((-1, 0), -1, 0),
        ((1, 0), 1, 0),
        ((1, 1), 1, -1),  # a diagonal push presses both neighbours (8-way d-pad)
        ((1, 0.1), 1, 0),  # a slight slant does not reach the other threshold
    ],
)
def test_push_directions_to_dpad(direction, hat_x, hat_y):
    maps = {
        d: dict(input=f"push_{d}", output=f"dpad_{d}", press_mm=2.0, release_mm=1.0)
        for d in ("up", "down", "left", "right")
    }
    state = Mapper(profile(**maps)).update(est(G.PUSH, 4.0, direction=direction))
    assert (state.axes["ABS_HAT0X"], state.axes["ABS_HAT0Y"]) == (hat_x, hat_y)
    assert not any(state.buttons.values())


def test_reset_forgets_toggles():
    mapper = Mapper(profile(b={**BUTTON, "mode": "toggle"}))
    assert mapper.update(est(G.ZOOM, 3.0)).buttons["BTN_SOUTH"]
    mapper.reset()
    assert not mapper.update(est(G.NONE, 0.0, t_us=10_000)).buttons["BTN_SOUTH"]


# --- smoothing ----------------------------------------------------------------------------------
def test_one_euro_is_an_exponential_low_pass_at_low_speed():
    f = OneEuroFilter(min_cutoff_hz=1.0, beta=0.0)
    assert f(0.0, 0) == 0.0
    alpha = 1.0 / (1.0 + 1.0 / (2 * math.pi * 1.0) / 0.01)  # Casiez et al.: tau = 1 / (2 pi fc)
    assert f(1.0, 10_000) == pytest.approx(alpha)
    assert f(1.0, 20_000) == pytest.approx(alpha + alpha * (1 - alpha))


def test_one_euro_filters_a_vector_element_by_element():
    rng = np.random.default_rng(2)
    both, xs, ys = OneEuroFilter(2.0, beta=0.05), OneEuroFilter(2.0, beta=0.05), OneEuroFilter(2.0, beta=0.05)
    t = 0
    for _ in range(200):
        t += int(rng.integers(0, 30_000))  # repeated timestamps too
        value = rng.normal(scale=5.0, size=2)
        out = both(value, t)
        assert out.shape == (2,) and out.dtype == np.float64
        assert out[0] == xs(float(value[0]), t) and out[1] == ys(float(value[1]), t)
    assert isinstance(xs(1.0, t + 1), float)


def test_one_euro_beta_cuts_lag_on_fast_moves():
    slow, fast = OneEuroFilter(1.0, beta=0.0), OneEuroFilter(1.0, beta=1.0)
    for f in (slow, fast):
        f(0.0, 0)
    assert fast(5.0, 10_000) > slow(5.0, 10_000)


def test_smoothing_converges_and_lags():
    m = {**TWIST_AXIS, "smoothing": {"filter": "one_euro", "min_cutoff_hz": 1.0, "beta": 0.0}}
    states = replay(
        profile(m=m), [est(G.NONE, 0.0, t_us=0)] + [est(G.TWIST_CCW, 5.0, t_us=10_000 * i) for i in range(1, 300)]
    )
    values = [s.axes["ABS_RX"] for s in states]
    assert 0 < values[5] < STICK_MAX // 2  # smoothed: not at once
    assert values == sorted(values)  # no overshoot
    assert values[-1] >= stick_value(0.99)  # converges to the unsmoothed value


@pytest.mark.parametrize("name", ["default", "spacecraft", "accessibility"])
def test_rest_gives_neutral_after_smoothing_settles(name):
    p = load_profile(shipped_profiles_dir() / f"{name}.yaml")
    gestures = [
        (G.PUSH, (0, 1)),
        (G.TWIST_CCW, (1, 0)),
        (G.TWIST_CW, (1, 0)),
        (G.ZOOM, (1, 0)),
        (G.PINCH, (1, 0)),
        (G.PUSH, (-1, 0)),
    ]
    stream, t = [], 0
    for gesture, direction in gestures:
        for _ in range(100):  # 1 s of a firm gesture
            stream.append(est(gesture, 9.0, t_us=t, direction=direction, contact=(5.0, 5.0)))
            t += 10_000
    active = replay(p, stream)
    assert not all(s.is_neutral() for s in active), "the gestures move something"
    rest = [est(G.NONE, 0.0, t_us=t + 10_000 * i) for i in range(300)]  # 3 s at rest
    mapper = Mapper(p)
    for e in stream:
        mapper.update(e)
    settled = [mapper.update(e) for e in rest][-1]
    hold_only = all(getattr(m, "mode", "hold") == "hold" for m in p.mappings.values())
    if hold_only:
        assert settled.is_neutral()
    else:  # toggled buttons keep their state; every axis is centred
        assert all(settled.axes[a] == AXES[a][2] for a in AXES)


def test_non_finite_estimates_count_as_nothing():
    inputs = gesture_inputs(est(G.PUSH, float("nan")))
    assert all(np.all(np.asarray(v) == 0) for v in inputs.values())
    assert response(float("inf"), 0.5, 5.0) == 0.0


# --- replay, summary and tuning -----------------------------------------------------------------
def test_summary_counts_presses_and_max_deflection():
    p = profile(b={**BUTTON}, a=dict(input="zoom", output="ABS_RZ", deadzone_mm=0.0, saturation_mm=4.0))
    stream = [est(G.ZOOM if mm else G.NONE, mm, t_us=10_000 * i) for i, mm in enumerate([0, 3, 0, 2.0, 0.5, 0])]
    s = summarise(replay(p, stream))
    assert s.presses["BTN_SOUTH"] == 2
    assert s.max_deflection["ABS_RZ"] == pytest.approx(round(0.75 * 255) / 255)
    assert s.max_deflection["ABS_X"] == 0.0


def test_tuned_saturation_is_the_percentile_of_reached_intensity():
    p = profile(
        push=PUSH_STICK,
        zoom=dict(input="zoom", output="ABS_RZ", deadzone_mm=0.5, saturation_mm=6.0),
        where=dict(input="contact", output="right_stick"),
    )
    pushes = [1.0 + 0.02 * i for i in range(101)]  # 1.0 .. 3.0 mm: a weak user
    stream = [est(G.PUSH, mm, t_us=10_000 * i, contact=(3.0, 0.0)) for i, mm in enumerate(pushes)]
    stream += [est(G.NONE, 0.0, t_us=2_000_000)]
    tuned = tuned_saturations(p, stream, percentile=95)
    assert set(tuned) == {"push"}  # zoom never happened; contact is a position, not an intensity
    old, new = tuned["push"]
    assert old == 5.0 and new == pytest.approx(1.0 + 0.02 * 95, abs=0.01)
    # a weak user's 95th-percentile push now gives full deflection
    tuned_profile = profile(push={**PUSH_STICK, "saturation_mm": new})
    assert Mapper(tuned_profile).update(est(G.PUSH, 2.9)).axes["ABS_X"] == STICK_MAX


def test_summary_counts_dpad_presses():
    p = profile(
        up=dict(input="push_up", output="dpad_up", press_mm=2.0, release_mm=1.0),
        right=dict(input="push_right", output="dpad_right", press_mm=2.0, release_mm=1.0),
    )
    pushes = [((0, 1), 3.0), ((0, 0), 0.0), ((0, 1), 3.0), ((1, 0), 3.0), ((0, 0), 0.0)]
    stream = [est(G.PUSH if mm else G.NONE, mm, t_us=10_000 * i, direction=d) for i, (d, mm) in enumerate(pushes)]
    presses = summarise(replay(p, stream)).presses
    assert presses["dpad_up"] == 2 and presses["dpad_right"] == 1 and presses["dpad_down"] == 0


# --- a resting gel: the kept state instead of the computation ---------------------------------------
def _session() -> list[GestureEstimate]:
    """Rest, every gesture (firm and light, a short tap and a long hold), each followed by rest long
    enough for every filter to reach exactly zero (80 s), some rests broken by single windows of
    a light non-resting ``none``."""
    stream, t = [], 0

    def add(e: GestureEstimate) -> None:
        nonlocal t
        stream.append(e)
        t += 10_000

    for _ in range(50):
        add(est(t_us=t))
    for gesture, direction, mm, n in [
        (G.PUSH, (0, 1), 9.0, 100),
        (G.TWIST_CCW, (1, 0), 4.0, 8),
        (G.ZOOM, (1, 0), 9.0, 120),
        (G.PINCH, (1, 0), 2.5, 60),
        (G.TWIST_CW, (1, 0), 9.0, 100),
        (G.PUSH, (-1, 0.3), 5.0, 30),
    ]:
        for _ in range(n):
            add(est(gesture, mm, t_us=t, direction=direction, contact=(5.0, 5.0)))
        for k in range(8000):
            add(est(G.NONE, 0.4, t_us=t, resting=False) if k % 997 == 500 else est(t_us=t))
    return stream


@pytest.mark.parametrize("name", ["default", "mouse", "spacecraft", "accessibility", "switch-access"])
def test_rest_at_the_fixed_point_gives_what_the_full_update_gives(name, monkeypatch):
    p = load_profile(shipped_profiles_dir() / f"{name}.yaml")
    session = _session()
    full = Mapper(p)
    reference = []
    for e in session:
        full._quiet = None  # never the kept state: every update computed
        reference.append(full.update(e))
    computed = []
    real_inputs = gesture_inputs
    monkeypatch.setattr(
        "neurotouch_hid.mapping.mapper.gesture_inputs", lambda e: computed.append(e.t_us) or real_inputs(e)
    )
    states = replay(p, session)
    assert [(s.t_us, s.axes, s.buttons, s.keys, s.rel) for s in states] == [
        (s.t_us, s.axes, s.buttons, s.keys, s.rel) for s in reference
    ]
    assert len(computed) < len(session) // 4  # most of the resting windows were not computed


def test_a_resting_gel_is_not_mapped_again_and_the_next_touch_is():
    p = load_profile(shipped_profiles_dir() / "default.yaml")
    mapper = Mapper(p)
    calls = []
    real_inputs = gesture_inputs
    import neurotouch_hid.mapping.mapper as mapper_module

    mapper_module.gesture_inputs, saved = (lambda e: calls.append(e) or real_inputs(e)), mapper_module.gesture_inputs
    try:
        first = mapper.update(est(t_us=0))
        rested = [mapper.update(est(t_us=10_000 * i)) for i in range(1, 200)]
        assert len(calls) == 1  # only the first resting window was computed
        assert all(s.axes == first.axes and s.buttons == first.buttons and not s.rel for s in rested)
        assert [s.t_us for s in rested] == [10_000 * i for i in range(1, 200)]
        touched = mapper.update(est(G.PUSH, 9.0, t_us=2_000_000, direction=(0, 1)))
        assert len(calls) == 2 and touched.axes["ABS_Y"] < AXES["ABS_Y"][2]  # pushed up at once
    finally:
        mapper_module.gesture_inputs = saved


def test_the_pointer_from_the_contact_point_saturates_at_the_gel_radius():
    """A finger 15 mm right of the centre (half the 30 mm radius, no dead zone) moves the pointer at
    half its speed: 5 px in 10 ms at 1000 px/s (with the 8 mm of the other inputs it would be 10)."""
    mapper = Mapper(profile(p=dict(input="contact", output="pointer", deadzone_mm=0.0)))
    mapper.update(est(G.PUSH, 2.0, contact=(15.0, 0.0)))
    assert mapper.update(est(G.PUSH, 2.0, t_us=10_000, contact=(15.0, 0.0))).rel == {"REL_X": 5}


def test_a_trigger_takes_only_the_positive_side_of_each_mapping_before_they_add_up():
    """``intensity`` and ``pinch_zoom`` both on RT, a 4 mm pinch: pinch_zoom's negative side is
    nothing on a trigger, so RT is intensity's half travel, not cancelled to 0."""
    a = dict(input="intensity", output="ABS_RZ", deadzone_mm=0.0, saturation_mm=8.0)
    b = dict(input="pinch_zoom", output="ABS_RZ", deadzone_mm=0.0, saturation_mm=8.0)
    assert Mapper(profile(a=a, b=b)).update(est(G.PINCH, 4.0)).axes["ABS_RZ"] == round(0.5 * 255)


@pytest.mark.parametrize("extra", [{}, {"c": dict(input="push_intensity", output="dpad_up")}])
def test_dpad_directions_are_or_ed_like_buttons(extra):
    """A push up presses d-pad up (push_up) and d-pad down (intensity): opposite directions at
    once leave the hat centred, however many mappings press each."""
    up = dict(input="push_up", output="dpad_up")
    down = dict(input="intensity", output="dpad_down")
    state = Mapper(profile(a=up, b=down, **extra)).update(est(G.PUSH, 3.0, direction=(0.0, 1.0)))
    assert state.axes["ABS_HAT0Y"] == 0
    alone = Mapper(profile(a=up, **extra)).update(est(G.PUSH, 3.0, direction=(0.0, 1.0)))
    assert alone.axes["ABS_HAT0Y"] == -1


# --- one window of another type (Mapper._confirmed) -----------------------------------------------
TWO_BUTTONS = dict(
    t=dict(input="twist_cw", output="BTN_EAST", press_mm=1.0, release_mm=0.5),
    p=dict(input="push_intensity", output="BTN_SOUTH", press_mm=1.0, release_mm=0.5),
)


def _buttons(mapper: Mapper, kinds: list[tuple[GestureType, float]]) -> list[tuple[bool, bool]]:
    """(BTN_EAST, BTN_SOUTH) of 10 ms windows of (type, mm), the gel never at rest between them."""
    out = []
    for k, (kind, mm) in enumerate(kinds):
        state = mapper.update(est(kind, mm, t_us=10_000 * (k + 1), resting=False))
        out.append((state.buttons["BTN_EAST"], state.buttons["BTN_SOUTH"]))
    return out


def test_one_window_of_another_type_presses_none_of_its_outputs():
    """A twist held on BTN_EAST with one window read push at 3 mm (a flip the vote let through):
    BTN_SOUTH (push) is never pressed and BTN_EAST stays down, one press. Two windows of push in a
    row are a change: push presses from the second, the twist is let go there."""
    twist, push = (G.TWIST_CW, 3.0), (G.PUSH, 3.0)
    got = _buttons(Mapper(profile(**TWO_BUTTONS)), [twist] * 5 + [push] + [twist] * 5)
    assert got == [(True, False)] * 11
    got = _buttons(Mapper(profile(**TWO_BUTTONS)), [twist] * 5 + [push] * 3)
    assert got == [(True, False)] * 6 + [(False, True)] * 2


def test_a_new_type_is_followed_at_once_where_the_type_before_moved_nothing():
    """Below the profile's lowest typed level (here the buttons' release 0.5 mm) the type before
    moved no output: an onset's provisional push at 0.3 mm, then the twist at 3 mm, presses the
    twist's button from its first window; after the fingers are off (a window without intensity),
    or after reset (a profile switch starts a new mapper), a push is followed from its first
    window too."""
    mapper = Mapper(profile(**TWO_BUTTONS))
    assert _buttons(mapper, [(G.PUSH, 0.3), (G.TWIST_CW, 3.0)])[1] == (True, False)
    mapper = Mapper(profile(**TWO_BUTTONS))
    got = _buttons(mapper, [(G.TWIST_CW, 3.0), (G.NONE, 0.0), (G.PUSH, 3.0)])
    assert got == [(True, False), (False, False), (False, True)]
    mapper = Mapper(profile(**TWO_BUTTONS))
    _buttons(mapper, [(G.TWIST_CW, 3.0)])
    mapper.reset()
    assert _buttons(mapper, [(G.PUSH, 3.0)]) == [(False, True)]


@pytest.mark.parametrize("name", ["default", "accessibility", "spacecraft", "mouse", "switch-access"])
def test_no_shipped_profile_follows_a_single_window_of_another_type(name):
    """Every shipped profile, a twist held at 3 mm with a window of each other type inside it: the
    states are those of the twist held throughout (the flip window is the twist's)."""
    others = [G.PUSH, G.PINCH, G.ZOOM, G.TWIST_CCW]
    held = [est(G.TWIST_CW, 3.0, t_us=10_000 * (k + 1), resting=False) for k in range(30)]
    flicked = list(held)
    for j, kind in enumerate(others):
        k = 5 + 6 * j
        flicked[k] = est(kind, 3.0, t_us=held[k].t_us, resting=False)
    plain, flips = Mapper(load_profile(name)), Mapper(load_profile(name))
    for a, b in zip(held, flicked):
        sa, sb = plain.update(a), flips.update(b)
        assert (sa.axes, sa.buttons, sa.keys, sa.rel) == (sb.axes, sb.buttons, sb.keys, sb.rel), b.t_us
