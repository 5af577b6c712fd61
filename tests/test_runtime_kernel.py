"""``neurotouch-hid run --output gamepad`` in a REAL Linux kernel (Debian's, booted under qemu once per
session by tests/kernel/vm.py); the guest checks are tests/kernel/checks_runtime.py. Skips, with
the reason, only where qemu cannot be installed at all."""

from __future__ import annotations

import pytest

from conftest import passed

pytestmark = pytest.mark.kernel


def test_run_drives_the_gamepad_exactly_as_the_profile_says(guest):
    details = passed(guest, "checks_runtime.check_run_gamepad_matches_the_profile")
    assert details["ID_INPUT_JOYSTICK"] == "1"
    assert details["states"] > 20 and details["with_button"] > 0


def test_sigterm_ends_run_with_exit_0_and_nothing_pressed(guest):
    details = passed(guest, "checks_runtime.check_run_sigterm_releases_everything")
    assert details["exit_code"] == 0 and details["ID_INPUT_JOYSTICK"] == "1"


def test_a_bad_profile_starts_no_device(guest):
    details = passed(guest, "checks_runtime.check_bad_profile_starts_no_device")
    assert details["exit_code"] == 2 and "broken.yaml" in details["error"]
