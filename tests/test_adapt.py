"""Adaptation (``enrolment/adapt*.py``, ``enrolment/model.py``; docs/method.md, "Adaptation"): the
model file, what ``adapt`` fits and keeps, and ``--model`` on the commands that run the pipeline."""

from __future__ import annotations

import csv
import dataclasses
import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from helpers import run_cli

from neurotouch_hid.core.estimate import GestureType
from neurotouch_hid.core.sensor import SensorGeometry
from neurotouch_hid.enrolment.adapt import adapt, summary
from neurotouch_hid.enrolment.adapt_fit import _felt_wrong, _fit_first_finger, replay
from neurotouch_hid.enrolment.adapt_record import Record, held_out_prompts, record_datasets
from neurotouch_hid.enrolment.model import (
    Model,
    ModelError,
    apply_model,
    load_model,
    resolve_model,
    user_model_path,
)
from neurotouch_hid.pipeline.config import EpisodeConfig, PipelineConfig
from neurotouch_hid.pipeline.episode import FIRST_FINGER_US
from neurotouch_hid.pipeline.learned import CLASSES, Classifier, learned_gesture
from neurotouch_hid.sources.sim_dataset import write_dataset

TWISTS = {"twist_cw": "twist_ccw", "twist_ccw": "twist_cw"}


def swapped_classifier() -> dict:
    """The shipped classifier with its two twist rows exchanged: reads every twist the other way."""
    c = Classifier.shipped()
    order = [CLASSES.index(GestureType(TWISTS.get(k.value, k.value))) for k in CLASSES]
    return {
        "mean": c.mean.tolist(),
        "scale": c.scale.tolist(),
        "weights": c.weights[order].tolist(),
        "intercept": c.intercept[order].tolist(),
    }


@pytest.fixture(scope="module")
def enrolment(tmp_path_factory) -> Path:
    """A small simulated enrolment: one hand, each gesture type 2-3 times (9 s each; odd seed: no test draw)."""
    folder = tmp_path_factory.mktemp("enrolment")
    return write_dataset(folder, seed=11, users=[0], minutes=0.75, progress=False)


@pytest.fixture(scope="module")
def records(enrolment) -> list[Record]:
    return record_datasets([enrolment])


@pytest.fixture(scope="module")
def mirrored(enrolment, tmp_path_factory) -> Path:
    """The same enrolment labelled by a hand whose twists the gel reads the other way (a sensor
    mounted mirrored): every twist label swapped."""
    folder = tmp_path_factory.mktemp("mirrored")
    for f in enrolment.iterdir():
        if f.name.endswith(".labels.csv"):
            rows = list(csv.reader(f.read_text().splitlines()))
            for row in rows[1:]:
                row[1] = TWISTS.get(row[1], row[1])
            (folder / f.name).write_text("\n".join(",".join(r) for r in rows) + "\n")
        elif f.suffix in (".aedat4", ".yaml"):
            shutil.copy(f, folder / f.name)
    return folder


# --- the model file --------------------------------------------------------------------------
def test_a_model_round_trips_and_applies_its_values(tmp_path):
    model = Model({"gesture.intensity_gain": 1.25, "resting.centroid_threshold_mm2": 0.002}, swapped_classifier())
    path = model.save(tmp_path / "sub" / "model.yaml")
    back = load_model(path)
    assert back.settings == model.settings and back.classifier == model.classifier and back.path == path
    config = apply_model(PipelineConfig(), back)
    assert config.gesture.intensity_gain == 1.25 and config.resting.centroid_threshold_mm2 == 0.002
    assert config.contacts == PipelineConfig().contacts  # nothing else changes
    features = np.array([0.1, 0.8, 0.1, 0.0, 0.8, 0.0, 0.9, 2.0, 1.5])  # a counter-clockwise twist
    assert learned_gesture(features) is GestureType.TWIST_CCW
    assert learned_gesture(features, config.gesture.classifier.arrays()) is GestureType.TWIST_CW
    assert not list(tmp_path.glob("sub/.*.tmp"))  # written through a temporary file, renamed


