"""benchmarks/felt_errors.py on hand-made labels and predictions: the gestures whose dead-zone
latency is long, and whether the episode vote's wait for a lone contact made them so."""

from __future__ import annotations

import numpy as np
import pytest
from helpers import load_benchmark

from neurotouch_hid.core.dataset import LabelRow
from neurotouch_hid.core.estimate import GestureEstimate, GestureType

G = GestureType
ONE = np.zeros((1, 2))


@pytest.fixture(scope="module")
def felt_errors():
    return load_benchmark("felt_errors")


def row(ms: int, gesture: GestureType, mm: float) -> LabelRow:
    return LabelRow(ms * 1000, gesture, gesture is G.NONE, mm, ONE if mm else np.zeros((0, 2)))


def pred(ms: int, gesture: GestureType, mm: float, contacts: int = 1) -> GestureEstimate:
    return GestureEstimate(ms * 1000, gesture, False, mm, np.zeros((contacts, 2)))


def test_a_push_held_undecided_past_the_dead_zone_is_listed_as_waiting(felt_errors):
    # push labelled 1.0 mm from 40 ms: it reaches 0.8 mm at 40 ms. Answered none with one contact
    # at 0.9-1.5 mm (undecided) until push 2.0 mm at 100 ms: dead-zone latency 60 ms, waiting.
    # pinch labelled 1.0 mm from 240 ms, answered pinch 1.2 mm at 300 ms (60 ms) with none at
    # 0.2 mm before (below the provisional limit): long, but not the wait.
    labels = [row(0, G.NONE, 0.0), row(40, G.PUSH, 1.0), row(80, G.PUSH, 1.0), row(120, G.PUSH, 1.0)]
    labels += [row(160, G.NONE, 0.0), row(200, G.NONE, 0.0), row(240, G.PINCH, 1.0), row(280, G.PINCH, 1.0)]
    labels += [row(320, G.PINCH, 1.0), row(360, G.NONE, 0.0)]
    preds = [pred(50, G.NONE, 0.9), pred(70, G.NONE, 1.5), pred(100, G.PUSH, 2.0)]
    preds += [pred(250, G.NONE, 0.2, 2), pred(300, G.PINCH, 1.2, 2)]
    tally = felt_errors.tally_sequence(labels, preds, 0.8)
    assert dict(tally.slow) == {("push", True): 1, ("pinch", False): 1}
    line = next(x for x in felt_errors.lines_for("hand", tally) if "dead-zone latency" in x)
    assert line == (
        "- dead-zone latency above 40 ms: 2 gestures; pinch 1 (of them waiting as an undecided lone contact 0); "
        "push 1 (of them waiting as an undecided lone contact 1)"
    )


def test_a_late_gesture_is_traced_window_by_window_up_to_its_answer(felt_errors):
    # the push above: its windows from 20 ms before its first labelled frame (40 ms) to its
    # answer (100 ms), with the label (its intensity interpolated between two labelled frames) and
    # the answer of each.
    labels = [row(0, G.NONE, 0.0), row(40, G.PUSH, 1.0), row(80, G.PUSH, 1.0), row(120, G.PUSH, 1.0)]
    labels += [row(160, G.NONE, 0.0)]
    preds = [pred(20, G.NONE, 0.0, 0), pred(50, G.NONE, 0.9), pred(70, G.NONE, 1.5), pred(100, G.PUSH, 2.0)]
    preds += [pred(130, G.PUSH, 2.0)]
    tally = felt_errors.tally_sequence(labels, preds, 0.8, seq="u0")
    assert tally.traces[0] == "  push, 60 ms late:"
    assert [line.split() for line in tally.traces[1:]] == [
        ["u0", "-20", "ms", "label", "none", "0.50", "mm", "n0", "answer", "none", "0.00", "mm", "n0"],
        ["u0", "10", "ms", "label", "push", "1.00", "mm", "n1", "answer", "none", "0.90", "mm", "n1"],
        ["u0", "30", "ms", "label", "push", "1.00", "mm", "n1", "answer", "none", "1.50", "mm", "n1"],
        ["u0", "60", "ms", "label", "push", "1.00", "mm", "n1", "answer", "push", "2.00", "mm", "n1"],
    ]


def test_wrong_windows_outside_the_collar_are_split_by_what_a_detector_could_see(felt_errors):
    # pinch labelled 1.0 mm from 40 to 200 ms, its last finger pressed at 120 ms; push labelled
    # 0.05 mm (the gel has not moved) from 400 to 600 ms. Scored (more than 40 ms from each change
    # of type, at 40, 240, 400 and 640 ms): push at 100 ms (before the last finger pressed), push
    # at 150 ms (after: a detector could have seen it), pinch at 180 ms (right), none at 300 ms
    # (right), none at 500 ms (the gel has not moved); the window at 60 ms lies in the collar.
    labels = [row(0, G.NONE, 0.0)] + [row(ms, G.PINCH, 1.0) for ms in range(40, 201, 40)]
    labels += [row(ms, G.NONE, 0.0) for ms in range(240, 361, 40)]
    labels += [row(ms, G.PUSH, 0.05) for ms in range(400, 601, 40)] + [row(640, G.NONE, 0.0)]
    preds = [pred(60, G.PUSH, 1.0), pred(100, G.PUSH, 1.0), pred(150, G.PUSH, 1.0), pred(180, G.PINCH, 1.0, 2)]
    preds += [pred(300, G.NONE, 0.0, 0), pred(500, G.NONE, 0.0, 0)]
    tally = felt_errors.tally_sequence(labels, preds, 0.8, pressed=[(40_000, 120_000)])
    assert dict(tally.collared) == {"scored": 5, "unpressed": 1, "unmoved": 1, "seen": 1}
    line = next(x for x in felt_errors.lines_for("hand", tally) if "outside the collar" in x)
    assert line == (
        "- gesture type outside the collar: 5 windows, 3 wrong (40.00 % right); of the wrong, before the "
        "gesture's last finger pressed 1, label below 0.1 mm 1, the rest 1: 60.00 % were the rest right"
    )
