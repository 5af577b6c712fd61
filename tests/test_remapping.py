"""Activators, anti-deadzone, face aliases, keys, the mouse's pointer and wheels, and layers:
table by table, on the estimates' camera clock (no wall clock anywhere)."""

from __future__ import annotations

import re

import numpy as np
import pytest

from neurotouch_hid.core.controller import AXES
from neurotouch_hid.core.errors import ProfileError
from neurotouch_hid.core.estimate import GestureEstimate, GestureType
from neurotouch_hid.mapping.activator import Activator
from neurotouch_hid.mapping.mapper import Mapper
from neurotouch_hid.mapping.profile import Profile, load_profile, parse_profile
from neurotouch_hid.mapping.rel_motion import HI_RES_PER_DETENT, RelMotion

G = GestureType
MS = 1000  # us


def run_activator(mode: str, samples: list[tuple[int, float]], **kw) -> list[int]:
    """The activator's output (0/1) for (t_ms, value_mm) samples; press at 2 mm, release below 1 mm."""
    act = Activator(mode, 2.0, 1.0, **kw)
    return [int(act.update(v, t * MS)) for t, v in samples]


def held(*spans: tuple[int, int], until: int, step: int = 10) -> list[tuple[int, float]]:
    """Samples every ``step`` ms from 0 to ``until`` ms: 3 mm inside the [start, end) spans, else 0."""
    return [(t, 3.0 if any(a <= t < b for a, b in spans) else 0.0) for t in range(0, until, step)]


def times_down(samples, outputs) -> list[int]:
    return [t for (t, _), o in zip(samples, outputs) if o]


# --- activators ---------------------------------------------------------------------------------
@pytest.mark.parametrize("dwell", [{}, {"dwell_ms": 0}])
def test_a_tap_with_its_documented_default_dwell_written_out_taps_at_once(dwell):
    """``dwell_ms: 0`` is tap's default written out: accepted, and the same keystroke."""
    profile = Profile.model_validate(
        {"mappings": {"t": {"input": "pinch", "output": "KEY_ENTER", "mode": "tap", **dwell}}}
    )
    activator = Activator.of(profile.mappings["t"])
    samples = held((0, 300), until=400)
    assert times_down(samples, [int(activator.update(v, t * MS)) for t, v in samples]) == list(range(0, 100, 10))


@pytest.mark.parametrize(
    "values, expected",
    [
        ([0, 1.9, 2.0, 1.5, 1.0, 0.9, 0], [0, 0, 1, 1, 1, 0, 0]),  # hysteresis: press at >= 2, release at < 1
        ([3, 0, 3, 0], [1, 0, 1, 0]),
        ([1.5, 1.5, 1.5], [0, 0, 0]),  # between the thresholds, never pressed
    ],
)
def test_hold_follows_the_input_with_hysteresis(values, expected):
    assert run_activator("hold", [(10 * i, v) for i, v in enumerate(values)]) == expected


@pytest.mark.parametrize(
    "values, expected",
    [
        ([3, 3, 0, 0, 3, 0, 3], [1, 1, 1, 1, 0, 0, 1]),  # each press flips
        ([3, 1.5, 3, 0], [1, 1, 1, 1]),  # no release in between: one press
    ],
)
def test_toggle_flips_on_each_press(values, expected):
    assert run_activator("toggle", [(10 * i, v) for i, v in enumerate(values)]) == expected


@pytest.mark.parametrize(
    "dwell_ms, spans, down",
    [
        (100, [(0, 50)], []),  # tremor shorter than the dwell: nothing
        (100, [(0, 100)], []),  # released at the dwell: nothing
        (100, [(0, 200)], [100, 110, 120, 130, 140, 150, 160, 170, 180, 190]),  # down from dwell on, up at release
        (100, [(0, 60), (100, 260)], list(range(200, 260, 10))),  # the dwell restarts with each hold
        (30, [(50, 100)], [80, 90]),
    ],
)
def test_long_press_needs_the_dwell_time_on_the_camera_clock(dwell_ms, spans, down):
    samples = held(*spans, until=300)
    assert times_down(samples, run_activator("long_press", samples, dwell_ms=dwell_ms)) == down


