"""A gesture whose type changes under the profile: the old type's outputs are released in the
very state the new type's begin (never both held), and a button both types press stays held
through the change (no release a toggle or a game would read as a new press)."""

from __future__ import annotations

import numpy as np
import pytest

from neurotouch_hid.core.estimate import GestureEstimate, GestureType
from neurotouch_hid.mapping.mapper import Mapper
from neurotouch_hid.mapping.profile import Profile, load_profile
from neurotouch_hid.mapping.replay import pressed, replay

G = GestureType
SMOOTH = {"filter": "one_euro", "min_cutoff_hz": 2.0, "beta": 0.05, "d_cutoff_hz": 1.0}


def windows(*parts: tuple[GestureType, float, int], direction=(0.0, 1.0)) -> list[GestureEstimate]:
    """Consecutive 10 ms windows: (type, intensity mm, how many) per part, the gel never at rest
    in between; then 30 windows at rest."""
    out, t = [], 1_000_000
    for kind, mm, n in (*parts, (G.NONE, 0.0, 30)):
        for _ in range(n):
            t += 10_000
            out.append(GestureEstimate(t, kind, kind is G.NONE and mm == 0.0, mm, translation_mm=np.array(direction)))
    return out


def test_default_profile_stick_and_trigger_never_both_held():
    """default: push -> left stick, pinch -> left trigger, both smoothed by a 1-euro filter (a
    decaying filter used to hold the stick for ~100 ms of pinch)."""
    est = windows((G.PUSH, 3.0, 40), (G.PINCH, 3.0, 40), (G.PUSH, 3.0, 40))
    states = replay(load_profile("default"), est)
    stick = [s.axes["ABS_Y"] != 0 or s.axes["ABS_X"] != 0 for s in states]
    trigger = [s.axes["ABS_Z"] > 0 for s in states]
    assert not any(a and b for a, b in zip(stick, trigger))
    # and no gap: the second pinch window in a row pulls the trigger (the first is still the push,
    # Mapper._confirmed), the second push window after it moves the stick
    assert stick[40] and not trigger[40] and trigger[41] and not stick[41]
    assert trigger[80] and not stick[80] and stick[81] and not trigger[81]
    assert all(stick[:41]) and all(trigger[41:81]) and all(stick[81:120])


def test_a_none_window_inside_the_gesture_does_not_leave_both_held():
    est = windows((G.TWIST_CCW, 4.0, 30), (G.NONE, 4.0, 2), (G.ZOOM, 4.0, 30))
    states = replay(load_profile("default"), est)
    assert not any(s.axes["ABS_RX"] != 0 and s.axes["ABS_RZ"] > 0 for s in states)
    assert states[32].axes["ABS_RX"] != 0 and states[33].axes["ABS_RZ"] > 0  # from the second zoom window


def two_types_one_button(mode: str) -> Profile:
    button = {"output": "BTN_SOUTH", "mode": mode, "press_mm": 2.0, "release_mm": 1.0, "smoothing": SMOOTH}
    return Profile.model_validate({"mappings": {"a": {"input": "pinch", **button}, "b": {"input": "zoom", **button}}})


@pytest.mark.parametrize("second_mm", [3.0, 1.5])
def test_a_button_both_types_press_stays_held(second_mm):
    """pinch and zoom both hold A; the zoom after the pinch is at 1.5 mm, between release (1.0)
    and press (2.0): A stays down through the change, one press in all."""
    est = windows((G.PINCH, 3.0, 30), (G.ZOOM, second_mm, 30))
    down = ["BTN_SOUTH" in pressed(s) for s in replay(two_types_one_button("hold"), est)]
    assert all(down[:60]) and not down[-1]
    assert rising_edges(down) == 1


def rising_edges(down: list[bool]) -> int:
    return sum(1 for a, b in zip([False, *down], down) if b and not a)


def accessibility_with_toggles() -> Profile:
    """The shipped accessibility profile with its twists toggling A and B instead of tapping."""
    from neurotouch_hid.mapping.profile import find_profile, parse_profile

    text = find_profile("accessibility").read_text(encoding="utf-8")
    assert text.count("mode: tap") == 2
    return parse_profile(text.replace("mode: tap", "mode: toggle").replace("    tap_ms: 150\n", ""), "toggles.yaml")


def test_a_toggle_flips_once_however_the_type_flickers():
    """accessibility with toggles: a counter-clockwise twist toggles A. One twist read as pinch for 150 ms in
    its middle: A toggles on once and stays on (the twist's return is no new press)."""
    est = windows((G.TWIST_CCW, 4.0, 30), (G.PINCH, 4.0, 15), (G.TWIST_CCW, 4.0, 30))
    down = ["BTN_SOUTH" in pressed(s) for s in replay(accessibility_with_toggles(), est)]
    assert rising_edges(down) == 1 and down[-1]


