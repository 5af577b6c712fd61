"""A profile's ``touchpad:``: the schema and its errors (file, line, field, what was expected), the
contact points followed as touch points (mapping/touchpad.py: slots, tracking ids, lifts) and the
click, through the Mapper into the ControllerState, and the shipped profile that uses it."""

from __future__ import annotations

import numpy as np
import pytest

from neurotouch_hid.core.controller import ControllerState, TouchPoint
from neurotouch_hid.core.errors import ProfileError
from neurotouch_hid.core.estimate import GestureEstimate, GestureType
from neurotouch_hid.mapping.mapper import Mapper
from neurotouch_hid.mapping.merge import merge_state
from neurotouch_hid.mapping.profile import TouchpadMapping, load_profile, parse_profile
from neurotouch_hid.mapping.touchpad import TouchTracker, pad_position


def estimate(t_ms: int, contacts=(), intensity=1.0, gesture=GestureType.NONE, resting=False) -> GestureEstimate:
    points = np.asarray(contacts, dtype=np.float64).reshape(-1, 2)
    return GestureEstimate(
        t_us=t_ms * 1000,
        gesture=gesture,
        resting=resting,
        intensity_mm=intensity,
        contacts_px=points.copy(),
        contacts_mm=points,
        translation_mm=np.array((0.0, 1.0)),
    )


@pytest.mark.parametrize(
    "text, expected",
    [
        ("touchpad:\n  max_points: 3\n", "t.yaml:2: touchpad.max_points: found 3; expected less than or equal to 2"),
        (
            "touchpad:\n  press_mm: 1\n  release_mm: 2\n",
            "t.yaml:3: touchpad.release_mm: found 2; expected a value <= press_mm (1.0)",
        ),
        (
            "touchpad:\n  widht_mm: 4\n",
            "t.yaml:2: touchpad.widht_mm: unknown field (found 4; did you mean 'width_mm'?); expected a known field: "
            "one of max_points, centre_x_mm, centre_y_mm, width_mm, height_mm, press_mm, release_mm, match_mm, click",
        ),
        (
            "touchpad:\n  centre_x_mm: 40\n",
            "t.yaml:2: touchpad.centre_x_mm: found 40; expected less than or equal to 30",
        ),
        ("touchpad:\n  width_mm: 0\n", "t.yaml:2: touchpad.width_mm: found 0; expected greater than 0"),
        ("touchpad: 5\n", "t.yaml:1: touchpad: found 5; expected a mapping (key: value lines)"),
        (
            "touchpad:\n  click:\n    input: push_intensty\n",
            "t.yaml:3: touchpad.click.input: found 'push_intensty'; expected 'intensity', 'push_intensity'",
        ),
        (
            "touchpad:\n  click:\n    input: pinch\n    mode: tap\n",
            "t.yaml:4: touchpad.click.mode: found 'tap'; expected",
        ),
        (
            "touchpad:\n  click: {input: pinch, dwell_ms: 100}\n",
            "t.yaml:2: touchpad.click.dwell_ms: found 100; expected no dwell_ms under mode 'hold': only long_press "
            "reads it",
        ),
        (
            "touchpad:\n  click: {inptu: pinch}\n",
            "t.yaml:2: touchpad.click.inptu: unknown field (found 'pinch'; did you mean 'input'?); expected a known "
            "field: one of input, press_mm",
        ),
    ],
)
def test_bad_touchpad_sections_name_file_line_field_and_what_was_expected(text, expected):
    with pytest.raises(ProfileError) as info:
        parse_profile(text, "t.yaml")
    assert expected in str(info.value)


def test_the_pad_covers_the_rectangle_user_up_at_its_top():
    spec = TouchpadMapping(width_mm=48.0, height_mm=27.0)
    assert pad_position(spec, 0.0, 0.0) == (960, 540)
    assert pad_position(spec, -24.0, 13.5) == (0, 0)  # left, up: the pad's top-left
    assert pad_position(spec, 24.0, -13.5) == (1919, 1079)
    assert pad_position(spec, 100.0, -100.0) == (1919, 1079)  # held at the edge
    assert pad_position(TouchpadMapping(centre_x_mm=10.0), 10.0, 0.0) == (960, 540)


