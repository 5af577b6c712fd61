"""How soon any detector could answer a gesture: the onset the simulated gel itself allows.

    python3 benchmarks/onset_bound.py --out DIR [--families default,...] [--mm 0.02,0.05,0.1,0.12,0.2]

DIR is a ``family_eval.py`` working folder (each family's dataset under ``DIR/FAMILY``). For each
gesture of the per-gesture metrics (docs/dataset.md: a run of labelled frames of one type, from
its first labelled frame t0), the time from t0 until some true marker (the simulator's 1 ms
``SEQUENCE.markers.npz``) is first at least X mm from its rest position, for each X; then its
median and p90 over the gestures (numpy's linear p90, as the onset latency's). A detector that
needs the gel to move X mm cannot have an onset latency below these (docs/accuracy.md, "Felt per
gesture"). A marker still displaced at t0 by the gesture before counts as moved (time 0), so
the figures are lower bounds.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import typer
from workdir import families_in, numbers

from neurotouch_hid.core.dataset import list_sequences, read_labels
from neurotouch_hid.core.sensor import SensorGeometry
from neurotouch_hid.evaluation.felt import gesture_spans
from neurotouch_hid.views.console import command_app

app = command_app()


def first_moved_ms(dataset: Path, thresholds_mm: list[float]) -> np.ndarray:
    """(G, T) float64: per gesture of ``dataset`` and threshold (mm), ms from the gesture's t0 to the
    first 1 ms sample at or after it whose largest marker displacement from rest is at least the
    threshold; NaN when the gesture never moves a marker that far before its last frame."""
    sensor = SensorGeometry.load(dataset / "sensor.yaml")
    rows = []
    for name in list_sequences(dataset):
        markers = np.load(dataset / f"{name}.markers.npz")
        t_us = markers["t_us"]
        moved = markers["positions_px"] - markers["rest_px"][None]
        largest_mm = np.hypot(moved[..., 0], moved[..., 1]).max(axis=1) / sensor.px_per_mm
        for _, t0, t1 in gesture_spans(read_labels(dataset / f"{name}.labels.csv")):
            span = (t_us >= t0) & (t_us <= t1)
            row = []
            for x in thresholds_mm:
                hit = np.flatnonzero(span & (largest_mm >= x))
                row.append((t_us[hit[0]] - t0) / 1000 if len(hit) else np.nan)
            rows.append(row)
    return np.array(rows, dtype=np.float64).reshape(-1, len(thresholds_mm))


@app.command()
def main(
    out: Path = typer.Option(..., "--out", help="family_eval.py working folder"),
    families: str = typer.Option("", "--families", help="comma-separated (default: every family with a dataset)"),
    mm: str = typer.Option("0.02,0.05,0.1,0.12,0.2", "--mm", help="displacements (mm) to time"),
) -> None:
    thresholds = numbers(mm, "--mm", finite=True)
    times = np.concatenate([first_moved_ms(out / f, thresholds) for f in families_in(out, families)])
    print(f"{len(times)} gestures")
    print("| largest marker displacement | median ms | p90 ms | never |")
    print("| ---: | ---: | ---: | ---: |")
    for k, x in enumerate(thresholds):
        col = times[:, k][np.isfinite(times[:, k])]
        print(f"| >= {x:g} mm | {np.median(col):.0f} | {np.percentile(col, 90):.0f} | {len(times) - len(col)} |")


if __name__ == "__main__":
    app()
