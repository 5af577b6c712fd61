"""Switch access: one gesture, one keystroke (``mode: tap``), and fields no activator reads are
refused. A key held for a whole gesture is repeated by X11 and Wayland clients after ~500 ms,
so a switch user's one push typed several spaces."""

from __future__ import annotations

import numpy as np
import pytest

from neurotouch_hid.core.errors import ProfileError
from neurotouch_hid.core.estimate import GestureEstimate, GestureType
from neurotouch_hid.mapping.activator import Activator
from neurotouch_hid.mapping.profile import MAX_TAP_MS, load_profile, parse_profile
from neurotouch_hid.mapping.replay import pressed, replay

G = GestureType
MS = 1000


def held(*spans: tuple[int, int], until: int, step: int = 10) -> list[tuple[int, float]]:
    return [(t, 3.0 if any(a <= t < b for a, b in spans) else 0.0) for t in range(0, until, step)]


def down_at(samples, **kw) -> list[int]:
    act = Activator("tap", 2.0, 1.0, **kw)
    return [t for t, v in samples if act.update(v, t * MS)]


@pytest.mark.parametrize(
    "kw, spans, down",
    [
        ({"dwell_ms": 0, "tap_ms": 50}, [(0, 1600)], [0, 10, 20, 30, 40]),  # one keystroke however long the hold
        ({"dwell_ms": 300, "tap_ms": 100}, [(0, 1600)], list(range(300, 400, 10))),  # after the dwell
        ({"dwell_ms": 300, "tap_ms": 100}, [(0, 200)], []),  # let go before the dwell: nothing
        ({"dwell_ms": 300, "tap_ms": 100}, [(0, 340)], [300, 310, 320, 330]),  # let go during the tap: up
        ({"dwell_ms": 0, "tap_ms": 30}, [(0, 100), (200, 300)], [0, 10, 20, 200, 210, 220]),  # one per hold
    ],
)
def test_tap_types_once_per_hold(kw, spans, down):
    assert down_at(held(*spans, until=2000), **kw) == down


def gesture(kind: GestureType, seconds: float, mm: float = 5.0, t0_us: int = 1_000_000) -> list[GestureEstimate]:
    """Windows of 10 ms: ``seconds`` of ``kind`` at ``mm``, then 1 s at rest."""
    out = []
    n = int(seconds * 100)
    for i in range(n + 100):
        t = t0_us + i * 10_000
        if i < n:
            out.append(GestureEstimate(t, kind, False, mm, translation_mm=np.array((0.0, 1.0))))
        else:
            out.append(GestureEstimate(t, G.NONE, True, 0.0))
    return out


def longest_press_ms(states) -> dict[str, float]:
    """Per output pressed: its longest continuous press (ms), from the states' times."""
    longest: dict[str, float] = {}
    since: dict[str, int] = {}
    for s in states:
        now = set(pressed(s))
        for name in now - set(since):
            since[name] = s.t_us
        for name in set(since) - now:
            longest[name] = max(longest.get(name, 0.0), (s.t_us - since.pop(name)) / 1000)
    assert not since, f"still pressed at the end: {since}"
    return longest


@pytest.mark.parametrize("kind", [G.PUSH, G.TWIST_CW, G.TWIST_CCW, G.PINCH, G.ZOOM])
def test_switch_access_presses_each_key_at_most_250_ms_per_gesture(kind):
    """A 1.6 s gesture (what the simulated hand makes) through the shipped profile: its key goes
    down once, after the dwell, and up again within 250 ms."""
    states = replay(load_profile("switch-access"), gesture(kind, 1.6))
    longest = longest_press_ms(states)
    assert longest, "the gesture pressed nothing"
    assert max(longest.values()) <= MAX_TAP_MS, longest
    downs = sum(1 for a, b in zip(states, states[1:]) if pressed(b) and not pressed(a))
    assert downs == 1


def test_accessibility_leaves_no_button_latched_after_a_twist_each_way():
    states = replay(
        load_profile("accessibility"), gesture(G.TWIST_CCW, 1.0) + gesture(G.TWIST_CW, 1.0, t0_us=4_000_000)
    )
    longest = longest_press_ms(states)
    assert set(longest) >= {"BTN_SOUTH", "BTN_EAST"}, longest
    assert max(longest[b] for b in ("BTN_SOUTH", "BTN_EAST")) <= MAX_TAP_MS
    assert not pressed(states[-1])


def mapping(**fields) -> str:
    return "mappings:\n  m:\n" + "".join(f"    {k}: {v}\n" for k, v in fields.items())


@pytest.mark.parametrize(
    "fields, line, expected",
    [
        (
            {"input": "pinch", "output": "KEY_A", "dwell_ms": 300},
            5,
            "mappings.m.dwell_ms: found 300; expected no dwell_ms under mode 'hold'",
        ),
        ({"input": "pinch", "output": "KEY_A", "mode": "toggle", "turbo_hz": 5}, 6, "no turbo_hz under mode 'toggle'"),
        ({"input": "pinch", "output": "KEY_A", "mode": "turbo", "double_press_ms": 5}, 6, "only double_press reads it"),
        (
            {"input": "pinch", "output": "KEY_A", "mode": "long_press", "tap_ms": 50},
            6,
            "(set mode: tap, or remove tap_ms)",
        ),
        (
            {"input": "pinch", "output": "KEY_A", "mode": "tap", "tap_ms": 400},
            6,
            "tap_ms: found 400; expected less than or equal to 250",
        ),
    ],
)
def test_a_field_the_mode_does_not_read_is_refused_on_its_line(fields, line, expected):
    with pytest.raises(ProfileError) as err:
        parse_profile(mapping(**fields), "q.yaml")
    assert f"q.yaml:{line}: " in str(err.value) and expected in str(err.value), str(err.value)


@pytest.mark.parametrize("mode, field", [("long_press", "dwell_ms"), ("tap", "dwell_ms"), ("tap", "tap_ms")])
def test_a_field_the_mode_reads_is_taken(mode, field):
    profile = parse_profile(mapping(input="pinch", output="KEY_A", mode=mode, **{field: 120}), "q.yaml")
    assert getattr(profile.mappings["m"], field) == 120.0


def test_a_chords_key_is_not_counted_as_a_press_of_that_key_alone():
    """``profile test switch-access`` said KEY_TAB "2 presses" for one clockwise twist: the
    counter-clockwise twist's Shift+Tab holds Tab too. A key down inside a chord the profile maps
    is that chord's press, not the key's."""
    from neurotouch_hid.core.controller import ControllerState
    from neurotouch_hid.mapping.replay import reach

    keys = [(), ("KEY_LEFTSHIFT", "KEY_TAB"), (), ("KEY_TAB",), (), ("KEY_LEFTSHIFT", "KEY_TAB"), ()]
    states = [ControllerState(t_us=i * 10_000, keys=frozenset(k)) for i, k in enumerate(keys)]
    detail = {r.output: r.detail for r in reach(load_profile("switch-access"), states)}
    assert detail["KEY_TAB"] == "1 press", detail
    assert detail["KEY_LEFTSHIFT+KEY_TAB"] == "2 presses", detail
    assert detail["KEY_SPACE"] == "0 presses", detail