def test_a_contact_keeps_its_slot_and_id_a_second_finger_takes_slot_1_and_a_lift_keeps_the_id():
    tracker = TouchTracker(TouchpadMapping())
    assert tracker.update(np.zeros((0, 2)), 0.0, resting=True) == (None, None)
    first = tracker.update(np.array([[0.0, 0.0]]), 1.0, resting=False)
    assert first == (TouchPoint(0, 960, 540), None)
    moved = tracker.update(np.array([[3.0, 3.0]]), 1.0, resting=False)
    assert moved[0].id == 0 and moved[0].active and moved[0].x > 960 and moved[0].y < 540
    # a second, stronger finger comes first in the list: the first finger stays in slot 0
    two = tracker.update(np.array([[-15.0, 0.0], [4.0, 3.0]]), 1.0, resting=False)
    assert (two[0].id, two[0].active, two[1].id, two[1].active) == (0, True, 1, True)
    assert two[1].x < two[0].x  # slot 1 is the finger on the left
    # the first finger lifts: slot 0 not touching with its id and place, slot 1 goes on
    lifted = tracker.update(np.array([[-14.0, 0.0]]), 1.0, resting=False)
    assert lifted[0] == TouchPoint(0, two[0].x, two[0].y, active=False)
    assert (lifted[1].id, lifted[1].active) == (1, True)
    # a new touch takes the free slot 0 and the next id
    again = tracker.update(np.array([[-14.0, 0.0], [10.0, -10.0]]), 1.0, resting=False)
    assert (again[0].id, again[0].active, again[1].id) == (2, True, 1)


def test_a_jump_past_match_mm_is_a_new_touch():
    tracker = TouchTracker(TouchpadMapping(match_mm=5.0, max_points=1))
    assert tracker.update(np.array([[0.0, 0.0]]), 1.0, False)[0].id == 0
    assert tracker.update(np.array([[4.0, 0.0]]), 1.0, False)[0].id == 0
    jumped = tracker.update(np.array([[20.0, 0.0]]), 1.0, False)
    assert jumped == (TouchPoint(1, jumped[0].x, jumped[0].y),)


def test_intensity_hysteresis_and_rest_lift_every_touch():
    tracker = TouchTracker(TouchpadMapping(press_mm=1.0, release_mm=0.5))
    contact = np.array([[0.0, 0.0]])
    assert tracker.update(contact, 0.8, False) == (None, None)  # below press_mm: no touch yet
    assert tracker.update(contact, 1.0, False)[0].active
    assert tracker.update(contact, 0.6, False)[0].active  # held down to release_mm
    assert not tracker.update(contact, 0.4, False)[0].active
    assert tracker.update(contact, 1.0, False)[0].id == 1
    assert not tracker.update(contact, 5.0, resting=True)[0].active
    assert tracker.update(np.array([[np.nan, 0.0]]), 1.0, False)[0].active is False  # not finite: no contact


def test_tracking_ids_wrap_at_128():
    tracker = TouchTracker(TouchpadMapping(max_points=1))
    ids = []
    for _ in range(130):
        ids.append(tracker.update(np.array([[0.0, 0.0]]), 1.0, False)[0].id)
        tracker.update(np.zeros((0, 2)), 0.0, True)
    assert ids[:2] == [0, 1] and ids[127:] == [127, 0, 1]


PROFILE = """
touchpad:
  click: {input: push_intensity, press_mm: 4.0, release_mm: 3.0}
mappings:
  push: {input: push, output: left_stick}
"""


def test_the_mapper_gives_the_touch_points_and_the_click():
    mapper = Mapper(parse_profile(PROFILE, "p.yaml"))
    assert mapper.update(estimate(0, resting=True, intensity=0.0)).touches == (None, None)
    two = mapper.update(estimate(10, [[0.0, 0.0], [10.0, 0.0]], 2.0, GestureType.PUSH))
    assert [(p.id, p.active) for p in two.touches] == [(0, True), (1, True)] and not two.touch_click
    pushed = mapper.update(estimate(20, [[0.0, 1.0], [10.0, 1.0]], 5.0, GestureType.PUSH))
    assert pushed.touch_click and pushed.axes["ABS_Y"] < 0 and pushed.touching
    rest = mapper.update(estimate(30, resting=True, intensity=0.0))
    assert not rest.touching and not rest.touch_click and rest.is_neutral()
    assert [(p.id, p.active) for p in rest.touches] == [(0, False), (1, False)]
    # at the fixed point the rest is given again as it was, touches lifted
    again = mapper.update(estimate(40, resting=True, intensity=0.0))
    assert again.touches == rest.touches and again.t_us == 40_000


