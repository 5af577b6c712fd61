"""A creeping gel (``pipeline/creep.py``, sensor.yaml's ``creep``, ``calibrate --press``): the
load behind the deformation, its fit to a press, and the release tails it ends."""

from __future__ import annotations

import csv
import dataclasses
import json
import shutil

import numpy as np
import pytest
from helpers import load_benchmark, run_cli
from typer.testing import CliRunner

from neurotouch_hid.cli import app
from neurotouch_hid.core.errors import SensorError
from neurotouch_hid.core.sensor import SensorGeometry
from neurotouch_hid.pipeline.creep import (
    SHARES,
    TIMES_S,
    CreepFilter,
    TailWatch,
    creep_misfit,
    fit_creep,
    load_estimate,
)
from neurotouch_hid.pipeline.creep import at_search_edge as creep_at_search_edge
from neurotouch_hid.sources.physics import sls_deformation
from neurotouch_hid.sources.sim_dataset import write_dataset

STEP_US = 10_000  # a window


def press_load(hold_s: float = 2.0, rest_s: float = 2.0) -> np.ndarray:
    """(T,) a finger's load every 10 ms: 0.5 s at rest, a 0.1 s ramp to 10 px, the hold, a
    0.1 s ramp down, then the rest."""
    ramp = np.linspace(0.0, 10.0, 11)[1:]
    return np.concatenate(
        [np.zeros(50), ramp, np.full(int(hold_s * 100), 10.0), ramp[::-1] - 1.0, np.zeros(int(rest_s * 100))]
    ).clip(0.0)


def creeping(load: np.ndarray, share: float, time_s: float) -> np.ndarray:
    """The simulator's standard linear solid (``physics.sls_deformation``) under ``load``."""
    return sls_deformation(load, float(STEP_US), share, time_s * 1e6)


def test_the_load_behind_a_creeping_gel_is_the_load_that_deformed_it():
    """The simulator's gel (its own discretisation of the standard linear solid) deformed by a
    press: the filter recovers the load within 2 % of the peak in every window, while the
    deformation itself is still 15 % of the peak 0.1 s after the release."""
    load = press_load()
    deformation = creeping(load, 0.3, 0.3)
    t = np.arange(len(load)) * STEP_US
    creep = CreepFilter(0.3, 0.3)
    estimate = np.array([creep.update(d, int(ti)) for d, ti in zip(deformation, t)])
    assert np.abs(estimate - load).max() < 0.2
    released = np.flatnonzero(load > 0)[-1] + 10
    assert deformation[released] > 1.5 and estimate[released] < 0.2
    # the same numbers for a grid of models at once
    grid = load_estimate(deformation, t, np.array([0.0, 0.3]), np.array([0.3, 0.3]))
    np.testing.assert_allclose(grid[:, 1], estimate, rtol=1e-12, atol=1e-12)
    np.testing.assert_array_equal(grid[:, 0], deformation)  # an elastic gel: the load is what is seen


def test_a_creep_measured_quicker_than_the_gels_still_reads_the_fingers_gone_at_the_release():
    """The gel creeps with tau 0.4 s, the filter was calibrated at 0.3 s (one press measures it
    only so well). Its load read rises back above the 0.3 px floor 50 ms after the fingers left and
    stays there for 0.45 s; with the margin (a fifth of the delayed deformation q y) the fingers are
    read gone within 20 ms of the release and stay gone, while the 2 s hold is never read released."""
    load = press_load()
    deformation = creeping(load, 0.3, 0.4)
    t = np.arange(len(load)) * STEP_US
    creep = CreepFilter(0.3, 0.3, floor=0.3)
    released = []
    for d, ti in zip(deformation, t):
        estimate = creep.update(d, int(ti))
        released.append((estimate < 0.3, creep.released(estimate)))
    no_margin, with_margin = (np.array(r) for r in zip(*released))
    last = int(np.flatnonzero(load > 0)[-1])
    start = int(np.flatnonzero(load > 0)[0])
    assert not with_margin[start:last].any()  # the press and its hold
    assert with_margin[last + 2 :].all()
    assert not no_margin[last + 6 : last + 50].any()  # without the margin: pressed again, 0.45 s