def test_long_press_uses_estimate_time_not_sample_count():
    """The same hold sampled every 5 ms or every 50 ms: down from 150 ms on either way."""
    fine = held((0, 400), until=400, step=5)
    coarse = held((0, 400), until=400, step=50)
    assert times_down(fine, run_activator("long_press", fine, dwell_ms=150))[0] == 150
    assert times_down(coarse, run_activator("long_press", coarse, dwell_ms=150))[0] == 150


@pytest.mark.parametrize(
    "spans, down",
    [
        ([(0, 50)], []),  # a single press: nothing
        ([(0, 50), (100, 150)], [100, 110, 120, 130, 140]),  # second press within 400 ms: down while held
        ([(0, 50), (400, 450)], [400, 410, 420, 430, 440]),  # second press starts exactly 400 ms later
        ([(0, 50), (500, 550)], []),  # too late: a new first press
        ([(0, 50), (500, 550), (600, 650)], [600, 610, 620, 630, 640]),  # ... whose second press counts
        ([(0, 50), (100, 150), (200, 250)], [100, 110, 120, 130, 140]),  # a third press starts a new pair
        ([(0, 50), (100, 150), (200, 250), (300, 350)], [100, 110, 120, 130, 140, 300, 310, 320, 330, 340]),
    ],
)
def test_double_press_fires_on_a_quick_second_press(spans, down):
    samples = held(*spans, until=800)
    assert times_down(samples, run_activator("double_press", samples, double_press_ms=400)) == down


@pytest.mark.parametrize(
    "hz, spans, down",
    [
        (10, [(0, 300)], [0, 10, 20, 30, 40, 100, 110, 120, 130, 140, 200, 210, 220, 230, 240]),  # 50 ms down, 50 up
        (25, [(0, 100)], [0, 10, 40, 50, 80, 90]),  # 20 ms down, 20 up
        (10, [(0, 70), (200, 260)], [0, 10, 20, 30, 40, 200, 210, 220, 230, 240]),  # each hold starts down
        (10, [], []),
    ],
)
def test_turbo_repeats_at_its_rate_while_held(hz, spans, down):
    samples = held(*spans, until=400)
    assert times_down(samples, run_activator("turbo", samples, turbo_hz=hz)) == down


# --- the mapper: keys, aliases, anti-deadzone, pointer, wheels -----------------------------------
def est(gesture=G.NONE, mm=0.0, t_us=0, direction=(1.0, 0.0)) -> GestureEstimate:
    return GestureEstimate(
        t_us=t_us,
        gesture=gesture,
        resting=gesture == G.NONE,
        intensity_mm=mm,
        translation_mm=np.array(direction, dtype=float),
    )


def profile(layers=None, **mappings) -> Profile:
    return Profile.model_validate({"mappings": mappings, "layers": layers or {}})


@pytest.mark.parametrize("alias, code", [("A", "BTN_SOUTH"), ("B", "BTN_EAST"), ("X", "BTN_NORTH"), ("Y", "BTN_WEST")])
def test_face_aliases_press_their_evdev_buttons(alias, code):
    state = Mapper(profile(m={"input": "pinch", "output": alias})).update(est(G.PINCH, 3.0))
    assert [b for b, v in state.buttons.items() if v] == [code]


def test_xpad_x_is_btn_north():
    from evdev import ecodes

    assert ecodes.BTN_X == ecodes.BTN_NORTH and ecodes.BTN_Y == ecodes.BTN_WEST


@pytest.mark.parametrize(
    "output, keys",
    [
        ("KEY_SPACE", {"KEY_SPACE"}),
        ("KEY_LEFTSHIFT+KEY_TAB", {"KEY_LEFTSHIFT", "KEY_TAB"}),
        ("BTN_LEFT", {"BTN_LEFT"}),
    ],
)
def test_keys_and_mouse_buttons_go_to_state_keys(output, keys):
    mapper = Mapper(profile(m={"input": "zoom", "output": output}))
    down = mapper.update(est(G.ZOOM, 3.0))
    assert down.keys == keys and not any(down.buttons.values())
    assert mapper.update(est(G.NONE, 0.0, 10 * MS)).keys == frozenset()


