"""An enrolment's plan (neurotouch_hid/enrolment/plan.py): what it prompts, and its JSON file
(docs/dataset.md, "Guided session plan (JSON)") read with clear errors."""

from __future__ import annotations

import json
import os
from collections import Counter

import pytest

from neurotouch_hid.core.errors import DatasetError
from neurotouch_hid.core.estimate import GestureType
from neurotouch_hid.enrolment.plan import (
    DIRECTIONS,
    HOLD_S,
    MAX_SESSION_S,
    PLAN_GESTURES,
    TAP_S,
    Plan,
    Prompt,
    make_plan,
    read_plan,
    write_plan,
)


@pytest.mark.parametrize("seed", [0, 1, 7, 123])
def test_a_plan_prompts_every_gesture_four_times_in_three_minutes(seed):
    plan = make_plan(seed)
    counts = Counter(p.gesture for p in plan.prompts)
    assert all(counts[g] >= 4 for g in PLAN_GESTURES)
    pushes = {p.direction for p in plan.prompts if p.gesture is GestureType.PUSH}
    assert pushes == set(DIRECTIONS)
    assert all(p.direction is None for p in plan.prompts if p.gesture is not GestureType.PUSH)
    taps = [p for p in plan.prompts if p.is_tap]
    holds = [p for p in plan.prompts if not p.is_tap]
    assert taps and holds
    assert all(TAP_S[0] <= p.seconds <= TAP_S[1] for p in taps)
    assert all(HOLD_S[0] <= p.seconds <= HOLD_S[1] for p in holds)
    # room left to ask again for a few missed prompts within the session's 3 minutes
    assert plan.end_s + 4 * (HOLD_S[1] + 4.5) <= MAX_SESSION_S
    for before, after in zip(plan.prompts, plan.prompts[1:]):
        assert after.cue_s - before.end_s >= 2.5  # the gel is seen at rest between gestures
        assert after.gesture is not before.gesture


def test_the_same_seed_makes_the_same_plan_another_seed_another():
    assert make_plan(5) == make_plan(5)
    assert make_plan(5) != make_plan(6)


def test_a_written_plan_reads_back_as_it_was(tmp_path):
    plan = make_plan(3)
    path = write_plan(plan, tmp_path / "plan.json")
    assert read_plan(path) == plan
    data = json.loads(path.read_text())
    assert set(data) == {"prompts"}
    assert data["prompts"][0].keys() >= {"gesture", "cue_s", "seconds"}
    assert [p for p in os.listdir(tmp_path)] == ["plan.json"]  # no temporary file left


def test_fields_a_reader_does_not_know_are_ignored(tmp_path):
    path = tmp_path / "plan.json"
    path.write_text(
        json.dumps(
            {
                "version": 3,
                "prompts": [
                    {"gesture": "push", "cue_s": 2.0, "seconds": 1.5, "direction": [0, 1], "hint": "gently"},
                    {"gesture": "pinch", "cue_s": 6, "seconds": 0.4, "direction": "up"},
                ],
            }
        )
    )
    # a direction that is not up/down/left/right, or not a push's, is ignored too
    assert read_plan(path) == Plan(
        (Prompt(GestureType.PUSH, 2.0, 1.5, None), Prompt(GestureType.PINCH, 6.0, 0.4, None))
    )


def _prompts(*items):
    return json.dumps({"prompts": list(items)})


