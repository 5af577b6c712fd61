"""benchmarks/felt_pooled.py on hand-made per-gesture records: the pooled figures are those of
all sessions' gestures together, each folder's p90 its own, and the p90's range is drawn from
whole sessions."""

from __future__ import annotations

import numpy as np
import pytest
from helpers import load_benchmark

from neurotouch_hid.evaluation.felt import FeltRecords


@pytest.fixture(scope="module")
def felt_pooled():
    return load_benchmark("felt_pooled")


def session(latencies_ms, wrong=()) -> FeltRecords:
    """One session's records: pushes reaching the dead zone with these latencies (NaN: missed)."""
    n = len(latencies_ms)
    return FeltRecords(
        gesture=np.zeros(n, np.int64),
        duration_ms=np.full(n, 500.0),
        onset_ms=np.full(n, 20.0),
        changes=np.zeros(n, np.int64),
        felt_changes=np.zeros(n, np.int64),
        felt_wrong=np.isin(np.arange(n), list(wrong)),
        wrong_as=np.full(n, -1, np.int64),
        reaches_deadzone=np.ones(n, bool),
        deadzone_latency_ms=np.asarray(latencies_ms, dtype=float),
        n_rest=10,
    )


def test_a_family_row_pools_the_folders_and_keeps_each_ones_p90(felt_pooled):
    slow = [session([10, 20, 30, 90]), session([10, 10, 20, 80])]  # one folder: two sessions
    fast = [session([10, 10, 20, 20], wrong=[0]), session([10, float("nan"), 20, 30])]
    row = felt_pooled.family_row("strong", [slow, fast], 200, np.random.default_rng(0))
    cells = [c.strip() for c in row.strip("|").split("|")]
    pooled = [10, 20, 30, 90, 10, 10, 20, 80, 10, 10, 20, 20, 10, 20, 30]
    assert cells[0] == "strong" and cells[1] == "16"
    assert cells[2] == "6.2 %"  # 1 of 16 gestures felt wrong
    assert cells[4] == f"{np.median(pooled):.0f} / {np.percentile(pooled, 90):.0f}"
    first, second = [10, 20, 30, 90, 10, 10, 20, 80], [10, 10, 20, 20, 10, 20, 30]
    assert cells[5] == f"{np.percentile(first, 90):.0f} / {np.percentile(second, 90):.0f}"
    low, high = (float(v) for v in cells[6].split("-"))
    assert low <= np.percentile(pooled, 90) <= high
    assert cells[7] == "1" and cells[8] == "0 of 40"


def test_the_p90_range_draws_whole_sessions(felt_pooled):
    # two sessions whose p90s are 10 and 100 ms: a draw of one session reads one or the other
    sessions = [session([10] * 10), session([100] * 10)]
    low, high = felt_pooled.p90_range(sessions, 1, 400, np.random.default_rng(1))
    assert (low, high) == (10.0, 100.0)
    assert np.isnan(felt_pooled.p90_range([session([float("nan")])], 1, 5, np.random.default_rng(0))[0])