def test_a_toggle_shared_by_two_types_flips_once():
    est = windows((G.PINCH, 3.0, 30), (G.ZOOM, 3.0, 30), (G.PINCH, 3.0, 30))
    mapper = Mapper(two_types_one_button("toggle"))
    down = ["BTN_SOUTH" in pressed(mapper.update(e)) for e in est]
    assert all(down)  # on from the first pinch window, never back off


def test_a_new_gesture_of_the_same_button_is_a_new_press():
    """Only a change inside a gesture is carried: pinch, rest, zoom presses A twice."""
    est = windows((G.PINCH, 3.0, 30))
    est += [
        GestureEstimate(e.t_us + 1_000_000, e.gesture, e.resting, e.intensity_mm) for e in windows((G.ZOOM, 3.0, 30))
    ]
    mapper = Mapper(two_types_one_button("hold"))
    down = ["BTN_SOUTH" in pressed(mapper.update(e)) for e in est]
    assert rising_edges(down) == 2


def test_the_same_type_after_the_gesture_ended_is_a_new_press():
    """A twist read as pinch at its end, the fingers off (none windows, the gel not yet at rest),
    then a new twist: the toggle flips again (twice in all: off at the end)."""
    est = windows((G.TWIST_CCW, 4.0, 30), (G.PINCH, 4.0, 10), (G.NONE, 0.5, 5), (G.TWIST_CCW, 4.0, 30))
    down = ["BTN_SOUTH" in pressed(s) for s in replay(accessibility_with_toggles(), est)]
    assert rising_edges(down) == 1 and not down[-1]


def onset_windows(contact_mm=(6.0, 0.0)) -> list[GestureEstimate]:
    """A pinch's onset as the pipeline answers it while its second finger is awaited: its first
    finger answered push below the provisional limit (3 windows), then undecided (``none`` with
    its intensity and contact, 6 windows), then the pinch (20 windows), then rest."""
    parts = [(G.PUSH, 0.3, 3), (G.NONE, 0.7, 6), (G.PINCH, 2.5, 20), (G.NONE, 0.0, 30)]
    out, t = [], 1_000_000
    contact = np.array([contact_mm], dtype=float)
    for kind, mm, n in parts:
        for _ in range(n):
            t += 10_000
            c = contact if mm > 0 else np.zeros((0, 2))
            out.append(GestureEstimate(t, kind, mm == 0.0, mm, contacts_px=c.copy(), contacts_mm=c))
    return out


def test_a_contact_mapping_neither_waits_for_the_type_nor_drops_while_it_is_decided():
    """contact_x -> a toggle and the right stick: the finger's position counts from the first
    window the gel moves, through the undecided windows, to the pinch: one toggle, the stick
    never back at the centre before the fingers leave."""
    toggle = {"input": "contact_x", "output": "BTN_NORTH", "mode": "toggle", "press_mm": 2.0, "release_mm": 1.0}
    stick = {"input": "contact", "output": "right_stick", "deadzone_mm": 0.5, "saturation_mm": 30.0}
    profile = Profile.model_validate({"mappings": {"t": toggle, "s": stick}})
    states = replay(profile, onset_windows())
    down = ["BTN_NORTH" in pressed(s) for s in states]
    assert rising_edges(down) == 1 and down[-1]
    moved = [s.axes["ABS_RX"] != 0 for s in states]
    assert all(moved[:29]) and not moved[-1]


def test_an_undecided_window_moves_no_output_of_a_type():
    """The same onset through default: nothing from the push below its dead zone, nothing while
    undecided, then the left trigger from the pinch; the stick never moves."""
    states = replay(load_profile("default"), onset_windows())
    assert not any(s.axes["ABS_X"] or s.axes["ABS_Y"] for s in states)
    trigger = [s.axes["ABS_Z"] > 0 for s in states]
    assert not any(trigger[:9]) and trigger[9]


def two_types_one_button_timed(mode: str, **timing) -> Profile:
    button = {"output": "BTN_SOUTH", "mode": mode, "press_mm": 2.0, "release_mm": 1.0, **timing}
    return Profile.model_validate({"mappings": {"a": {"input": "pinch", **button}, "b": {"input": "zoom", **button}}})


def down_windows(profile: Profile, est: list[GestureEstimate]) -> list[bool]:
    return ["BTN_SOUTH" in pressed(s) for s in replay(profile, est)]


def test_a_long_press_goes_on_through_the_change():
    """Two long presses (300 ms) on A: a pinch held 490 ms that the pipeline then reads as zoom
    for 400 ms. A is down from 300 ms to the end of the gesture, one press (not let go at the
    change and pressed again 300 ms later)."""
    est = windows((G.PINCH, 3.0, 49), (G.ZOOM, 3.0, 40))
    down = down_windows(two_types_one_button_timed("long_press", dwell_ms=300), est)
    assert not any(down[:30]) and all(down[30:89]) and not down[89]
    assert rising_edges(down) == 1


def test_a_long_press_dwell_under_way_counts_from_the_hold_start():
    """The type changes 200 ms into a 300 ms dwell: A goes down 300 ms after the hold began, not
    300 ms after the change (a flicker must not lengthen the wait)."""
    est = windows((G.PINCH, 3.0, 20), (G.ZOOM, 3.0, 40))
    down = down_windows(two_types_one_button_timed("long_press", dwell_ms=300), est)
    assert not any(down[:30]) and all(down[30:60])
    assert rising_edges(down) == 1


