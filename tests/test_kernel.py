"""The virtual gamepad, udev rules and doctor in a REAL Linux kernel (Debian's, booted under qemu).

This machine's kernel has no uinput, so tests/kernel/vm.py boots Debian's generic kernel once per
session (virtme-ng, software emulation) and tests/kernel/guest.py runs every guest check
(tests/kernel/checks_*.py) in that boot; these tests assert on its JSON result. The first run
downloads the kernel (~70 MB) into ~/.cache/neurotouch-hid/kernel; it skips, with the reason,
only where qemu cannot be installed at all.
"""

from __future__ import annotations

import pytest
from conftest import passed

pytestmark = pytest.mark.kernel


def test_guest_loads_uinput_and_our_rules(guest):
    setup = passed(guest, "setup")
    assert setup["modprobe"]["uinput"], setup
    assert "60-neurotouch.rules" in setup["rules"], setup


def test_gamepad_appears_with_xbox360_identity_and_only_gamepad_capabilities(guest):
    details = passed(guest, "checks_gamepad.check_device_appears")
    assert details["info"] == "0003:045e:028e:0114"


def test_udev_classes_the_pad_as_joystick_and_tags_it(guest):
    details = passed(guest, "checks_gamepad.check_udev_classifies_joystick")
    assert details["ID_INPUT_JOYSTICK"] == "1" and details["ID_NEUROTOUCH_VIRTUAL"] == "1"


def test_evdev_reads_back_exactly_the_changed_axes_and_buttons(guest):
    passed(guest, "checks_gamepad.check_evdev_roundtrip")


def test_close_releases_every_button_before_the_device_goes(guest):
    passed(guest, "checks_gamepad.check_close_releases")


def test_sigterm_to_a_process_holding_a_button_releases_it(guest):
    details = passed(guest, "checks_gamepad.check_sigterm_releases")
    assert details["held_before_sigterm"], details


def test_sdl_sees_a_gamecontroller_and_reads_what_was_written(guest):
    details = passed(guest, "checks_gamepad.check_sdl_gamecontroller")
    assert details["is_controller"]
    assert details["pressed"]["a"] and details["pressed"]["leftx"] > 30000


def test_camera_plug_in_starts_the_service_and_doctor_sees_it(guest):
    details = passed(guest, "checks_packaging.check_camera_plug_and_play")
    assert "neurotouch-hid.service" in details["SYSTEMD_USER_WANTS"]


def devices_part(guest: dict, part: str) -> dict:
    """One part of the guest's checks_devices.check_devices (the camera is plugged in once for all)."""
    entry = passed(guest, "checks_devices.check_devices")[part]
    assert entry["ok"], f"{part}: {entry.get('error')}\n{entry.get('traceback', '')}"
    return entry["details"]


def test_dv_processing_refusing_to_open_is_explained_in_one_line(guest):
    details = devices_part(guest, "dv_open")
    assert "EXPLAIN" in details["dv_open"] or "OPENED" in details["dv_open"]


def test_devices_says_which_program_holds_a_busy_camera(guest):
    details = devices_part(guest, "busy")
    assert details["camera"]["status"] == "busy"


def test_devices_as_unprivileged_user_says_not_accessible_with_the_udev_rule_fix(guest):
    details = devices_part(guest, "unprivileged")
    assert details["camera"]["status"] == "no-access" and "udev rule" in details["camera"]["fix"]
