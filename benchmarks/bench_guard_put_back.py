"""How soon a killed driver's hidden nodes are back (docs/performance.md, "Memory").

A driver process hides a device's nodes (``neurotouch_hid.inputs.hide.Hider``, guarded, on a
folder standing in for /dev and /sys: regular files, as tests/test_copilot_hide.py's) and is then
killed with SIGKILL; this times the kill to the event node being back in the folder (ms), once
per ``--runs``. What it measures is the guard's part (the pipe's end-of-file reaching it, the
put-back) plus the dead process's teardown by the kernel, which for the real driver (its
compiled pipeline, hundreds of MB mapped) is larger than this small one's. Needs no root.

Run: ``python3 benchmarks/bench_guard_put_back.py [--runs 8]``; prints one JSON object.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

DRIVER = (
    "import sys\n"
    "from neurotouch_hid.inputs.hide import Hider\n"
    "h = Hider(sys.argv[1], sys.argv[2], sys.argv[3], guarded=True)\n"
    "h.hide(sys.argv[2] + '/input/event5')\n"
    "print(h._guard.pid, flush=True)\n"
    "sys.stdin.read()\n"
)


def _tree(root: Path) -> tuple[Path, Path, Path]:
    dev, sysfs, run = root / "dev", root / "sys", root / "run"
    (dev / "input").mkdir(parents=True)
    (dev / "input/event5").write_text("event5")
    device = sysfs / "devices/usb1/1-1/1-1:1.0/input/input5"
    (device / "event5").mkdir(parents=True)
    (sysfs / "class/input/event5").mkdir(parents=True)
    (sysfs / "class/input/event5/dev").write_text("0:0\n")  # a regular file's st_rdev
    (sysfs / "class/input/event5/device").symlink_to(device)
    return dev, sysfs, run


def _asleep_in_read(pid: int) -> bool:
    """The guard ready: its main thread asleep in its pipe's read, its preparing thread ended."""
    with open(f"/proc/{pid}/wchan") as wchan:
        return "pipe_read" in wchan.read() and len(os.listdir(f"/proc/{pid}/task")) == 1


def once(timeout_s: float = 60.0) -> float:
    """One kill to put-back, in ms. Raises RuntimeError when a step takes over ``timeout_s``."""
    with tempfile.TemporaryDirectory() as folder:
        dev, sysfs, run = _tree(Path(folder))
        driver = subprocess.Popen(
            [sys.executable, "-c", DRIVER, str(run), str(dev), str(sysfs)],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=subprocess.DEVNULL,  # the guard's line naming what it put back
            text=True,
        )
        try:
            guard = int(driver.stdout.readline())
            end = time.monotonic() + timeout_s
            while not _asleep_in_read(guard):  # the guard ready: started and waiting on its pipe
                if time.monotonic() > end:
                    raise RuntimeError("the guard did not reach its read")
                time.sleep(0.01)
            start = time.monotonic()
            driver.kill()
            while not (dev / "input/event5").exists():
                if time.monotonic() - start > timeout_s:
                    raise RuntimeError("the node was not put back")
                time.sleep(0.0005)
            return (time.monotonic() - start) * 1000
        finally:
            driver.kill()
            driver.wait()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=8)
    runs = [round(once(), 1) for _ in range(parser.parse_args().runs)]
    print(json.dumps({"kill_to_back_ms": runs, "load_1min": round(os.getloadavg()[0], 1)}))


if __name__ == "__main__":
    main()
