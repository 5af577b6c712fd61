"""Where the resting errors are: against the labels, and against the offset's rule at the onset too.

    python3 benchmarks/resting_errors.py --out DIR --method NAME [--families default,drift,...] [--collar-ms 40,80]

DIR is a ``family_eval.py`` working folder (each family's dataset under ``DIR/FAMILY``, a
method's predictions under ``DIR/predictions/FAMILY/NAME``). Per family it prints the resting F1
against the labels, the windows called resting while the labels say not (false positives), how
many of those lie in a gesture before any marker has moved ``REST_TOLERANCE_MM`` (0.1 mm), the
missed rests (false negatives), and the resting F1 when a window also counts as at rest whenever
every true marker (the simulator's 1 ms ``SEQUENCE.markers.npz``) is within 0.1 mm of its rest
position -- the rule the labels apply after a gesture, applied at the onset too. Last, the
resting F1 of the labels' tolerance itself: a detector that, on the same windows, calls rest
exactly when every true marker is within 0.1 mm of rest (no noise, no delay), so the most that a
detector which needs the gel to move 0.1 mm can score against the labels (docs/accuracy.md,
"Where the errors are").

Then the same outside the 40 ms collar (docs/dataset.md, the target's F1; ``--collar-ms`` other
half-widths too, one table each: how far from the labels' changes rest is decided): the method's, its
windows called resting while the labels say not (and how many of them lie in a gesture before any
marker has moved 0.1 mm), its missed rests, its F1 with the offset's rule at the onset too, and the F1 of ideal
detectors that call rest exactly when every true marker is within ``--ideal-mm`` of rest (the
frames' rest noise is ~0.02 mm): what a detector that must see the gel move that far can score
at best.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import typer
from workdir import families_in, numbers

from neurotouch_hid.core.dataset import labels_at, list_sequences, read_labels, read_predictions
from neurotouch_hid.core.estimate import GestureType
from neurotouch_hid.core.sensor import SensorGeometry
from neurotouch_hid.evaluation.metrics import RESTING_COLLAR_US, outside_resting_collar
from neurotouch_hid.sources.simulator import REST_TOLERANCE_MM
from neurotouch_hid.views.console import command_app

app = command_app()


def f1(truth: np.ndarray, predicted: np.ndarray) -> float:
    """F1 of the positive class (resting) of two (M,) bool arrays."""
    tp = int(np.sum(truth & predicted))
    wrong = int(np.sum(truth != predicted))
    return 2 * tp / max(2 * tp + wrong, 1)


def family_errors(
    dataset: Path, predictions: Path, ideal_mm: tuple[float, ...] = (), collar_us: int = RESTING_COLLAR_US
) -> dict:
    """The figures of one family (module docstring); ``ideal_mm`` the ideal detectors' tolerances (mm),
    ``collar_us`` the collar's half-width (us) about each change of the labelled resting flag."""
    sensor = SensorGeometry.load(dataset / "sensor.yaml")
    truth, said, gesture, scored, moved_max = [], [], [], [], []
    for name in list_sequences(dataset):
        labels = read_labels(dataset / f"{name}.labels.csv")
        preds = read_predictions(predictions / f"{name}.jsonl")
        at = labels_at(labels, np.array([p.t_us for p in preds], dtype=np.int64))
        keep = [k for k, label in enumerate(at) if label is not None]
        markers = np.load(dataset / f"{name}.markers.npz")
        t_us = np.array([preds[k].t_us for k in keep], dtype=np.int64)
        row = np.clip(np.searchsorted(markers["t_us"], t_us), 0, len(markers["t_us"]) - 1)
        moved = markers["positions_px"][row] - markers["rest_px"][None]
        moved_mm = np.hypot(moved[..., 0], moved[..., 1]).max(axis=1) / sensor.px_per_mm
        moved_max += list(moved_mm)
        scored += list(
            outside_resting_collar(
                np.array([label.t_us for label in labels], dtype=np.int64),
                np.array([label.resting for label in labels], dtype=bool),
                t_us,
                collar_us,
            )
        )
        truth += [at[k].resting for k in keep]
        said += [preds[k].resting for k in keep]
        gesture += [at[k].gesture is not GestureType.NONE for k in keep]
    truth, said, gesture, scored = (np.array(v, dtype=bool) for v in (truth, said, gesture, scored))
    moved_max = np.array(moved_max, dtype=np.float64)
    still = moved_max < REST_TOLERANCE_MM
    false_rest = ~truth & said
    return {
        "f1_collared": f1(truth[scored], said[scored]),
        "false_rest_collared": int(np.sum(false_rest & scored)),
        "false_rest_collared_below_tolerance": int(np.sum(false_rest & scored & gesture & still)),
        "f1_offset_rule_collared": f1((truth | still)[scored], said[scored]),
        "missed_rest_collared": int(np.sum(truth & ~said & scored)),
        "f1_ideal_collared": {mm: f1(truth[scored], moved_max[scored] < mm) for mm in ideal_mm},
        "f1": f1(truth, said),
        "f1_offset_rule": f1(truth | still, said),
        "false_rest": int(false_rest.sum()),
        "false_rest_at_onset_below_tolerance": int(np.sum(false_rest & gesture & still)),
        "missed_rest": int(np.sum(truth & ~said)),
        "f1_tolerance_detector": f1(truth, still),
    }


