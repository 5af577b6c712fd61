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