def test_an_empty_model_is_the_shipped_method(tmp_path):
    assert apply_model(PipelineConfig(), load_model(Model().save(tmp_path / "m.yaml"))) == PipelineConfig()


@pytest.mark.parametrize(
    "text, expected",
    [
        ("format: neurotouch-hid model\nversion: 7\n", ["version 7", "reads version 1", "adapt", "--model none"]),
        ("format: a profile\nversion: 1\n", ["'format'", "neurotouch-hid model"]),
        (
            "format: neurotouch-hid model\nversion: 1\nsettings:\n  contacts.r_mm: 3\n",
            ["m.yaml:4", "settings.contacts.r_mm", "one of gesture.min_intensity_mm"],
        ),
        (
            "format: neurotouch-hid model\nversion: 1\nsettings:\n  gesture.intensity_gain: fast\n",
            ["m.yaml:4", "'fast'", "a finite number"],
        ),
        (
            "format: neurotouch-hid model\nversion: 1\nclassifier:\n  mean: [1, 2]\n  scale: [1]\n"
            "  weights: [[1]]\n  intercept: [1]\n",
            ["m.yaml:3", "classifier", "9 values"],
        ),
        (
            "format: neurotouch-hid model\nversion: 1\nsettings:\n  gesture.intensity_gain: -2\n",
            ["intensity_gain", "from 0.2 to 5"],
        ),
        ("format: neurotouch-hid model\nversion: 1\nextra: 1\n", ["'extra'", "only format"]),
        ("- a\n- list\n", ["expected a mapping"]),
        ("format: [unclosed\n", ["not valid YAML"]),
    ],
)
def test_a_bad_model_file_says_where_and_what_was_expected(tmp_path, text, expected):
    path = tmp_path / "m.yaml"
    path.write_text(text)
    with pytest.raises(ModelError) as caught:
        load_model(path)
    for part in expected:
        assert part in str(caught.value)
    assert str(path) in str(caught.value)


def test_a_missing_or_oversized_model_is_refused_clearly(tmp_path):
    with pytest.raises(ModelError, match="no such model file.*adapt"):
        load_model(tmp_path / "nothing.yaml")
    big = tmp_path / "big.yaml"
    big.write_text("#" * (1 << 20))
    with pytest.raises(ModelError, match="larger than"):
        load_model(big)


def test_the_users_model_is_used_unless_none_is_asked(tmp_path):
    assert resolve_model(None) is None  # no user model: the shipped method
    Model({"gesture.intensity_gain": 1.1}).save(user_model_path())
    assert resolve_model(None).settings == {"gesture.intensity_gain": 1.1}
    assert resolve_model("none") is None and resolve_model("NONE") is None
    other = Model({"gesture.intensity_gain": 0.9}).save(tmp_path / "other.yaml")
    assert resolve_model(str(other)).settings == {"gesture.intensity_gain": 0.9}


def test_doctor_names_the_model_in_use():
    from neurotouch_hid.service.doctor import FAIL, OK, check_model

    assert check_model().status == OK and "shipped method" in check_model().detail
    Model({"gesture.intensity_gain": 1.1}).save(user_model_path())
    check = check_model()
    assert check.status == OK and str(user_model_path()) in check.detail and "intensity_gain = 1.1" in check.detail
    user_model_path().write_text("format: neurotouch-hid model\nversion: 99\n")
    check = check_model()
    assert check.status == FAIL and "version 99" in check.detail and "adapt" in check.fix


# --- adapt -----------------------------------------------------------------------------------
def test_the_replay_answers_what_the_pipeline_answered(records):
    for r in records:
        assert len(r.t_us) > 500
        assert np.array_equal(replay(r), r.answered)
        assert len(r.frame_t_us) > 100 and r.frame_resting.any() and not r.frame_resting.all()  # every frame's verdict
        assert np.isfinite(r.features[r.gesture >= 0]).all() and np.isnan(r.features[r.gesture < 0]).all()


