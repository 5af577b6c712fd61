"""Contact count per labelled gesture type as docs/dataset.md scores it, outside a collar about
each change of the labelled type, and where the wrong windows are (docs/lab/contact-count.md).

    python3 docs/lab/count_collar.py --out DIR --method NAME [--families stickslip,powerlaw] [--collar-ms 40]
        [--below-mm 0.2]

``DIR`` is a ``benchmarks/family_eval.py`` folder: ``DIR/FAMILY`` the dataset and
``DIR/predictions/FAMILY/NAME`` the method's predictions. Each sequence's predictions are paired
with its labels as ``eval`` pairs them (:func:`~neurotouch_hid.evaluation.metrics.align`). Per
family and gesture type: the count accuracy on every window of that labelled type; the wrong
windows labelled below ``--below-mm`` (the gel barely moved: an attack's first instants, a
release's last); and the accuracy on the windows more than ``--collar-ms`` from every change of
the labelled type (``gesture_collar.scored_outside_collar``, the resting F1's collar of docs/dataset.md).
One markdown row per family and type.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import typer

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))  # workdir.py, a benchmark's helper

from gesture_collar import scored_outside_collar  # noqa: E402
from workdir import families_in  # noqa: E402

from neurotouch_hid.core.dataset import list_sequences, read_labels, read_predictions  # noqa: E402
from neurotouch_hid.core.estimate import GESTURE_ORDER, GestureType  # noqa: E402
from neurotouch_hid.core.sensor import SensorGeometry  # noqa: E402
from neurotouch_hid.evaluation.metrics import align  # noqa: E402
from neurotouch_hid.views.console import command_app


def main(
    out: Path = typer.Option(..., "--out", help="a benchmarks/family_eval.py folder"),
    method: str = typer.Option(..., "--method", help="the method's name in DIR/predictions/FAMILY/"),
    families: str = typer.Option("", "--families", help="comma-separated; default: every family with predictions"),
    collar_ms: float = typer.Option(40.0, "--collar-ms", min=0.0, help="the collar's half-width (ms)"),
    below_mm: float = typer.Option(0.2, "--below-mm", min=0.0, help="labelled intensity counted as barely moved (mm)"),
) -> None:
    chosen = families_in(out, families, method)
    head = f"| family | type | count | wrong | of them labelled below {below_mm:g} mm |"
    print(f"{head} outside a {collar_ms:g} ms collar |")
    print("| --- | --- | ---: | ---: | ---: | ---: |")
    for family in chosen:
        sensor = SensorGeometry.load(out / family / "sensor.yaml")
        kinds, right, wrong_low, kept = [], [], [], []
        for name in list_sequences(out / family):
            labels = read_labels(out / family / f"{name}.labels.csv")
            estimates = read_predictions(out / "predictions" / family / method / f"{name}.jsonl")
            obs = align(labels, estimates, sensor)
            ok = obs.count_true == obs.count_pred
            kinds.append(obs.gesture_true)
            right.append(ok)
            wrong_low.append(~ok & (obs.intensity_true < below_mm))
            kept.append(scored_outside_collar(labels, estimates, collar_ms))
        kind, ok, low, out_of_collar = (np.concatenate(a) for a in (kinds, right, wrong_low, kept))
        for k, gesture in enumerate(GESTURE_ORDER):
            mine = kind == k
            if gesture is GestureType.NONE or not mine.any():
                continue
            outer = mine & out_of_collar
            row = f"| {family} | {gesture.value} | {100 * ok[mine].mean():.1f} % | {int((~ok[mine]).sum())} |"
            print(f"{row} {int(low[mine].sum())} | {100 * ok[outer].mean():.1f} % |", flush=True)


if __name__ == "__main__":
    app = command_app()
    app.command()(main)
    app()