def test_fingers_read_gone_stay_gone_through_a_tails_sawtooth_until_a_new_press_or_a_still_gel():
    """After the release the tracked tail rises up to 0.45 px between two APS frames' corrections
    (every 4 windows). Against the threshold alone the fingers would be read back every fourth
    window, switching the output on and off; with the hysteresis they stay gone. A new press
    (0.5 px more a window, 0.9 s after the release) is read from its second window, and a gel
    seen still (a deformation below the floor) reads nothing back either."""
    load = press_load(rest_s=1.0)
    start = len(load) - 60
    second = np.zeros_like(load)
    second[start:] = np.minimum(np.arange(60) * 0.5, 3.0)
    last = int(np.flatnonzero(load > 0)[-1])
    k = np.arange(len(load))
    sawtooth = np.where(k > last, 0.45 * (k % 4) / 3, 0.0)
    deformation = creeping(load + second, 0.3, 0.3) + sawtooth
    creep = CreepFilter(0.3, 0.3, floor=0.3)
    threshold_only, released = [], []
    for d, ti in zip(deformation, k * STEP_US):
        estimate = creep.update(d, int(ti))
        threshold_only.append(estimate < creep.threshold)
        released.append(creep.released(estimate))
    threshold_only, released = np.array(threshold_only), np.array(released)
    assert threshold_only[last + 1 : start].sum() < start - last - 1 - 5  # read back 6 times or more
    assert released[last + 1 : start].all()
    assert not released[start + 1 :].any()
    assert creep.released(0.0)  # gone again
    assert creep.released(1.2 * creep.threshold)  # above the threshold, below REARM times it: still gone
    creep.update(0.1, int(len(k) * STEP_US))  # the gel seen still
    assert not creep.released(1.2 * creep.threshold)


def test_a_gel_seen_at_rest_holds_no_creep_so_the_next_press_is_read_at_once():
    """A deep press held 3 s, released; its tail is followed until it reads 0.7 px, then the
    pipeline's rest reference takes in what is left (0 px for 150 ms), and a slow press starts
    elsewhere (3 px in 0.4 s). With the creep calibrated slower than the gel (tau 0.45 s for 0.3 s),
    the unbounded inverse still holds the first press's creep: its load passes the 0.3 px
    threshold 90 ms after the true load; bounded (no pull: y <= max(d, floor) / q) 30 ms after,
    and the tail stays below the threshold all the same."""
    load1 = 2.0 * press_load(hold_s=3.0, rest_s=0.0)
    seen = creeping(np.concatenate([load1, np.zeros(300)]), 0.3, 0.3)
    tail = seen[len(load1) :]
    tail = tail[: int(np.argmax(tail < 0.7))]
    second_load = np.concatenate([np.linspace(0.0, 3.0, 41), np.full(60, 3.0)])
    d = np.concatenate([seen[: len(load1)], tail, np.zeros(15), creeping(second_load, 0.3, 0.3)])
    t = np.arange(len(d)) * STEP_US
    creep = CreepFilter(0.28, 0.45, floor=0.3)
    bounded = np.array([creep.update(x, int(ti)) for x, ti in zip(d, t)])
    unbounded = load_estimate(d, t, 0.28, 0.45)
    start = len(d) - len(second_load)
    assert bounded[len(load1) + 5 : start].max() < 0.3  # the tail: no false activation
    true_onset = int(np.argmax(second_load >= 0.3))
    assert int(np.argmax(bounded[start:] >= 0.3)) - true_onset <= 3
    assert int(np.argmax(unbounded[start:] >= 0.3)) - true_onset >= 8
    # while the gel is seen still, y is at most floor / q: the load no lower than -floor / (1 - q)
    still = bounded[start - 15 : start]
    assert np.all(still <= 0.0) and np.all(still >= -0.3 / 0.72 - 1e-9)


