"""bench_live_poll.py (docs/performance.md, "Event path and noise filter"): it drains every packet and
every APS frame of a recording through the live source's poll, and refuses bad input in one usage
line. No speed is asserted."""

from __future__ import annotations

import re
import subprocess
import sys

import pytest
from helpers import BENCHMARKS

SCRIPT = BENCHMARKS / "bench_live_poll.py"


def test_the_drain_takes_every_frame_of_the_street_recording(street_recording):
    done = subprocess.run(
        [sys.executable, str(SCRIPT), "--recording", str(street_recording.path), "--repeat", "1"],
        capture_output=True,
        text=True,
    )
    assert done.returncode == 0, done.stderr
    taken = re.search(r"drain with the frames: +[\d.]+ M events/s \((\d+) polls, (\d+) frames\)", done.stdout)
    assert taken and int(taken[2]) == street_recording.n_frames, done.stdout
    assert re.search(r"ratio with / without: +\d+\.\d{3}", done.stdout)


@pytest.mark.parametrize(
    ("args", "said"),
    [(["--recording", "missing.aedat4"], "missing.aedat4"), (["--packet-us", "0"], "--packet-us")],
)
def test_bad_input_is_one_usage_error(args, said, tmp_path):
    done = subprocess.run([sys.executable, str(SCRIPT), *args], capture_output=True, text=True, cwd=tmp_path)
    assert done.returncode == 2 and said in done.stderr and "Traceback" not in done.stderr, done.stderr
