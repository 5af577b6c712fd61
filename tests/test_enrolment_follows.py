"""``enrol --from`` labels what the gel did, not only what the plan asked
(neurotouch_hid/enrolment/agree.py): recordings made with the simulated hand that follow their
plan, and the same recordings given plans they do not follow."""

from __future__ import annotations

import dataclasses
import os

import pytest
from helpers import run_main

from neurotouch_hid.core.dataset import read_labels
from neurotouch_hid.core.estimate import GestureType
from neurotouch_hid.core.sensor import SensorGeometry
from neurotouch_hid.enrolment.hand import simulate_enrolment
from neurotouch_hid.enrolment.label import check_gestures, find_gestures, measure_motion
from neurotouch_hid.enrolment.plan import Plan, Prompt, write_plan

G = GestureType
PLAN = Plan(
    (
        Prompt(G.PUSH, 2.0, 1.5, "up"),
        Prompt(G.PINCH, 6.5, 0.4),
        Prompt(G.TWIST_CW, 10.0, 1.5),
        Prompt(G.ZOOM, 14.0, 0.4),
    )
)
#: Cues in the recording's tail, after the hand's last gesture: nothing is done there.
TAIL_CUES = (17.0, 18.0, 19.0, 20.0, 21.0)


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    """The simulated hand follows PLAN (seed 3, missing none), recorded 7 s past its end; the
    recording is also put, as a second name, in a folder with no sensor.yaml beside it."""
    folder = tmp_path_factory.mktemp("followed")
    done = simulate_enrolment(PLAN, folder, seed=3, miss_rate=0.0, tail_s=7.0)
    assert all(p.gesture is not None for p in done)
    bare = tmp_path_factory.mktemp("bare") / "session.aedat4"
    os.link(folder / "enrolment.aedat4", bare)
    return folder, bare


@pytest.fixture(scope="module")
def motion(recorded):
    folder, _ = recorded
    return measure_motion(folder / "enrolment.aedat4", SensorGeometry.load(folder / "sensor.yaml"))


def _enrol(monkeypatch, capsys, tmp_path, recording, plan: Plan, *extra: str):
    plan_file = write_plan(plan, tmp_path / "given.plan.json")
    out = tmp_path / "dataset"
    done = run_main(
        monkeypatch, capsys, ["enrol", "--from", str(recording), "--plan", str(plan_file), "--out", str(out), *extra]
    )
    return done, out


def test_every_prompt_agrees_with_its_own_gesture_and_with_no_other_type(recorded, motion):
    """What the gel did at each cue agrees with the type the hand performed there, and with none
    of the four other types (a plan asking another type at that cue leaves it out, named)."""
    folder, _ = recorded
    sensor = SensorGeometry.load(folder / "sensor.yaml")
    found = check_gestures(find_gestures(PLAN, motion), motion, sensor)
    assert [f.labelled for f in found] == [True] * 4, [f.disagrees for f in found]
    for i, prompt in enumerate(PLAN.prompts):
        for other in set(G) - {G.NONE, prompt.gesture}:
            asked = dataclasses.replace(prompt, gesture=other, direction="up" if other is G.PUSH else None)
            plan = Plan((*PLAN.prompts[:i], asked, *PLAN.prompts[i + 1 :]))
            checked = check_gestures(find_gestures(plan, motion), motion, sensor)[i]
            assert checked.seen and not checked.labelled, (prompt.gesture, other)
            assert checked.disagrees.startswith("the gel showed"), checked.disagrees


def test_a_push_the_other_way_is_not_the_push_asked(recorded, motion):
    folder, _ = recorded
    sensor = SensorGeometry.load(folder / "sensor.yaml")
    plan = Plan((dataclasses.replace(PLAN.prompts[0], direction="down"), *PLAN.prompts[1:]))
    found = check_gestures(find_gestures(plan, motion), motion, sensor)
    assert not found[0].labelled and "push up" in found[0].disagrees, found[0].disagrees
    assert all(f.labelled for f in found[1:])


def test_a_recording_that_follows_its_plan_is_labelled_and_linked_not_copied(recorded, tmp_path, monkeypatch, capsys):
    """With no sensor.yaml beside the recording (and no calibration), it says it labels with the
    built-in geometry; the dataset's recording is the same file under a second name."""
    _, bare = recorded
    done, out = _enrol(monkeypatch, capsys, tmp_path, bare, PLAN)
    assert done.returncode == 0, done.stderr
    assert "labelled 4 of 4 prompts" in done.stdout, done.stdout
    assert "the built-in geometry" in done.stderr, done.stderr
    assert os.stat(out / "session.aedat4").st_ino == os.stat(bare).st_ino
    assert "hard link" in done.stdout and "not a copy" in done.stdout, done.stdout
    kinds = {row.gesture for row in read_labels(out / "session.labels.csv")}
    assert kinds == {G.NONE, G.PUSH, G.PINCH, G.TWIST_CW, G.ZOOM}


def test_a_prompt_done_as_another_gesture_is_left_out_and_named(recorded, tmp_path, monkeypatch, capsys):
    folder, _ = recorded
    asked = (*PLAN.prompts[:1], dataclasses.replace(PLAN.prompts[1], gesture=G.ZOOM), *PLAN.prompts[2:])
    done, out = _enrol(monkeypatch, capsys, tmp_path, folder / "enrolment.aedat4", Plan(asked))
    assert done.returncode == 0, done.stderr
    assert "labelled 3 of 4 prompts" in done.stdout, done.stdout
    assert "prompt 2 (zoom at 0:06): the gel showed" in done.stdout, done.stdout
    assert "moving together (a pinch), not the zoom asked: left out" in done.stdout, done.stdout
    rows = read_labels(out / "enrolment.labels.csv")
    assert sum(r.gesture is G.ZOOM for r in rows) > 0  # the fourth prompt's
    cue, nxt = (int(PLAN.prompts[k].cue_s * 1e6) for k in (1, 2))
    first = rows[0].t_us  # cues count from the recording's start
    assert all(r.gesture is G.NONE for r in rows if cue <= r.t_us - first < nxt)


