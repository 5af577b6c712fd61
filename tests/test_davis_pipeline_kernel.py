"""The gesture pipeline on the live camera path, an emulated DAVIS-346 on USB, in a REAL Linux
kernel: the slow tier (``pytest -m slow``).

The guest check checks_davis_pipeline.check_pipeline_on_the_emulated_davis (tests/kernel) starts
the emulated camera of test_davis_kernel.py and runs ``calibrate``, ``run --output jsonl`` and
``run`` on the gamepad against it, with the pipeline's numba code compiled on the host. Under
software emulation that takes about 5 minutes on an idle host and up to 17 on a loaded one, so it
has a guest of its own (tests/kernel/vm.py ``slow_guest_results``), booted only when these tests
are selected.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from conftest import passed_part
from kernel.vm import KernelUnavailable, slow_guest_results

pytestmark = [pytest.mark.kernel, pytest.mark.slow]

ON_THE_CAMERA = "checks_davis_pipeline.check_pipeline_on_the_emulated_davis"


@pytest.fixture(scope="module")
def pipeline_guest() -> dict:
    """The slow tier's guest results (one boot per session); skips only where qemu cannot be
    installed at all."""
    try:
        return slow_guest_results()
    except KernelUnavailable as exc:
        pytest.skip(reason=f"cannot boot a real kernel here: {exc}")


def test_calibrate_on_the_camera_measures_the_replayed_rest_frame(pipeline_guest):
    """``calibrate --source davis`` in the guest gives what calibrate gives here on the frame the
    gadget replays (the recording's first, once per pass), taken three times as three rest frames
    (the values are rounded to 0.01 px and 0.0001 px/mm: one step of rounding apart at most)."""
    from kernel.vm import ensure_replay_recording

    from neurotouch_hid.calibration.measure import calibrate
    from neurotouch_hid.sources import Frame
    from neurotouch_hid.sources.recording import RecordingReader

    details = passed_part(pipeline_guest, ON_THE_CAMERA, "calibrate")
    sensor = details["sensor"]
    with RecordingReader(ensure_replay_recording()) as reader:
        _, frames = reader.read_all()
    sent = [Frame(frames[0].t_us + k * details["pass_us"], frames[0].image) for k in range(3)]
    expected = calibrate(sent, n_frames=3).sensor
    assert sensor["px_per_mm"] == pytest.approx(expected.px_per_mm, abs=1.1e-4)
    assert sensor["gel_center_px"] == pytest.approx(list(expected.gel_center_px), abs=0.011)
    assert sensor["gel_radius_px"] == pytest.approx(expected.gel_radius_px, abs=0.011)
    markers = expected.extra["rest_markers_px"]
    assert len(markers) > 100
    np.testing.assert_allclose(sensor["rest_markers_px"], markers, rtol=0, atol=0.011)


def test_run_on_the_camera_gives_estimates_from_the_hosts_compiled_pipeline(pipeline_guest):
    """``run --source davis --output jsonl``: states (the gel at rest: no gesture) from windows of
    camera data; numba loaded the pipeline from the cache compiled on the host (vm.py)."""
    details = passed_part(pipeline_guest, ON_THE_CAMERA, "run_jsonl")
    assert details["states"] > 0 and details["windows"] > 0, details
    assert details["gestures"] == ["none"], details
    assert details["cache_loads"] > 0, details


@pytest.mark.xfail(
    reason="not met, open: the floor within the decided bounds (docs/performance.md, 'At rest'): with the "
    "early packet delay at 10 ms at rest and a resting poll waiting for the camera's next transfer, 1.91x, "
    "2.36x and 2.40x (185, 244, 247 against 97, 103, 103 context switches a second): the source thread 92, 97, "
    "one a window as the recording's 94, 100, and dv-processing's reader thread 85, 144, 142, about one a USB "
    "transfer completed "
    "(the emulated camera's 34, 69 short transfers a second and an APS frame's readout in 8 KiB transfers), "
    "0.9-1.4x the recording's run by itself; "
    "strict: the day it passes, this mark must go",
    strict=True,
)
def test_the_live_camera_rests_like_the_same_stream_from_a_recording(pipeline_guest):
    """With the camera streaming the gel at rest, ``run --source davis`` makes at most 1.5 times the
    context switches per second (its threads summed, steady state) of ``run`` on the same stream as
    a recording, in the same guest (docs/performance.md, "At rest")."""
    details = passed_part(pipeline_guest, ON_THE_CAMERA, "at_rest")
    davis, recording = details["davis"], details["recording"]
    assert 0 < davis["switches_per_s"] <= 1.5 * recording["switches_per_s"], details
    assert davis["span_s"] >= 10 and recording["span_s"] >= 10, details


def _host_full_push(tmp_path: Path) -> dict[str, int]:
    """The left stick's axes where ``run`` on this machine (the default profile, ``--fast``) moves
    it farthest from the centre on the replay recording's push (its first 3 s)."""
    from kernel.vm import ensure_replay_recording

    from neurotouch_hid.engine.driver import DriverOptions, run_driver

    out = tmp_path / "states.jsonl"
    run_driver(str(ensure_replay_recording()), "default", "jsonl", DriverOptions(seconds=3.0, fast=True, out=out))
    sticks = [{axis: state["axes"][axis] for axis in ("ABS_X", "ABS_Y")} for state in map(json.loads, out.open())]
    return max(sticks, key=lambda stick: max(map(abs, stick.values())))


def test_run_unplugged_mid_push_centres_the_pad_and_carries_on_when_the_camera_is_back(pipeline_guest, tmp_path):
    """``run --source davis`` on the gamepad: the camera's push (the gadget's cue, given once the
    run's stream had started) moved the left stick at least halfway, the way ``run`` on this
    machine moves it on the same recording; unplugged mid-push, the driver reported the loss with
    the pad neutral and wrote nothing while the camera was away; plugged in again, it said the
    camera is back and kept running until SIGTERM (exit 0)."""
    details = passed_part(pipeline_guest, ON_THE_CAMERA, "run_gamepad_unplug")
    host = _host_full_push(tmp_path)
    axis = max(host, key=lambda name: abs(host[name]))
    assert abs(host[axis]) >= 16_000, f"the host's run of the replay's push: {host}"
    pushed = details["pushed_axes"].get(axis, 0)
    assert abs(pushed) >= 16_000 and (pushed > 0) == (host[axis] > 0), (host, details)
    assert "gamepad centred" in details["lost"] and "is back" in details["back"], details
    assert details["exit_code"] == 0
