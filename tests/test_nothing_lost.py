"""Nothing lost, with the disk, the clock and other commands against the driver (docs/limits.md):
a full or read-only disk ends every command in one line and exit 2 with what was there before
byte-identical; commands run side by side change the same files without losing a change.

A full disk is a real one: a small tmpfs mounted for the test (root and ``mount`` are needed: CI
runs as root; elsewhere those tests are skipped, saying why). A read-only folder is a read-only
bind mount: ``chmod`` does not stop root."""

from __future__ import annotations

import contextlib
import os
import subprocess
import sys
from pathlib import Path

import pytest
from hostile_helpers import ROOT, assert_refused, cli

PROFILE = [sys.executable, "-m", "neurotouch_hid.cli", "profile"]


def _mount(*args: str) -> None:
    done = subprocess.run(["mount", *args], capture_output=True, text=True)
    if done.returncode != 0:
        pytest.skip(
            reason=f"cannot mount here ({done.stderr.strip() or 'mount failed'}): run as root to test a full disk"
        )


@contextlib.contextmanager
def full_disk(folder: Path, size_kb: int = 64, prepare=None):
    """``folder`` as a tmpfs of ``size_kb`` KB (``prepare(folder)`` run on it first), filled to its
    last byte; unmounted afterwards."""
    folder.mkdir(parents=True, exist_ok=True)
    _mount("-t", "tmpfs", "-o", f"size={size_kb}k", "tmpfs", str(folder))
    try:
        if prepare is not None:
            prepare(folder)
        with open(folder / ".filler", "wb", buffering=0) as fh, contextlib.suppress(OSError):
            while fh.write(b"\0" * 4096):
                pass
        yield folder
    finally:
        subprocess.run(["umount", "-l", str(folder)], check=False)


@contextlib.contextmanager
def read_only(folder: Path):
    """``folder`` bind-mounted read-only over itself (root writes through a chmod)."""
    _mount("--bind", str(folder), str(folder))
    try:
        _mount("-o", "remount,bind,ro", str(folder))
        yield folder
    finally:
        subprocess.run(["umount", "-l", str(folder)], check=False)


