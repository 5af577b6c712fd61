"""Predictions, labels and pressed files crafted to break the driver (docs/limits.md): FIFOs, deep
nesting, numbers past int64 and float, fields of the wrong type, line separators inside strings,
files too large to hold. Each is refused with one short line naming file and line."""

from __future__ import annotations

import json
import os

import pytest
from hostile_helpers import _predictions, assert_refused, cli


def test_a_predictions_file_that_is_a_fifo_or_nests_deeply_is_one_line(tmp_path):
    """``run --source PRED.jsonl`` replays predictions: a FIFO does not hang it, a line of 100 000
    '[' is one error naming the line (it was a RecursionError traceback)."""
    fifo = tmp_path / "fifo.jsonl"
    os.mkfifo(fifo)
    assert_refused(cli("run", "--source", str(fifo), "--output", "jsonl", "--seconds", "1"), "not a regular file")
    deep = tmp_path / "deep.jsonl"
    deep.write_text("[" * 100_000 + "\n")
    assert_refused(cli("run", "--source", str(deep), "--output", "jsonl", "--seconds", "1"), f"{deep}:1:")


def test_reading_a_small_file_reserves_no_more_than_it_holds(tmp_path):
    """The bounded read of a predictions file (at most 1 GiB) reserved its bound before reading:
    a MemoryError in a guest of 1 GiB. A run reading a small one fits a 1.5 GiB address space."""
    preds = _predictions(tmp_path, 2.0)
    code, out, err, _ = cli("run", "--source", str(preds), "--output", "jsonl", "--seconds", "1", address_space_gib=1.5)
    assert code == 0 and "Traceback" not in err, err[-2000:]
    assert out.strip()


# --- numbers past what the kernel and int64 hold --------------------------------------------------
@pytest.mark.parametrize("t_us", ["1e30", "Infinity", "9223372036854775807"])
def test_a_predictions_time_past_int64_is_one_line(tmp_path, t_us):
    """``run --source P.jsonl`` with a line whose t_us is 1e30 (an OverflowError traceback),
    infinite, negative or past 2^62."""
    preds = tmp_path / "p.jsonl"
    preds.write_text(
        '{"t_us": 0, "gesture": "none", "resting": true, "intensity_mm": 0.0}\n'
        f'{{"t_us": {t_us}, "gesture": "none", "resting": true, "intensity_mm": 0.0}}\n'
    )
    assert_refused(cli("run", "--source", str(preds), "--fast", "--output", "jsonl"), f"{preds}:2:")


@pytest.mark.parametrize(
    "field",
    [
        '"intensity_mm": 1e999',
        '"intensity_mm": 1.0, "translation_mm": [-1e400, 0.0]',
        '"intensity_mm": 1.0, "rotation_rad": 1e309',
    ],
)
def test_a_predictions_number_past_a_float_is_refused_with_its_line(tmp_path, field):
    """JSON's 1e999 is no constant: it read as infinity, and ``profile test`` went on (exit 0)
    with a push of infinite intensity that moved nothing."""
    preds = tmp_path / "p.jsonl"
    preds.write_text(
        '{"t_us": 0, "gesture": "none", "resting": true, "intensity_mm": 0.0}\n'
        f'{{"t_us": 10000, "gesture": "push", "resting": false, {field}}}\n'
    )
    assert_refused(cli("profile", "test", "default", "--source", str(preds)), f"{preds}:2:")


@pytest.mark.parametrize(
    ("field", "named"),
    [
        ('"resting": "no", "intensity_mm": 1.0', "resting"),
        ('"resting": false, "intensity_mm": -5', "intensity_mm"),
        ('"resting": false, "intensity_mm": "5"', "intensity_mm"),
        ('"resting": false, "intensity_mm": 1.0, "translation_mm": [1, 2, 3]', "translation_mm"),
        ('"resting": false, "intensity_mm": 1.0, "contacts_mm": [[1, "a"]], "contacts_px": [[1, 2]]', "contacts_mm"),
        ('"resting": false, "intensity_mm": 1.0, "scale": true', "scale"),
    ],
)
def test_a_predictions_field_of_the_wrong_type_is_refused_by_name(tmp_path, field, named):
    """``"resting": "no"`` read as resting (a non-empty string is true), a negative or quoted
    intensity and a three-number translation were taken as they came: each is refused with its
    line and field (docs/dataset.md, Predictions)."""
    preds = tmp_path / "p.jsonl"
    preds.write_text(
        '{"t_us": 0, "gesture": "none", "resting": true, "intensity_mm": 0.0}\n'
        f'{{"t_us": 10000, "gesture": "push", {field}}}\n'
    )
    result = cli("profile", "test", "default", "--source", str(preds))
    assert_refused(result, f"{preds}:2: {named}")


