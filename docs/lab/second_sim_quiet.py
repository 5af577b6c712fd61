"""The second simulator's sessions with a lone contact's field read and unread: felt wrong and the
dead-zone latency per gesture (docs/accuracy.md, "A second simulator's sessions and multi-finger
starts"; docs/method.md, "A lone contact's field").

    python3 docs/lab/second_sim_quiet.py [--data ../shared/data/second-simulator]

Each session runs through the product's pipeline twice: as it is, and with the counter-motion
unread (inf: the one-contact wait as before). Printed per run: felt wrong of the 10 gestures, each
gesture's dead-zone latency (ms, session order) and their p90 (linear percentile).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import typer

from neurotouch_hid.core.dataset import read_labels
from neurotouch_hid.core.sensor import SensorGeometry
from neurotouch_hid.evaluation.felt import gesture_records
from neurotouch_hid.pipeline.pipeline import GesturePipeline
from neurotouch_hid.sources.recording import RecordingReader
from neurotouch_hid.views.console import command_app

app = command_app()
SESSIONS = ("session_a", "session_b", "session_c")


class Unread(GesturePipeline):
    """The product's pipeline, a lone contact's field not read."""

    def _counter_drag(self) -> float:
        return math.inf


@app.command()
def main(
    data: Path = typer.Option(
        Path(__file__).resolve().parents[3] / "shared/data/second-simulator", "--data", help="the sessions' folder"
    ),
) -> None:
    sensor = SensorGeometry.load(data / "sensor.yaml")
    for label, cls in (("field unread", Unread), ("the product", GesturePipeline)):
        felt, latency = [], []
        for name in SESSIONS:
            with RecordingReader(data / f"{name}.aedat4") as reader:
                estimates = list(cls(sensor).run(reader.stream()))
            rec = gesture_records(read_labels(data / f"{name}.labels.csv"), estimates)
            felt.append(rec.felt_wrong)
            latency.append(rec.deadzone_latency_ms)
        f, la = np.concatenate(felt), np.concatenate(latency)
        p90 = np.percentile(la[np.isfinite(la)], 90)
        print(
            f"{label}: felt wrong {f.sum()} of {len(f)}; dead-zone latency {np.round(la, 1).tolist()} ms, p90 {p90:.1f}"
        )


if __name__ == "__main__":
    app()