def test_gestures_are_held_out_by_prompt_with_their_rest(records):
    held = held_out_prompts(records)
    kinds = [k for r in records for k in r.prompt_type.values()]
    assert 0 < len(held) < len(kinds)
    for r in records:
        windows = np.isin(r.prompt, list(held))
        for prompt in set(r.prompt[windows].tolist()):  # a held-out prompt's windows, gesture and rest
            assert prompt in held


def test_adapt_learns_a_hand_whose_twists_read_the_other_way(mirrored):
    adaptation = adapt(record_datasets([mirrored]))
    check = next(c for c in adaptation.checks if c.what == "classifier")
    assert check.kept and check.fitted > check.shipped + 0.02
    assert adaptation.model.classifier is not None
    assert adaptation.accuracy_after > adaptation.accuracy_before + 0.02
    lines = summary(adaptation)
    assert any(line.startswith("your unseen gestures read right: shipped") for line in lines)
    assert any("the learned gesture type refitted" in line for line in lines)
    changes = next(line for line in lines if line.startswith("what changes for you: "))
    assert "which gesture it reads from how your gel moves" in changes


def test_adapt_keeps_the_shipped_value_where_the_fit_does_not_beat_it(records):
    """The fitted part says every twist turns the other way and every intensity is twice what is
    read; the held-out gestures say neither: the shipped classifier and scale stay."""
    held = held_out_prompts(records)
    swap = {CLASSES.index(GestureType.TWIST_CW): CLASSES.index(GestureType.TWIST_CCW)}
    swap.update({v: k for k, v in swap.items()})
    misled = []
    for r in records:
        fit = ~np.isin(r.prompt, list(held))
        label = r.label.copy()
        for a, b in swap.items():
            label[fit & (r.label == a)] = b
        misled.append(
            dataclasses.replace(
                r, label=label, label_intensity_mm=np.where(fit, 2 * r.label_intensity_mm, r.label_intensity_mm)
            )
        )
    adaptation = adapt(misled)
    by_name = {c.what: c for c in adaptation.checks}
    assert not by_name["classifier"].kept and by_name["classifier"].fitted < by_name["classifier"].shipped
    assert not by_name["gesture.intensity_gain"].kept and float(by_name["gesture.intensity_gain"].value) > 1.5
    assert adaptation.model.classifier is None and "gesture.intensity_gain" not in adaptation.model.settings
    assert any(": left as shipped: " in line for line in summary(adaptation))


def test_adapt_refuses_labels_in_micrometres(records):
    """Labels whose intensities are 1000x what the gel reads (micrometres): the fit refuses the
    scale (it kept 999, and a light pinch was a full trigger)."""
    from neurotouch_hid.core.errors import DatasetError

    micrometres = [dataclasses.replace(r, label_intensity_mm=1000 * r.label_intensity_mm) for r in records]
    with pytest.raises(DatasetError, match="in another unit"):
        adapt(micrometres)


def test_the_replay_with_another_first_finger_wait_answers_what_the_pipeline_answers(enrolment, records):
    for shipped in records:  # the shipped wait, a lone contact's field read as the pipeline read it
        assert np.array_equal(replay(shipped), shipped.answered)
    wait = 0
    again = record_datasets([enrolment], config=PipelineConfig(episode=EpisodeConfig(first_finger_us=wait)))
    for shipped, rerun in zip(records, again):
        assert np.array_equal(replay(shipped, first_finger_us=wait), rerun.answered)
    assert any(not np.array_equal(replay(r, first_finger_us=wait), r.answered) for r in records)  # it matters


ONE_HOT = Classifier.of(np.zeros(9), np.ones(9), 10 * np.eye(5, 9), np.zeros(5))  # feature k: class k