def test_a_new_press_in_a_release_tail_is_found_and_measured_from_the_gel_the_tail_left():
    """A tail whose 40 markers relax back towards rest, 0.05 px a window with +-0.1 px of tracking
    noise, shows no new press; once 6 of them move 0.2 px or more out again from their least, a
    new press has begun, and the reference given back is where each marker was at its least (the
    new press's markers from before they moved out). Forgotten, the watch starts afresh."""
    rng = np.random.default_rng(3)
    n = 40
    direction = np.tile([1.0, 0.0], (n, 1))
    watch = TailWatch()
    positions = []
    for k in range(30):  # the relaxing tail
        distance = 3.0 - 0.05 * k + rng.uniform(-0.1, 0.1, n)
        positions.append(direction * distance[:, None])
        assert watch.update(distance, positions[-1], 0.15, 6) is None
    least_at = np.stack(positions)[np.argmin(np.stack([p[:, 0] for p in positions]), axis=0), np.arange(n)]
    distance = 3.0 - 0.05 * 30 + rng.uniform(-0.1, 0.1, n)
    pressed = np.arange(6)
    distance[pressed] = least_at[pressed, 0] + 0.3  # out again, beyond 0.15 px
    reference = watch.update(distance, direction * distance[:, None], 0.15, 6)
    assert reference is not None
    np.testing.assert_allclose(reference[pressed], least_at[pressed])
    distance[pressed[-1]] = least_at[pressed[-1], 0]  # one fewer: 5 of 6
    assert watch.update(distance, direction * distance[:, None], 0.15, 6) is None
    watch.reset()
    assert watch.update(distance + 1.0, direction * (distance + 1.0)[:, None], 0.15, 6) is None


def test_a_creep_model_needs_a_share_below_one_a_positive_time_a_floor_and_a_margin_not_below_zero():
    for share, time_s, floor, margin in (
        (1.0, 0.3, 0.0, 0.2),
        (-0.1, 0.3, 0.0, 0.2),
        (0.3, 0.0, 0.0, 0.2),
        (0.3, 0.3, -0.1, 0.2),
        (0.3, 0.3, 0.0, -0.1),
    ):
        with pytest.raises(ValueError, match=r"0 <= q < 1, tau > 0 s, a floor >= 0 and a margin >= 0"):
            CreepFilter(share, time_s, floor, margin)


@pytest.mark.parametrize(("share", "time_s"), [(0.3, 0.3), (0.2, 0.6), (0.4, 0.3), (0.15, 1.0)])
def test_a_press_gives_the_gels_creep(share, time_s):
    """A press on a simulated creeping gel with tracking noise (0.1 px) and a tremor: the fit
    finds q within 0.05 and tau within 30 %; on an elastic gel no creep. (A much faster
    creep, tau ~0.15 s, is mostly over before the hold starts: its q is then found low, which
    matters little, as its tail is as short.)"""
    rng = np.random.default_rng(3)
    load = press_load()
    load = load * (1.0 + 0.02 * np.sin(np.arange(len(load)) * 0.3))  # a 5 Hz tremor
    t = np.arange(len(load)) * STEP_US
    fitted_q, fitted_tau = fit_creep(t, creeping(load, share, time_s) + rng.normal(0.0, 0.1, len(load)))
    assert abs(fitted_q - share) <= 0.05
    assert abs(fitted_tau - time_s) <= 0.3 * time_s
    assert fit_creep(t, load + rng.normal(0.0, 0.1, len(load))) is None


def test_an_elastic_gel_with_the_trackers_error_after_a_quick_lift_does_not_creep():
    """After a quick lift the tracker can leave a few blobs up to half a marker pitch behind their
    markers until the gel is seen near rest (the elastic simulated families' presses: ~4 px for
    ~0.1 s, then 0). A small creep explains part of that plateau (q 0.1-0.14 was written for
    those gels, and ended their gestures' release ramps early), but not half of what the elastic
    gel leaves: no creep. The same plateau on a gel that does creep keeps its creep."""
    rng = np.random.default_rng(4)
    load = press_load()
    t = np.arange(len(load)) * STEP_US
    end = int(np.flatnonzero(load > 0)[-1]) + 1
    stuck = np.zeros(len(load))
    stuck[end : end + 10] = 4.0  # left behind, then re-anchored when the gel is seen near rest
    noise = rng.normal(0.0, 0.1, len(load))
    misfit = creep_misfit(t, load + stuck + noise)
    assert SHARES[np.unravel_index(np.argmin(misfit), misfit.shape)[0]] >= 0.04  # the best model: a creep not there
    assert fit_creep(t, load + stuck + noise) is None
    share, time_s = fit_creep(t, creeping(load, 0.3, 0.3) + stuck + noise)
    assert abs(share - 0.3) <= 0.05 and abs(time_s - 0.3) <= 0.3 * 0.3


