"""Damaged recordings: which AEDAT4 reader always ends, and how fast each reads (docs/performance.md,
"Recording I/O").

The two options for reading files that come from users and other tools:

- dv-processing's ``MonoCameraRecording`` (the reader before), in a child process with a
  watchdog: the parent kills a child that sends nothing for ``--limit`` seconds (a hang) and
  sees a crash as the child's death; events come back through a pipe;
- the ``aedat`` decoder (Rust, memory-safe) in the process: ``RecordingReader`` now.

Robustness: copies of the real DAVIS-346 street recording (LZ4) and of a simulated gel
recording (ZSTD) with 1-32 flipped bits (10 each), cut at a random byte (5 each) and with two
neighbouring packets swapped (5 each), every copy read to the end by both readers, each in its
own child process with a time limit: "read" (no error), "error" (a clear error after what was
readable), "hang" (killed at the limit), "crash" (killed by a signal). Speed: events/s reading a
synthetic recording (uniform events, APS frames at 25 Hz, LZ4 and ZSTD) with dv-processing in
the process, dv-processing in a child process (the watchdog option's cost: a pipe), and aedat.

    python3 benchmarks/bench_damaged_recordings.py [--events 5000000] [--limit 20]
"""

from __future__ import annotations

import argparse
import multiprocessing
import os
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path

import numpy as np

from neurotouch_hid.core.errors import RecordingError
from neurotouch_hid.sources import EVENT_DTYPE, Frame
from neurotouch_hid.sources.dv import events_from_store
from neurotouch_hid.sources.recording import RecordingReader
from neurotouch_hid.sources.recording_writer import RecordingWriter
from neurotouch_hid.sources.simulator import SimulatedSource

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from recording_damage import damage  # noqa: E402  (the tests' damage: flips, cuts, swaps)

STREET = Path(__file__).resolve().parents[2] / "shared" / "data" / "davis346-street" / "recording.aedat4"


# --- the two readers, each in a child process --------------------------------------------------
def _dv_child(path: str, conn) -> None:
    """dv-processing's reader (the one before aedat): events then frames; messages through
    ``conn`` are tagged: E events, F a frame, D done, X an error."""
    import dv_processing as dv

    try:
        rec = dv.io.MonoCameraRecording(path)
        while (store := rec.getNextEventBatch()) is not None:
            conn.send_bytes(b"E" + events_from_store(store).tobytes())
        while rec.isFrameStreamAvailable() and rec.getNextFrame() is not None:
            conn.send_bytes(b"F")
        conn.send_bytes(b"D")
    except Exception as exc:  # what pybind11 raises for dv-processing's C++ errors
        conn.send_bytes(b"X" + str(exc).encode()[:200])


def _aedat_child(path: str, conn) -> None:
    """RecordingReader (aedat) in a child process, so that a crash would be seen as one."""
    try:
        with RecordingReader(path) as reader:
            for item in reader.stream(batch_us=10_000):
                conn.send_bytes(b"F" if isinstance(item, Frame) else b"E" + item.tobytes())
        conn.send_bytes(b"D")
    except RecordingError as exc:
        conn.send_bytes(b"X" + str(exc).encode()[:200])


def read_in_child(target, path: Path, limit_s: float) -> tuple[str, int, float]:
    """Read ``path`` with ``target`` in a child process: ``(outcome, events, seconds)``; the
    watchdog kills the child after ``limit_s`` seconds without a message."""
    ctx = multiprocessing.get_context("fork")
    parent, child = ctx.Pipe(duplex=False)
    process = ctx.Process(target=target, args=(str(path), child), daemon=True)
    start = time.perf_counter()
    process.start()
    child.close()
    events, outcome = 0, None
    while outcome is None:
        if not parent.poll(limit_s):
            process.kill()
            outcome = "hang"
            break
        try:
            message = parent.recv_bytes()
        except EOFError:  # the child died without a word
            break
        tag = message[:1]
        if tag == b"E":
            events += (len(message) - 1) // EVENT_DTYPE.itemsize
        elif tag in (b"D", b"X"):
            outcome = "read" if tag == b"D" else "error"
    process.join(5)
    if outcome is None:
        outcome = "crash" if process.exitcode and process.exitcode < 0 else f"exit {process.exitcode}"
    return outcome, events, time.perf_counter() - start


# --- inputs --------------------------------------------------------------------------------------
def gel_recording(path: Path, seconds: float) -> Path:
    with RecordingWriter(path, compression="ZSTD") as writer:
        for item in SimulatedSource(seed=0).stream(seconds=seconds, batch_us=10_000):
            writer.write_frame(item) if isinstance(item, Frame) else writer.write_events(item)
    return path


