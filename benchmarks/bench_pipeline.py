"""Gesture pipeline: time per stage per window, and ``track``'s real-time factor end to end
(docs/performance.md, "Pipeline stages").

1. Per stage (``GesturePipeline(profile=True)``), on simulated recordings read back through
   ``RecordingReader`` into memory: tracker per window (every ``BlobTracker.update`` between two
   window ends), contacts and gesture per window that is not at rest (resting windows skip them),
   their sum, resting detection per APS frame, and the total per window (tracker + contacts +
   gesture; the resting detector runs per frame, in its own thread in the runtime). Wall-clock
   and CPU time of the calling thread (the CPU figure is what a machine shared with other jobs
   does not inflate).
2. ``track_recording`` (what ``neurotouch-hid track`` runs: AEDAT4 reading, pipeline, predictions
   JSON lines) on each recording: recording time / elapsed time, wall-clock and process CPU.

Run: ``python3 benchmarks/bench_pipeline.py`` (``--help`` for options). Simulates a dataset
(``write_dataset(preset="quick", minutes=...)``) unless ``--dataset`` is given.
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

import numpy as np
from rich.table import Table

from neurotouch_hid.core.dataset import list_sequences
from neurotouch_hid.core.sensor import find_sensor_file
from neurotouch_hid.pipeline.pipeline import GesturePipeline, PipelineConfig
from neurotouch_hid.pipeline.track import track_recording
from neurotouch_hid.sources.recording import RecordingReader
from neurotouch_hid.sources.sim_dataset import write_dataset
from neurotouch_hid.views.console import make_console


def profile_sequence(recording: Path, config: PipelineConfig) -> dict[str, list[tuple[float, float]]]:
    """Per-window / per-frame (wall us, CPU us) samples of each stage on one recording."""
    sensor = find_sensor_file(recording)
    with RecordingReader(recording) as reader:
        items = list(reader.stream(batch_us=config.window_us))
    samples: dict[str, list[tuple[float, float]]] = {
        k: [] for k in ("tracker", "contacts", "gesture", "contacts+gesture", "total", "total (moving)", "resting")
    }
    marks = {"tracker": 0, "contacts": 0, "gesture": 0}

    def take(stage: str) -> tuple[float, float]:
        wall = pipeline.timings[stage][marks[stage] :]
        cpu = pipeline.cpu_timings[stage][marks[stage] :]
        marks[stage] = len(pipeline.timings[stage])
        return sum(wall) / 1e3, sum(cpu) / 1e3

    def on_window(estimate) -> None:
        tracker = take("tracker")
        moving = len(pipeline.timings["contacts"]) > marks["contacts"]
        contacts, gesture = take("contacts"), take("gesture")
        samples["tracker"].append(tracker)
        total = tuple(a + b + c for a, b, c in zip(tracker, contacts, gesture))
        samples["total"].append(total)
        if moving:
            samples["contacts"].append(contacts)
            samples["gesture"].append(gesture)
            samples["contacts+gesture"].append(tuple(a + b for a, b in zip(contacts, gesture)))
            samples["total (moving)"].append(total)

    pipeline = GesturePipeline(sensor, config, on_window=on_window, profile=True)
    for item in items:
        pipeline.process(item)
    samples["resting"] = [
        (w / 1e3, c / 1e3) for w, c in zip(pipeline.timings["resting"], pipeline.cpu_timings["resting"])
    ]
    return samples


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--dataset", type=Path, help="dataset folder (docs/dataset.md); default: simulate one")
    parser.add_argument("--minutes", type=float, default=1.0, help="simulated minutes when no --dataset (default 1)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--window-us", type=int, default=10_000)
    args = parser.parse_args()
    console = make_console()
    config = PipelineConfig(window_us=args.window_us)

    with tempfile.TemporaryDirectory() as tmp:
        folder = args.dataset
        if folder is None:
            console.print(f"simulating {args.minutes} min (preset quick, seed {args.seed}) ...")
            folder = write_dataset(
                Path(tmp) / "ds", preset="quick", seed=args.seed, minutes=args.minutes, progress=False
            )
        recordings = [Path(folder) / f"{name}.aedat4" for name in list_sequences(folder)]

        warm = GesturePipeline(find_sensor_file(recordings[0]), config)  # numba JIT, OpenCV first calls
        with RecordingReader(recordings[0]) as reader:
            for i, item in enumerate(reader.stream(batch_us=config.window_us)):
                warm.process(item)
                if i > 200:
                    break

        samples: dict[str, list] = {}
        for recording in recordings:
            for stage, values in profile_sequence(recording, config).items():
                samples.setdefault(stage, []).extend(values)

        table = Table(title=f"pipeline per stage ({config.window_us} us windows, {len(recordings)} recordings)")
        for col in ("stage", "per", "n", "wall median us", "wall p99 us", "CPU median us", "CPU p99 us"):
            table.add_column(col, justify="left" if col in ("stage", "per") else "right")
        for stage, values in samples.items():
            a = np.array(values)
            per = (
                "frame"
                if stage == "resting"
                else (
                    "moving window"
                    if stage in ("contacts", "gesture", "contacts+gesture", "total (moving)")
                    else "window"
                )
            )
            table.add_row(
                stage,
                per,
                str(len(a)),
                f"{np.median(a[:, 0]):.0f}",
                f"{np.percentile(a[:, 0], 99):.0f}",
                f"{np.median(a[:, 1]):.0f}",
                f"{np.percentile(a[:, 1], 99):.0f}",
            )
        console.print(table)

        track = Table(title="track end to end (AEDAT4 reading + pipeline + predictions JSON lines)")
        for col in ("recording", "recording s", "events", "wall s", "x real time", "CPU s", "x real time (CPU)"):
            track.add_column(col, justify="left" if col == "recording" else "right")
        totals = np.zeros(4)
        for recording in recordings:
            cpu0, wall0 = time.process_time(), time.perf_counter()
            summary = track_recording(recording, Path(tmp) / "pred.jsonl", find_sensor_file(recording), config)
            cpu, wall = time.process_time() - cpu0, time.perf_counter() - wall0
            rec_s = summary.duration_us * 1e-6
            totals += (rec_s, summary.events, wall, cpu)
            track.add_row(
                recording.name,
                f"{rec_s:.2f}",
                str(summary.events),
                f"{wall:.2f}",
                f"{rec_s / wall:.1f}",
                f"{cpu:.2f}",
                f"{rec_s / cpu:.1f}",
            )
        track.add_row(
            "all",
            f"{totals[0]:.2f}",
            str(int(totals[1])),
            f"{totals[2]:.2f}",
            f"{totals[0] / totals[2]:.1f}",
            f"{totals[3]:.2f}",
            f"{totals[0] / totals[3]:.1f}",
        )
        console.print(track)
        console.print(f"load average during the run: {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores")


if __name__ == "__main__":
    main()
