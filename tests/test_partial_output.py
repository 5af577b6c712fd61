"""A ``track`` or ``run --output jsonl`` that fails part-way never replaces an existing output:
that file stays byte-identical, what was computed goes beside it (``NAME.partial``), and the
command exits non-zero saying both (neurotouch_hid/core/jsonl_writer.py, ``JsonlWriter``)."""

from __future__ import annotations

import json

import pytest
from helpers import run_main

from neurotouch_hid.core.controller import ControllerState
from neurotouch_hid.core.jsonl_writer import JsonlWriter
from neurotouch_hid.views.jsonl import StateJsonlWriter

EARLIER = b"earlier output\n"


@pytest.fixture(scope="module")
def cut(sim_gel_short_recording, tmp_path_factory):
    """The short simulated recording cut at two thirds, its sensor.yaml beside it."""
    folder = tmp_path_factory.mktemp("cut")
    data = sim_gel_short_recording.read_bytes()
    (folder / "cut.aedat4").write_bytes(data[: len(data) * 2 // 3])
    return folder / "cut.aedat4"


def test_track_on_a_cut_recording_leaves_the_earlier_predictions_and_puts_its_windows_beside(
    cut, tmp_path, monkeypatch, capsys
):
    out = tmp_path / "pred.jsonl"
    out.write_bytes(EARLIER)
    done = run_main(monkeypatch, capsys, ["track", str(cut), "--out", str(out)])
    assert done.returncode == 2, done.stderr
    assert out.read_bytes() == EARLIER
    partial = tmp_path / "pred.jsonl.partial"
    windows = len(partial.read_text().splitlines())
    assert windows > 10
    assert f"the {windows} windows before it are in {partial} ({out} is left as it was)" in done.stderr, done.stderr


@pytest.mark.parametrize("earlier", [True, False], ids=["a file there", "nothing there"])
def test_a_run_that_fails_part_way_never_leaves_its_states_at_the_outputs_name(
    cut, tmp_path, monkeypatch, capsys, earlier
):
    """The recording's cut ends the run with an error after states were written: a file that
    was there is byte-identical (it was not replaced at the first state); with none there, the
    states published live at the first one are moved aside too; they end on a neutral line."""
    out = tmp_path / "states.jsonl"
    if earlier:
        out.write_bytes(EARLIER)
    done = run_main(
        monkeypatch, capsys, ["run", "--source", str(cut), "--output", "jsonl", "--out", str(out), "--fast"]
    )
    assert done.returncode == 2, done.stderr
    partial = tmp_path / "states.jsonl.partial"
    lines = partial.read_text().splitlines()
    assert len(lines) >= 2 and json.loads(lines[-1])["gesture"] == "none"
    if earlier:
        assert out.read_bytes() == EARLIER
        assert f"{out} is left as it was; the {len(lines)} lines written before the error are in {partial}" in (
            done.stderr
        ), done.stderr
    else:
        assert not out.exists()
        assert f"{out} was not written; the {len(lines)} lines written before the error are in {partial}" in (
            done.stderr
        ), done.stderr


def test_a_run_stopped_by_ctrl_c_ends_its_file_as_at_its_end(tmp_path):
    """Ctrl-C is how a live run is stopped, not a failure: the states replace the file."""
    out = tmp_path / "states.jsonl"
    out.write_bytes(EARLIER)
    with pytest.raises(KeyboardInterrupt), StateJsonlWriter(out) as writer:
        writer.write(ControllerState.neutral(10))
        assert out.read_bytes() == EARLIER  # not replaced at the first state: a file was there
        raise KeyboardInterrupt
    assert json.loads(out.read_text())["t_us"] == 10
    assert not (tmp_path / "states.jsonl.partial").exists()


def test_an_interrupted_track_keeps_its_lines_aside_and_notes_where(tmp_path):
    """What ``track`` does on Ctrl-C or any error: the note is what the CLI prints."""
    out = tmp_path / "pred.jsonl"
    out.write_bytes(EARLIER)
    with pytest.raises(KeyboardInterrupt) as caught, JsonlWriter(out, keep_partial=True) as writer:
        writer.write_dict({"t_us": 1})
        raise KeyboardInterrupt
    assert out.read_bytes() == EARLIER
    assert (tmp_path / "pred.jsonl.partial").read_text() == '{"t_us": 1}\n'
    assert caught.value.__notes__ == [
        f"{out} is left as it was; the 1 lines written before the error are in {out}.partial"
    ]
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")], "a temporary file was left"


def test_a_failure_before_any_line_leaves_nothing_beside(tmp_path):
    out = tmp_path / "pred.jsonl"
    out.write_bytes(EARLIER)
    with pytest.raises(ValueError), JsonlWriter(out, keep_partial=True):
        raise ValueError("no gel")
    assert out.read_bytes() == EARLIER and sorted(p.name for p in tmp_path.iterdir()) == ["pred.jsonl"]
