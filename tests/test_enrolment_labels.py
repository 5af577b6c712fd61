"""Labelling a recording made by following an enrolment's plan (``enrol --from``,
neurotouch_hid/enrolment/label.py) against the simulator's own labels.

The simulated hand (neurotouch_hid/enrolment/hand.py) starts late, holds longer or shorter; the
gel is the ``markers`` family with seed 8, neither of which the labeller was designed on (the
``default`` family, seed 1)."""

from __future__ import annotations

import dataclasses
import os
import re
import subprocess
import sys

import pytest

from neurotouch_hid.core.dataset import list_sequences, read_labels
from neurotouch_hid.core.estimate import GestureType
from neurotouch_hid.core.sensor import SensorGeometry
from neurotouch_hid.enrolment.hand import simulate_enrolment
from neurotouch_hid.enrolment.label import agreement, find_gestures, label_frames, label_recording, measure_motion
from neurotouch_hid.enrolment.plan import Plan, Prompt, make_plan, write_plan
from neurotouch_hid.sources.simulator import START_US

FAMILY, SEED, PROMPTS = "markers", 8, 6


@pytest.fixture(scope="module")
def performed(tmp_path_factory):
    """The hand performs the first prompts of seed 8's plan, missing none; and the plan a person
    would have been given with one more prompt, in a rest, that the hand never did."""
    folder = tmp_path_factory.mktemp("enrolment")
    plan = Plan(make_plan(SEED).prompts[:PROMPTS])
    done = simulate_enrolment(plan, folder, seed=SEED, physics=FAMILY, miss_rate=0.0)
    assert all(p.gesture is not None for p in done)
    settled_s = (done[2].gesture.t_settled_us - START_US) * 1e-6
    extra_cue = round(settled_s + 0.2, 3)  # the gel at rest after the third gesture, before the fourth's cue
    assert extra_cue + 0.4 < plan.prompts[3].cue_s
    extra = Prompt(GestureType.ZOOM, extra_cue, 0.4)
    with_extra = Plan((*plan.prompts[:3], extra, *plan.prompts[3:]))
    return folder, plan, with_extra


def test_labels_from_the_plan_agree_with_the_simulators(performed):
    folder, plan, _ = performed
    sensor = SensorGeometry.load(folder / "sensor.yaml")
    motion = measure_motion(folder / "enrolment.aedat4", sensor)
    found = find_gestures(plan, motion)
    assert all(f.seen for f in found)
    score = agreement(read_labels(folder / "enrolment.labels.csv"), label_frames(motion, found, sensor.px_per_mm))
    print(score)
    assert score.frames > 300
    assert score.gesture >= 0.95
    assert score.contacts >= 0.8
    assert score.intensity_mae_mm < 1.0


def test_a_prompt_with_no_gesture_is_left_out_and_said(performed, tmp_path):
    folder, _, with_extra = performed
    plan_file = write_plan(with_extra, tmp_path / "given.plan.json")
    out = tmp_path / "dataset"
    env = {**os.environ, "PYTHONPATH": os.getcwd()}
    result = subprocess.run(
        [
            sys.executable,
            "-m",
            "neurotouch_hid.cli",
            "enrol",
            "--from",
            str(folder / "enrolment.aedat4"),
            "--plan",
            str(plan_file),
            "--out",
            str(out),
        ],
        capture_output=True,
        text=True,
        env=env,
        timeout=600,
    )
    assert result.returncode == 0, result.stderr
    assert "labelled 6 of 7 prompts" in result.stdout
    # recorded from the simulated camera: adapt keeps such a model out of the user's (it needs --out)
    assert f"neurotouch-hid adapt {out} --out sim-model.yaml" in " ".join(result.stdout.split()), result.stdout
    assert (
        f"prompt 4 (zoom at {with_extra.prompts[3].cue_s:g} s): no gesture seen near its cue, left out" in result.stdout
    )
    # the folder is a dataset (docs/dataset.md): eval reads it; the zoom never done is not labelled
    assert list_sequences(out) == ["enrolment"]
    labels = read_labels(out / "enrolment.labels.csv")
    kinds = [r.gesture for r in labels]
    runs = [k for i, k in enumerate(kinds) if k is not GestureType.NONE and (i == 0 or kinds[i - 1] is not k)]
    assert runs == [p.gesture for p in with_extra.prompts if p is not with_extra.prompts[3]]
    assert (out / "sensor.yaml").exists() and (out / "enrolment.plan.json").exists()
    assert sorted(os.listdir(out)) == ["enrolment.aedat4", "enrolment.labels.csv", "enrolment.plan.json", "sensor.yaml"]


def test_labelling_in_place_writes_over_no_input(performed, tmp_path):
    folder, plan, _ = performed
    work = tmp_path / "in-place"
    work.mkdir()
    for name in ("enrolment.aedat4", "sensor.yaml"):
        (work / name).write_bytes((folder / name).read_bytes())
    plan_file = write_plan(dataclasses.replace(plan), work / "enrolment.plan.json")
    before = {name: (work / name).read_bytes() for name in os.listdir(work)}
    stats = {name: os.stat(work / name).st_ino for name in before}
    sensor = SensorGeometry.load(work / "sensor.yaml")
    done = label_recording(work / "enrolment.aedat4", plan, work, sensor, inputs=[plan_file, work / "sensor.yaml"])
    assert not done.missed
    for name, data in before.items():  # the recording, the plan and sensor.yaml are untouched
        assert (work / name).read_bytes() == data
        assert os.stat(work / name).st_ino == stats[name]
    assert (work / "enrolment.labels.csv").exists()


