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


def test_sdl_reads_the_run_as_a_gamecontroller_exactly_as_the_profile_says(guest):
    details = passed(guest, "checks_runtime.check_sdl_reads_run_like_the_profile")
    assert details["ID_INPUT_JOYSTICK"] == "1"
    assert details["evdev_name"] == details["profile_device_name"]
    assert details["guid"][8:12] == "5e04" and details["guid"][16:20] == "8e02"  # 045e:028e, little-endian
    assert details["mapping"]["a"] and details["mapping"]["lefttrigger"]  # SDL has a GameController mapping
    assert details["evdev_states"] == details["expected_states"] > 20
    assert details["sdl_moving_states"] > 1 and details["sdl_saw_unplug"]
    held = details["sdl_held_raw"]
    assert held["a"] and held["start"] and not held["b"]
    assert held["leftx"] == details["held_evdev"]["ABS_X"] and held["lefty"] == details["held_evdev"]["ABS_Y"]
    assert round(held["triggerleft"] * 255 / 32767) == details["held_evdev"]["ABS_Z"] > 0


def test_sigterm_ends_run_with_exit_0_and_nothing_pressed(guest):
    # the SDL check's run is a process of its own, ended by SIGTERM in a push that holds A
    details = passed(guest, "checks_runtime.check_sdl_reads_run_like_the_profile")
    assert details["held_evdev"]["BTN_SOUTH"] and details["held_evdev"]["ABS_X"] > 0
    assert details["exit_code"] == 0 and details["evdev_last_neutral"]
    assert details["device_outlived_run"] == []


def test_a_bad_profile_starts_no_device(guest):
    details = passed(guest, "checks_runtime.check_bad_profile_starts_no_device")
    assert details["exit_code"] == 2 and "broken.yaml" in details["error"]