@pytest.mark.parametrize(
    "anti, mm, fraction",
    [
        (0.0, 1.0, 0.0),
        (0.2, 1.0, 0.0),  # inside the dead zone: still 0
        (0.2, 1.5, 0.2 + 0.8 * 0.125),  # just past it: at least the anti-deadzone
        (0.2, 5.0, 1.0),
        (0.0, 3.0, 0.5),
        (0.3, 3.0, 0.3 + 0.7 * 0.5),
    ],
)
def test_anti_deadzone_lifts_every_non_zero_output(anti, mm, fraction):
    m = {"input": "twist", "output": "ABS_RX", "deadzone_mm": 1.0, "saturation_mm": 5.0, "anti_deadzone": anti}
    state = Mapper(profile(m=m)).update(est(G.TWIST_CCW, mm))
    assert state.axes["ABS_RX"] == round(fraction * AXES["ABS_RX"][1])


def test_rel_motion_integrates_velocity_over_camera_time_and_keeps_the_fraction():
    motion = RelMotion()
    steps = [motion.step(150.0, t) for t in range(0, 100_001, 10_000)]  # 150 counts/s for 0.1 s
    assert steps[0] == 0 and sum(steps) == 15 and set(steps[1:]) == {1, 2}
    assert motion.step(0.0, 110_000) == 0 and motion.step(-150.0, 120_000) == -1


def test_rel_motion_caps_a_gap():
    motion = RelMotion()
    motion.step(1000.0, 0)
    assert motion.step(1000.0, 5_000_000) == 100  # 0.1 s at most, not 5 s


def test_pointer_moves_with_the_push_direction_up_is_negative_rel_y():
    m = {"input": "push", "output": "pointer", "deadzone_mm": 0.0, "saturation_mm": 4.0, "speed": 1000.0}
    mapper = Mapper(profile(m=m))
    total = {"REL_X": 0, "REL_Y": 0}
    for k in range(11):  # push up-right at full deflection for 100 ms
        state = mapper.update(est(G.PUSH, 8.0, k * 10 * MS, direction=(0.6, 0.8)))
        for name in total:
            total[name] += state.rel.get(name, 0)
    assert total == {"REL_X": 60, "REL_Y": -80}
    assert mapper.update(est(G.NONE, 0.0, 120 * MS)).rel == {}


def test_twist_scrolls_in_hi_res_units_and_whole_detents():
    m = {"input": "twist", "output": "REL_WHEEL", "deadzone_mm": 0.0, "saturation_mm": 4.0, "speed": 10.0}
    mapper = Mapper(profile(m=m))
    hi, detents = 0, 0
    for k in range(26):  # 250 ms at 10 detents/s = 2.5 detents = 300 hi-res units
        state = mapper.update(est(G.TWIST_CCW, 4.0, k * 10 * MS))
        hi += state.rel.get("REL_WHEEL_HI_RES", 0)
        detents += state.rel.get("REL_WHEEL", 0)
    assert hi == 300 and detents == 2 == hi // HI_RES_PER_DETENT
    clockwise = Mapper(profile(m=m))
    states = [clockwise.update(est(G.TWIST_CW, 4.0, k * 10 * MS)) for k in range(26)]
    assert sum(s.rel.get("REL_WHEEL", 0) for s in states) == -2


