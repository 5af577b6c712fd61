"""What the driver costs while the gel rests: CPU of a core at steady state and peak memory
(docs/performance.md, "At rest").

    python3 benchmarks/bench_rest.py [--workdir DIR] [--short 10] [--long 40] [--repeat 1]

A resting gel's recording is made once by the simulator (``GelSimulator`` with an empty script:
the markers at rest, the camera's noise events, 25 APS frames a second; 45 s, seed 0) and kept in
``--workdir`` (default: a fresh temporary folder). It is replayed in real time through
``neurotouch-hid run --source REC --output jsonl --out /dev/null --seconds S`` in a child
process, once for ``--short`` and once for ``--long`` seconds. The child's CPU time (user + sys,
all its threads, from ``os.wait4``) of the long run minus the short one, over the seconds
between them, is the steady state's share of a core: the start (imports, loading the compiled
pipeline, the first frame's markers) cancels out. Peak resident memory is the child's
``ru_maxrss``, the larger of the two runs. ``--repeat N`` runs each N times, interleaved, and
prints every pair and the median.
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

#: Length of the resting recording (s): the longest run plus the start's margin.
RECORDING_S = 45.0


def make_rest_recording(folder: Path, seconds: float = RECORDING_S, seed: int = 0) -> Path:
    """A resting gel (noise events, 25 APS frames a second) as AEDAT4 with its sensor.yaml beside it."""
    from neurotouch_hid.sensor import SensorGeometry
    from neurotouch_hid.sources.recording import RecordingWriter
    from neurotouch_hid.sources.simulator import GelSimulator

    path = folder / f"rest-{seconds:g}s-seed{seed}.aedat4"
    if path.exists():
        return path
    sim = GelSimulator(SensorGeometry(), seed=seed, script=())
    sim.sensor.save(folder / "sensor.yaml")
    partial = path.with_suffix(".partial.aedat4")
    with RecordingWriter(partial) as writer:
        for chunk in sim.run(seconds):
            writer.write_frame(chunk.frame)
            writer.write_events(chunk.events)
    partial.rename(path)
    return path


def measure(recording: Path, seconds: float) -> dict[str, float]:
    """One real-time ``run`` of ``seconds``: CPU s (user + sys), peak RSS (MiB), wall s."""
    command = [sys.executable, "-m", "neurotouch_hid.cli", "run", "--source", str(recording)]
    command += ["--output", "jsonl", "--out", os.devnull, "--seconds", f"{seconds:g}"]
    start = time.perf_counter()
    child = subprocess.Popen(command, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    _, status, usage = os.wait4(child.pid, 0)
    wall = time.perf_counter() - start
    err = child.stderr.read().decode(errors="replace")
    child.stderr.close()
    child.returncode = os.waitstatus_to_exitcode(status)
    if child.returncode != 0:
        sys.exit(f"bench_rest.py: {' '.join(command)} failed ({child.returncode}): {err.strip()}")
    return {"cpu": usage.ru_utime + usage.ru_stime, "rss_mib": usage.ru_maxrss / 1024, "wall": wall}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--workdir", type=Path, default=None, help="keep the recording here")
    ap.add_argument("--short", type=float, default=10.0, help="the short run (s)")
    ap.add_argument("--long", type=float, default=40.0, help="the long run (s)")
    ap.add_argument("--repeat", type=int, default=1, help="pairs of runs")
    args = ap.parse_args()
    if not 0 < args.short < args.long <= RECORDING_S:
        sys.exit(f"bench_rest.py: expected 0 < --short < --long <= {RECORDING_S:g}")
    folder = args.workdir or Path(tempfile.mkdtemp(prefix="bench-rest-"))
    folder.mkdir(parents=True, exist_ok=True)
    recording = make_rest_recording(folder)
    print(f"recording {recording}; load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores", flush=True)
    shares, peaks = [], []
    for _ in range(args.repeat):
        short, long = measure(recording, args.short), measure(recording, args.long)
        share = (long["cpu"] - short["cpu"]) / (args.long - args.short)
        shares.append(share)
        peaks.append(max(short["rss_mib"], long["rss_mib"]))
        print(
            f"run {args.short:g} s: {short['cpu']:.2f} s CPU, {short['rss_mib']:.0f} MiB; "
            f"run {args.long:g} s: {long['cpu']:.2f} s CPU, {long['rss_mib']:.0f} MiB; "
            f"steady state {100 * share:.1f} % of a core; load average {os.getloadavg()[0]:.1f}",
            flush=True,
        )
    print(
        f"at rest: {100 * statistics.median(shares):.1f} % of a core (median of {len(shares)}), "
        f"peak RSS {max(peaks):.0f} MiB",
        flush=True,
    )


if __name__ == "__main__":
    main()