@app.command()
def main(
    out: Path = typer.Option(..., "--out", help="family_eval.py working folder"),
    method: str = typer.Option(..., "--method", help="the method's name in family_eval.py"),
    families: str = typer.Option("", "--families", help="comma-separated (default: every family with predictions)"),
    ideal_mm: str = typer.Option(
        "0.02,0.05,0.1", "--ideal-mm", help="comma-separated tolerances (mm) of the ideal detectors outside the collar"
    ),
    collar_ms: str = typer.Option(
        "40", "--collar-ms", help="comma-separated collar half-widths (ms; 40 is docs/dataset.md's), a table each"
    ),
) -> None:
    names = families_in(out, families, method)
    tolerances = tuple(numbers(ideal_mm, "--ideal-mm", finite=True))
    collars_us = [round(1000 * ms) for ms in numbers(collar_ms, "--collar-ms", finite=True)]
    by_collar = {
        collar_us: {
            fam: family_errors(out / fam, out / "predictions" / fam / method, tolerances, collar_us) for fam in names
        }
        for collar_us in collars_us
    }
    results = by_collar[collars_us[0]]  # the figures over every window are the same for each collar
    print(
        "| family | resting F1 | F1, offset rule at onset too | false rest | of which at onset < 0.1 mm | missed rest "
        "| F1 of the 0.1 mm tolerance itself |"
    )
    print("| --- | ---: | ---: | ---: | ---: | ---: | ---: |")
    for fam in names:
        r = results[fam]
        print(
            f"| {fam} | {100 * r['f1']:.2f} % | {100 * r['f1_offset_rule']:.2f} % | {r['false_rest']} | "
            f"{r['false_rest_at_onset_below_tolerance']} | {r['missed_rest']} | "
            f"{100 * r['f1_tolerance_detector']:.2f} % |"
        )
    ideal = " | ".join(f"ideal detector, {mm:g} mm" for mm in tolerances)
    for collar_us, results in by_collar.items():
        print(
            f"\nOutside the {collar_us / 1000:g} ms collar:\n\n| family | resting F1 | false rest "
            f"| of which at onset < 0.1 mm | missed rest | F1, offset rule at onset too | {ideal} |"
        )
        print("| --- | ---: | ---: | ---: | ---: | ---: |" + " ---: |" * len(tolerances))
        for fam in names:
            r = results[fam]
            cells = " | ".join(f"{100 * r['f1_ideal_collared'][mm]:.2f} %" for mm in tolerances)
            print(
                f"| {fam} | {100 * r['f1_collared']:.2f} % | {r['false_rest_collared']} | "
                f"{r['false_rest_collared_below_tolerance']} | {r['missed_rest_collared']} | "
                f"{100 * r['f1_offset_rule_collared']:.2f} % | {cells} |"
            )


if __name__ == "__main__":
    app()
