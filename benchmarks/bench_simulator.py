"""Simulator throughput: simulated seconds per wall-clock (and CPU) second, events/s written.

Cases: the ``quick`` preset, and one minute of paper-like data (the ``paper`` preset for user 0,
all five gesture types, 12 s each). Also the simulation alone (no files) for the same minute,
to separate the gel/camera model from AEDAT4 writing. Figures go to docs/performance.md
("Simulator").

    python3 benchmarks/bench_simulator.py [--minutes 1.0] [--full-paper]

``--full-paper`` also writes the whole ``paper`` preset (25 simulated minutes).
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import dv_processing as dv

from neurotouch_hid.sources.hands import SIM_GESTURES, USERS
from neurotouch_hid.sources.sim_dataset import write_dataset
from neurotouch_hid.sources.simulator import GelSimulator


def _count_events(folder: Path) -> tuple[int, float, int]:
    """Events, simulated seconds and bytes of the dataset's recordings (read with dv-processing)."""
    n, seconds, size = 0, 0.0, 0
    for path in sorted(folder.glob("*.aedat4")):
        rec = dv.io.MonoCameraRecording(str(path))
        start, end = rec.getTimeRange()
        seconds += (end - start) * 1e-6
        while rec.isRunning():
            batch = rec.getNextEventBatch()
            if batch is None:
                break
            n += len(batch)
        size += path.stat().st_size + path.with_suffix("").with_suffix(".markers.npz").stat().st_size
    return n, seconds, size


def _timed(fn):
    w0, c0 = time.perf_counter(), time.process_time()
    out = fn()
    return out, time.perf_counter() - w0, time.process_time() - c0


def _row(name: str, sim_s: float, wall: float, cpu: float, events: int, size: int | None) -> str:
    mb = f"{size / 1e6:.0f}" if size is not None else "-"
    return (
        f"| {name} | {sim_s:.1f} | {wall:.1f} | {sim_s / wall:.2f} | {cpu:.1f} | {sim_s / cpu:.2f} | "
        f"{events / 1e6:.2f} | {events / wall / 1e6:.3f} | {events / cpu / 1e6:.3f} | {mb} |"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--minutes", type=float, default=1.0, help="paper-like simulated minutes")
    parser.add_argument("--full-paper", action="store_true", help="also write the whole paper preset")
    args = parser.parse_args()
    # compile (numba cache) outside the measurements
    GelSimulator().step()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        out, wall, cpu = _timed(lambda: write_dataset(tmp / "quick", preset="quick", seed=0, progress=False))
        n, sim_s, size = _count_events(out)
        rows.append(_row("write `quick` (1 user x 5 gestures)", sim_s, wall, cpu, n, size))

        out, wall, cpu = _timed(
            lambda: write_dataset(
                tmp / "paper1", preset="paper", seed=0, users=[0], minutes=args.minutes, progress=False
            )
        )
        n, sim_s, size = _count_events(out)
        rows.append(_row(f"write paper-like {args.minutes:g} min (user 0 x 5 gestures)", sim_s, wall, cpu, n, size))

        def simulate_only() -> tuple[int, float]:
            n_ev, span = 0, 0.0
            for k, kind in enumerate(SIM_GESTURES):
                sim = GelSimulator(user=USERS[0], gestures=[kind], seed=0, stream_seed=(0, k))
                for chunk in sim.run(args.minutes * 60.0 / len(SIM_GESTURES)):
                    n_ev += len(chunk.events)
                    span += 0.04
            return n_ev, span

        (n, sim_s), wall, cpu = _timed(simulate_only)
        rows.append(_row(f"simulate only, {args.minutes:g} min (no files)", sim_s, wall, cpu, n, None))

        if args.full_paper:
            out, wall, cpu = _timed(lambda: write_dataset(tmp / "paper", preset="paper", seed=0, progress=False))
            n, sim_s, size = _count_events(out)
            rows.append(_row("write `paper` (5 users x 5 gestures x 60 s)", sim_s, wall, cpu, n, size))

    print(
        "| case | simulated s | wall s | x real time | CPU s | x real time (CPU) | M events | M events/s (wall) "
        "| M events/s (CPU) | MB written |"
    )
    print("| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |")
    for row in rows:
        print(row)


if __name__ == "__main__":
    main()
