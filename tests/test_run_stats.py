"""RunStats: the engine's threads count into one RunStats; no increment is lost between them."""

from __future__ import annotations

import sys
import threading

import pytest

from neurotouch_hid.core.stats import RunStats

THREADS = 4
CALLS = 20_000


def _hammer(stats: RunStats, start: threading.Barrier) -> None:
    start.wait()
    for _ in range(CALLS):
        stats.count(windows=1, events=3)
        stats.add_latency(1, 1000, compiling=True, waiting=0, window_latencies_ns=(5,))
        stats.add_latency(1, 1000, compiling=False, waiting=0, counted=1)  # an item's last window


def test_increments_from_threads_are_not_lost():
    """Real threads, many increments each, a thread switch as often as the interpreter allows:
    every window, event and latency sample counted (the engine's pipeline, source and resting
    threads and its loop all count into one RunStats)."""
    stats = RunStats()
    start = threading.Barrier(THREADS)
    previous = sys.getswitchinterval()
    sys.setswitchinterval(1e-6)
    try:
        threads = [threading.Thread(target=_hammer, args=(stats, start)) for _ in range(THREADS)]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
    finally:
        sys.setswitchinterval(previous)
    total = THREADS * CALLS
    assert (stats.windows, stats.events) == (2 * total, 3 * total)
    assert stats.interpreted_windows == total
    assert len(stats.latency) == min(2 * total, 65_536) and len(stats.window_latency) == min(total, 65_536)


def test_count_names_what_it_does_not_know():
    stats = RunStats()
    with pytest.raises(ValueError, match="not a counter: window"):
        stats.count(window=1)
    with pytest.raises(ValueError, match="not a noted value: windows"):
        stats.note(windows=3)
    stats.note(merged=("Pad",), missing=("Stick",))
    assert stats.copilot == (("Pad",), ("Stick",))
