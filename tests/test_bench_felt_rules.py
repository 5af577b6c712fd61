"""benchmarks/felt_rules.py on a hand-made sequence: the type scored under the 0.3 mm rule leaves
out a multi-finger gesture's windows before its last finger pressed (and the 40 ms collar), and
the dead-zone latency of a one-output profile takes the first window of any type."""

from __future__ import annotations

import numpy as np
from helpers import load_benchmark

from neurotouch_hid.core.dataset import LabelRow, write_labels, write_predictions, write_pressed
from neurotouch_hid.core.estimate import GestureEstimate, GestureType
from neurotouch_hid.core.sensor import SensorGeometry

G = GestureType
TWO = np.array([[160.0, 130.0], [186.0, 130.0]])


def test_the_rule_leaves_out_the_windows_before_the_last_finger_pressed(tmp_path):
    felt_rules = load_benchmark("felt_rules")
    folder, predictions = tmp_path / "fam", tmp_path / "pred"
    folder.mkdir()
    predictions.mkdir()
    # a pinch labelled from 400 to 1000 ms (frames every 40 ms), 2 mm from 480 ms; its last finger
    # pressed at 600 ms
    rows = []
    for ms in range(0, 1600, 40):
        on = 400 <= ms <= 1000
        mm = 0.0 if not on else min(2.0, (ms - 400) / 40.0)
        rows.append(LabelRow(ms * 1000, G.PINCH if on else G.NONE, not on, mm, TWO if on else np.zeros((0, 2))))
    write_labels(folder / "s.labels.csv", rows)
    (folder / "s.aedat4").write_bytes(b"")  # listed by its name: the script reads no recording
    SensorGeometry().save(folder / "sensor.yaml")
    write_pressed(folder / "s.pressed.csv", [(400_000, 600_000)])
    # answered push 450-590 ms (the lone first finger, before it pressed), pinch from 600 ms
    out = []
    for ms in range(10, 1600, 10):
        kind = G.PUSH if 450 <= ms < 600 else G.PINCH if 600 <= ms <= 1000 else G.NONE
        mm = 1.5 if kind is not G.NONE else 0.0
        out.append(GestureEstimate(ms * 1000, kind, kind is G.NONE and not 400 <= ms <= 1040, mm))
    write_predictions(predictions / "s.jsonl", out)
    f = felt_rules.family_figures(folder, predictions, 0.8)
    # before the rule: the push windows 450-590 outside the collar (> 440 ms) are wrong, and the
    # undecided 410-440 is in the collar; the rule leaves out 440 < t < 600 (15 windows)
    assert f["left_out"] == 15
    assert f["gesture_rule"] == 1.0
    # the labels reach 0.8 mm at 432 ms; the first window of any type at or above it: 450 ms
    assert np.isclose(f["latency_median"], 18.0) and f["missed"] == 0 and f["gestures"] == 1