def test_a_recording_that_does_not_follow_the_plan_fails_and_writes_nothing(performed, tmp_path):
    """``enrol --from`` with a plan whose cues all fall after the recording's gestures: no
    prompt's gesture is found, so no "labelled 0 of 7" dataset that ``adapt`` then refuses: exit
    2, what to do, and no folder."""
    folder, plan, _ = performed
    last = plan.prompts[-1].end_s + 10.0
    elsewhere = Plan(tuple(dataclasses.replace(p, cue_s=p.cue_s + last) for p in plan.prompts))
    plan_file = write_plan(elsewhere, tmp_path / "other.plan.json")
    out = tmp_path / "dataset"
    env = {**os.environ, "PYTHONPATH": os.getcwd()}
    argv = ["enrol", "--from", str(folder / "enrolment.aedat4"), "--plan", str(plan_file), "--out", str(out)]
    result = subprocess.run(
        [sys.executable, "-m", "neurotouch_hid.cli", *argv], capture_output=True, text=True, env=env, timeout=600
    )
    assert result.returncode == 2, (result.stdout, result.stderr)
    n = len(plan.prompts)  # cues past the recording's end, or (within it) no gesture near any cue
    assert f"every one of the plan's {n} prompts is cued after" in result.stderr or (
        f"no gesture near any of the plan's {n} cues" in result.stderr
    )
    assert "labelled 0" not in result.stdout and "adapt" not in result.stdout
    assert not out.exists()


def test_an_intensity_is_the_displacement_of_the_labelled_contact_points_since_the_gesture_s_start():
    """docs/dataset.md: a label's intensity is the mean displacement of its contact points since
    the gesture's start. Points held from an earlier window were labelled with another window's
    intensity (0 mm beside a held point), and a frame with no point with the gel's motion."""
    import numpy as np

    from neurotouch_hid.core.estimate import GestureEstimate
    from neurotouch_hid.enrolment.label import Found, GelMotion, contact_displacement_mm

    start = np.array([[100.0, 100.0], [110.0, 100.0], [200.0, 200.0]], np.float32)
    pressed = start + np.array([[3.0, 4.0], [0.0, 1.0], [0.0, 0.0]], np.float32)  # 5 px and 1 px moved
    assert contact_displacement_mm(pressed, start, np.array([[103.0, 104.0]]), 2.5) == pytest.approx(2.0)
    both = np.array([[103.0, 104.0], [110.0, 101.0]])
    assert contact_displacement_mm(pressed, start, both, 2.5) == pytest.approx((5.0 + 1.0) / 2 / 2.5)
    assert contact_displacement_mm(pressed, start, np.zeros((0, 2)), 2.5) == 0.0
    lost = pressed.copy()
    lost[0] = np.nan  # the nearest marker lost: the next nearest tracked one
    assert contact_displacement_mm(lost, start, np.array([[103.0, 104.0]]), 2.5) == pytest.approx(0.4)

    # windows at 10, 20, 30 ms; the push starts at 10 ms; frames at 15 and 25 ms
    point = np.array([[103.0, 104.0]])
    own = GestureEstimate(20_000, GestureType.PUSH, False, 1.9, point, point / 2.5)
    none = GestureEstimate(30_000, GestureType.PUSH, False, 0.0)  # no contact point in this window
    motion = GelMotion(
        t_us=np.array([10_000, 20_000, 30_000]),
        moved_mm=np.array([0.0, 2.0, 2.0]),
        estimates=[GestureEstimate(10_000, GestureType.NONE, True, 0.0), own, none],
        frames_us=np.array([15_000, 25_000]),
        start_us=0,
        positions_px=np.stack([start, pressed, pressed]),
    )
    prompt = Prompt(GestureType.PUSH, 0.0, 1.0)
    rows = label_frames(motion, [Found(prompt, 10_000, 40_000, 2.0)], 2.5)
    assert rows[0].intensity_mm == pytest.approx(1.9)  # the window's own point: the pipeline's measure
    np.testing.assert_allclose(rows[1].contacts_px, point)  # held from the window before
    assert rows[1].intensity_mm == pytest.approx(2.0)  # measured at the held point's marker, not 0


@pytest.mark.parametrize(
    "of, says", [(None, "any of the plan's 2 cues"), (24, "any of the 2 cues within it (of the plan's 24 prompts)")]
)
def test_a_recording_that_follows_no_cue_says_how_many_cues_it_covers(tmp_path, of, says):
    """A 5 s recording of a 24-prompt plan covers 2 of its cues: the message counts those two
    and names the plan's 24, not '1 cues' of a plan the user knows as 24 prompts."""
    import numpy as np

    from neurotouch_hid.core.errors import DatasetError
    from neurotouch_hid.core.estimate import GestureEstimate
    from neurotouch_hid.enrolment.label import GelMotion, write_dataset

    t = np.arange(10_000, 5_000_001, 10_000)
    still = GelMotion(t, np.zeros(len(t)), [GestureEstimate(int(x)) for x in t], np.array([0]), 0)
    plan = Plan((Prompt(GestureType.PUSH, 1.0, 2.0), Prompt(GestureType.PINCH, 3.0, 4.0)))
    with pytest.raises(DatasetError, match=r"no gesture near " + re.escape(says)):
        write_dataset(tmp_path / "out", tmp_path / "rec.aedat4", plan, still, SensorGeometry(), of=of)
    assert not (tmp_path / "out").exists()
