"""Per-window gesture accuracy as docs/dataset.md scores it, and outside a collar about each change
of the labelled gesture type, for the shipped and the adapted method (docs/lab/adaptation.md).

    python3 docs/lab/gesture_collar.py --out DIR [--families powerlaw,drift] [--collar-ms 40]

``DIR`` is a ``benchmarks/adapt_eval.py`` folder: ``DIR/FAMILY/u{0,3}_session0.aedat4`` with their
labels and sensor.yaml, and ``DIR/models/enrol/FAMILY/u{0,3}.yaml`` the models ``adapt`` fitted.
Each session is tracked with ``--model none`` and with its user's model (``DIR/collar/``, kept),
paired with its labels as ``eval`` pairs them (:func:`~neurotouch_hid.evaluation.metrics.align`),
and scored on every window and on the windows more than ``--collar-ms`` from every change of the
labelled type: the labels start a gesture at its attack's first instant, before the gel has
measurably moved, and end it when every marker is back within 0.1 mm of rest. One markdown row
per family and method.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import typer

from neurotouch_hid.core.dataset import read_labels, read_predictions
from neurotouch_hid.core.estimate import GESTURE_ORDER
from neurotouch_hid.core.sensor import SensorGeometry
from neurotouch_hid.evaluation.metrics import align, outside_collar
from neurotouch_hid.views.console import command_app

USERS = (0, 3)


def scored_outside_collar(labels, estimates, collar_ms: float) -> np.ndarray:
    """(M,) bool: which of a sequence's scored windows (``estimates`` from its first label on, as
    :func:`~neurotouch_hid.evaluation.metrics.align` pairs them with ``labels``) lie more than
    ``collar_ms`` from every change of the labelled gesture type
    (:func:`~neurotouch_hid.evaluation.metrics.outside_collar`)."""
    t_us = np.array([e.t_us for e in estimates if e.t_us >= labels[0].t_us], dtype=np.int64)
    label_t = np.array([r.t_us for r in labels], dtype=np.int64)
    label_type = np.array([GESTURE_ORDER.index(r.gesture) for r in labels])
    return outside_collar(label_t, label_type, t_us, int(collar_ms * 1000))


def main(
    out: Path = typer.Option(..., "--out", help="a benchmarks/adapt_eval.py folder"),
    families: str = typer.Option("powerlaw,drift,strong,viscoelastic,late,camera,contrast", "--families"),
    collar_ms: float = typer.Option(40.0, "--collar-ms", min=0.0, help="the collar's half-width (ms)"),
) -> None:
    missing = [
        str(out / family / f"u{user}_session0.aedat4")
        for family in families.split(",")
        for user in USERS
        if not (out / family / f"u{user}_session0.aedat4").is_file()
        or not (out / "models" / "enrol" / family / f"u{user}.yaml").is_file()
    ]
    if missing:
        typer.echo(f"{missing[0]}: no session or no model fitted (benchmarks/adapt_eval.py --out {out})", err=True)
        raise typer.Exit(2)
    predictions = out / "collar"
    predictions.mkdir(exist_ok=True)
    print(f"| family | method | gesture | outside a {collar_ms:g} ms collar | windows left out |")
    print("| --- | --- | ---: | ---: | ---: |")
    for family in families.split(","):
        sensor = SensorGeometry.load(out / family / "sensor.yaml")
        for method in ("shipped", "adapted"):
            right = total = right_out = total_out = 0
            for user in USERS:
                recording = out / family / f"u{user}_session0.aedat4"
                path = predictions / f"{family}-{method}-u{user}.jsonl"
                model = "none" if method == "shipped" else str(out / "models" / "enrol" / family / f"u{user}.yaml")
                if not path.exists():
                    command = [sys.executable, "-m", "neurotouch_hid.cli", "track", str(recording)]
                    subprocess.run([*command, "--out", str(path), "--model", model], check=True, capture_output=True)
                labels = read_labels(recording.with_name(f"u{user}_session0.labels.csv"))
                estimates = read_predictions(path)
                obs = align(labels, estimates, sensor)
                kept = scored_outside_collar(labels, estimates, collar_ms)
                right_window = obs.gesture_true == obs.gesture_pred
                right += int(right_window.sum())
                total += len(right_window)
                right_out += int(right_window[kept].sum())
                total_out += int(kept.sum())
            row = f"| {family} | {method} | {100 * right / total:.2f} % | {100 * right_out / total_out:.2f} % |"
            print(f"{row} {total - total_out} of {total} |", flush=True)


if __name__ == "__main__":
    app = command_app()
    app.command()(main)
    app()