def episode_record(windows: list[tuple[str, float, int]], label: str) -> Record:
    """One labelled gesture of 10 ms windows (type read, intensity mm, contacts), rest before and
    after; the type is read from a one-hot feature (:data:`ONE_HOT`)."""
    rows = [("none", 0.0, 0)] * 20 + windows + [("none", 0.0, 0)] * 20
    kinds = np.array([-1 if k == "none" else CLASSES.index(GestureType(k)) for k, _, _ in rows], dtype=np.int8)
    features = np.full((len(rows), 9), np.nan)
    features[kinds >= 0] = np.eye(9)[kinds[kinds >= 0]]
    labelled = np.zeros(len(rows), dtype=bool)
    labelled[20 : 20 + len(windows)] = True
    n = len(rows)
    return Record(
        name="synthetic",
        t_us=10_000 * np.arange(1, n + 1, dtype=np.int64),
        gesture=kinds,
        intensity_mm=np.array([i for _, i, _ in rows]),
        n_contacts=np.array([c for _, _, c in rows], dtype=np.int16),
        features=features,
        answered=kinds,
        label=np.where(labelled, CLASSES.index(GestureType(label)), -1).astype(np.int8),
        label_intensity_mm=np.array([i for _, i, _ in rows]),
        prompt=np.zeros(n, dtype=np.int64),
        frame_t_us=np.zeros(0, dtype=np.int64),
        frame_distance_mm2=np.zeros(0),
        frame_resting=np.zeros(0, dtype=bool),
        frame_prompt=np.zeros(0, dtype=np.int64),
        prompt_type={0: CLASSES.index(GestureType(label))},
    )


def test_the_first_fingers_wait_is_shortened_only_where_no_window_reads_wrong_above_the_dead_zone():
    """A push is one finger: the wait for a second one only answers ``none`` meanwhile, so the fit
    drops it. A pinch whose second finger lags 40 ms reads as a strong push meanwhile: without the
    wait the player would feel a push, so the shipped wait stays (the longest of equal accuracy)."""
    push = episode_record([("push", 0.5 + 0.1 * i, 1) for i in range(30)], "push")
    assert _fit_first_finger([push], ONE_HOT, 0.0, {0}) == 0
    lagging = episode_record([("push", 1.5, 1)] * 4 + [("pinch", 1.5, 2)] * 26, "pinch")
    assert _fit_first_finger([lagging], ONE_HOT, 0.0, {0}) == FIRST_FINGER_US
    assert _felt_wrong([lagging], [replay(lagging, ONE_HOT, first_finger_us=0)], {0}) == 4
    assert _felt_wrong([lagging], [replay(lagging, ONE_HOT)], {0}) == 0


