"""The live camera path against an emulated DAVIS-346 on USB, in a REAL Linux kernel.

tests/kernel/davis_gadget.py, run inside the test kernel (tests/kernel/vm.py, one boot per
session), is a USB device on dummy_hcd that speaks the DAVIS FX3 protocol and replays a simulated
gel recording at rest; dv-processing's own camera driver opens it through libusb. These tests
assert on the guest's checks_davis.check_emulated_davis (one gadget, every part of its USB path
against it); the gesture pipeline on the same camera is the slow tier's
(test_davis_pipeline_kernel.py).
"""

from __future__ import annotations

import pytest
from conftest import passed, passed_part

pytestmark = pytest.mark.kernel

AT_REST = "checks_davis.check_emulated_davis"


def test_the_emulated_camera_appears_on_usb(guest):
    """How long it takes is recorded, not asserted: it is mostly Python and dv-processing starting
    under emulation, 19 s on an idle host and up to 67 s on a loaded one (tests/kernel/README.md)."""
    ready = passed(guest, AT_REST)["ready"]
    assert ready["line"].startswith("READY bus "), ready


def test_its_descriptors_are_the_davis_fx3_ones_libcaer_expects(guest):
    details = passed_part(guest, AT_REST, "descriptors")
    assert details["attrs"]["idVendor"] == "152a" and details["attrs"]["idProduct"] == "841a"
    assert details["endpoints"]["ep_82"] == "Bulk" and details["endpoints"]["ep_81"] == "Interrupt"


def test_devices_lists_it_as_ready_and_dv_processing_lists_a_davis(guest):
    details = passed_part(guest, AT_REST, "devices")
    assert details["message"].startswith("ready: DAVIS-346 at bus ")
    assert details["dv"]["model"] == "DAVIS"


def test_record_writes_the_replayed_events_and_frames_exactly(guest):
    details = passed_part(guest, AT_REST, "record")
    assert details["found_in_source"] == details["recorded_events"] > 100
    assert details["recorded_events"] == details["sent_outside_holes"], details["holes"]
    assert details["frame_shapes"] == [[260, 346]] and set(details["frame_max_diff"]) == {0}


def test_sigterm_unplugs_the_emulated_camera(guest):
    entry = passed(guest, AT_REST)["sigterm"]
    assert entry["ok"], entry


#: The longest span of camera time a batch may hold outside rest (ms): a 1 ms data commit interval
#: gives at most 1 ms (p90 0.94 ms on the emulated camera at rest, 0.79 ms pushed); the 10 ms one
#: dv-processing opens with gave 9.9 ms at p90 (docs/performance.md, "The live camera's events
#: reach the source 1 ms after their transfer"). The margin is the emulation's.
TOUCHED_SPAN_P90_MS = 2.0


def test_the_source_sets_a_1_ms_data_commit_interval_and_a_window_at_rest(guest):
    """Through the product's DavisSource on dv-processing's own driver: the commit interval the
    driver reports is 1 ms once the source opened the camera, a resting window's 10 ms (with the
    early packet delay) while its consumer says the gel rests, 1 ms again after. A batch's first
    event waits its span longer than its last: outside rest the span stays under a commit of
    1 ms and a margin, at rest it is about a window. The ages themselves (emulated, a loaded guest:
    tens of ms) are reported in the details, not bounded."""
    details = passed_part(guest, AT_REST, "event_age")
    assert details["opened_time_interval_us"] == 1000, details
    assert details["at_rest"]["time_interval_us"] == details["at_rest"]["early_packet_delay_us"] == 10_000, details
    assert details["after_rest_time_interval_us"] == 1000, details
    touched, resting = details["touched"], details["at_rest"]
    assert touched["batches"] > 100 and touched["span_p90_ms"] <= TOUCHED_SPAN_P90_MS, details
    assert resting["batches"] > 10 and resting["span_p50_ms"] >= 5.0, details
