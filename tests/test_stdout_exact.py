"""What a command writes to standard output when its result goes there (``-``, ``/dev/stdout``)
is that result only, parseable; human lines go to stderr; a file name is printed as it is, with
no markup read into it; and a result is the same bytes however the work was split."""

from __future__ import annotations

import json

import pytest
import yaml
from helpers import run_cli


def test_track_to_standard_output_writes_json_lines_only(sim_quick_dataset, tmp_path):
    """The summary line came after the last window on stdout: a JSON-lines reader failed on it."""
    recording = str(sim_quick_dataset / "u0_push.aedat4")
    for out in ("-", "/dev/stdout"):
        done = run_cli("track", recording, "--out", out)
        assert done.returncode == 0, done.stderr
        lines = done.stdout.splitlines()
        assert len(lines) > 100 and all(json.loads(line)["t_us"] > 0 for line in lines)
        assert "windows of 10000 us" in done.stderr and f"-> {out}" in done.stderr


def test_eval_json_to_standard_output_is_the_json_alone_and_the_tables_go_to_stderr(sim_quick_dataset, tmp_path):
    """``eval --json -`` wrote a file named ``-`` and the tables to stdout."""
    for out in ("-", "/dev/stdout"):
        done = run_cli("eval", str(sim_quick_dataset), "--json", out, cwd=tmp_path)
        assert done.returncode == 0, done.stderr
        summary = json.loads(done.stdout)
        assert summary["command"].endswith(f"--json={out}") and "gesture_accuracy" in summary
        assert "Gesture type accuracy" in done.stderr
        # the title whole on its own line (rich wrapped it to the table's width)
        title = next(line for line in done.stderr.splitlines() if line.startswith("NeuroTouch evaluation:"))
        assert title.endswith("before the first label skipped)"), title
    assert list(tmp_path.iterdir()) == []


def test_eval_with_jobs_gives_the_same_json_as_without(sim_quick_dataset, tmp_path):
    """Sequences were summed in the order their processes finished: the last digits moved."""
    one = run_cli("eval", str(sim_quick_dataset), "--json", "-", cwd=tmp_path)
    three = run_cli("eval", str(sim_quick_dataset), "--json", "-", "--jobs", "3", cwd=tmp_path)
    assert one.returncode == three.returncode == 0, (one.stderr, three.stderr)
    strip = lambda text: {k: v for k, v in json.loads(text).items() if k != "command"}  # noqa: E731
    assert strip(one.stdout) == strip(three.stdout)


def test_simulate_draws_its_progress_on_stderr(tmp_path):
    done = run_cli("simulate", "--out", str(tmp_path / "ds"), "--preset", "quick", "--seed", "3")
    assert done.returncode == 0, done.stderr
    assert done.stdout == f"wrote {tmp_path / 'ds'}\n"


@pytest.mark.parametrize(
    "args, says",
    [
        (["calibrate", "--source", "sim", "--no-check", "--out", "-"], "--out -: calibrate writes a sensor file"),
        (["track", "REC", "--out", "p.jsonl", "--markers", "-"], "--markers -: the markers are an .npz file"),
        (["simulate", "--out", "-", "--preset", "quick"], "--out -: a dataset is a folder"),
        (["eval", "DS", "--report", "-"], "--report -: the report is a folder"),
        (["eval", "DS", "--predictions", "-"], "--predictions -: the predictions are a folder"),
        (["enrol", "--source", "sim", "--out", "-"], "--out -: an enrolment is a dataset folder"),
    ],
)
def test_an_output_that_cannot_be_standard_output_refuses_dash_before_any_work(sim_quick_dataset, tmp_path, args, says):
    """A file or a folder named ``-`` was written instead (``track --markers -``: 117 KB of .npz)."""
    args = [str(sim_quick_dataset / "u0_push.aedat4") if a == "REC" else a for a in args]
    args = [str(sim_quick_dataset) if a == "DS" else a for a in args]
    done = run_cli(*args, cwd=tmp_path)
    assert done.returncode == 2, done.stderr
    assert says in done.stderr and "not standard output; give a path" in done.stderr
    assert "Traceback" not in done.stderr and done.stdout == ""
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("name", ["q[/]p.jsonl", "p [b]x.jsonl", "a{0}b.jsonl"])
def test_a_file_name_with_brackets_is_printed_as_it_is_and_the_command_succeeds(sim_quick_dataset, tmp_path, name):
    """rich read ``[/]`` in a name as markup: a MarkupError traceback (exit 1) after the output was
    written; ``[b]`` vanished from the name printed."""
    out = tmp_path / "q[" / name if name.startswith("q[/]") else tmp_path / name
    out.parent.mkdir(parents=True, exist_ok=True)
    done = run_cli("track", str(sim_quick_dataset / "u0_push.aedat4"), "--out", str(out))
    assert done.returncode == 0, done.stderr
    assert f"-> {out} (geometry:" in done.stdout
    info = run_cli("info", str(sim_quick_dataset / "u0_push.aedat4"))
    assert info.returncode == 0, info.stderr
    missing = run_cli("info", str(tmp_path / "r[/]x [b].aedat4"))
    assert missing.returncode == 2 and f"{tmp_path / 'r[/]x [b].aedat4'}" in missing.stderr, missing.stderr


def test_adapt_to_standard_output_writes_the_model_alone(tmp_path):
    """Seven summary lines came before the model's YAML on stdout, and ``-> -`` after it."""
    from neurotouch_hid.enrolment.hand import simulate_enrolment
    from neurotouch_hid.enrolment.plan import Plan, make_plan

    folder = tmp_path / "enrolment"
    simulate_enrolment(Plan(make_plan(1).prompts[:6]), folder, seed=1, miss_rate=0.0)
    done = run_cli("adapt", str(folder), "--out", "-")
    assert done.returncode == 0, done.stderr
    model = yaml.safe_load(done.stdout)
    assert isinstance(model, dict) and model.get("version") == 1
    assert "-> -" in done.stderr


def test_a_recording_whose_name_is_not_utf8_is_refused_for_what_it_is(sim_quick_dataset, tmp_path):
    """It was called a corrupt AEDAT4 file ("No such file or directory"): the decoder takes the
    name as a Rust string."""
    import os
    import shutil

    odd = os.path.join(os.fsencode(tmp_path), b"bad\xffname.aedat4")
    shutil.copyfile(sim_quick_dataset / "u0_push.aedat4", odd)
    done = run_cli("info", os.fsdecode(odd))
    assert done.returncode == 2 and "Traceback" not in done.stderr
    assert "a file name that is not UTF-8 cannot be opened by the AEDAT4 decoder; rename the file" in done.stderr