def test_no_press_or_no_release_is_refused_with_what_to_do():
    t = np.arange(300) * STEP_US
    with pytest.raises(ValueError, match="no press"):
        fit_creep(t, np.zeros(300))
    held_to_the_end = np.concatenate([np.zeros(50), np.full(250, 10.0)])
    with pytest.raises(ValueError, match="hold it still ~2 s, lift it quickly"):
        fit_creep(t, held_to_the_end)


def test_sensor_yaml_keeps_the_creep_and_names_a_bad_one(tmp_path):
    path = tmp_path / "sensor.yaml"
    SensorGeometry(creep=(0.28, 0.45)).save(path)
    assert SensorGeometry.load(path).creep == (0.28, 0.45)
    SensorGeometry().save(path)
    assert "creep" not in path.read_text() and SensorGeometry.load(path).creep is None
    path.write_text("px_per_mm: 2.5\ncreep: [1.2, 0.3]\n")
    with pytest.raises(SensorError, match=r"sensor.yaml:2: field 'creep': .*less than 1"):
        SensorGeometry.load(path)


@pytest.fixture(scope="module")
def viscoelastic_push(tmp_path_factory):
    """One push of test user 0 on the simulated viscoelastic gel (q 0.3, tau 0.3 s)."""
    folder = tmp_path_factory.mktemp("visco")
    write_dataset(folder, seed=2, users=[0], gestures=["push"], minutes=0.06, progress=False, physics="viscoelastic")
    return folder


def tails(folder, sensor_file, out):
    """(windows labelled none after a gesture and answered with one, windows labelled a gesture
    and answered with one) of ``track`` on the push."""
    result = CliRunner().invoke(
        app, ["track", str(folder / "u0_push.aedat4"), "--out", str(out), "--sensor", str(sensor_file)]
    )
    assert result.exit_code == 0, result.output
    answered = {json.loads(line)["t_us"]: json.loads(line)["gesture"] for line in out.read_text().splitlines()}
    tail = held = 0
    seen = False
    for row in csv.DictReader((folder / "u0_push.labels.csv").open()):
        t = int(row["t_us"])
        nearest = min(answered, key=lambda k: abs(k - t))
        seen |= row["gesture"] != "none"
        if row["gesture"] != "none":
            held += answered[nearest] != "none"
        elif seen and row["resting"] == "0":
            tail += answered[nearest] != "none"
    return tail, held


def test_a_measured_creep_ends_the_gesture_when_the_fingers_leave(viscoelastic_push, tmp_path):
    """The hand-made case of the change: on a viscoelastic push the old rule answers the release's
    relaxation (labelled none: the fingers have left) as push; with the gel's creep in
    sensor.yaml most of those windows answer none, and the windows of the push itself still
    answer a gesture."""
    sensor = SensorGeometry.load(viscoelastic_push / "sensor.yaml")
    sensor.save(tmp_path / "elastic.yaml")
    dataclasses.replace(sensor, creep=(0.3, 0.3)).save(tmp_path / "creep.yaml")
    old_tail, old_held = tails(viscoelastic_push, tmp_path / "elastic.yaml", tmp_path / "a.jsonl")
    new_tail, new_held = tails(viscoelastic_push, tmp_path / "creep.yaml", tmp_path / "b.jsonl")
    assert old_tail >= 5  # the old rule reads the relaxation as the gesture (11 windows here)
    assert new_tail <= old_tail / 3
    assert new_held >= 0.95 * old_held