def test_short_twists_add_up_to_whole_detents_as_the_kernel_counts_them():
    """Four counter-clockwise twists of 0.6-0.7 detent each, the gel resting in between: 324 hi-res
    units and the 2 detents a program reading only REL_WHEEL scrolls (the kernel's hid-input keeps
    the remainder between turns the same way); back by half a detent after 1.5: no detent down."""
    m = {"input": "twist", "output": "REL_WHEEL", "deadzone_mm": 0.0, "saturation_mm": 4.0, "speed": 10.0}
    mapper = Mapper(profile(m=m))
    hi, detents, t = 0, 0, 0
    for _ in range(4):
        for k in range(7):  # 70 ms at 10 detents/s, 84 hi-res units (60 ms, 72, the very first)
            state = mapper.update(est(G.TWIST_CCW, 4.0, t + k * 10 * MS))
            hi += state.rel.get("REL_WHEEL_HI_RES", 0)
            detents += state.rel.get("REL_WHEEL", 0)
        for k in range(7, 30):
            state = mapper.update(est(G.NONE, 0.0, t + k * 10 * MS))
            assert not state.rel
        t += 300 * MS
    assert hi == 72 + 3 * 84 and detents == 2 == hi // HI_RES_PER_DETENT
    back = Mapper(profile(m=m))
    states = [back.update(est(G.TWIST_CCW, 4.0, k * 10 * MS)) for k in range(16)]  # 180 units: 1 detent
    states += [back.update(est(G.TWIST_CW, 4.0, (16 + k) * 10 * MS)) for k in range(6)]  # 60 back (50 counted)
    assert sum(s.rel.get("REL_WHEEL", 0) for s in states) == 1


def test_profile_test_counts_a_wheel_that_scrolled_less_than_a_detent_as_reached():
    """The summary of ``profile test``: a twist of half a detent moved the hi-res wheel (what
    desktops scroll by), so the wheel is reached, its hi-res units named."""
    from neurotouch_hid.mapping.replay import reach, replay

    m = {"input": "twist", "output": "REL_WHEEL", "deadzone_mm": 0.0, "saturation_mm": 4.0, "speed": 10.0}
    states = replay(profile(m=m), [est(G.TWIST_CCW, 4.0, k * 10 * MS) for k in range(6)])
    (wheel,) = reach(profile(m=m), states)
    assert wheel.reached and wheel.detail == "REL_WHEEL 0 counts, REL_WHEEL_HI_RES 60 counts"


def test_tune_sets_a_triggers_saturation_from_the_side_the_trigger_takes():
    """pinch_zoom on RT (zoom pulls it, pinch does nothing): a user's zooms of 2 mm and pinches of
    9 mm give a saturation of 2 mm, not 9 (the zoom would then pull RT to a fifth)."""
    from neurotouch_hid.mapping.replay import tuned_saturations

    rt = {"input": "pinch_zoom", "output": "ABS_RZ", "deadzone_mm": 0.5}
    gestures = [est(G.ZOOM, 2.0, k * 10 * MS) for k in range(20)] + [est(G.PINCH, 9.0, k * 10 * MS) for k in range(20)]
    assert tuned_saturations(profile(rt=rt), gestures)["rt"] == (8.0, 2.0)
    inverted = tuned_saturations(profile(rt={**rt, "invert": True}), gestures)["rt"]
    assert inverted == (8.0, 9.0)


# --- layers -------------------------------------------------------------------------------------
LAYERED = dict(
    layers={"nav": {"input": "pinch", "mode": "hold", "press_mm": 2.0, "release_mm": 1.0}},
    fire={"input": "push_intensity", "output": "KEY_SPACE"},
    fire_nav={"input": "push_intensity", "output": "KEY_ENTER", "layer": "nav"},
    toggled={"input": "zoom", "output": "BTN_SOUTH", "mode": "toggle"},
)


def test_a_layer_switch_releases_everything_of_the_old_layer_first():
    mapper = Mapper(profile(**LAYERED))
    assert mapper.update(est(G.ZOOM, 3.0, 0)).buttons["BTN_SOUTH"]  # toggled on in base
    assert mapper.update(est(G.NONE, 0.0, 10 * MS)).buttons["BTN_SOUTH"]  # stays on
    switch = mapper.update(est(G.PINCH, 3.0, 20 * MS))  # pinch: to nav
    assert mapper.layer == "nav" and switch.is_neutral()
    assert not mapper.update(est(G.PINCH, 3.0, 30 * MS)).buttons["BTN_SOUTH"]  # base's mappings are off in nav
    assert mapper.update(est(G.NONE, 0.0, 40 * MS)).is_neutral() and mapper.layer == "base"  # pinch let go