@pytest.mark.parametrize(
    ("text", "says"),
    [
        ("{not json", ["not JSON"]),
        ("[1, 2]", ['{"prompts": [...]}']),
        ('{"prompt": []}', ['{"prompts": [...]}']),
        (_prompts({"gesture": "wave", "cue_s": 1, "seconds": 1}), ["prompt 1", "'gesture'", "push, pinch", "'wave'"]),
        (_prompts({"cue_s": 1, "seconds": 1}), ["prompt 1", "'gesture'", "found nothing"]),
        (_prompts({"gesture": "none", "cue_s": 1, "seconds": 1}), ["prompt 1", "'gesture'"]),
        (_prompts({"gesture": "zoom", "seconds": 1}), ["prompt 1", "'cue_s' is missing", "seconds from 0 to 86400"]),
        (_prompts({"gesture": "zoom", "cue_s": -1, "seconds": 1}), ["prompt 1", "'cue_s'", "to 86400", "found -1"]),
        (_prompts({"gesture": "zoom", "cue_s": "2", "seconds": 1}), ["prompt 1", "'cue_s'", "'2'"]),
        (_prompts({"gesture": "zoom", "cue_s": 1, "seconds": 0}), ["prompt 1", "'seconds'", "> 0"]),
        (_prompts({"gesture": "zoom", "cue_s": 1, "seconds": True}), ["prompt 1", "'seconds'", "True"]),
        ('{"prompts": [{"gesture": "zoom", "cue_s": 1e999, "seconds": 1}]}', ["prompt 1", "'cue_s'", "inf"]),
        (
            _prompts({"gesture": "zoom", "cue_s": 1, "seconds": 1}, "push"),
            ["prompt 2", "expected a JSON object", "'push'"],
        ),
        (
            _prompts({"gesture": "zoom", "cue_s": 5, "seconds": 1}, {"gesture": "push", "cue_s": 2, "seconds": 1}),
            ["prompt 2", "'cue_s'", "ordered by cue_s"],
        ),
        (
            _prompts({"gesture": "zoom", "cue_s": 5, "seconds": 2}, {"gesture": "push", "cue_s": 6, "seconds": 1}),
            ["prompt 2", "before the end of prompt 1", "not overlap"],
        ),
    ],
)
def test_a_bad_plan_says_where_and_what_was_expected(tmp_path, text, says):
    path = tmp_path / "plan.json"
    path.write_text(text)
    with pytest.raises(DatasetError) as info:
        read_plan(path)
    message = str(info.value)
    assert message.startswith(str(path))
    for part in says:
        assert part in message
    assert "\n" not in message


def test_a_plan_that_is_not_a_readable_file_is_refused_clearly(tmp_path):
    with pytest.raises(DatasetError, match="cannot read the session plan"):
        read_plan(tmp_path / "missing.json")
    fifo = tmp_path / "fifo.json"
    os.mkfifo(fifo)
    with pytest.raises(DatasetError, match="not a regular file"):
        read_plan(fifo)  # would block for ever if opened as a file
    big = tmp_path / "big.json"
    big.write_text('{"prompts": []' + " " * (2 << 20) + "}")
    with pytest.raises(DatasetError, match="larger than"):
        read_plan(big)
    binary = tmp_path / "binary.json"
    binary.write_bytes(b"\xff\xfe{}")
    with pytest.raises(DatasetError, match="not UTF-8"):
        read_plan(binary)


def test_cues_count_from_the_stream_s_first_event_not_its_first_frame():
    """docs/dataset.md: ``cue_s`` counts from the recording's first event. The first APS frame
    came 30 ms before it here; the cues counted from the frame, 30 ms early."""
    import numpy as np

    from neurotouch_hid.core.sensor import default_sensor
    from neurotouch_hid.enrolment.label import MotionMeter
    from neurotouch_hid.enrolment.plan import NOT_YET_US, Plan, Prompt, Script
    from neurotouch_hid.sources import EVENT_DTYPE, Frame

    script = Script(Plan((Prompt(GestureType.PUSH, 2.0, 1.0),)))
    prompt = script.prompts()[0]
    script.reach(1_000_000, 1_000_000, events=False)  # an APS frame
    assert script.start_us is None and script.cue_us(prompt) == NOT_YET_US  # no cue is due yet
    script.reach(1_030_000, 1_031_000)  # the first event batch
    script.reach(1_031_000, 1_032_000)
    assert script.start_us == 1_030_000 and script.cue_us(prompt) == 3_030_000

    meter = MotionMeter(default_sensor())
    events = np.zeros(3, dtype=EVENT_DTYPE)
    events["timestamp"] = [1_030_000, 1_030_500, 1_031_000]
    meter.note(Frame(1_000_000, np.zeros((260, 346), np.uint8)), [])
    meter.note(events, [])
    assert meter.motion().start_us == 1_030_000