def pushes_with_weak_windows(after_end_ms: int, prompts: int = 9) -> Record:
    """``prompts`` labelled pushes at 1.0 mm, each followed by three 10 ms windows the pipeline
    reads as a push at 0.2 mm and the labels call ``none``, starting ``after_end_ms`` after the
    labelled end (rest belongs to the gesture after it)."""
    kinds, intensity, labelled, prompt = [], [], [], []
    for p in range(prompts):
        before = [(-1, 0.0, False)] * 20 + [(0, 1.0, True)] * 30
        after = [(-1, 0.0, False)] * (after_end_ms // 10) + [(0, 0.2, False)] * 3 + [(-1, 0.0, False)] * 20
        for rows, owner in ((before, p), (after, min(p + 1, prompts - 1))):
            for k, i, lab in rows:
                kinds.append(k)
                intensity.append(i)
                labelled.append(lab)
                prompt.append(owner)
    n = len(kinds)
    kinds_a = np.array(kinds, dtype=np.int8)
    features = np.full((n, 9), np.nan)
    features[kinds_a >= 0] = np.eye(9)[0]
    push = CLASSES.index(GestureType.PUSH)
    read = np.where(kinds_a >= 0, push, -1).astype(np.int8)
    return Record(
        name="synthetic",
        t_us=10_000 * np.arange(1, n + 1, dtype=np.int64),
        gesture=read,
        intensity_mm=np.array(intensity),
        n_contacts=(kinds_a >= 0).astype(np.int16),
        features=features,
        answered=read,
        label=np.where(labelled, push, -1).astype(np.int8),
        label_intensity_mm=np.where(labelled, 1.0, 0.0),
        prompt=np.array(prompt, dtype=np.int64),
        frame_t_us=np.zeros(0, dtype=np.int64),
        frame_distance_mm2=np.zeros(0),
        frame_resting=np.zeros(0, dtype=bool),
        frame_prompt=np.zeros(0, dtype=np.int64),
        prompt_type=dict.fromkeys(range(prompts), push),
    )


def test_the_contact_threshold_is_not_kept_for_windows_the_labels_end_a_frame_early():
    """A release's last windows read at 0.2 mm just after the enrolment's labels end the gesture (they
    end it at a tenth of its peak): a game's labels still call them the gesture, so a threshold that
    only answers them ``none`` is not kept. The same weak windows 200 ms after the end, in a rest the
    labels are sure of, keep it."""
    tail = pushes_with_weak_windows(after_end_ms=0)
    assert "gesture.min_intensity_mm" not in adapt([tail]).model.settings
    blip = adapt([pushes_with_weak_windows(after_end_ms=200)])
    assert blip.model.settings["gesture.min_intensity_mm"] == pytest.approx(0.24)
    check = next(c for c in blip.checks if c.what == "gesture.min_intensity_mm")
    assert check.kept and "outside the 40 ms collar" in check.metric


def test_adapt_writes_a_model_the_commands_use_and_none_means_shipped(mirrored, tmp_path):
    out = tmp_path / "model.yaml"
    done = run_cli("adapt", str(mirrored), "--out", str(out), "--jobs", "1")
    assert done.returncode == 0, done.stderr
    assert "your unseen gestures read right: shipped" in done.stdout and f"-> {out}" in done.stdout
    assert load_model(out).classifier is not None
    recording = mirrored / "u0_twist_cw.aedat4"
    answers = {}
    for name, extra in (("shipped", []), ("none", ["--model", "none"]), ("adapted", ["--model", str(out)])):
        pred = tmp_path / f"{name}.jsonl"
        done = run_cli("track", str(recording), "--out", str(pred), *extra)
        assert done.returncode == 0, done.stderr
        answers[name] = [json.loads(line)["gesture"] for line in pred.read_text().splitlines()]
    assert answers["none"] == answers["shipped"]
    assert answers["adapted"].count("twist_ccw") > answers["shipped"].count("twist_ccw")  # read the other way
    user_model_path().parent.mkdir(parents=True, exist_ok=True)
    shutil.copy(out, user_model_path())  # the user's model: used by default, named on stderr
    pred = tmp_path / "default.jsonl"
    done = run_cli("track", str(recording), "--out", str(pred))
    assert done.returncode == 0 and str(user_model_path()) in done.stderr
    assert [json.loads(line)["gesture"] for line in pred.read_text().splitlines()] == answers["adapted"]


def test_adapt_never_writes_over_an_input_and_a_bad_model_is_one_line(enrolment, tmp_path):
    labels = sorted(enrolment.glob("*.labels.csv"))[0]
    before = labels.read_bytes()
    done = run_cli("adapt", str(enrolment), "--out", str(labels))
    assert done.returncode == 2 and "never overwrites an input" in done.stderr and labels.read_bytes() == before
    bad = tmp_path / "bad.yaml"
    bad.write_text("format: neurotouch-hid model\nversion: 3\n")
    recording = sorted(enrolment.glob("*.aedat4"))[0]
    done = run_cli("track", str(recording), "--out", str(tmp_path / "p.jsonl"), "--model", str(bad))
    assert done.returncode == 2 and "version 3" in done.stderr and "Traceback" not in done.stderr


def test_the_summary_speaks_to_players_and_says_why_a_small_gain_is_not_taken():
    """A wait fitted 99.21 % -> 99.28 % held out: not taken, and said as a gain too small to
    trust, not as "not better"; each line begins with what the player feels, the setting's name
    last, in brackets."""
    from neurotouch_hid.enrolment.adapt import Adaptation, Check

    small = Check("episode.first_finger_us", "gesture type accuracy", 0.9921, 0.9928, False, "45000")
    worse = Check("gesture.intensity_gain", "intensity MAE mm", 0.40, 0.45, False, "1.2", False)
    taken = Check("gesture.min_intensity_mm", "gesture type accuracy", 0.95, 0.97, True, "0.6")
    lines = summary(
        Adaptation(Model({"gesture.min_intensity_mm": 0.6}), [small, worse, taken], 9, 27, 3400, 0.95, 0.97)
    )
    wait = next(line for line in lines if "episode.first_finger_us" in line)
    assert wait.startswith("how long it waits for your second finger before it answers: left as shipped: ")
    assert "99.21 % -> 99.28 %" in wait and "with 45 ms" in wait and "a gain under 0.2 points" in wait
    assert "not better" not in wait and "shipped value stays" not in wait
    gain = next(line for line in lines if "intensity_gain" in line)
    assert "left as shipped: x1.2 did no better (strength off by 0.400 mm -> 0.450 mm" in gain
    firm = next(line for line in lines if "min_intensity_mm" in line)
    assert firm.startswith("how firm a touch must be to count: changed to 0.6 mm: read right 95.00 % -> 97.00 %")
    assert lines[-2].startswith("what changes for you: how firm a touch must be to count [")


def test_a_simulated_enrolment_never_becomes_the_users_model_and_reset_goes_back(enrolment, tmp_path):
    """``adapt`` on a dataset the simulated camera recorded, without --out: refused before any
    work (the user's model untouched); ``adapt --reset`` moves the user's model aside and the
    commands use the shipped method again."""
    path = user_model_path()
    path.parent.mkdir(parents=True, exist_ok=True)
    Model({"gesture.intensity_gain": 1.1}).save(path)
    before = path.read_bytes()
    done = run_cli("adapt", str(enrolment))
    assert done.returncode == 2 and "recorded from the simulated camera" in done.stderr, done.stderr
    assert "--out FILE" in done.stderr and "Traceback" not in done.stderr
    assert path.read_bytes() == before
    done = run_cli("adapt", "--reset")
    assert done.returncode == 0 and "the shipped recogniser is in use again" in done.stdout, done.stderr
    assert not path.exists() and path.with_name("model.yaml.bak").read_bytes() == before
    assert resolve_model(None) is None
    again = run_cli("adapt", "--reset")
    assert again.returncode == 0 and "already in use" in again.stdout
    missing = run_cli("adapt")
    assert missing.returncode == 2 and "--reset" in missing.stderr


def test_the_driver_and_profile_test_run_the_pipeline_with_the_model():
    from neurotouch_hid.engine.assembly import build_pipeline

    model = Model({"gesture.intensity_gain": 1.3, "gesture.min_intensity_mm": 0.2}, swapped_classifier())
    pipeline, _ = build_pipeline(SensorGeometry(), 10_000, model=model)
    assert pipeline.settings.gesture.intensity_gain == 1.3 and pipeline.settings.gesture.min_intensity_mm == 0.2
    assert pipeline.config.classifier.weights.tolist() == model.classifier["weights"]
    shipped, _ = build_pipeline(SensorGeometry(), 10_000)
    assert shipped.settings == PipelineConfig() and shipped.config.classifier is Classifier.shipped()
    from neurotouch_hid.pipeline.paper import PaperConfig

    paper, _ = build_pipeline(SensorGeometry(), 10_000, method="paper", model=model)  # the paper's stays its own
    assert paper.settings == PaperConfig()
