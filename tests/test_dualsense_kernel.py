"""``neurotouch-hid run --output hid --protocol dualsense`` in a REAL Linux kernel (Debian's, booted
under qemu by tests/kernel/vm.py, in the same boot as the other output checks): the DualSense on
UHID read by hid-playstation, hidraw, evdev and SDL; the guest check is
tests/kernel/checks_dualsense.py. Skips, with the reason, only where qemu cannot be installed at all."""

from __future__ import annotations

import pytest
from conftest import passed

from neurotouch_hid.targets.identity import identity_for
from neurotouch_hid.targets.reports.dualsense import DESCRIPTOR, DUALSENSE

pytestmark = pytest.mark.kernel


@pytest.fixture(scope="module")
def details(guest):
    return passed(guest, "checks_dualsense.check_run_output_hid_dualsense")


@pytest.fixture(scope="module")
def killed(guest):
    return passed(guest, "checks_dualsense.check_killed_dualsense_leaves_the_host_neutral")


def test_hid_playstation_binds_without_complaint_and_makes_pad_touchpad_and_motion_sensors(details):
    assert details["modprobe"]["uhid"]
    assert details["driver"] == "playstation"
    assert details["hid_device"].startswith("0003:054C:0CE6.")
    assert not [line for line in details["kernel_log_new"] if "Failed to retrieve" in line or "Duplicate" in line]
    assert len(details["evdev"]) == 3
    assert {name.removeprefix("DualSense Wireless Controller").strip() for name in details["evdev"]} == {
        "",
        "Touchpad",
        "Motion Sensors",
    }
    assert details["descriptor_bytes"] == len(DESCRIPTOR)


def test_feature_reports_read_back_through_hidraw_and_uniq_is_the_mac_across_a_restart(details):
    identity = identity_for(None)
    features = {int(k, 16): bytes.fromhex(v) for k, v in details["features"].items()}
    assert features == {rid: DUALSENSE.feature(rid, identity) for rid in (0x05, 0x09, 0x20)}
    assert {rid: len(data) for rid, data in features.items()} == {0x05: 41, 0x09: 20, 0x20: 64}
    assert details["uniq"] == details["uniq_again"] == identity.uniq


def test_the_touchpad_follows_the_fingers_and_every_lift_ends_its_slot(details):
    ids0, ids1 = details["ids"]
    assert ids0[1] == ids1[1] == -1 and ids0[-1] == ids1[-1] == -1
    assert details["clicked"]


def test_sigterm_leaves_the_last_report_neutral_every_touch_point_inactive(details):
    last = bytes.fromhex(details["last_report"])
    assert last == DUALSENSE.neutral() and last[33] & 0x80 and last[37] & 0x80


def test_sdl_opens_it_as_a_game_controller_and_its_rumble_comes_back_as_feedback(details):
    assert details["sdl_opened"]["opened"]
    assert any(guid[16:20] == "e60c" for guid in details["sdl_opened"]["guids"])  # 0ce6, little-endian
    assert details["sdl_rumble"]["rumble"] is True
    assert details["rumble_said"].startswith("rumble (the gel has no motor): strong")


def test_sdls_rumble_on_the_dualsense_reaches_the_merged_pad(details):
    """The profile merges a helper's pad (``copilot:``): SDL's rumble, Feedback from the UHID
    device, is uploaded to the helper's pad as FF_RUMBLE and played."""
    from evdev import ecodes

    rumble = details["merged_rumble"]
    assert rumble["plays"] and rumble["plays"][0][1] > 0
    assert any(kind == ecodes.FF_RUMBLE and max(strong, weak) > 0 for kind, strong, weak in rumble["uploads"])


def test_sigkill_leaves_every_touch_point_inactive_and_the_pad_at_rest_before_the_device_goes(killed):
    """SIGKILL with two touches active, the stick pushed and the touchpad clicked: the guard's
    neutral report is what hidraw and evdev read last (tracking ids -1, nothing pressed, the stick
    at 128), then the device goes."""
    assert min(killed["at_kill"]["touch_ids"]) >= 0 and killed["at_kill"]["pad_axes"]["0"] != 128
    assert killed["touchpad_last"] == {"ids": [-1, -1], "keys": []}
    assert killed["pad_last"]["axes"]["0"] == 128 and killed["pad_last"]["keys"] == []
    assert killed["hidraw_after"][-1] == DUALSENSE.neutral().hex() and killed["gone"]
