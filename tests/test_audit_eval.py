"""Bad labels and predictions files (docs/dataset.md): each refused with an error that names the
file, the line, the field and what was expected, never read as something else; labels on another
clock than the recording's refused before they are scored."""

from __future__ import annotations

import shutil

import pytest

from neurotouch_hid.core.dataset import read_labels, read_predictions
from neurotouch_hid.core.errors import DatasetError

HEADER = "t_us,gesture,resting,intensity_mm,n_contacts,x1_px,y1_px,x2_px,y2_px,x3_px,y3_px"


def test_an_empty_labels_file_is_said_empty(tmp_path):
    path = tmp_path / "empty.labels.csv"
    path.write_text("")
    with pytest.raises(DatasetError, match=r"empty\.labels\.csv:1: the file is empty; expected the header t_us,"):
        read_labels(path)


LINE = '"gesture": "push", "resting": false, "intensity_mm": 1.0'


@pytest.mark.parametrize(
    "text, message",
    [
        # times in seconds would all read as 1 us
        (
            '{"t_us": 1.25, %s}\n{"t_us": 1.26, %s}\n' % (LINE, LINE),
            r":1: t_us: expected a whole number of microseconds from 0 to 2\^62, found 1\.25",
        ),
        # a required field null: resting read as false, intensity as a Python TypeError
        (
            '{"t_us": 1000, "gesture": "push", "resting": null, "intensity_mm": 1.0}\n',
            r":1: resting: expected true or false \(or 1 or 0\), found None",
        ),
        (
            '{"t_us": 1000, "gesture": "push", "resting": false, "intensity_mm": null}\n',
            r":1: intensity_mm: expected mm from 0 to 60, found None",
        ),
        # Python's json.dumps writes NaN and Infinity: the field is named
        (
            '{"t_us": 1000, "gesture": "push", "resting": false, "intensity_mm": NaN}\n',
            r":1: intensity_mm: expected mm from 0 to 60, found nan",
        ),
        (
            '{"t_us": 1000, %s, "contacts_px": [[1e999, 2]], "contacts_mm": [[1, 2]]}\n' % LINE,
            r":1: contacts_px: expected a list of \[x, y\] image pixels within 4096, found \[\[inf, 2\]\]",
        ),
        (
            '{"t_us": 1000, "gesture": "Push", "resting": false, "intensity_mm": 1.0}\n',
            r":1: bad value: gesture: expected one of none, push, pinch, zoom, twist_cw, twist_ccw, found 'Push'",
        ),
    ],
)
def test_a_bad_predictions_field_names_the_field_and_what_was_expected(tmp_path, text, message):
    path = tmp_path / "p.jsonl"
    path.write_text(text)
    with pytest.raises(DatasetError, match=r"p\.jsonl" + message):
        read_predictions(path)


def test_a_whole_float_time_is_still_read(tmp_path):
    path = tmp_path / "p.jsonl"
    path.write_text('{"t_us": 1e6, %s}\n' % LINE)
    assert [p.t_us for p in read_predictions(path)] == [1_000_000]


@pytest.mark.parametrize("how", ["ms", "other clock"])
def test_labels_on_another_clock_than_the_recording_are_refused_before_scoring(tmp_path, sim_rest_dataset, how):
    # labels in milliseconds, or on a clock that starts elsewhere, would score every prediction
    # against the last label (or skip them all) and report a figure without a word
    from neurotouch_hid.evaluation.runner import run_sequence

    ds = tmp_path / "ds"
    shutil.copytree(sim_rest_dataset, ds)
    path = ds / "u0_push.labels.csv"
    lines = path.read_text().splitlines()
    shifted = [lines[0]]
    for line in lines[1:]:
        t, rest = line.split(",", 1)
        shifted.append(f"{int(t) // 1000 if how == 'ms' else int(t) + 100_000_000},{rest}")
    path.write_text("\n".join(shifted) + "\n")
    with pytest.raises(DatasetError, match=r"u0_push\.labels\.csv:2: t_us: the labels run from .* us, the recording "):
        run_sequence(ds, "u0_push")
    path.write_text("\n".join(lines) + "\n")  # the labels as written: scored
    assert len(run_sequence(ds, "u0_push")) > 0


def test_the_command_eval_quotes_names_the_model_it_ran_with(tmp_path, sim_rest_dataset, monkeypatch, capsys):
    # `--model none` while the user has a model.yaml scores the shipped method: the JSON's (and
    # the report's) command, run again, must do the same
    import json

    from helpers import run_main

    out = tmp_path / "m.json"
    done = run_main(monkeypatch, capsys, ["eval", str(sim_rest_dataset), "--model", "none", "--json", str(out)])
    assert done.returncode == 0, done.stderr
    assert json.loads(out.read_text())["command"] == f"neurotouch-hid eval {sim_rest_dataset} --model=none --json={out}"


@pytest.mark.parametrize("flag", ["--report", "--predictions"])
def test_eval_refuses_a_json_summary_that_another_of_its_outputs_would_replace(
    tmp_path, sim_rest_dataset, monkeypatch, capsys, flag
):
    # `--report R --json R/summary.md` left the Markdown summary where the JSON was asked for;
    # `--predictions P --json P/u0_push.jsonl` left the JSON where the predictions were (exit 0)
    from helpers import run_main

    if flag == "--report":
        pytest.importorskip("matplotlib")
    folder = tmp_path / "out"
    target = folder / ("summary.md" if flag == "--report" else "u0_push.jsonl")
    args = ["eval", str(sim_rest_dataset), flag, str(folder), "--json", str(target)]
    done = run_main(monkeypatch, capsys, args)
    assert done.returncode == 2 and f"{target}: the JSON summary is also the " in done.stderr, done.stderr
    assert not target.exists()
