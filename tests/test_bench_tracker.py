"""benchmarks/bench_tracker.py's scoring against the simulator's truth: the position error and the
lag along the motion, on hand-computed cases."""

import numpy as np
from helpers import load_benchmark

bench = load_benchmark("bench_tracker")


def test_the_lag_is_how_far_behind_along_the_motion_in_ms():
    rest = np.array([[10.0, 10.0], [50.0, 50.0], [90.0, 90.0]])
    truth = rest + np.array([[3.0, 0.0], [0.0, 2.0], [1.5, 0.0]])
    velocity = np.array([[0.1, 0.0], [0.0, -0.05], [0.01, 0.0]])  # px/ms; the third too slow to count
    est = truth + np.array([[-0.5, 0.3], [0.0, -0.1], [-1.0, 0.0]])  # 5 ms behind, 2 ms ahead
    run = bench.Run("probe")
    bench.score(run, est, np.ones(3, bool), truth, rest, np.arange(3), velocity)
    np.testing.assert_allclose(run.lags[0], [5.0, -2.0])
    np.testing.assert_allclose(run.errors[0], [np.hypot(0.5, 0.3), 0.1, 1.0])
    assert run.row()[4] == "1.50"


def test_the_true_velocity_is_the_motion_over_the_last_5_ms():
    t_grid = np.arange(0, 20_001, 1_000, dtype=np.int64)
    positions = np.zeros((len(t_grid), 1, 2))
    positions[:, 0, 0] = 0.02 * (t_grid / 1000.0) ** 2  # accelerating: v = 0.04 t px/ms
    v = bench.true_velocity(t_grid, positions, 10)
    np.testing.assert_allclose(v, [[0.02 * (100 - 25) / 5, 0.0]])
    np.testing.assert_array_equal(bench.true_velocity(t_grid, positions, 0), [[0.0, 0.0]])
