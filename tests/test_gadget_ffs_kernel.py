"""The gadget's FunctionFS functions answering their host's control requests, in a REAL Linux
kernel (Debian's, booted under qemu by tests/kernel/vm.py) on dummy_hcd; the guest checks are
tests/kernel/checks_gadget_ffs.py. Skips, with the reason, only where qemu cannot be installed."""

from __future__ import annotations

import pytest
from conftest import passed

pytestmark = pytest.mark.kernel


def test_a_hid_interface_on_functionfs_answers_get_feature_and_hears_output_reports(guest):
    """What the kernel's f_hid of 6.1 cannot do (it answers GET_REPORT with zeros)."""
    details = passed(guest, "checks_gadget_ffs.check_usb_hid_interface_answers_feature_reports")
    assert details["driver"] == "hid-generic"
    assert details["feature"] == "05" + bytes(range(40)).hex()
    assert details["unknown_feature"].startswith("refused")
    assert details["feedback"][0][:2] == ["rumble", 1.0]


def test_the_xbox_360_pad_answers_the_vendor_requests_of_a_wired_pad(guest):
    details = passed(guest, "checks_gadget_ffs.check_usb_xinput_answers_the_vendor_requests")
    assert details["answers"] == {"0100": "00143ff7ffff00000000c0ffc0ff000000000000", "0000": "0008000000000000"}
    assert details["interfaces"] == 1


def test_a_dualsense_over_usb_is_bound_by_hid_playstation_and_its_touchpad_follows_the_finger(guest):
    """run --output usb --protocol dualsense: hid-playstation binds on the host side (it reads the
    three feature reports before it binds, which the kernel's f_hid of 6.1 answers with zeros),
    the Touchpad's slot 0 follows a stroke to the right, the host's rumble reaches a merged pad,
    and SIGTERM leaves the touch inactive."""
    from neurotouch_hid.targets.reports.dualsense import DUALSENSE

    details = passed(guest, "checks_gadget_ffs.check_usb_dualsense")
    assert details["driver"] == "playstation"
    assert details["features"] == {"0x05": 41, "0x09": 20, "0x20": 64}
    moved = details["slot0_x"]
    assert len(moved) >= 3 and moved == sorted(moved) and moved[-1] > moved[0]
    assert details["ids"][-1] == -1 and details["last_report"] == DUALSENSE.neutral().hex()
    assert details["merged_rumble"]["plays"]  # the host's output report 0x02 reached the merged pad


def test_a_killed_dualsense_gadget_hands_the_host_the_neutral_report_before_it_goes(guest):
    """SIGKILL mid-press: the guard's copy of the IN endpoint keeps the function bound while it
    sends the neutral report (tracking ids -1, the stick at 128); then the gadget is unbound."""
    from neurotouch_hid.targets.reports.dualsense import DUALSENSE

    killed = passed(guest, "checks_gadget_ffs.check_usb_dualsense_killed")
    assert killed["touchpad_last"] == {"ids": [-1, -1], "keys": []} and killed["pad_last"]["axes"]["0"] == 128
    assert killed["hidraw_after"][-1] == DUALSENSE.neutral().hex() and killed["gone"]
