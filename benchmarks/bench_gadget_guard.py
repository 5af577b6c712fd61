"""What the USB gadget's guard costs while the driver runs (docs/performance.md, "Memory").

The guard (``neurotouch_hid.service.guard.Guard``) is a process of its own beside
every ``run --output usb`` with a ``hid`` function; it waits for the driver's end in a read. This
starts one over a pipe standing for a ``/dev/hidgN`` node, then reads from ``/proc/PID``: its
anonymous memory and resident set (``smaps_rollup``, KiB), the CPU time of its start and the CPU
time and context switches over ``--seconds`` of rest after it (``bench_rest.proc_reading``). Needs no
gadget and no root.

Run: ``python3 benchmarks/bench_gadget_guard.py [--seconds 10]``; prints one JSON object.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_rest import proc_reading  # noqa: E402


def _rss_kib(pid: int) -> int:
    with open(f"/proc/{pid}/smaps_rollup") as rollup:
        return next(int(line.split()[1]) for line in rollup if line.startswith("Rss:"))


def _asleep_in_read(pid: int) -> bool:
    """Whether process ``pid`` waits in a pipe's read (``/proc/PID/wchan``: ``pipe_read``, or
    ``anon_pipe_read`` in newer kernels)."""
    with open(f"/proc/{pid}/wchan") as wchan:  # and no thread left preparing (``--hidden``)
        return "pipe_read" in wchan.read() and len(os.listdir(f"/proc/{pid}/task")) == 1


def measure(seconds: float = 10.0, start_timeout_s: float = 60.0, hidden: bool = False) -> dict:
    """The guard's costs (module docstring): a dict of its anonymous memory and RSS (KiB), its
    start's CPU (s) and, over ``seconds`` of rest, its CPU (s) and context switches. The rest
    starts once the guard waits in its read. ``hidden``: the guard as a root run that hides merged
    devices starts it, with the put-back of the hidden nodes imported at its start
    (``inputs/hide.py``'s ``RESTORE_CODE``; folders of its own, nothing hidden). Raises
    RuntimeError if it does not reach its read within ``start_timeout_s``."""
    import tempfile

    from neurotouch_hid.inputs import hide
    from neurotouch_hid.service.guard import Guard

    host, node = os.pipe()
    if hidden:
        where = tempfile.mkdtemp(prefix="bench-guard-")
        package_parent = str(Path(hide.__file__).resolve().parents[2])
        then = ["-c", hide.RESTORE_CODE, package_parent, str(os.getpid()), where, where, where]
        guard = Guard(then=then, what="the hidden devices")
    else:
        guard = Guard([(node, bytes(13))])
    try:
        end = time.monotonic() + start_timeout_s
        while not _asleep_in_read(guard.pid):
            if time.monotonic() > end:
                raise RuntimeError(f"the guard (pid {guard.pid}) did not reach its read in {start_timeout_s} s")
            time.sleep(0.01)
        before = proc_reading(guard.pid)
        time.sleep(seconds)
        after = proc_reading(guard.pid)
        result = {
            "anonymous_kib": round(after["anon_mib"] * 1024),
            "rss_kib": _rss_kib(guard.pid),
            "start_cpu_s": before["cpu"],
            "rest_s": seconds,
            "rest_cpu_s": after["cpu"] - before["cpu"],
            "rest_context_switches": after["switches"] - before["switches"],
        }
    finally:
        guard.release()
        os.close(host)
        os.close(node)
    return result


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=10.0, help="rest measured after the start (s)")
    parser.add_argument("--hidden", action="store_true", help="the guard of a run that hides merged devices")
    args = parser.parse_args()
    print(json.dumps(measure(args.seconds, hidden=args.hidden)))


if __name__ == "__main__":
    main()