def test_a_recording_of_other_gestures_than_asked_does_not_follow_the_plan(recorded, tmp_path, monkeypatch, capsys):
    """A plan asking a push at every cue where a pinch, a twist and a zoom were done: exit 2,
    nothing written, the prompts named."""
    folder, _ = recorded
    pushes = Plan(tuple(dataclasses.replace(p, gesture=G.PUSH, direction="up") for p in PLAN.prompts))
    done, out = _enrol(monkeypatch, capsys, tmp_path, folder / "enrolment.aedat4", pushes)
    assert done.returncode == 2, done.stdout + done.stderr
    assert "it does not follow this plan: 3 of the 4 gestures found are not what their prompts asked" in done.stderr
    assert "prompt 2 (push up at 6.5 s): the gel showed" in done.stderr, done.stderr
    assert not out.exists()


def test_a_recording_with_fewer_than_half_the_prompts_done_does_not_follow_the_plan(
    recorded, tmp_path, monkeypatch, capsys
):
    folder, _ = recorded
    longer = Plan((*PLAN.prompts, *(Prompt(G.PINCH, cue, 0.4) for cue in TAIL_CUES)))
    done, out = _enrol(monkeypatch, capsys, tmp_path, folder / "enrolment.aedat4", longer)
    assert done.returncode == 2, done.stdout + done.stderr
    assert "it does not follow this plan: only 4 of the 9 prompts within it have the gesture asked" in done.stderr
    assert "no gesture near its cue" in done.stderr and not out.exists()


def test_an_empty_plan_labels_nothing_and_says_so(recorded, tmp_path, monkeypatch, capsys):
    folder, _ = recorded
    done, out = _enrol(monkeypatch, capsys, tmp_path, folder / "enrolment.aedat4", Plan(()))
    assert done.returncode == 2, done.stdout + done.stderr
    assert "the plan has no prompt" in done.stderr and not out.exists(), done.stderr


def test_session_options_beside_from_are_refused(recorded, tmp_path, monkeypatch, capsys):
    folder, _ = recorded
    done, out = _enrol(monkeypatch, capsys, tmp_path, folder / "enrolment.aedat4", PLAN, "--source", "sim")
    assert done.returncode == 2 and not out.exists()
    assert "--source: for a guided session, not for --from" in done.stderr, done.stderr


def test_adapt_refuses_labels_the_shipped_recogniser_contradicts_wholesale(
    recorded, motion, tmp_path, monkeypatch, capsys
):
    """A dataset whose labels call every gesture a push (the labels a plan of pushes would have
    given before they were checked): adapt writes no model and says why; the same recording
    labelled right passes the check."""
    from neurotouch_hid.core.dataset import write_labels
    from neurotouch_hid.enrolment.adapt_record import contradiction, record_datasets
    from neurotouch_hid.enrolment.label import label_frames, write_dataset

    folder, _ = recorded
    sensor = SensorGeometry.load(folder / "sensor.yaml")
    right = tmp_path / "right"
    write_dataset(right, folder / "enrolment.aedat4", PLAN, motion, sensor)
    assert contradiction(record_datasets([right])) is None
    wrong = tmp_path / "wrong"
    write_dataset(wrong, folder / "enrolment.aedat4", PLAN, motion, sensor)
    pushes = Plan(tuple(dataclasses.replace(p, gesture=G.PUSH, direction="up") for p in PLAN.prompts))
    write_labels(wrong / "enrolment.labels.csv", label_frames(motion, find_gestures(pushes, motion), sensor.px_per_mm))
    model = tmp_path / "model.yaml"
    done = run_main(monkeypatch, capsys, ["adapt", str(wrong), "--out", str(model), "--jobs", "1"])
    assert done.returncode == 2, done.stdout + done.stderr
    assert "the shipped recogniser reads 3 of the 4 labelled gestures it reads at all as another type" in done.stderr
    assert "labelled push read as pinch" in done.stderr and "no model is fitted" in done.stderr, done.stderr
    assert not model.exists()


def test_eval_says_when_labels_and_model_share_the_scored_folder(recorded, motion, tmp_path, monkeypatch, capsys):
    """An enrolment's labels were partly read by the pipeline eval scores, and a model fitted on
    the folder has seen its gestures: eval says both; a dataset of the simulator's own labels,
    scored with the shipped method, gets neither caution."""
    from neurotouch_hid.enrolment.label import write_dataset
    from neurotouch_hid.enrolment.model import Model

    folder, _ = recorded
    sensor = SensorGeometry.load(folder / "sensor.yaml")
    enrolled = tmp_path / "enrolled"
    write_dataset(enrolled, folder / "enrolment.aedat4", PLAN, motion, sensor)
    model = Model({"gesture.intensity_gain": 1.1}, None, {"from": [str(enrolled.resolve())]}).save(tmp_path / "m.yaml")
    done = run_main(monkeypatch, capsys, ["eval", str(enrolled), "--model", str(model)])
    assert done.returncode == 0, done.stderr
    assert "caution: enrolment: labelled by enrol from a plan" in done.stderr, done.stderr
    assert f"caution: --model {model} was fitted on {enrolled}" in done.stderr, done.stderr
    done = run_main(monkeypatch, capsys, ["eval", str(folder), "--model", "none"])
    assert done.returncode == 0 and "caution" not in done.stderr, done.stderr
