"""bench_stages.py (docs/performance.md, "Pipeline stages"): its arguments, and that its timers sit
on functions that exist, leave them as they were and change no estimate. No speed is asserted."""

from __future__ import annotations

import subprocess
import sys

import cv2
import pytest
from helpers import BENCHMARKS, load_benchmark

from neurotouch_hid.core.sensor import SensorGeometry
from neurotouch_hid.pipeline import contacts, fit_path, pipeline

SCRIPT = BENCHMARKS / "bench_stages.py"


@pytest.fixture(scope="module")
def bench_stages():
    return load_benchmark("bench_stages")


@pytest.mark.parametrize("args", [["--idle-ms", "-1"], ["--slowest-percent", "0"], ["--slowest-percent", "100"]])
def test_bad_arguments_are_refused_before_any_recording_is_made(args, tmp_path):
    done = subprocess.run(
        [sys.executable, str(SCRIPT), "--workdir", str(tmp_path / "w"), *args], capture_output=True, text=True
    )
    assert done.returncode == 2, done.stderr
    assert args[0] in done.stderr
    assert not (tmp_path / "w").exists()


def test_the_timers_wrap_existing_functions_and_are_removed_afterwards(bench_stages):
    targets = [
        (fit_path, "estimate_gel_motion"),
        (fit_path, "detect_contacts"),
        (fit_path, "estimate_gesture"),
        (pipeline.GesturePipeline, "_learned_type"),
        (contacts, "bump_fit"),
        (contacts, "with_missed_finger"),
        (contacts, "_refine_peak"),
        (cv2, "findHomography"),
        (cv2, "estimateAffinePartial2D"),
    ]
    before = [getattr(owner, name) for owner, name in targets]
    with bench_stages.Wrappers().installed():
        assert all(getattr(owner, name) is not f for (owner, name), f in zip(targets, before))
    assert all(getattr(owner, name) is f for (owner, name), f in zip(targets, before))


def test_a_wrapped_pass_gives_the_unwrapped_estimates_and_times_every_step(bench_stages, tmp_path):
    path = bench_stages.make_recording(tmp_path, 4.0)  # the first gestures: fits, no two-contact one yet
    sensor = SensorGeometry.load(tmp_path / "sensor.yaml")
    stream = bench_stages.items(*bench_stages.load(path), 1000)
    reference = bench_stages.run_pass(stream, sensor, 10_000, 0.0, "reference", None)
    hot = bench_stages.run_pass(stream, sensor, 10_000, 0.0, "hot", bench_stages.Wrappers())
    assert hot.digest == reference.digest
    assert hot.fits > 0 and hot.windows == reference.windows
    timed = ("item", "tracker", "contact_step", "detect_contacts", "homography", "gesture_step", "resting", "mapper")
    for key in timed:
        assert hot.steps[key], key
    assert len(hot.steps["contact_step"]) == len(hot.steps["homography"]) == hot.fits
    slowest = bench_stages.slowest(hot, 2.0)
    assert slowest["n"] >= 1 and slowest["item_mean_us"] >= slowest["threshold_us"]  # the items at or above the cut
    assert all(0 <= step["ran"] <= slowest["n"] for step in slowest["steps"].values())