def test_toggled_layer_maps_the_same_gesture_to_another_key_and_back():
    spec = dict(LAYERED, layers={"nav": {"input": "pinch", "mode": "toggle"}})
    mapper = Mapper(profile(**spec))
    assert mapper.update(est(G.PUSH, 3.0, 0)).keys == {"KEY_SPACE"}
    # one window of pinch inside the push is the push still (Mapper._confirmed): no switch yet
    assert mapper.update(est(G.PINCH, 3.0, 10 * MS)).keys == {"KEY_SPACE"} and mapper.layer == "base"
    assert mapper.update(est(G.PINCH, 3.0, 20 * MS)).is_neutral()  # switch: KEY_SPACE released first
    assert mapper.layer == "nav"
    assert mapper.update(est(G.NONE, 0.0, 30 * MS)).is_neutral()
    assert mapper.update(est(G.PUSH, 3.0, 40 * MS)).keys == {"KEY_ENTER"}
    assert mapper.update(est(G.PINCH, 3.0, 50 * MS)).keys == {"KEY_ENTER"}
    assert mapper.update(est(G.PINCH, 3.0, 60 * MS)).is_neutral()  # back to base: KEY_ENTER released
    assert mapper.layer == "base"
    assert not mapper.update(est(G.NONE, 0.0, 70 * MS)).buttons["BTN_SOUTH"]


# --- validation ---------------------------------------------------------------------------------
@pytest.mark.parametrize(
    "text, expected",
    [
        (
            "mappings:\n  m: {input: zoom, output: KEY_SPACEE}\n",
            "q.yaml:2: mappings.m.output: found 'KEY_SPACEE'; expected a pad button",
        ),
        (
            "mappings:\n  m: {input: zoom, output: A+KEY_A}\n",
            "q.yaml:2: mappings.m.output: found 'A+KEY_A'; expected a chord",
        ),
        (
            "mappings:\n  m:\n    input: zoom\n    output: KEY_A\n    layer: fn\n",
            "q.yaml:5: mappings.m.layer: found 'fn'; expected 'base' or a layer",
        ),
        (
            "mappings:\n  m:\n    input: zoom\n    output: KEY_A\n    mode: turbo\n    turbo_hz: 80\n",
            "q.yaml:6: mappings.m.turbo_hz: found 80; expected less than or equal to 50",
        ),
        (
            "mappings:\n  m:\n    input: zoom\n    output: ABS_RX\n    anti_deadzone: 1.0\n",
            "q.yaml:5: mappings.m.anti_deadzone: found 1.0; expected less than 1",
        ),
        (
            "mappings:\n  m:\n    input: twist\n    output: pointer\n",
            "q.yaml:3: mappings.m.input: found 'twist'; expected 'push' or 'contact'",
        ),
        (
            "layers:\n  nav:\n    input: pinch\n    dwell_ms: 3\n",
            "q.yaml:4: layers.nav.dwell_ms: unknown field (found 3); expected a known field: one of input",
        ),
        (
            "mappings:\n  m: {input: zoom, output: KEY_A, dwel_ms: 300}\n",
            "q.yaml:2: mappings.m.dwel_ms: unknown field (found 300; did you mean 'dwell_ms'?); expected a known field",
        ),
    ],
)
def test_remapping_errors_name_file_line_field_and_expectation(text, expected):
    with pytest.raises(ProfileError) as info:
        parse_profile(text, "q.yaml")
    assert expected in str(info.value), str(info.value)


def test_devices_are_needed_only_when_used():
    pad_only = profile(m={"input": "zoom", "output": "A"})
    assert not pad_only.uses_keyboard and not pad_only.uses_mouse
    assert profile(m={"input": "zoom", "output": "KEY_A"}).uses_keyboard
    assert profile(m={"input": "push", "output": "pointer"}).uses_mouse
    assert profile(m={"input": "zoom", "output": "BTN_RIGHT"}).uses_mouse