def synthetic_recording(path: Path, n_events: int, seconds: float, compression: str) -> Path:
    rng = np.random.default_rng(0)
    duration_us = int(seconds * 1e6)
    events = np.zeros(n_events, EVENT_DTYPE)
    events["timestamp"] = np.sort(rng.integers(0, duration_us, n_events))
    events["x"], events["y"] = rng.integers(0, 346, n_events), rng.integers(0, 260, n_events)
    events["polarity"] = rng.integers(0, 2, n_events)
    with RecordingWriter(path, compression=compression) as writer:
        ts, start = events["timestamp"], 0
        for t in range(0, duration_us, 40_000):
            k = int(np.searchsorted(ts, t))
            if k > start:
                writer.write_events(events[start:k])
            start = max(start, k)
            writer.write_frame(Frame(t, rng.integers(0, 256, (260, 346), dtype=np.uint8)))
        writer.write_events(events[start:])
    return path


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--events", type=int, default=5_000_000, help="events of the synthetic recording (speed)")
    parser.add_argument("--limit", type=float, default=20.0, help="watchdog: seconds without data that count as a hang")
    parser.add_argument("--gel-seconds", type=float, default=3.0)
    args = parser.parse_args()
    print(f"load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores", flush=True)
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        bases = {"gel (ZSTD)": gel_recording(tmp / "gel.aedat4", args.gel_seconds)}
        if STREET.exists():
            bases["street (LZ4)"] = STREET
        print(
            "\n| file | damage | copies | dv-processing: read / error / hang / crash "
            "| aedat: read / error / hang / crash |"
        )
        print("| --- | --- | ---: | --- | --- |")
        for name, base in bases.items():
            data = base.read_bytes()
            for label, kind, copies, seed0 in (
                ("1-32 flipped bits", "flip", 10, 0),
                ("cut", "cut", 5, 100),
                ("2 packets swapped", "swap", 5, 200),
            ):
                tally = {"dv": Counter(), "aedat": Counter()}
                for seed in range(seed0, seed0 + copies):
                    path = tmp / "damaged.aedat4"
                    path.write_bytes(damage(data, kind, seed))
                    for reader, target in (("dv", _dv_child), ("aedat", _aedat_child)):
                        tally[reader][read_in_child(target, path, args.limit)[0]] += 1
                cells = [" / ".join(str(t[o]) for o in ("read", "error", "hang", "crash")) for t in tally.values()]
                print(f"| {name} | {label} | {copies} | {cells[0]} | {cells[1]} |", flush=True)

        print("\nM events/s by CPU time (process and children, all threads) and, in brackets, by wall time")
        print(
            "\n| synthetic recording | dv-processing in the process | dv-processing in a child (pipe) "
            "| aedat (RecordingReader.read_all) | aedat, time-ordered batches (RecordingReader.stream) |"
        )
        print("| --- | ---: | ---: | ---: | ---: |")
        import dv_processing as dv

        def dv_in_process(path: Path) -> int:
            n, rec = 0, dv.io.MonoCameraRecording(str(path))
            while (store := rec.getNextEventBatch()) is not None:
                n += len(events_from_store(store))
            while rec.getNextFrame() is not None:
                pass
            return n

        def aedat_read_all(path: Path) -> int:
            with RecordingReader(path) as reader:
                return len(reader.read_all()[0])

        def aedat_stream(path: Path) -> int:
            with RecordingReader(path) as reader:
                return sum(0 if isinstance(item, Frame) else len(item) for item in reader.stream(batch_us=10_000))

        def dv_in_child(path: Path) -> int:
            return read_in_child(_dv_child, path, args.limit)[1]

        for compression in ("LZ4", "ZSTD"):
            path = synthetic_recording(tmp / f"synthetic-{compression}.aedat4", args.events, 60.0, compression)
            cells = []
            for read in (dv_in_process, dv_in_child, aedat_read_all, aedat_stream):
                before, wall = os.times(), time.perf_counter()
                n = read(path)
                wall, after = time.perf_counter() - wall, os.times()
                cpu = sum(after[:4]) - sum(before[:4])
                cells.append(f"{n / cpu / 1e6:.1f} ({n / wall / 1e6:.1f})")
            print(
                f"| {args.events / 1e6:g} M events, 60 s, APS frames at 25 Hz, {compression} | "
                + " | ".join(cells)
                + " |",
                flush=True,
            )
    print(f"\nload average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores")


if __name__ == "__main__":
    main()