def test_a_profile_without_touchpad_gives_no_touch_points():
    state = Mapper(parse_profile("mappings:\n  p: {input: push, output: left_stick}\n", "p.yaml")).update(
        estimate(10, [[0.0, 0.0]], 3.0, GestureType.PUSH)
    )
    assert state.touches == () and not state.touch_click


def test_a_layer_change_lifts_the_touches():
    text = PROFILE + "layers:\n  other: {input: pinch, press_mm: 2.0, release_mm: 1.0}\n"
    mapper = Mapper(parse_profile(text, "p.yaml"))
    assert mapper.update(estimate(10, [[0.0, 0.0]], 3.0, GestureType.PUSH)).touching
    # one window of pinch inside the push is still the push (Mapper._confirmed): no switch yet
    assert mapper.update(estimate(15, [[0.0, 0.0]], 3.0, GestureType.PINCH)).touching
    switched = mapper.update(estimate(20, [[0.0, 0.0]], 3.0, GestureType.PINCH))
    assert switched.is_neutral() and switched.touches == ()
    after = mapper.update(estimate(30, [[0.0, 0.0]], 3.0, GestureType.PINCH))
    assert after.touches[0].id == 1 and after.touches[0].active  # a new touch, the next id


def test_neutral_has_no_touch_and_merging_keeps_the_gels_touches():
    assert ControllerState.neutral().touches == () and ControllerState.neutral().is_neutral()
    touched = ControllerState(touches=(TouchPoint(3, 10, 20),), touch_click=True)
    assert not touched.is_neutral() and touched.touching
    assert not ControllerState(touches=(TouchPoint(3, 10, 20, active=False),)).touching
    merged = merge_state(touched, [])
    assert merged.touches == touched.touches and merged.touch_click


def test_the_shipped_touchpad_profile_maps_the_touchpad():
    profile = load_profile("touchpad")
    assert profile.touchpad is not None and profile.touchpad.click is not None
    assert profile.touchpad.width_mm / profile.touchpad.height_mm == pytest.approx(1920 / 1080)
    assert profile.uses_pad


def test_run_output_jsonl_carries_the_touch_points_and_the_click(tmp_path, monkeypatch):
    """``run --profile touchpad --output jsonl``: a line's ``touches`` are the active touch points
    by slot (docs/dataset.md, "Controller states"), a lift leaves its slot out, a firm push sets
    ``touch_click``, and the last line (the run's end) has neither."""
    import json

    from neurotouch_hid.core.dataset import write_predictions
    from neurotouch_hid.engine.driver import DriverOptions, run_driver

    monkeypatch.setenv("XDG_RUNTIME_DIR", str(tmp_path))
    spec = load_profile("touchpad").touchpad
    one, two = (-10.0, 0.0), (12.0, 6.0)
    estimates = [estimate(10 * k, [one], intensity=2.0, gesture=GestureType.PUSH) for k in range(1, 11)]
    estimates += [estimate(100 + 10 * k, [one, two], intensity=5.0, gesture=GestureType.PUSH) for k in range(1, 11)]
    estimates += [estimate(200 + 10 * k, [two], intensity=2.0, gesture=GestureType.PUSH) for k in range(1, 11)]
    write_predictions(tmp_path / "p.jsonl", estimates)
    out = tmp_path / "states.jsonl"
    run_driver(str(tmp_path / "p.jsonl"), "touchpad", "jsonl", DriverOptions(fast=True, out=out))
    lines = [json.loads(line) for line in out.read_text().splitlines()]
    touches = [line["touches"] for line in lines]
    first = [t for t in touches if len(t) == 1 and t[0]["slot"] == 0][0][0]
    assert (first["x"], first["y"]) == pad_position(spec, *one) and 0 <= first["id"] < 128
    both = [t for t in touches if len(t) == 2][-1]
    assert [p["slot"] for p in both] == [0, 1] and (both[1]["x"], both[1]["y"]) == pad_position(spec, *two)
    assert both[0]["id"] == first["id"] != both[1]["id"]  # the first finger keeps its id
    assert any(line["touch_click"] for line in lines)  # the 5 mm push clicks (from 4 mm)
    assert [p["slot"] for p in touches[-2]] == [1]  # the first finger lifted: slot 0 left out
    assert touches[-1] == [] and lines[-1]["touch_click"] is False
