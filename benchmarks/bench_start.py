"""Start-up on a cold and a warm numba cache: progress, first state, first gesture, full speed
(docs/performance.md, "Start-up").

Runs ``neurotouch-hid run --source sim --output jsonl --seconds S`` (the demo's simulated gel,
its states as JSON lines) in a child process, its output piped, with ``NUMBA_CACHE_DIR`` set to a
new empty folder (cold: nothing compiled), then once more on the filled cache (warm), and prints
for each, in wall seconds from the process's start:

* ``progress``: the line saying the pipeline compiles (cold only);
* ``first state``: the first state (the first window mapped);
* ``first gesture``: the first state recognising a gesture (not ``none``);
* ``full speed``: the line saying every compiled kernel took over (cold only);
* ``end``, and the CPU seconds the run and its compile children used.

Between the two runs the cache is completed (``python -m neurotouch_hid.service.warmup GROUP``) in case the
cold run ended before its compile did. Usage::

    python benchmarks/bench_start.py [--seconds 20]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import threading
import time

MILESTONES = ("progress", "first state", "first gesture", "full speed", "end")


def measure(cache: str, seconds: float) -> dict[str, float | None]:
    """One run of the simulated gel on ``cache``: when its milestones came (s), its CPU time (s)."""
    env = dict(os.environ, NUMBA_CACHE_DIR=cache)
    command = [sys.executable, "-m", "neurotouch_hid.cli", "run", "--source", "sim", "--output", "jsonl"]
    command += ["--seconds", str(seconds)]
    before = os.times()
    start = time.perf_counter()
    child = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    found: dict[str, float | None] = dict.fromkeys(MILESTONES)

    def said() -> None:  # the compile's lines go to stderr
        for line in child.stderr:
            now = time.perf_counter() - start
            if found["progress"] is None and "compiling the gesture pipeline" in line:
                found["progress"] = now
            elif found["full speed"] is None and "full speed now" in line:
                found["full speed"] = now

    reader = threading.Thread(target=said, daemon=True)
    reader.start()
    for line in child.stdout:
        now = time.perf_counter() - start
        found["first state"] = found["first state"] or now
        if found["first gesture"] is None and json.loads(line).get("gesture") not in (None, "none"):
            found["first gesture"] = now
    child.wait()
    reader.join(10)
    after = os.times()
    found["end"] = time.perf_counter() - start
    found["cpu"] = (after.children_user + after.children_system) - (before.children_user + before.children_system)
    found["exit"] = child.returncode
    return found


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=20.0, help="simulated seconds per run")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(prefix="bench-start-numba-") as cache:
        cold = measure(cache, args.seconds)
        for group in ("simulator", "tracker", "pipeline"):  # the cold run may have ended before its compile
            subprocess.run(
                [sys.executable, "-m", "neurotouch_hid.service.warmup", group],
                env=dict(os.environ, NUMBA_CACHE_DIR=cache),
                stdout=subprocess.DEVNULL,
                check=True,
            )
        warm = measure(cache, args.seconds)
    load = os.getloadavg()[0]
    print(f"run --source sim --output jsonl --seconds {args.seconds:g}, {os.cpu_count()} cores, load {load:.1f}")
    print(f"{'':6} " + " ".join(f"{name:>13}" for name in MILESTONES) + f" {'CPU':>7}")
    for name, r in (("cold", cold), ("warm", warm)):
        cells = [f"{r[k]:.1f} s" if r[k] is not None else "-" for k in MILESTONES]
        print(f"{name:6} " + " ".join(f"{cell:>13}" for cell in cells) + f" {r['cpu']:>5.1f} s")


if __name__ == "__main__":
    main()