@pytest.fixture(scope="module")
def viscoelastic_press(tmp_path_factory):
    """A press on the simulated viscoelastic gel: one push of tuning user 5, seed 1, 6 s (what
    family_eval.py calibrates that family on)."""
    folder = tmp_path_factory.mktemp("press")
    write_dataset(folder, seed=1, users=[5], gestures=["push"], minutes=0.1, progress=False, physics="viscoelastic")
    return folder


def test_calibrate_press_measures_the_creep_and_keeps_it_when_recalibrated(viscoelastic_press, tmp_path):
    """``calibrate --press`` on a simulated press of the viscoelastic gel (q 0.3, tau 0.3 s)
    writes a creep near it; calibrating again without --press keeps it."""
    recording = str(viscoelastic_press / "u5_push.aedat4")
    out = tmp_path / "sensor.yaml"
    runner = CliRunner()
    args = ["calibrate", "--source", recording, "--out", str(out), "--mirror", "--rotation", "0"]
    result = runner.invoke(app, [*args, "--press", recording])
    assert result.exit_code == 0, result.output
    share, time_s = SensorGeometry.load(out).creep
    assert 0.2 <= share <= 0.4 and 0.2 <= time_s <= 0.6
    assert "creep: q" in result.output
    result = runner.invoke(app, args)
    assert result.exit_code == 0, result.output
    assert SensorGeometry.load(out).creep == (share, time_s)
    assert "kept from" in result.output


def test_calibrate_press_on_an_elastic_gel_writes_no_creep_and_says_so(sim_push_recording, tmp_path):
    """``calibrate --press`` on a push of the default (elastic) simulated gel: "creep: none", and
    the creep an earlier calibration wrote is gone from sensor.yaml (it would end every gesture's
    release early); the rest of the calibration is written as without --press."""
    recording = str(sim_push_recording)
    out = tmp_path / "sensor.yaml"
    SensorGeometry(creep=(0.1, 0.2)).save(out)
    args = ["calibrate", "--source", recording, "--out", str(out), "--mirror", "--rotation", "0"]
    result = CliRunner().invoke(app, [*args, "--press", recording])
    assert result.exit_code == 0, result.output
    assert "creep: none" in result.output and "creep: q" not in result.output
    written = SensorGeometry.load(out)
    assert written.creep is None and "creep" not in out.read_text()
    assert written.px_per_mm > 0 and written.gel_radius_px > 0


def test_calibrate_press_refuses_a_recording_without_a_press_and_loses_nothing(sim_rest_dataset, tmp_path):
    """A press recording that shows no press (the gel at rest throughout), or that does not
    exist: one line saying what to do, no traceback, and the sensor.yaml already there is left
    as it was."""
    recording = str(sim_rest_dataset / "u0_push.aedat4")  # 0.6 s: the gel rests until the push would start
    out = tmp_path / "sensor.yaml"
    SensorGeometry(creep=(0.1, 0.2)).save(out)
    before = out.read_text()
    args = ["calibrate", "--source", recording, "--out", str(out), "--mirror", "--rotation", "0"]
    done = run_cli(*args, "--press", recording)
    assert done.returncode == 2, done.stdout + done.stderr
    assert "cannot measure the gel's creep: the recording shows no press" in done.stderr
    assert "Traceback" not in done.stderr and len(done.stderr.strip().splitlines()) == 1
    done = run_cli(*args, "--press", str(tmp_path / "missing.aedat4"))
    assert done.returncode == 2 and "missing.aedat4" in done.stderr and "Traceback" not in done.stderr
    assert out.read_text() == before


def test_a_creep_on_the_edge_of_the_search_is_flagged():
    """The shortest or longest tau, or the largest q, searched: the press did not look like a
    creeping gel's (e.g. the strong family's 32 px press: q 0.58, tau 0.05 s)."""
    assert creep_at_search_edge(0.58, float(TIMES_S[0]))
    assert creep_at_search_edge(float(SHARES[-1]), 0.3)
    assert creep_at_search_edge(0.1, float(TIMES_S[-1]))
    assert not creep_at_search_edge(0.28, 0.45)


