"""Per family: the gesture type under the 0.3 mm rule, and the dead-zone latency through a profile
that maps every type to one output (docs/accuracy.md, "Felt per gesture").

    python3 benchmarks/felt_rules.py --out DIR --method NAME [--families starts,late,...]
        [--deadzone-mm 0.8]

DIR is a ``family_eval.py`` working folder (``--sessions``). Per family, from the method's saved
predictions (no pipeline run):

* **gesture outside the collar, 0.3 mm rule**: the gesture type accuracy over the windows outside
  the 40 ms collar about each change of the labelled type, leaving out as well the windows of a
  gesture whose fingers start apart before the gel under its last finger has moved 0.3 mm
  (``SEQUENCE.pressed.csv``; docs/dataset.md, "Predictions (JSON lines)"), with how many windows
  that leaves out;
* **dead-zone latency, any type**: as docs/dataset.md's dead-zone latency, but the first window of
  *any* type (not ``none``) at or above the dead zone answers: what a profile that maps every type
  to the same output feels (run the method with ``episode.first_finger_us=0``, as the driver runs
  under such a profile: ``mapping/commitment.py``). Median and p90 (linear percentile), gestures
  with none of it (missed).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import typer
from workdir import families_in

from neurotouch_hid.core.dataset import labels_at, list_sequences, read_labels, read_predictions, read_pressed
from neurotouch_hid.core.estimate import GestureType
from neurotouch_hid.evaluation.felt import (
    DEFAULT_DEADZONE_MM,
    FRAME_PERIOD_US,
    deadzone_crossing,
    gesture_spans,
    pressed_at,
)
from neurotouch_hid.evaluation.metrics import TYPE_COLLAR_US, outside_collar
from neurotouch_hid.views.console import command_app

app = command_app()


def family_figures(folder: Path, predictions: Path, deadzone_mm: float) -> dict:
    """The figures of one family's sequences (module docstring)."""
    scored = right = left_out = 0
    latencies: list[float] = []
    missed = gestures = 0
    for name in list_sequences(folder):
        labels = read_labels(folder / f"{name}.labels.csv")
        preds = read_predictions(predictions / f"{name}.jsonl")
        pressed = read_pressed(folder / f"{name}.pressed.csv")
        t = np.array([p.t_us for p in preds], dtype=np.int64)
        truth = labels_at(labels, t)
        label_t = np.array([row.t_us for row in labels], dtype=np.int64)
        kinds = np.array([list(GestureType).index(row.gesture) for row in labels], dtype=np.int64)
        outside = outside_collar(label_t, kinds, t, TYPE_COLLAR_US)
        before = np.zeros(len(preds), dtype=bool)
        for _kind, t0, t1 in gesture_spans(labels):
            at = pressed_at(pressed, t0, t1)
            if at is not None:
                before |= (t >= t0) & (t < min(at, t1 + FRAME_PERIOD_US))
            gestures += 1
            frames = [row for row in labels if t0 <= row.t_us <= t1]
            crossing = deadzone_crossing(
                np.array([r.t_us for r in frames]), np.array([r.intensity_mm for r in frames]), deadzone_mm
            )
            if crossing is None:
                gestures -= 1
                continue
            answered = [
                p.t_us
                for p in preds
                if t0 <= p.t_us < t1 + FRAME_PERIOD_US
                and p.gesture is not GestureType.NONE
                and p.intensity_mm >= deadzone_mm
            ]
            if answered:
                latencies.append((answered[0] - crossing) / 1000.0)
            else:
                missed += 1
        for k, (p, row) in enumerate(zip(preds, truth)):
            if row is None or not outside[k]:
                continue
            if before[k]:
                left_out += 1
                continue
            scored += 1
            right += p.gesture is row.gesture
    lat = np.array(latencies)
    return {
        "gesture_rule": right / scored if scored else float("nan"),
        "left_out": left_out,
        "scored": scored,
        "latency_median": float(np.median(lat)) if len(lat) else float("nan"),
        "latency_p90": float(np.percentile(lat, 90)) if len(lat) else float("nan"),
        "missed": missed,
        "gestures": gestures,
    }


@app.command()
def main(
    out: Path = typer.Option(..., "--out", help="family_eval.py working folder"),
    method: str = typer.Option(..., "--method", help="the method whose predictions to read"),
    families: str = typer.Option("", "--families", help="comma-separated (default: every family with predictions)"),
    deadzone_mm: float = typer.Option(DEFAULT_DEADZONE_MM, "--deadzone-mm", min=0.0),
) -> None:
    print(
        "| family | gesture outside the collar, 0.3 mm rule | windows left out by the rule "
        "| dead-zone latency, any type, median / p90 ms | missed |"
    )
    print("| --- | ---: | ---: | ---: | ---: |")
    for family in families_in(out, families, method):
        f = family_figures(out / family, out / "predictions" / family / method, deadzone_mm)
        print(
            f"| {family} | {100 * f['gesture_rule']:.2f} % | {f['left_out']} of {f['left_out'] + f['scored']} "
            f"| {f['latency_median']:.0f} / {f['latency_p90']:.0f} | {f['missed']} of {f['gestures']} |"
        )


if __name__ == "__main__":
    app()
