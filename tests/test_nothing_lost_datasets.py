"""Nothing lost in datasets and the outputs of the commands that read them (docs/limits.md): a dataset
folder replaced only on ``--force`` and then whole, two writers into one folder, no output over a
file of the dataset read, no part folder left by a terminated command, ``--plan-out`` and
``--out`` refusing links, and messages that misled."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest
from hostile_helpers import ROOT, assert_refused, cli
from nothing_lost_helpers import SIMULATE, _env, _snapshot


def test_a_dataset_folder_is_replaced_only_on_force_and_then_whole(tmp_path):
    """``simulate --out DS`` over a dataset replaced its sensor.yaml and sequences silently."""
    ds = tmp_path / "ds"
    assert cli(*SIMULATE, "--out", str(ds), "--seed", "1", timeout_s=300)[0] == 0
    (ds / "u9_old.labels.csv").write_text("an earlier sequence's labels\n")
    before = _snapshot(ds)
    assert_refused(cli(*SIMULATE, "--out", str(ds), timeout_s=300), "holds a dataset already", "--force")
    assert _snapshot(ds) == before
    code, _, err, _ = cli(*SIMULATE, "--out", str(ds), "--force", timeout_s=300)
    assert code == 0, err
    after = _snapshot(ds)
    assert "u9_old.labels.csv" not in after and after["sensor.yaml"] and after != before  # whole: nothing old left
    home = tmp_path / "home"
    home.mkdir()
    (home / "notes.txt").write_text("not a dataset\n")
    assert_refused(cli(*SIMULATE, "--out", str(home), "--force", timeout_s=300), "no dataset's")
    assert _snapshot(home) == {"notes.txt": b"not a dataset\n"}
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ds", "home"], "a part folder was left"


def test_two_writers_into_one_new_folder_one_wins_whole_the_other_says_it_lost(tmp_path):
    from neurotouch_hid.core.dataset_out import DatasetOut
    from neurotouch_hid.core.errors import DatasetError

    out = tmp_path / "enrolment"
    first, second = DatasetOut(out), DatasetOut(out)
    (first.work / "enrolment.labels.csv").write_text("first\n")
    (second.work / "enrolment.labels.csv").write_text("second\n")
    assert first.commit() == out
    with pytest.raises(DatasetError, match="another command wrote a dataset there meanwhile"):
        second.commit()
    assert _snapshot(out) == {"enrolment.labels.csv": b"first\n"}
    assert sorted(p.name for p in tmp_path.iterdir()) == ["enrolment"]
    forced = DatasetOut(out, force=True)
    (forced.work / "sensor.yaml").write_text("new\n")
    forced.commit()
    assert _snapshot(out) == {"sensor.yaml": b"new\n"}
    assert sorted(p.name for p in tmp_path.iterdir()) == ["enrolment"]


def test_enrol_from_a_recording_inside_the_dataset_keeps_its_labels_unless_forced(tmp_path, sim_quick_dataset):
    ds = tmp_path / "ds"
    ds.mkdir()
    for name in ("u0_push.aedat4", "u0_push.labels.csv", "sensor.yaml"):
        (ds / name).write_bytes((sim_quick_dataset / name).read_bytes())
    plan = tmp_path / "plan.json"
    assert cli("enrol", "--plan-out", str(plan))[0] == 0
    before = _snapshot(ds)
    args = ("enrol", "--from", str(ds / "u0_push.aedat4"), "--plan", str(plan), "--out", str(ds))
    assert_refused(cli(*args, timeout_s=300), "holds a dataset already")
    assert _snapshot(ds) == before


@pytest.mark.parametrize("name", ["u0_push.aedat4", "u0_push.labels.csv", "sensor.yaml"])
def test_eval_writes_no_output_over_a_file_of_the_dataset_it_reads(tmp_path, sim_quick_dataset, name):
    """``eval DS --json DS/u0_push.aedat4`` replaced the 5.7 MB recording with 5.9 KB of JSON
    (exit 0): only the folder was an input, not its files."""
    ds = tmp_path / "ds"
    ds.mkdir()
    for part in ("u0_push.aedat4", "u0_push.labels.csv", "sensor.yaml"):
        (ds / part).write_bytes((sim_quick_dataset / part).read_bytes())
    before = _snapshot(ds)
    assert_refused(cli("eval", str(ds), "--json", str(ds / name), timeout_s=300), "a file of the input folder")
    assert _snapshot(ds) == before


@pytest.mark.parametrize("flag", ["--json", "--report", "--predictions"])
def test_eval_says_before_its_work_when_an_outputs_folder_is_a_file(tmp_path, sim_quick_dataset, flag):
    """``eval DS --report one.json`` (a file there) ran the whole evaluation, then ended in a
    FileExistsError traceback."""
    blocker = tmp_path / "one.json"
    blocker.write_text("{}\n")
    target = blocker / "x.json" if flag == "--json" else blocker
    result = cli("eval", str(sim_quick_dataset), flag, str(target), timeout_s=300)
    assert_refused(result, f"{flag}: {blocker} is a file, not a folder")
    assert blocker.read_text() == "{}\n"


def test_calibrate_replaces_no_recording_given_as_its_output(tmp_path, sim_gel_short_recording):
    """``calibrate --source REC --out REC`` replaced the 6.4 MB recording with a 3.9 KB
    sensor.yaml ("which was not a valid sensor.yaml"); any other recording given as --out too."""
    rec = tmp_path / "c.aedat4"
    rec.write_bytes(sim_gel_short_recording.read_bytes())
    other = tmp_path / "other.aedat4"
    other.write_bytes(sim_gel_short_recording.read_bytes())
    before = _snapshot(tmp_path)
    assert_refused(cli("calibrate", "--source", str(rec), "--out", str(rec)), "the same file as the input")
    assert_refused(cli("calibrate", "--source", str(rec), "--out", str(other)), "is not a sensor.yaml")
    assert _snapshot(tmp_path) == before


@pytest.mark.parametrize("signum", [15, 1])  # SIGTERM, SIGHUP (the terminal closed)
def test_a_terminated_command_leaves_no_part_folder_and_dies_by_the_signal(tmp_path, signum):
    """``simulate`` stopped by SIGTERM or SIGHUP left its hidden ``.ds.XXXX.part`` folder (tens of
    MB each time; nothing cleans them up): the signal now unwinds it as Ctrl-C does, and the
    process still ends by that signal, as its parent (a shell, systemd) expects."""
    import signal
    import time

    said = tmp_path.parent / f"{tmp_path.name}.stderr"  # what the command said, for a failure's message
    child = subprocess.Popen(
        [sys.executable, "-m", "neurotouch_hid.cli", "simulate", "--out", str(tmp_path / "ds"), "--preset", "paper"],
        env=dict(os.environ, PYTHONPATH=str(ROOT), HOME=str(tmp_path)),
        stdout=subprocess.DEVNULL,
        stderr=said.open("w"),
    )

    def recording_size() -> int:  # the first sequence's recording in the hidden folder, as written
        sizes = [r.stat().st_size for p in tmp_path.iterdir() if p.name.endswith(".part") for r in p.glob("*.aedat4")]
        return max(sizes, default=0)

    try:
        # into its work: the recording grows once the simulation runs (a first run compiles
        # first, for as long as the machine takes): the bounds only end a hang
        seen = 0
        deadline = time.monotonic() + 900
        while not 0 < seen < recording_size():
            assert child.poll() is None, child.returncode
            assert time.monotonic() < deadline, "simulate never got into its work"
            seen = recording_size()
            time.sleep(0.2)
        child.send_signal(signal.Signals(signum))
        assert child.wait(timeout=300) == -signum, said.read_text()[-3000:]
    finally:
        child.kill()
    assert sorted(p.name for p in tmp_path.iterdir() if p.name != ".cache") == [], list(tmp_path.iterdir())


# --- outputs of enrol --plan-out and adapt --out ---------------------------------------------
def test_plan_out_and_adapt_out_refuse_links_write_devices_in_place_and_dash_is_stdout(tmp_path):
    """``--plan-out /dev/null`` replaced the device node by a file (as root); ``--plan-out -``
    wrote a file named ``-``; a link was replaced by a file."""
    from neurotouch_hid.enrolment.model import Model

    device = tmp_path / "null"
    os.mknod(device, 0o666 | 0o020000, os.makedev(1, 3))  # a character device: /dev/null's numbers
    assert cli("enrol", "--plan-out", str(device))[0] == 0
    assert device.is_char_device()
    code, out, err, _ = cli("enrol", "--plan-out", "-")
    assert code == 0 and out.startswith('{"prompts": [') and "prompts over" in err, (out, err)
    assert not (ROOT / "-").exists()
    precious, link = tmp_path / "precious.json", tmp_path / "link.json"
    precious.write_text("keep me\n")
    link.symlink_to(precious)
    assert_refused(cli("enrol", "--plan-out", str(link)), "symbolic link")
    assert_refused(cli("adapt", str(tmp_path), "--out", str(link)), "symbolic link")
    assert precious.read_text() == "keep me\n" and link.is_symlink()
    Model({"gesture.intensity_gain": 1.1}).save(device)
    assert device.is_char_device()
    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)
    reader = subprocess.Popen(["cat", str(fifo)], stdout=subprocess.PIPE)
    assert cli("enrol", "--plan-out", str(fifo))[0] == 0
    assert reader.communicate(timeout=30)[0].startswith(b'{"prompts": [')
    assert fifo.is_fifo()


# --- messages that misled ----------------------------------------------------------------------
def test_a_dataset_given_twice_to_adapt_is_read_once_and_said(tmp_path, sim_rest_dataset):
    """``adapt D D D`` said its held-out gestures were never seen by the fit: they were copies of
    fitted ones."""
    out = tmp_path / "model.yaml"
    d = str(sim_rest_dataset)
    code, _, err, _ = cli("adapt", d, d, f"{d}/.", "--out", str(out), "--jobs", "1", timeout_s=300)
    assert err.count("given more than once: read once") == 2, err


def test_an_adaptation_with_nothing_held_out_says_no_nan():
    import math

    from neurotouch_hid.enrolment.adapt import Adaptation, Check, summary
    from neurotouch_hid.enrolment.model import Model

    nan = math.nan
    checks = [Check("classifier", "gesture type accuracy", nan, nan, False, "refitted", False)]
    lines = summary(Adaptation(Model(), checks, 0, 0, 0, nan, nan))
    assert not [line for line in lines if "nan" in line.lower()], lines


def test_plan_cues_past_the_recordings_end_are_said_once(tmp_path, sim_push_only_recording):
    """A plan whose cues run past the recording: one line for them (it was a line per prompt);
    a plan entirely past it is refused in one line."""
    import json

    late = [{"gesture": "pinch", "cue_s": 100.0 + 5 * i, "seconds": 0.5} for i in range(30)]
    plan = tmp_path / "plan.json"
    plan.write_text(json.dumps({"prompts": [{"gesture": "push", "cue_s": 0.5, "seconds": 1.0}, *late]}))
    args = ("enrol", "--from", str(sim_push_only_recording), "--plan", str(plan))
    code, out, err, _ = cli(*args, "--out", str(tmp_path / "ds"), timeout_s=300)
    assert code == 0, err
    assert "prompts 2 to 31 are cued after the recording's end: left out" in out
    assert len(out.strip().splitlines()) <= 3, out
    plan.write_text(json.dumps({"prompts": late}))
    assert_refused(cli(*args, "--out", str(tmp_path / "ds2"), timeout_s=300), "every one of the plan's 30 prompts")
    assert not (tmp_path / "ds2").exists()


def test_two_simulations_into_one_new_folder_one_wins_whole_the_other_says_it_lost(tmp_path):
    """Two writers into one folder both said they succeeded, and one was lost."""
    out = tmp_path / "ds"
    runs = [
        subprocess.Popen(
            [sys.executable, "-m", "neurotouch_hid.cli", *SIMULATE, "--out", str(out), "--seed", str(seed)],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            env=_env(tmp_path / "config"),
            cwd=ROOT,
        )  # fmt: skip
        for seed in (1, 2)
    ]
    done = [(p.wait(timeout=600), *p.communicate()) for p in runs]
    assert sorted(code for code, _, _ in done) == [0, 2], done
    lost = next(err for code, _, err in done if code == 2)
    assert "meanwhile" in lost or "holds a dataset already" in lost, lost
    names = sorted(p.name for p in out.iterdir())
    assert names == sorted(
        ["sensor.yaml", "physics.json"]
        + [
            f"u0_{g}{s}"
            for g in ("pinch", "push", "twist_ccw", "twist_cw", "zoom")
            for s in (".aedat4", ".labels.csv", ".markers.npz", ".pressed.csv")
        ]
    ), names
    assert not [p.name for p in tmp_path.iterdir() if p.name.startswith(".")], "a part folder was left"
