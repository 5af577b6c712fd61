"""``track``'s fixed start apart from its throughput (docs/performance.md, "track").

    python3 benchmarks/bench_track.py [--workdir DIR] [--short 8] [--long 40] [--repeat 3]

Two simulated-gel recordings through every gesture (``bench_latency.make_recording``, seed 0,
``--short`` and ``--long`` seconds; kept in ``--workdir``) are tracked by ``neurotouch-hid track
REC --out FILE`` in a child process, each ``--repeat`` times, interleaved. CPU of the child (user
+ sys, from ``os.wait4``) and its wall time, against the recording's length: the **throughput** is
the slope between the two (seconds of recording per CPU or wall second, and M events/s of CPU),
the **start** the intercept (the fixed cost of any ``track``: the interpreter, the imports,
numba's cached kernels loaded). Also ``track``'s own figure (its last line: the tracking loop
alone, reading and writing included). The medians are printed.
"""

from __future__ import annotations

import argparse
import os
import re
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_latency import make_recording  # noqa: E402


def track(recording: Path, out: Path) -> dict[str, float]:
    """One ``track`` of ``recording`` in a child: CPU s, wall s, its loop's seconds, events."""
    command = [sys.executable, "-m", "neurotouch_hid.cli", "track", str(recording), "--out", str(out)]
    start = time.perf_counter()
    child = subprocess.Popen(command, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    _, status, usage = os.wait4(child.pid, 0)
    wall = time.perf_counter() - start
    said = child.stdout.read().decode(errors="replace")
    err = child.stderr.read().decode(errors="replace")
    child.stdout.close()
    child.stderr.close()
    if os.waitstatus_to_exitcode(status) != 0:
        sys.exit(f"bench_track.py: {' '.join(command)} failed: {err.strip()}")
    found = re.search(r"\(([0-9]+) events, [0-9]+ frames\) in ([0-9.]+) s", said)
    if found is None:
        sys.exit(f"bench_track.py: no summary line in track's output: {said.strip()}")
    return {
        "cpu": usage.ru_utime + usage.ru_stime,
        "wall": wall,
        "loop": float(found.group(2)),
        "events": int(found.group(1)),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--workdir", type=Path, default=None, help="keep the recordings here")
    ap.add_argument("--short", type=float, default=8.0, help="the short recording (s)")
    ap.add_argument("--long", type=float, default=40.0, help="the long recording (s)")
    ap.add_argument("--repeat", type=int, default=3, help="runs of each")
    args = ap.parse_args()
    if not 0 < args.short < args.long:
        sys.exit("bench_track.py: expected 0 < --short < --long")
    folder = args.workdir or Path(tempfile.mkdtemp(prefix="bench-track-"))
    folder.mkdir(parents=True, exist_ok=True)
    short_rec, long_rec = make_recording(folder, args.short), make_recording(folder, args.long)
    out = folder / "track-out.jsonl"
    print(f"load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores", flush=True)
    starts, starts_wall, rates, rates_wall, mevents, loops = [], [], [], [], [], []
    for _ in range(args.repeat):
        short, long = track(short_rec, out), track(long_rec, out)
        span = args.long - args.short
        cpu_per_s = (long["cpu"] - short["cpu"]) / span
        wall_per_s = (long["wall"] - short["wall"]) / span
        starts.append(short["cpu"] - cpu_per_s * args.short)
        starts_wall.append(short["wall"] - wall_per_s * args.short)
        rates.append(1 / cpu_per_s)
        rates_wall.append(1 / wall_per_s)
        mevents.append((long["events"] - short["events"]) / (long["cpu"] - short["cpu"]) / 1e6)
        loops.append(args.long / long["loop"])
        print(
            f"{args.short:g} s: {short['cpu']:.2f} s CPU, {short['wall']:.2f} s wall; {args.long:g} s: "
            f"{long['cpu']:.2f} s CPU, {long['wall']:.2f} s wall; start {starts[-1]:.2f} s CPU "
            f"({starts_wall[-1]:.2f} s wall); throughput {rates[-1]:.1f}x real time of CPU ({rates_wall[-1]:.1f}x "
            f"wall, {mevents[-1]:.2f} M events/s of CPU); track's loop on {args.long:g} s: {loops[-1]:.1f}x; "
            f"load average {os.getloadavg()[0]:.1f}",
            flush=True,
        )
    print(
        f"start (fixed): {statistics.median(starts):.2f} s CPU, {statistics.median(starts_wall):.2f} s wall; "
        f"throughput: {statistics.median(rates):.1f}x real time of CPU, {statistics.median(rates_wall):.1f}x wall, "
        f"{statistics.median(mevents):.2f} M events/s of CPU; track's loop {statistics.median(loops):.1f}x "
        f"(medians of {args.repeat})",
        flush=True,
    )


if __name__ == "__main__":
    main()
