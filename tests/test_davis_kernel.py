"""The live camera path against an emulated DAVIS-346 on USB, in a REAL Linux kernel.

tests/kernel/davis_gadget.py, run inside the test kernel (tests/kernel/vm.py, one boot per
session), is a USB device on dummy_hcd that speaks the DAVIS FX3 protocol and replays a simulated
gel recording at rest; dv-processing's own camera driver opens it through libusb. These tests
assert on the guest's checks_davis.check_emulated_davis (one gadget, every part against it).
"""

from __future__ import annotations

import numpy as np
import pytest
from conftest import passed

pytestmark = pytest.mark.kernel

AT_REST = "checks_davis.check_emulated_davis"


def part(guest: dict, name: str) -> dict:
    entry = passed(guest, AT_REST)[name]
    assert entry["ok"], f"{name}: {entry.get('error')}\n{entry.get('traceback', '')}"
    return entry["details"]


def test_the_emulated_camera_appears_on_usb(guest):
    """How long it takes is recorded, not asserted: it is mostly Python and dv-processing starting
    under emulation, 19 s on an idle host and up to 67 s on a loaded one (tests/kernel/README.md)."""
    ready = passed(guest, AT_REST)["ready"]
    assert ready["line"].startswith("READY bus "), ready


def test_its_descriptors_are_the_davis_fx3_ones_libcaer_expects(guest):
    details = part(guest, "descriptors")
    assert details["attrs"]["idVendor"] == "152a" and details["attrs"]["idProduct"] == "841a"
    assert details["endpoints"]["ep_82"] == "Bulk" and details["endpoints"]["ep_81"] == "Interrupt"


def test_devices_lists_it_as_ready_and_dv_processing_lists_a_davis(guest):
    details = part(guest, "devices")
    assert details["message"].startswith("ready: DAVIS-346 at bus ")
    assert details["dv"]["model"] == "DAVIS"


def test_record_writes_the_replayed_events_and_frames_exactly(guest):
    details = part(guest, "record")
    assert details["found_in_source"] == details["recorded_events"] > 100
    assert details["frame_shapes"] == [[260, 346]] and set(details["frame_max_diff"]) == {0}


def test_calibrate_on_the_camera_measures_the_replayed_rest_frame(guest):
    """``calibrate --source davis`` in the guest gives what calibrate gives here on the frame the
    gadget replays (the recording's first, once per pass), taken three times as three rest frames
    (the values are rounded to 0.01 px and 0.0001 px/mm: one step of rounding apart at most)."""
    from kernel.vm import ensure_replay_recording

    from neurotouch_hid.calibration import calibrate
    from neurotouch_hid.sources import Frame
    from neurotouch_hid.sources.recording import RecordingReader

    details = part(guest, "calibrate")
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


def test_sigterm_unplugs_the_emulated_camera(guest):
    entry = passed(guest, AT_REST)["sigterm"]
    assert entry["ok"], entry


def test_run_on_the_camera_gives_estimates_from_the_hosts_compiled_pipeline(guest):
    """``run --source davis --output jsonl``: states (the gel at rest: no gesture) from windows of
    camera data; numba loaded the pipeline from the cache compiled on the host (vm.py)."""
    details = part(guest, "run_jsonl")
    assert details["states"] > 0 and details["windows"] > 0, details
    assert details["gestures"] == ["none"], details
    assert details["cache_loads"] > 0, details


@pytest.mark.xfail(
    reason="flaky under emulation, open (failed in 3 of 4 guest runs on a loaded host): the emulated "
    "camera's cued push did not reach the pad in 120 s; in two runs every event of the push was dropped "
    "as lag (about 108k of 133k events), in one only 24k events arrived in 132 s of camera time (1.1k "
    "dropped): the gadget, dv-processing and the pipeline share one emulated CPU. The same replay through "
    "`run` and `track` on the host gives the push; the unplug itself is asserted on the host (test_davis.py)",
    strict=False,
)
def test_run_unplugged_mid_push_centres_the_pad_and_carries_on_when_the_camera_is_back(guest):
    """``run --source davis`` on the gamepad: the camera's push (the gadget's cue) moved the left
    stick; unplugged mid-push, the driver reported the loss with the pad neutral and wrote nothing
    while the camera was away; plugged in again, it said the camera is back and kept running until
    SIGTERM (exit 0)."""
    details = part(guest, "run_gamepad_unplug")
    assert details["pushed_axes"].get("ABS_X", 0) <= -16_000, details
    assert "gamepad centred" in details["lost"] and "is back" in details["back"], details
    assert details["exit_code"] == 0
