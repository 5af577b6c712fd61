"""What makes ``track`` fast (docs/performance.md, "track"): no
progress bar and no pass over the file for its total when nothing shows it, the start-up's
objects kept out of the garbage collector's passes, the library noise filter made only when
used, the resting detector stopping once its verdict is certain. Behaviour only: the same
predictions, progress figures and verdicts; no timing."""

from __future__ import annotations

import gc
import io
import subprocess
import sys

import pytest
from helpers import run_cli
from rich.console import Console

from neurotouch_hid.cli.common import long_lived_start_up
from neurotouch_hid.core.sensor import find_sensor_file
from neurotouch_hid.pipeline.pipeline import GesturePipeline
from neurotouch_hid.pipeline.resting import RestingDetector
from neurotouch_hid.pipeline.track import recording_progress, track_recording
from neurotouch_hid.sources import Frame
from neurotouch_hid.sources.recording import RecordingReader


@pytest.fixture(scope="module")
def tracked(sim_push_recording, tmp_path_factory):
    """``track_recording`` in this process with a progress callback: (summary, predictions
    bytes, every (done_us, total_us) reported)."""
    out = tmp_path_factory.mktemp("track") / "p.jsonl"
    calls: list[tuple[int, int]] = []
    summary = track_recording(
        sim_push_recording, out, find_sensor_file(sim_push_recording), on_progress=lambda d, t: calls.append((d, t))
    )
    return summary, out.read_bytes(), calls


def test_progress_totals_are_the_recording_s_length_from_the_start(sim_push_recording, tracked):
    summary, _, calls = tracked
    with RecordingReader(sim_push_recording) as reader:
        length = reader.info.duration_us
    assert len(calls) > 10
    assert all(total == length for _, total in calls)  # known before the first window
    assert [done for done, _ in calls] == sorted(done for done, _ in calls)
    assert calls[-1][0] == summary.duration_us <= length


def test_a_terminal_gets_a_bar_that_reports_to_the_end(sim_push_recording, tmp_path):
    screen = io.StringIO()
    console = Console(file=screen, force_terminal=True, width=100)
    with recording_progress(console, "tracking") as report:
        assert report is not None
        track_recording(
            sim_push_recording, tmp_path / "p.jsonl", find_sensor_file(sim_push_recording), on_progress=report
        )
    assert "tracking" in screen.getvalue()


def test_without_a_terminal_no_bar_and_no_pass_for_its_total(sim_push_recording, tracked, tmp_path, monkeypatch):
    screen = io.StringIO()
    with recording_progress(Console(file=screen), "tracking") as report:
        assert report is None
    assert screen.getvalue() == ""

    def no_second_pass(self):
        raise AssertionError("the progress total was read without a progress bar")

    monkeypatch.setattr(RecordingReader, "info", property(no_second_pass))
    out = tmp_path / "p.jsonl"
    summary = track_recording(sim_push_recording, out, find_sensor_file(sim_push_recording), on_progress=report)
    assert out.read_bytes() == tracked[1]  # the same predictions
    assert (summary.windows, summary.events, summary.frames) == (
        tracked[0].windows,
        tracked[0].events,
        tracked[0].frames,
    )


def test_the_track_command_writes_the_same_predictions_and_nothing_on_a_piped_stderr(
    sim_push_recording, tracked, tmp_path
):
    out = tmp_path / "p.jsonl"
    done = run_cli("track", str(sim_push_recording), "--out", str(out))
    assert done.returncode == 0, done.stderr
    assert done.stderr == ""  # no bar drawn into a pipe
    assert out.read_bytes() == tracked[1]
    assert f"{tracked[0].windows} windows" in done.stdout


def test_start_up_objects_are_frozen_and_the_collector_is_back_on():
    before = gc.get_freeze_count()
    try:
        with long_lived_start_up():
            assert not gc.isenabled()
            made = [[i] for i in range(1000)]  # long-lived containers, e.g. a module's tables
        assert gc.isenabled()
        assert gc.get_freeze_count() >= before + len(made)
        walked = {id(x) for x in gc.get_objects()}  # the collector's generations
        assert not any(id(x) in walked for x in made)
    finally:
        gc.unfreeze()


def test_start_up_leaves_a_disabled_collector_disabled_and_recovers_from_an_error():
    try:
        gc.disable()
        with long_lived_start_up():
            pass
        assert not gc.isenabled()
        gc.enable()
        with pytest.raises(RuntimeError), long_lived_start_up():
            raise RuntimeError("a bad sensor.yaml")
        assert gc.isenabled()
    finally:
        gc.enable()
        gc.unfreeze()


def test_the_numba_noise_filter_never_loads_dv_processing():
    code = (
        "import sys, numpy as np\n"
        "from neurotouch_hid.pipeline.noise import EventNoiseFilter\n"
        "from neurotouch_hid.sources import EVENT_DTYPE\n"
        "ev = np.zeros(3, EVENT_DTYPE); ev['timestamp'] = [10**6, 10**6 + 10, 10**6 + 20]\n"
        "ev['x'] = [5, 6, 5]; ev['y'] = 5\n"
        "f = EventNoiseFilter('BackgroundActivityNoiseFilter', 346, 260)\n"
        "print(len(f(ev)), 'dv_processing' in sys.modules)\n"
        "f.reset(); print(len(f(ev)), 'dv_processing' in sys.modules)\n"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    assert done.stdout.split() == ["2", "False", "2", "False"]


# --- the resting detector's early verdict --------------------------------------------------------
def _gel_frames(recording, n: int = 400):
    """The recording's first ``n`` APS frames (rest, presses and releases) and a pixel-set
    detector on its reference frame (the per-marker distance at 0.4 px^2): ``verdict_only``
    shortens the pixel-set distance only."""
    pipeline = GesturePipeline(find_sensor_file(recording))
    frames, detector = [], None
    with RecordingReader(recording) as reader:
        for item in reader.stream(batch_us=10_000):
            if isinstance(item, Frame):
                frames.append(item)
                if detector is None:
                    pipeline.process(item)
                    if pipeline.resting_detector is not None:
                        detector = RestingDetector(item.image, pipeline.sensor, 0.4, per_marker=True, centroids=False)
            if len(frames) >= n:
                break
    assert detector is not None
    return detector, frames


def test_verdict_only_gives_every_verdict_and_the_exact_distance_at_rest(sim_push_recording):
    detector, frames = _gel_frames(sim_push_recording)
    full = [detector.update(f) for f in frames]
    quick = [detector.update(f, verdict_only=True) for f in frames]
    assert [q.resting for q in quick] == [f.resting for f in full]
    assert sum(f.resting for f in full) > 10 and sum(not f.resting for f in full) > 10  # both kinds seen
    early = [q for q, f in zip(quick, full) if q.distance != f.distance]
    assert early  # some frames were decided by the first term alone
    for q, f in zip(quick, full):
        if f.resting:  # a resting verdict always needs, and reports, the whole distance
            assert q.distance == f.distance
        else:
            assert detector.threshold < q.distance <= f.distance
