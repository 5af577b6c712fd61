"""Recording I/O throughput: write and read a synthetic AEDAT4 recording through dv-processing.

Writes N events (default 5 M, uniform over the DAVIS-346 array, 60 s at ~83 k events/s) and
APS frames at 25 Hz with :class:`RecordingWriter`, then reads them back with
:meth:`RecordingReader.read_all` and :meth:`RecordingReader.stream` (1 ms batches, what the
``track`` command uses) and :func:`read_info`. Prints events/s and the real-time factor.

    python3 benchmarks/bench_recording.py [--events 5000000]
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

from neurotouch_hid.sources import EVENT_DTYPE, Frame
from neurotouch_hid.sources.recording import RecordingReader, read_info, write_recording


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
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "bench.aedat4"
        t0 = time.perf_counter()
        write_recording(path, events, frames)
        t_write = time.perf_counter() - t0
        size_mb = path.stat().st_size / 1e6

        t0 = time.perf_counter()
        info = read_info(path)
        t_info = time.perf_counter() - t0
        assert info.n_events == n and info.n_frames == len(frames)

        with RecordingReader(path) as reader:
            t0 = time.perf_counter()
            got, _ = reader.read_all()
            t_all = time.perf_counter() - t0
            assert np.array_equal(got, events)
            t0 = time.perf_counter()
            count = sum(len(item) for item in reader.stream(batch_us=1000) if not isinstance(item, Frame))
            t_stream = time.perf_counter() - t0
            assert count == n

    print(f"recording: {n:,} events, {len(frames)} APS frames, {args.seconds:.0f} s, {size_mb:.1f} MB (LZ4)")
    for name, seconds in [("write (RecordingWriter)", t_write), ("info (exact counts)", t_info),
                          ("read_all", t_all), ("stream, 1 ms batches", t_stream)]:
        print(f"{name:26s} {seconds:7.2f} s  {n / seconds / 1e6:6.1f} M events/s  "
              f"{args.seconds / seconds:7.1f}x real time")


if __name__ == "__main__":
    main()