def test_a_tap_keystroke_keeps_its_length_through_the_change():
    """Taps of 150 ms: the type changes 50 ms into the keystroke. It lasts its 150 ms, once."""
    down = down_windows(two_types_one_button_timed("tap", tap_ms=150), windows((G.PINCH, 3.0, 5), (G.ZOOM, 3.0, 30)))
    assert all(down[:15]) and not any(down[15:])
    assert rising_edges(down) == 1


def test_a_tap_is_one_keystroke_per_gesture_whatever_the_type():
    """The keystroke is over when the type changes: the new type gives no second one."""
    down = down_windows(two_types_one_button_timed("tap"), windows((G.PINCH, 3.0, 30), (G.ZOOM, 3.0, 30)))
    assert all(down[:10]) and rising_edges(down) == 1


def test_a_double_press_second_press_goes_on_through_the_change():
    """A double press: a pinch, let go (0.5 mm, the gel not at rest), a second pinch that turns to
    zoom half-way: A is down for the whole second press, once."""
    est = windows((G.PINCH, 3.0, 10), (G.NONE, 0.5, 5), (G.PINCH, 3.0, 10), (G.ZOOM, 3.0, 10))
    down = down_windows(two_types_one_button_timed("double_press"), est)
    assert not any(down[:15]) and all(down[15:35]) and not down[35]
    assert rising_edges(down) == 1


def test_the_old_type_back_below_its_press_threshold_goes_on_holding():
    """Hysteresis holds through the flicker: a pinch eased to 1.5 mm (between release 1.0 and
    press 2.0), read as zoom, then as pinch again at 1.5 mm: A stays down throughout, one press."""
    est = windows((G.PINCH, 3.0, 10), (G.PINCH, 1.5, 10), (G.ZOOM, 1.5, 10), (G.PINCH, 1.5, 10), (G.PINCH, 3.0, 10))
    down = down_windows(two_types_one_button_timed("hold"), est)
    assert all(down[:50]) and not down[50]
    assert rising_edges(down) == 1
    # zoom on another button: A is let go while zoom is read, and pinch's return at 1.5 mm is its hold going on
    a = {"input": "pinch", "output": "BTN_SOUTH", "press_mm": 2.0, "release_mm": 1.0}
    b = {"input": "zoom", "output": "BTN_EAST", "press_mm": 2.0, "release_mm": 1.0}
    down = down_windows(Profile.model_validate({"mappings": {"a": a, "b": b}}), est)
    assert all(down[:21]) and not any(down[21:31]) and all(down[31:50])  # each type from its second window


ARROWS = """
layers:
  arrows: {input: pinch, mode: toggle, press_mm: 2.5, release_mm: 1.2}
mappings:
  scroll: {input: twist, output: REL_WHEEL}
  up: {input: twist_ccw, output: KEY_UP, layer: arrows}
  down: {input: twist_cw, output: KEY_DOWN, layer: arrows}
"""


def layers_of(profile: Profile, est: list[GestureEstimate]) -> list[str]:
    mapper, out = Mapper(profile), []
    for e in est:
        mapper.update(e)
        out.append(mapper.layer)
    return out


def test_a_layer_toggle_flips_once_however_the_type_flickers():
    """docs/profiles.md's layer example: one pinch read as push for 20 ms in its middle turns the
    layer on once (not on, then off at the pinch's return); the next pinch turns it off."""
    from neurotouch_hid.mapping.profile import parse_profile

    profile = parse_profile(ARROWS, "arrows.yaml")
    one = windows((G.PINCH, 3.0, 5), (G.PUSH, 3.0, 2), (G.PINCH, 3.0, 5))
    layers = layers_of(profile, one)
    assert layers[0] == "arrows" and set(layers) == {"arrows"}
    later = windows((G.PINCH, 3.0, 5))
    again = one + [GestureEstimate(e.t_us + 1_000_000, e.gesture, e.resting, e.intensity_mm) for e in later]
    assert layers_of(profile, again)[-1] == "base"


def test_a_held_layer_stays_through_a_flicker_of_its_gesture():
    """A layer held by zoom: one window read as pinch does not drop the layer (each drop releases
    everything: the trigger would fall to 0 for that window)."""
    from neurotouch_hid.mapping.profile import parse_profile

    text = "layers:\n  aim: {input: zoom, mode: hold}\nmappings:\n  fire: {input: intensity, output: RT, layer: aim}\n"
    states = replay(parse_profile(text, "aim.yaml"), windows((G.ZOOM, 3.0, 5), (G.PINCH, 3.0, 1), (G.ZOOM, 3.0, 5)))
    trigger = [s.axes["ABS_RZ"] for s in states]
    assert trigger[0] == 0 and all(v > 0 for v in trigger[1:11]) and trigger[-1] == 0
