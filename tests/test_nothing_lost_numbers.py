"""Numbers and clocks against the driver (docs/limits.md): every number of a model, a labels file, a
plan or a command's option within what a gel and int64 can be, refused in one line with file, line
and field; a closed standard output is no traceback; a year's gap in a recording costs no more than
its data."""

from __future__ import annotations

import subprocess
import sys

import pytest
from hostile_helpers import ROOT, assert_refused, cli
from nothing_lost_helpers import _HEADER, _env


@pytest.mark.parametrize("kind", ["labels", "pressed"])
def test_a_csv_field_past_the_readers_limit_is_one_line_with_file_and_line(tmp_path, kind):
    """A labels row with a 200 000-character field ended ``eval`` in a ``_csv.Error`` traceback."""
    from neurotouch_hid.core.dataset import LABEL_COLUMNS, PRESSED_COLUMNS, read_labels, read_pressed
    from neurotouch_hid.core.errors import DatasetError

    path = tmp_path / f"s.{kind}.csv"
    columns = LABEL_COLUMNS if kind == "labels" else PRESSED_COLUMNS
    path.write_text(",".join(columns) + "\n" + "1," * (len(columns) - 1) + "x" * 200_000 + "\n")
    with pytest.raises(DatasetError, match=rf"{path}:2: not a CSV row"):
        (read_labels if kind == "labels" else read_pressed)(path)


def test_a_plan_cue_past_a_day_is_refused_with_its_field(tmp_path):
    """A cue of 1e308 s ended ``enrol --from`` in an OverflowError traceback (its microseconds)."""
    from neurotouch_hid.core.errors import DatasetError
    from neurotouch_hid.enrolment.plan import read_plan

    plan = tmp_path / "p.json"
    plan.write_text('{"prompts": [{"gesture": "push", "cue_s": 1e308, "seconds": 1}]}')
    with pytest.raises(DatasetError, match="prompt 1: field 'cue_s'.*from 0 to 86400"):
        read_plan(plan)


# --- models and labels: every number within what a gel can be --------------------------------
_MODEL = "format: neurotouch-hid model\nversion: 1\n"


@pytest.mark.parametrize(
    "text, line, field",
    [
        (_MODEL + "settings:\n  gesture.intensity_gain: 1.7e308\n", 4, "settings.gesture.intensity_gain"),
        (_MODEL + "settings:\n  gesture.intensity_gain: 999\n", 4, "settings.gesture.intensity_gain"),
        (_MODEL + "settings:\n  gesture.min_intensity_mm: -1\n", 4, "settings.gesture.min_intensity_mm"),
        (_MODEL + "settings:\n  episode.first_finger_us: 1e12\n", 4, "settings.episode.first_finger_us"),
        ("format: neurotouch-hid model\nversion: true\n", 2, "version"),
    ],
)
def test_a_model_number_outside_what_a_gel_can_be_is_refused_with_file_line_and_field(tmp_path, text, line, field):
    from neurotouch_hid.enrolment.model import ModelError, load_model

    path = tmp_path / "model.yaml"
    path.write_text(text)
    with pytest.raises(ModelError) as caught:
        load_model(path)
    said = str(caught.value)
    assert said.startswith(f"{path}:{line}: ") and (field in said or "version" in said), said


def test_classifier_weights_of_1e308_are_refused(tmp_path):
    from neurotouch_hid.enrolment.model import Model, ModelError, load_model
    from neurotouch_hid.pipeline.learned import Classifier

    c = Classifier.shipped()
    weights = c.weights.copy()
    weights[0, 3] = 1e308
    parts = {"mean": c.mean.tolist(), "scale": c.scale.tolist(), "weights": weights.tolist()}
    path = Model({}, {**parts, "intercept": c.intercept.tolist()}).save(tmp_path / "model.yaml")
    with pytest.raises(ModelError, match=r"model.yaml:\d+: field 'classifier.weights': found 1e\+308"):
        load_model(path)
    assert_refused(cli("track", "x.aedat4", "--out", str(tmp_path / "p.jsonl"), "--model", str(path)), "1e+308")


@pytest.mark.parametrize(
    "row, column",
    [
        ("1000000000000000000000000000000,none,1,0,0,,,,,,", "t_us"),
        ("-5,none,1,0,0,,,,,,", "t_us"),
        ("40000,push,0,nan,0,,,,,,", "intensity_mm"),
        ("40000,push,0,inf,0,,,,,,", "intensity_mm"),
        ("40000,push,0,5e7,0,,,,,,", "intensity_mm"),
        ("40000,push,0,-1,0,,,,,,", "intensity_mm"),
        ("40000,push,0,1,1,nan,3,,,,", "x1_px"),
        ("40000,push,0,1,1,1e300,3,,,,", "x1_px"),
    ],
)
def test_a_labels_number_out_of_bounds_is_one_line_with_file_line_and_column(tmp_path, row, column):
    from neurotouch_hid.core.dataset import read_labels
    from neurotouch_hid.core.errors import DatasetError

    path = tmp_path / "seq.labels.csv"
    path.write_text(_HEADER + "0,none,1,0,0,,,,,,\n" + row + "\n")
    with pytest.raises(DatasetError) as caught:
        read_labels(path)
    assert str(caught.value).startswith(f"{path}:3: column '{column}'"), caught.value