def test_family_eval_calibrates_a_familys_creep_on_its_press(viscoelastic_press, tmp_path):
    """family_eval.py's ``press_creep`` (the press of tuning user 5, seed 1, here the fixture's
    same simulation) writes the measured creep into the family's sensor.yaml, the rest of it
    unchanged."""
    family_eval = load_benchmark("family_eval")
    press_dir = tmp_path / "presses" / "viscoelastic"
    shutil.copytree(viscoelastic_press, press_dir)
    sensor_file = tmp_path / "sensor.yaml"
    shutil.copy(viscoelastic_press / "sensor.yaml", sensor_file)
    share, time_s = family_eval.press_creep(press_dir, "viscoelastic", sensor_file)
    written = SensorGeometry.load(sensor_file)
    assert written.creep == (share, time_s) and 0.2 <= share <= 0.4
    assert dataclasses.replace(written, creep=None) == SensorGeometry.load(viscoelastic_press / "sensor.yaml")


def test_the_filter_reads_the_gels_amplitude_and_scales_the_intensity_by_its_load_share():
    """The gesture's intensity is a mean about its contacts: a larger share of the gel's field in a
    release tail (the fingers gone, the field relaxing about its peaks) than in the hold (0.64
    against 1.0 on a simulated twist). Fed that intensity, a creep calibrated on the gel's
    amplitude reads the tail as load for its first 0.3 s (a gesture answered where the fingers have
    left); the pipeline feeds the filter the amplitude the creep was calibrated on, and reads the
    intensity's share of load (load / amplitude), so the tail reads gone from the release on while
    the hold never does."""
    from types import SimpleNamespace

    from neurotouch_hid.pipeline.creep import amplitude
    from neurotouch_hid.pipeline.pipeline import GesturePipeline

    load = press_load()
    field = creeping(load, 0.3, 0.3) * 2.0  # the top markers' mean displacement (px)
    pressed = load > 0
    intensity = np.where(pressed, 0.64, 1.0) * field  # the intensity's share of it: hold, tail
    t = np.arange(len(load)) * STEP_US
    rest = np.zeros((20, 2))
    gone_old, gone_new = [], []
    old = CreepFilter(0.3, 0.3, floor=0.3)
    new = SimpleNamespace(_creep=CreepFilter(0.3, 0.3, floor=0.3), rest_px=rest, _tail=TailWatch())
    for a, i, ti in zip(field, intensity, t):
        positions = np.column_stack([np.linspace(0.5, 1.0, 20) * a, np.zeros(20)])
        positions[-10:, 0] = a  # the ten most displaced markers at the amplitude
        new.tracker = SimpleNamespace(positions_px=positions, valid=np.ones(20, bool))
        assert amplitude(positions, rest, np.ones(20, bool)) == pytest.approx(a)
        gone_old.append(old.released(old.update(i, int(ti))))
        gone_new.append(GesturePipeline._released(new, float(i), int(ti)))
    gone_old, gone_new = np.array(gone_old), np.array(gone_new)
    start, last = int(np.flatnonzero(pressed)[0]), int(np.flatnonzero(pressed)[-1])
    tail = slice(last + 1, last + 31)  # the first 0.3 s after the fingers left
    assert not gone_new[start:last].any() and not gone_old[start:last].any()  # the hold
    assert gone_new[tail].all()
    assert not gone_old[tail].any()


def test_the_gels_amplitude_is_its_ten_most_displaced_valid_markers():
    from neurotouch_hid.pipeline.creep import amplitude

    rest = np.zeros((14, 2))
    positions = np.column_stack([np.arange(14.0), np.zeros(14)])
    valid = np.ones(14, bool)
    assert amplitude(positions, rest, valid) == pytest.approx(np.arange(4.0, 14.0).mean())
    valid[13] = False  # a lost marker does not count
    positions[12] = np.nan
    assert amplitude(positions, rest, valid) == pytest.approx(np.arange(2.0, 12.0).mean())
    assert amplitude(positions[:3], rest[:3], valid[:3]) == pytest.approx(1.0)  # fewer than ten
    assert amplitude(positions[:0], rest[:0], valid[:0]) == 0.0