def test_a_line_separator_inside_a_predictions_string_is_no_line_break(tmp_path):
    """JSON lines end at "\\n" only: a raw U+2028 inside a string split the line in two (refused as
    an unterminated string), and every line number after it was off."""
    preds = tmp_path / "p.jsonl"
    preds.write_text(
        '{"t_us": 0, "gesture": "none", "resting": true, "intensity_mm": 0.0, "note": "a\u2028b"}\r\n'
        '{"t_us": 10000, "gesture": "wave", "resting": true, "intensity_mm": 0.0}\n',
        encoding="utf-8",
    )
    assert_refused(cli("profile", "test", "default", "--source", str(preds)), f"{preds}:2:", "wave")


def _prediction_line(t_us: int, gesture: str = "none") -> str:
    return json.dumps({"t_us": t_us, "gesture": gesture, "resting": True, "intensity_mm": 0.0}) + "\n"


def test_a_predictions_file_is_read_a_line_at_a_time_and_a_replay_refuses_it_before_it_starts(tmp_path):
    """An hour of predictions (80 MB) was read whole, split and kept as estimates: 0.6 GB. The
    estimates come now as they are asked for, each line bounded; a replay checks the file first."""
    from neurotouch_hid.core.dataset import MAX_PREDICTION_LINE_BYTES, iter_predictions, open_predictions
    from neurotouch_hid.core.errors import DatasetError

    preds = tmp_path / "p.jsonl"
    preds.write_text(_prediction_line(0) + _prediction_line(10_000, "wave"))
    estimates = iter_predictions(preds)
    assert next(estimates).t_us == 0  # the first line's estimate before the second is read
    with pytest.raises(DatasetError, match=rf"^{preds}:2: bad value: .*wave"):
        next(estimates)
    with pytest.raises(DatasetError, match=rf"^{preds}:2: bad value: .*wave"):
        open_predictions(preds)  # nothing handed on from a file that breaks a rule

    padded = '{"t_us": 0, "gesture": "none", "resting": true, "intensity_mm": 0.0, "note": "%s"}\n'
    preds.write_text(_prediction_line(0) + padded % ("x" * MAX_PREDICTION_LINE_BYTES))
    with pytest.raises(DatasetError, match=rf"^{preds}:2: longer than 64 KB, the most a line of a predictions file"):
        open_predictions(preds)
    preds.write_text(_prediction_line(0) + padded % ("x" * (MAX_PREDICTION_LINE_BYTES - 100)))
    assert [e.t_us for e in open_predictions(preds)] == [0, 0]  # a long line within the bound is read


def test_a_pressed_file_has_at_most_as_many_rows_as_a_labels_file(tmp_path, monkeypatch):
    from neurotouch_hid.core import dataset
    from neurotouch_hid.core.errors import DatasetError

    monkeypatch.setattr(dataset, "MAX_LABEL_ROWS", 3)
    pressed = tmp_path / "s.pressed.csv"
    pressed.write_text("t_start_us,pressed_us\n" + "".join(f"{t},{t + 5}\n" for t in range(0, 30, 10)))
    assert len(dataset.read_pressed(pressed)) == 3
    pressed.write_text("t_start_us,pressed_us\n" + "".join(f"{t},{t + 5}\n" for t in range(0, 40, 10)))
    with pytest.raises(DatasetError, match=rf"^{pressed}:5: more than 3 rows"):
        dataset.read_pressed(pressed)


def test_a_labels_file_that_is_a_fifo_or_a_huge_header_is_one_line(tmp_path):
    """Labels (``eval``, ``enrol``) are read through the bounded reader: a FIFO was waited on for
    ever; a header line of a million cells was quoted whole."""
    from neurotouch_hid.core.dataset import read_labels
    from neurotouch_hid.core.errors import DatasetError

    fifo = tmp_path / "x.labels.csv"
    os.mkfifo(fifo)
    with pytest.raises(DatasetError, match="not a regular file"):
        read_labels(fifo)
    wide = tmp_path / "wide.labels.csv"
    wide.write_text(",".join(["x"] * 1_000_000) + "\n")
    with pytest.raises(DatasetError) as err:
        read_labels(wide)
    assert len(str(err.value)) < 1000
