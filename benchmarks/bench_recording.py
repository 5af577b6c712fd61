"""Recording I/O throughput: write and read a synthetic AEDAT4 recording through dv-processing.

Writes N events (default 5 M, uniform over the DAVIS-346 array, 60 s at ~83 k events/s) and
APS frames at 25 Hz with :class:`RecordingWriter`, then reads them back with
:meth:`RecordingReader.read_all` and :meth:`RecordingReader.stream` (1 ms batches, what the
``track`` command uses) and :func:`read_info`. Prints events/s and the real-time factor, by
wall-clock time and by the process's CPU time (all threads; on a shared, loaded machine the wall
figures mostly measure waiting for a core).

    python3 benchmarks/bench_recording.py [--events 5000000]
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

from neurotouch_hid.sources import EVENT_DTYPE, Frame
from neurotouch_hid.sources.recording import RecordingReader, read_info
from neurotouch_hid.sources.recording_writer import write_recording


def synthetic(n_events: int, duration_us: int, seed: int = 0) -> tuple[np.ndarray, list[Frame]]:
    """``n_events`` random events over ``duration_us`` and one random APS frame every 40 ms."""
    rng = np.random.default_rng(seed)
    events = np.zeros(n_events, EVENT_DTYPE)
    events["timestamp"] = np.sort(rng.integers(0, duration_us, n_events))
    events["x"] = rng.integers(0, 346, n_events)
    events["y"] = rng.integers(0, 260, n_events)
    events["polarity"] = rng.integers(0, 2, n_events)
    frames = [Frame(t, rng.integers(0, 256, (260, 346), dtype=np.uint8)) for t in range(0, duration_us, 40_000)]
    return events, frames


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--events", type=int, default=5_000_000)
    parser.add_argument("--seconds", type=float, default=60.0, help="recording duration")
    args = parser.parse_args()
    duration_us = int(args.seconds * 1e6)
    events, frames = synthetic(args.events, duration_us)
    n = len(events)
    timings: list[tuple[str, float, float]] = []

    def timed(name, fn):
        wall, cpu = time.perf_counter(), time.process_time()
        result = fn()
        timings.append((name, time.perf_counter() - wall, time.process_time() - cpu))
        return result

    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "bench.aedat4"
        timed("write (RecordingWriter)", lambda: write_recording(path, events, frames))
        size_mb = path.stat().st_size / 1e6
        info = timed("info (exact counts)", lambda: read_info(path))
        assert info.n_events == n and info.n_frames == len(frames)
        with RecordingReader(path) as reader:
            got, _ = timed("read_all", reader.read_all)
            assert np.array_equal(got, events)
            count = timed(
                "stream, 1 ms batches",
                lambda: sum(len(item) for item in reader.stream(batch_us=1000) if not isinstance(item, Frame)),
            )
            assert count == n

    print(f"recording: {n:,} events, {len(frames)} APS frames, {args.seconds:.0f} s, {size_mb:.1f} MB (LZ4)")
    print(f"{'':26s} {'wall s':>7s} {'M ev/s':>7s} {'x real':>7s} | {'CPU s':>7s} {'M ev/s':>7s} {'x real':>7s}")
    for name, wall, cpu in timings:
        print(
            f"{name:26s} {wall:7.2f} {n / wall / 1e6:7.1f} {args.seconds / wall:7.1f} | "
            f"{cpu:7.2f} {n / cpu / 1e6:7.1f} {args.seconds / cpu:7.1f}"
        )


if __name__ == "__main__":
    main()
