"""What a longer USB early packet delay at rest can cost the dead-zone latency, on game sessions.

    python3 benchmarks/rest_delay_bound.py --out DIR [--method final] [--families default,...]
        [--delay-ms 2,5,10] [--switch-ms 3] [--deadzone-mm 0.8]

DIR is a ``family_eval.py`` working folder (each family's game sessions under ``DIR/FAMILY``, a
method's predictions under ``DIR/predictions/FAMILY/METHOD``, each window's ``resting`` flag with
them). While the gel rests the live camera's early packet delay is D (``sources/davis.py``,
:data:`~neurotouch_hid.sources.davis.REST_EARLY_PACKET_DELAY_US`): data that does not fill a USB
transfer waits in the camera up to D, not 1 ms. The first window that does not rest (ending at
``e0``) then reaches the pipeline up to D late; once it is processed, the source sets the delay
back to 1 ms, at the latest ``e0 + D + S`` (S, ``--switch-ms``: the window's processing, the
source's next poll and the control transfer), and the camera sends what it held at once. So a
window ending at ``t`` is delivered at most ``min(t + D, e0 + D + S)`` instead of ``t + 1 ms``:
late by ``max(0, min(D, e0 + D + S - t) - 1)`` ms, and a window while the gel rests by ``D - 1``.
The same model bounds an engine that hands a paced source's items on once every k windows while
the gel rests: the first window that does not rest is then up to k - 1 windows late and those after
it on time, i.e. D = (k - 1) x the window + 1 ms and S = 0 (``--delay-ms 11 --switch-ms 0`` for two
10 ms windows).

Per gesture the dead-zone latency (docs/dataset.md, "Per-gesture metrics";
``neurotouch_hid.evaluation.felt``: from the labelled intensity's crossing to the first window of
the gesture's type at or above the dead zone, camera time) is read from the predictions, then that
window's lateness added: the wall-clock dead-zone latency with the delay at rest, against today's
(1 ms, nothing late). Per family and delay: median / p90 (ms) then and now, and how many gestures
moved. An upper bound: the camera holds the data the full D, and S is taken whole.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import typer
from workdir import families_in, numbers

from neurotouch_hid.core.dataset import list_sequences, read_labels, read_predictions
from neurotouch_hid.core.estimate import GestureEstimate, GestureType
from neurotouch_hid.evaluation.felt import (
    DEFAULT_DEADZONE_MM,
    FRAME_PERIOD_US,
    deadzone_crossing,
    gesture_records,
    gesture_runs,
)
from neurotouch_hid.views.console import command_app

app = command_app()


def lateness_ms(predictions: list[GestureEstimate], delay_ms: float, switch_ms: float) -> np.ndarray:
    """(N,) float64: how late (ms, wall clock) each window's output comes with ``delay_ms`` of
    early packet delay at rest, set back to 1 ms at most ``switch_ms`` after the first window that
    does not rest was delivered (the module docstring's model)."""
    late = np.zeros(len(predictions))
    e0_ms: float | None = None
    was_resting = True
    for k, p in enumerate(predictions):
        t_ms = p.t_us / 1000.0
        if p.resting:
            late[k], e0_ms = max(0.0, delay_ms - 1.0), None
        else:
            if was_resting or e0_ms is None:
                e0_ms = t_ms
            late[k] = max(0.0, min(delay_ms, e0_ms + delay_ms + switch_ms - t_ms) - 1.0)
        was_resting = p.resting
    return late


def deadzone_windows(labels, predictions: list[GestureEstimate], deadzone_mm: float) -> list[tuple[int, float]]:
    """Per gesture whose labelled intensity reaches the dead zone and whose type is answered there:
    (the answering window's index into ``predictions``, its dead-zone latency in ms, camera time),
    as ``felt.gesture_records`` finds them."""
    t_pred = np.array([p.t_us for p in predictions], dtype=np.int64)
    t_lab = np.array([r.t_us for r in labels], dtype=np.int64)
    i_lab = np.array([r.intensity_mm for r in labels], dtype=np.float64)
    found = []
    for kind, first, last in gesture_runs(labels):
        crossing = deadzone_crossing(t_lab[first : last + 1], i_lab[first : last + 1], deadzone_mm)
        if crossing is None:
            continue
        t0, t1 = int(t_lab[first]), int(t_lab[last])
        lo, hi = np.searchsorted(t_pred, t0, "left"), np.searchsorted(t_pred, t1 + FRAME_PERIOD_US, "left")
        for k in range(lo, hi):
            p = predictions[k]
            if p.gesture is kind and p.gesture is not GestureType.NONE and p.intensity_mm >= deadzone_mm:
                found.append((k, (p.t_us - crossing) / 1000.0))
                break
    return found


def quantiles(latencies_ms: list[float]) -> str:
    """``median / p90`` (ms, numpy's linear p90) of ``latencies_ms``."""
    return f"{np.median(latencies_ms):.1f} / {np.percentile(latencies_ms, 90):.1f}"


def row(name: str, rows: list[list[float]]) -> str:
    """A markdown row: ``rows[0]`` today's latencies, ``rows[j]`` the same gestures' with delay j."""
    today = np.array(rows[0])
    cells = [name, str(len(today)), quantiles(rows[0])]
    for moved_ms in rows[1:]:
        late = np.array(moved_ms) - today
        cells.append(f"{quantiles(moved_ms)}, {int(np.sum(late > 1e-9))} (max +{late.max(initial=0):.1f})")
    return "| " + " | ".join(cells) + " |"


@app.command()
def main(
    out: Path = typer.Option(..., help="a family_eval.py working folder"),
    method: str = typer.Option("final", help="whose predictions"),
    families: str = typer.Option("", help="comma-separated (default: every family with predictions)"),
    delay_ms: str = typer.Option("2,5,10", help="early packet delays at rest (ms, comma-separated)"),
    switch_ms: float = typer.Option(3.0, min=0.0, help="from the first moving window's delivery to 1 ms again (ms)"),
    deadzone_mm: float = typer.Option(DEFAULT_DEADZONE_MM, min=0.0, help="dead zone (mm)"),
) -> None:
    """Print per family the dead-zone latency today and with each delay at rest."""
    delays = numbers(delay_ms, "--delay-ms")
    heads = [f"{d:g} ms at rest: median / p90, moved (max)" for d in delays]
    print("| family | gestures | today median / p90 ms | " + " | ".join(heads) + " |")
    print("| --- | ---: | ---: | " + " | ".join("---:" for _ in delays) + " |")
    pooled: list[list[float]] = [[] for _ in range(len(delays) + 1)]
    for family in families_in(out, families, method):
        rows: list[list[float]] = [[] for _ in range(len(delays) + 1)]
        for name in list_sequences(out / family):
            labels = read_labels(out / family / f"{name}.labels.csv")
            predictions = read_predictions(out / "predictions" / family / method / f"{name}.jsonl")
            found = deadzone_windows(labels, predictions, deadzone_mm)
            check = gesture_records(labels, predictions, deadzone_mm).deadzone_latency_ms
            assert sorted(lat for _, lat in found) == sorted(check[~np.isnan(check)].tolist()), (family, name)
            rows[0] += [lat for _, lat in found]
            for j, d in enumerate(delays, 1):
                late = lateness_ms(predictions, d, switch_ms)
                rows[j] += [lat + late[k] for k, lat in found]
        print(row(family, rows))
        for j in range(len(rows)):
            pooled[j] += rows[j]
    print(row("all", pooled))


if __name__ == "__main__":
    app()