def _snapshot(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def _env(config: Path) -> dict:
    return dict(os.environ, PYTHONPATH=str(ROOT), XDG_CONFIG_HOME=str(config))


# --- profiles: a full or read-only config folder, side by side edits ---------------------------
def test_profile_edits_on_a_full_or_read_only_config_folder_are_one_line_and_keep_the_profile(tmp_path):
    config = tmp_path / "config"
    env = _env(config)
    assert cli("profile", "new", "mine", "--from", "default", env=env)[0] == 0
    profiles = config / "neurotouch-hid"
    before = _snapshot(profiles)
    set_push = ("profile", "set", "mine", "mappings.push.deadzone_mm", "1.25")
    with read_only(profiles):
        for args in (set_push, ("profile", "new", "other"), ("profile", "auto", "add", "4242", "mine")):
            assert_refused(cli(*args, env=env), "nothing was changed")
        assert _snapshot(profiles) == before
    work = tmp_path / "full"
    env = _env(work)
    with full_disk(work, 512, lambda _: cli("profile", "new", "mine", "--from", "default", env=env)) as full:
        before = _snapshot(full / "neurotouch-hid")
        for args in (set_push, ("profile", "new", "other"), ("profile", "auto", "add", "4242", "default")):
            assert_refused(cli(*args, env=env), "No space left on device")
        assert _snapshot(full / "neurotouch-hid") == before
    flat = tmp_path / "flat"
    flat.write_text("a file where the config folder should be\n")
    assert_refused(cli(*set_push[:2], "default", *set_push[3:], env=_env(flat)), "nothing was changed")
    assert flat.read_text() == "a file where the config folder should be\n"


def test_parallel_profile_edits_all_land(tmp_path):
    """8 ``profile set`` of different keys and 10 ``profile auto add`` at once: every change is in
    the files afterwards (they kept 2 and 7)."""
    env = _env(tmp_path / "config")
    assert subprocess.run([*PROFILE, "new", "mine", "--from", "default"], env=env, cwd=ROOT).returncode == 0
    keys = [f"mappings.{m}.{f}" for m in ("push", "twist", "zoom", "pinch") for f in ("deadzone_mm", "saturation_mm")]
    values = {key: f"{(9 + i) if 'saturation' in key else 0.1 + 0.01 * i:.2f}" for i, key in enumerate(keys)}
    runs = [subprocess.Popen([*PROFILE, "set", "mine", key, value], env=env, cwd=ROOT) for key, value in values.items()]
    runs += [
        subprocess.Popen(
            [*PROFILE, "auto", "add", str(4000 + i), "mouse"], env=env, cwd=ROOT, stdout=subprocess.DEVNULL
        )
        for i in range(10)
    ]
    assert [p.wait(timeout=300) for p in runs] == [0] * len(runs)
    from neurotouch_hid.mapping.profile import load_profile
    from neurotouch_hid.service.games import load_game_map

    profile = load_profile(tmp_path / "config" / "neurotouch-hid" / "profiles" / "mine.yaml")
    for key, value in values.items():
        _, name, field = key.split(".")
        assert getattr(profile.mappings[name], field) == pytest.approx(float(value)), key
    assert sorted(load_game_map(tmp_path / "config" / "neurotouch-hid" / "games.yaml").steam) == list(range(4000, 4010))


def test_a_profile_name_ending_in_a_newline_is_refused(cli):
    from neurotouch_hid.core.errors import ProfileError
    from neurotouch_hid.mapping.editor import user_profile_path

    with pytest.raises(ProfileError, match="not allowed"):
        user_profile_path("evil\n")
    done = cli("new", "evil\n")
    assert done.returncode == 2 and "not allowed" in done.stderr, done.stderr
    assert not cli.user_dir.exists() or not list(cli.user_dir.glob("evil*"))


def test_profile_set_writes_through_a_symlinked_profile_and_keeps_the_link(cli, tmp_path):
    kept = tmp_path / "kept" / "mine.yaml"
    kept.parent.mkdir()
    assert cli("new", "mine").returncode == 0
    (cli.user_dir / "mine.yaml").rename(kept)
    (cli.user_dir / "mine.yaml").symlink_to(kept)
    done = cli("set", "mine", "mappings.push.deadzone_mm", "1.5")
    assert done.returncode == 0, done.stderr
    assert (cli.user_dir / "mine.yaml").is_symlink()
    assert "deadzone_mm: 1.5" in kept.read_text()


# --- recordings: a full disk, the terminal closed ---------------------------------------------
RECORD = ("record", "--source", "sim", "--seconds", "30", "--fast")


def _no_hidden(folder: Path) -> None:
    assert not [p.name for p in folder.iterdir() if p.name.startswith(".") and p.name != ".filler"], "a part file"


def test_record_on_a_full_disk_is_one_line_and_keeps_an_existing_recording(tmp_path, sim_gel_short_recording):
    """dv-processing's writer thread threw on a full disk (std::terminate, exit 134); ``record
    --force`` replaced a recording by a truncated one."""
    from neurotouch_hid.sources.recording import read_info

    old = sim_gel_short_recording.read_bytes()

    def put_old(folder: Path) -> None:
        (folder / "old.aedat4").write_bytes(old)

    with full_disk(tmp_path / "full", 8192, put_old) as full:
        assert_refused(cli(RECORD[0], str(full / "new.aedat4"), *RECORD[1:], timeout_s=120), "the disk is full")
        assert_refused(cli(RECORD[0], str(full / "old.aedat4"), *RECORD[1:], "--force", timeout_s=120), "disk is full")
        assert (full / "old.aedat4").read_bytes() == old
        assert not (full / "new.aedat4").exists()
        _no_hidden(full)
    roomy = tmp_path / "roomy"  # a disk that fills during the recording: 8 MB, 4 MB kept free
    roomy.mkdir()
    _mount("-t", "tmpfs", "-o", "size=8m", "tmpfs", str(roomy))
    try:
        put_old(roomy)
        assert_refused(cli(RECORD[0], str(roomy / "old.aedat4"), *RECORD[1:], "--force", timeout_s=120), "as it was")
        assert (roomy / "old.aedat4").read_bytes() == old
        _no_hidden(roomy)
        code, _, err, _ = cli(RECORD[0], str(roomy / "new.aedat4"), *RECORD[1:], timeout_s=120)
        assert code == 2 and len(err.strip().splitlines()) == 1 and "complete in" in err, err
        info = read_info(roomy / "new.aedat4")  # whole: its index table is there
        assert info.n_frames > 0 and info.duration_s < 30
        _no_hidden(roomy)
    finally:
        subprocess.run(["umount", "-l", str(roomy)], check=False)


def test_a_closed_terminal_ends_a_recording_complete(tmp_path):
    """SIGHUP (the terminal closed) ends ``record`` as Ctrl-C does: exit 0, a whole file."""
    import signal

    from helpers import wait_until

    from neurotouch_hid.sources.recording import read_info

    out = tmp_path / "hup.aedat4"
    proc = subprocess.Popen(
        [sys.executable, "-m", "neurotouch_hid.cli", "record", str(out), "--source", "sim"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=_env(tmp_path / "config"), cwd=ROOT,
    )  # fmt: skip
    try:
        assert wait_until(lambda: proc.poll() is not None or (out.exists() and out.stat().st_size > 200_000), 120)
        proc.send_signal(signal.SIGHUP)
        stdout, stderr = proc.communicate(timeout=60)
    finally:
        proc.kill()
    assert proc.returncode == 0, stderr
    assert read_info(out).n_frames > 0


# --- datasets: a folder that holds one is replaced only on --force, whole ----------------------
SIMULATE = ("simulate", "--preset", "quick", "--users", "0", "--minutes", "0.01")


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


def test_a_plan_cue_past_a_day_is_refused_with_its_field(tmp_path):
    """A cue of 1e308 s ended ``enrol --from`` in an OverflowError traceback (its microseconds)."""
    from neurotouch_hid.core.errors import DatasetError
    from neurotouch_hid.enrolment.plan import read_plan

    plan = tmp_path / "p.json"
    plan.write_text('{"prompts": [{"gesture": "push", "cue_s": 1e308, "seconds": 1}]}')
    with pytest.raises(DatasetError, match="prompt 1: field 'cue_s'.*from 0 to 86400"):
        read_plan(plan)


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


_HEADER = "t_us,gesture,resting,intensity_mm,n_contacts,x1_px,y1_px,x2_px,y2_px,x3_px,y3_px\n"


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


# --- the control socket: many `profile use` at once --------------------------------------------
def test_parallel_profile_use_all_get_their_answer(tmp_path):
    """The backlog of 4 made ten `profile use` at once fail with "Resource temporarily
    unavailable"; over the clients served at once they were answered busy."""
    import threading
    import time

    from neurotouch_hid.service.control import ControlServer, request_use

    folder = tmp_path / "run"
    folder.mkdir(mode=0o700)
    (folder / "neurotouch-hid").mkdir(mode=0o700)
    gate = threading.Event()

    def use(ref: str) -> str:
        gate.wait(5)  # every client waits here: the backlog and the served ones fill up
        time.sleep(0.01)
        return f"switched to {ref}"

    server = ControlServer(use, path=folder / "neurotouch-hid" / "control.sock")
    assert server.start()
    answers, errors = [], []

    def ask(i: int) -> None:
        try:
            answers.append(request_use(f"p{i}", path=server.path, timeout_s=20))
        except Exception as exc:  # noqa: BLE001 (each failure is collected and shown)
            errors.append(repr(exc))

    try:
        threads = [threading.Thread(target=ask, args=(i,)) for i in range(40)]
        for t in threads:
            t.start()
        time.sleep(0.5)
        gate.set()
        for t in threads:
            t.join(60)
    finally:
        server.stop()
    assert not errors, errors[:3]
    assert sorted(answers) == sorted(f"switched to p{i}" for i in range(40))


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


def test_every_command_on_a_full_disk_is_one_line_and_keeps_what_was_there(tmp_path, sim_gel_short_recording):
    """``track``, ``run --output jsonl --out`` and ``simulate`` ended in tracebacks (``run`` left
    a 0-byte temporary file); ``enrol`` aborted in dv-processing's thread."""
    from neurotouch_hid.core.errors import NeurotouchError
    from neurotouch_hid.enrolment.model import Model

    preds = tmp_path / "pred.jsonl"
    assert cli("track", str(sim_gel_short_recording), "--out", str(preds), timeout_s=300)[0] == 0

    def earlier(folder: Path) -> None:
        (folder / "p.jsonl").write_text('{"earlier": "predictions"}\n')
        (folder / "s.jsonl").write_text('{"earlier": "states"}\n')
        (folder / "plan.json").write_text('{"prompts": []}\n')
        (folder / "model.yaml").write_text("# an earlier model\n")
        (folder / "ds").mkdir()
        (folder / "ds" / "sensor.yaml").write_text("# an earlier dataset's\n")
        (folder / "ds" / "old.labels.csv").write_text(_HEADER)

    with full_disk(tmp_path / "full", 256, earlier) as full:
        before = _snapshot(full)
        commands = [
            ("track", str(sim_gel_short_recording), "--out", str(full / "p.jsonl")),
            ("run", "--fast", "--profile", "default", "--source", str(preds), "--output", "jsonl"),
            (*SIMULATE, "--out", str(full / "ds"), "--force"),
            (*SIMULATE, "--out", str(full / "new")),
            ("enrol", "--source", "sim", "--fast", "--out", str(full / "ds"), "--force"),
            ("enrol", "--plan-out", str(full / "plan.json")),
        ]
        commands[1] = (*commands[1], "--out", str(full / "s.jsonl"))
        for args in commands:
            code, _, err, _ = cli(*args, timeout_s=300)
            assert code == 2 and "Traceback" not in err and len(err.strip().splitlines()) == 1, (args, code, err)
            assert "No space left on device" in err or "disk is full" in err, err
            assert _snapshot(full) == before, args
            assert sorted(p.name for p in full.iterdir()) == sorted({p.split("/")[0] for p in before}), "a part left"
        with pytest.raises(NeurotouchError, match="No space left on device"):
            Model({"gesture.intensity_gain": 1.1}).save(full / "model.yaml")
        assert _snapshot(full) == before


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
