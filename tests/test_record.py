"""neurotouch-hid record: what the camera sees, as AEDAT4 that `info` (and DV) read back.

The simulated gel stands in for the camera in the CLI tests; the live-camera path (DavisSource)
is driven by a replay of a street (the real recording where it is, and a simulated one) with an
unplug, on a clock the test controls (tests/camera_replay.py).
"""

from __future__ import annotations

import os
import signal
import subprocess

import numpy as np
import pytest
from camera_replay import Fault, ManualClock, ReplayWorld
from helpers import CLI, run_cli, run_main, wait_until

from neurotouch_hid.core.errors import DeviceError, RecordingError
from neurotouch_hid.sources import Frame
from neurotouch_hid.sources.davis import DavisConfig, DavisSource
from neurotouch_hid.sources.recording import RecordingReader, read_info
from neurotouch_hid.sources.recording_writer import record_stream
from neurotouch_hid.sources.simulator import SimulatedSource

ENV = dict(os.environ, COLUMNS="200")


def test_record_sim_writes_exactly_what_the_source_gave(tmp_path):
    out = tmp_path / "sim.aedat4"
    proc = run_cli("record", str(out), "--source", "sim", "--seconds", "1.5", "--fast", "--seed", "3", columns=200)
    assert proc.returncode == 0, proc.stderr
    items = list(SimulatedSource(seed=3).stream(seconds=1.5))
    want_events = np.concatenate([i for i in items if not isinstance(i, Frame)])
    want_frames = [i for i in items if isinstance(i, Frame)]
    with RecordingReader(out) as reader:
        events, frames = reader.read_all()
    assert np.array_equal(events, want_events)
    assert [f.t_us for f in frames] == [f.t_us for f in want_frames]
    assert all(np.array_equal(a.image, b.image) for a, b in zip(frames, want_frames))
    info = read_info(out)
    assert (info.n_events, info.n_frames, info.width, info.height) == (len(want_events), len(want_frames), 346, 260)
    assert f"{len(want_events):,} events" in proc.stdout


def written_so_far(path) -> tuple[int, int]:
    """(events, APS frames) readable in the part of ``path`` written so far: (0, 0) until there
    are both."""
    events = frames = 0
    try:
        with RecordingReader(path) as reader:
            for item in reader.stream(batch_us=10_000):
                if isinstance(item, Frame):
                    frames += 1
                else:
                    events += len(item)
    except RecordingError:
        pass  # where the writing is, or no file yet
    return (events, frames) if events and frames else (0, 0)


def test_ctrl_c_ends_a_recording_with_a_complete_file(tmp_path):
    out = tmp_path / "stopped.aedat4"
    proc = subprocess.Popen(
        [*CLI, "record", str(out), "--source", "sim"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=ENV,
    )
    try:
        # stopped once it has recorded something (a frame and events), however long that takes
        assert wait_until(lambda: proc.poll() is not None or written_so_far(out) != (0, 0), timeout_s=120)
        proc.send_signal(signal.SIGINT)
        stdout, stderr = proc.communicate(timeout=60)
    finally:
        proc.kill()
    assert proc.returncode == 0, stderr
    assert "stopped by Ctrl-C" in stdout
    info = read_info(out)  # the index table is there: the file is whole
    assert info.n_frames > 0 and info.n_events > 0


def test_a_lost_camera_ends_the_recording_but_keeps_the_file_whole(any_street, tmp_path):
    world = ReplayWorld(any_street.path, faults=(Fault("unplug", 0.8),), clock=ManualClock())
    out = tmp_path / "street.aedat4"
    seen = []
    with DavisSource(DavisConfig(stall_timeout_s=0.3), backend=world, **world.source_clock()) as camera:
        with pytest.raises(DeviceError, match="unplugged"):
            record_stream(
                camera.stream(seconds=5, batch_us=10_000),
                out,
                camera_name=camera.camera_name,
                on_progress=lambda us, events, frames: seen.append((events, frames)),
            )
    info = read_info(out)
    assert (info.n_events, info.n_frames) == seen[-1] and info.n_frames >= 10
    assert info.camera_name == "DAVIS346_00000499"


def test_record_keeps_the_driver_s_10_ms_commit_interval(any_street, tmp_path, monkeypatch, capsys):
    """``record --source davis`` waits for nobody: the camera keeps a 10 ms data commit interval,
    whose batches fill dv-processing's queue with ten times the camera time of ``run``'s 1 ms
    (a writer that falls behind loses nothing for longer), and the file holds what it read."""
    import dv_processing as dv

    world = ReplayWorld(any_street.path)
    monkeypatch.setattr(dv.io, "camera", world)
    out = tmp_path / "street.aedat4"
    done = run_main(monkeypatch, capsys, ["record", "--source", "davis", "--seconds", "0.5", str(out)])
    assert done.returncode == 0, done.stderr
    assert [us for _, us in world.time_intervals] == [10_000], world.time_intervals
    assert read_info(out).n_events > 0


@pytest.mark.parametrize(
    "args, message",
    [
        (["--source", "sim", "--fast"], "--fast needs --seconds: how much of the simulated gel to record"),
        (["--source", "davis", "--fast", "--seconds", "1"], "--fast is for --source sim (a camera cannot"),
        (["--source", "street"], "expected davis or sim"),
        (["--source", "sim", "--seconds", "-1"], "expected a positive duration"),
    ],
)
def test_bad_options_say_what_is_expected(tmp_path, args, message):
    proc = run_cli("record", str(tmp_path / "x.aedat4"), *args, columns=200)
    assert proc.returncode == 2 and message in proc.stderr, proc.stderr
    assert not (tmp_path / "x.aedat4").exists()


def test_an_existing_file_is_kept_unless_forced(tmp_path):
    out = tmp_path / "keep.aedat4"
    out.write_bytes(b"precious")
    proc = run_cli("record", str(out), "--source", "sim", "--seconds", "0.2", "--fast", columns=200)
    assert proc.returncode == 2 and "--force" in proc.stderr
    assert out.read_bytes() == b"precious"
    proc = run_cli("record", str(out), "--source", "sim", "--seconds", "0.2", "--fast", "--force", columns=200)
    assert proc.returncode == 0, proc.stderr
    assert read_info(out).n_frames == 5
