"""Start-up on a cold and a warm numba cache: progress, first state, full speed (docs/performance.md).

Runs ``neurotouch-hid run --source sim --output term --seconds S`` (what ``demo`` runs when
there is no /dev/uinput) in a child process, its output piped, with ``NUMBA_CACHE_DIR`` set to
a new empty folder (cold: nothing compiled), then once more on the filled cache (warm), and
prints for each, in wall seconds from the process's start:

* ``progress``: the first line saying the pipeline compiles (cold only);
* ``first state``: the first state line of the terminal view (the first window mapped);
* ``full speed``: the line saying the compiled kernels took over (cold only);
* ``end``, and the CPU seconds the run and its compile children used.

Between the two runs the cache is completed (``python -m neurotouch_hid.warmup GROUP``) in case the
cold run ended before its compile did. Usage::

    python benchmarks/bench_start.py [--seconds 20]
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time


def measure(cache: str, seconds: float) -> dict[str, float | None]:
    """One run of the simulated gel on ``cache``: when its milestones came (s), its CPU time (s)."""
    env = dict(os.environ, NUMBA_CACHE_DIR=cache)
    command = [sys.executable, "-m", "neurotouch_hid.cli", "run", "--source", "sim", "--output", "term"]
    command += ["--seconds", str(seconds)]
    before = os.times()
    start = time.perf_counter()
    child = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env)
    found: dict[str, float | None] = {"progress": None, "first state": None, "full speed": None}
    for line in child.stdout:
        now = time.perf_counter() - start
        if found["progress"] is None and "compiling the gesture pipeline" in line:
            found["progress"] = now
        elif found["first state"] is None and line.startswith("t "):
            found["first state"] = now
        elif found["full speed"] is None and "full speed now" in line:
            found["full speed"] = now
    child.wait()
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
        for group in ("pipeline", "simulator"):  # the cold run may have ended before its compile
            subprocess.run(
                [sys.executable, "-m", "neurotouch_hid.warmup", group],
                env=dict(os.environ, NUMBA_CACHE_DIR=cache),
                stdout=subprocess.DEVNULL,
                check=True,
            )
        warm = measure(cache, args.seconds)
    load = os.getloadavg()[0]
    print(f"run --source sim --output term --seconds {args.seconds:g}, {os.cpu_count()} cores, load {load:.1f}")
    print(f"{'':6} {'progress':>9} {'first state':>12} {'full speed':>11} {'end':>7} {'CPU':>7}")
    for name, r in (("cold", cold), ("warm", warm)):
        cells = [f"{r[k]:.1f} s" if r[k] is not None else "-" for k in ("progress", "first state", "full speed", "end")]
        print(f"{name:6} {cells[0]:>9} {cells[1]:>12} {cells[2]:>11} {cells[3]:>7} {r['cpu']:>5.1f} s")


if __name__ == "__main__":
    main()