# --- the shipped profiles -----------------------------------------------------------------------
def hold_gesture(
    gesture: GestureType, mm: float, seconds: float, t0_ms: int = 0, direction=(1.0, 0.0)
) -> list[GestureEstimate]:
    """10 ms windows: ``seconds`` of the gesture at ``mm``, then 0.3 s of rest."""
    n, rest = int(seconds * 100), 30
    return [est(gesture, mm, (t0_ms + 10 * k) * MS, direction) for k in range(n)] + [
        est(G.NONE, 0.0, (t0_ms + 10 * (n + k)) * MS) for k in range(rest)
    ]


def test_shipped_mouse_profile_push_moves_the_pointer_pinch_zoom_click_twist_scrolls():
    mapper = Mapper(load_profile("mouse"))
    states = [mapper.update(e) for e in hold_gesture(G.PUSH, 6.0, 0.5, direction=(-0.6, 0.8))]  # up-left
    dx, dy = (sum(s.rel.get(n, 0) for s in states) for n in ("REL_X", "REL_Y"))
    assert dx < -50 and dy < -50 and abs(dx / dy - 0.75) < 0.1, (dx, dy)
    assert states[-1].rel == {} and not states[-1].keys
    for gesture, button in ((G.PINCH, "BTN_LEFT"), (G.ZOOM, "BTN_RIGHT")):
        states = [mapper.update(e) for e in hold_gesture(gesture, 4.0, 0.2, t0_ms=10_000 * (1 + len(button)))]
        assert any(s.keys == {button} for s in states) and not states[-1].keys
    states = [mapper.update(e) for e in hold_gesture(G.TWIST_CCW, 6.0, 0.5, t0_ms=50_000)]
    assert sum(s.rel.get("REL_WHEEL", 0) for s in states) >= 2
    assert sum(s.rel.get("REL_WHEEL_HI_RES", 0) for s in states) >= 240


@pytest.mark.parametrize(
    "gesture, keys",
    [
        (G.PUSH, {"KEY_SPACE"}),
        (G.TWIST_CW, {"KEY_TAB"}),
        (G.TWIST_CCW, {"KEY_LEFTSHIFT", "KEY_TAB"}),
        (G.PINCH, {"KEY_ENTER"}),
        (G.ZOOM, {"KEY_ESC"}),
    ],
)
def test_shipped_switch_access_profile_needs_a_dwell_and_releases(gesture, keys):
    profile = load_profile("switch-access")
    tremor = Mapper(profile)
    assert not any(tremor.update(e).keys for e in hold_gesture(gesture, 4.0, 0.25))  # shorter than the dwell
    mapper = Mapper(profile)
    states = [mapper.update(e) for e in hold_gesture(gesture, 4.0, 0.6)]
    down = [s.t_us for s in states if s.keys]
    assert all(s.keys == keys for s in states if s.keys)
    # typed once: down at the dwell for tap_ms (100 ms), then up while the gesture is still held
    assert down[0] == 300 * MS and down[-1] == 390 * MS and not states[-1].keys
    assert not any(any(s.buttons.values()) for s in states)


@pytest.mark.parametrize(
    "mapping, says",
    [
        ("{input: pinch, output: KEY_ENTER, press_mm: 0.6}", "press_mm (0.6) is below release_mm (1, the default)"),
        ("{input: twist, output: ABS_RX, deadzone_mm: 8.0}", "deadzone_mm (8) must be below the saturation (8 mm"),
    ],
)
def test_a_default_that_breaks_the_given_value_is_refused_with_what_to_give(mapping, says):
    """press_mm 0.6 under the default release_mm 1 pressed and released every window of a steady
    pinch (50 presses a second); a dead zone at the default saturation divided by zero."""
    from neurotouch_hid.core.errors import ProfileError
    from neurotouch_hid.mapping.profile import parse_profile

    with pytest.raises(ProfileError, match=re.escape(says)):
        parse_profile(f"mappings:\n  a: {mapping}\n", "p.yaml")
