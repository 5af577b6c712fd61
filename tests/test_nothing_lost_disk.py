"""Nothing lost on a full disk or a closed terminal (docs/limits.md): ``record`` and every command that
writes end in one line and exit 2 with what was there before byte-identical; a closed terminal ends
a recording complete.

A full disk is a real one: a small tmpfs mounted for the test (root and ``mount`` are needed: CI
runs as root; elsewhere those tests are skipped, saying why)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
from hostile_helpers import ROOT, assert_refused, cli
from nothing_lost_helpers import _HEADER, SIMULATE, _env, _mount, _snapshot, full_disk

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