def test_a_labels_file_with_a_header_alone_or_too_many_rows_is_one_line(tmp_path, monkeypatch):
    from neurotouch_hid.core import dataset
    from neurotouch_hid.core.errors import DatasetError

    path = tmp_path / "seq.labels.csv"
    path.write_text(_HEADER)
    with pytest.raises(DatasetError, match=r"seq.labels.csv:2: no labelled frame"):
        dataset.read_labels(path)
    monkeypatch.setattr(dataset, "MAX_LABEL_ROWS", 10)
    path.write_text(_HEADER + "".join(f"{i * 40000},none,1,0,0,,,,,,\n" for i in range(11)))
    with pytest.raises(DatasetError, match=r"seq.labels.csv:12: more than 10 rows"):
        dataset.read_labels(path)


# --- tracebacks: a closed standard output, windows past int64, long numbers -------------------
def test_a_closed_standard_output_is_no_traceback(tmp_path, sim_gel_short_recording):
    """``neurotouch-hid ... >&-`` failed at import (``sys.stdout`` is None)."""
    for args in (["info", str(sim_gel_short_recording)], ["profile", "list"]):
        done = subprocess.run(
            ["sh", "-c", 'exec "$@" >&-', "sh", sys.executable, "-m", "neurotouch_hid.cli", *args],
            capture_output=False, stderr=subprocess.PIPE, text=True, env=_env(tmp_path / "config"), cwd=ROOT,
            timeout=120,
        )  # fmt: skip
        assert done.returncode == 0 and "Traceback" not in done.stderr, done.stderr


@pytest.mark.parametrize("window", [str(2**63), str(2**63 - 1), "9" * 301])
def test_a_window_past_a_second_is_one_line(tmp_path, sim_gel_short_recording, window):
    """``--window-us`` of 2^63 overflowed; 2^63-1 ran no window at all and exited 0."""
    result = cli("track", str(sim_gel_short_recording), "--out", str(tmp_path / "p.jsonl"), "--window-us", window)
    assert_refused(result, "at most 1000000 us")
    assert len(result[2]) < 400 and not (tmp_path / "p.jsonl").exists()


def test_a_301_digit_exposure_is_not_echoed_whole(tmp_path):
    result = cli("record", str(tmp_path / "r.aedat4"), "--exposure-us", "9" * 301)
    assert_refused(result, "--exposure-us")
    assert "9" * 100 not in result[2]


# --- a gap in the clock costs what the data costs ---------------------------------------------
YEAR_US = 365 * 24 * 3600 * 10**6


def test_a_years_gap_in_a_recording_costs_no_more_than_its_data(tmp_path, sim_gel_chunks):
    """Every empty window of a gap was made: a year's gap ended in MemoryError in ``track``,
    ``run --fast`` and ``eval``. The windows of the gap's first second are emitted, the rest
    skipped (the predictions format asks for no empty window)."""
    from neurotouch_hid.core.dataset import LabelRow, read_predictions, write_labels
    from neurotouch_hid.core.estimate import GestureType
    from neurotouch_hid.sources import Frame
    from neurotouch_hid.sources.recording_writer import RecordingWriter
    from neurotouch_hid.sources.simulator import SimulatedSource

    ds = tmp_path / "ds"
    ds.mkdir()
    SimulatedSource(seed=0).sensor.save(ds / "sensor.yaml")
    recording, frames = ds / "gap.aedat4", []
    with RecordingWriter(recording) as writer:
        for shift in (0, YEAR_US):
            for chunk in sim_gel_chunks[:15]:  # 0.6 s of rest, then the same a year later
                frames.append(chunk.frame.t_us + shift)
                writer.write_frame(Frame(frames[-1], chunk.frame.image))
                events = chunk.events.copy()
                events["timestamp"] += shift
                writer.write_events(events)
    write_labels(ds / "gap.labels.csv", [LabelRow(t, GestureType.NONE, True, 0.0) for t in frames])
    out = tmp_path / "pred.jsonl"
    code, _, err, rss = cli("track", str(recording), "--out", str(out), timeout_s=180)
    assert code == 0 and rss < 512 * 1024, (code, rss, err[-500:])
    times = [e.t_us for e in read_predictions(out)]
    assert 100 <= len(times) < 400 and times[-1] > YEAR_US, len(times)  # both sides, a second of the gap
    assert max(b - a for a, b in zip(times, times[1:])) > YEAR_US - 10**7
    states = tmp_path / "states.jsonl"
    run = ("run", "--fast", "--profile", "default", "--output", "jsonl", "--out", str(states))
    code, _, err, rss = cli(*run, "--source", str(recording), timeout_s=180)
    assert code == 0 and rss < 512 * 1024, (code, rss, err[-500:])
    code, _, err, rss = cli("eval", str(ds), timeout_s=180)
    assert code == 0 and rss < 512 * 1024, (code, rss, err[-500:])
