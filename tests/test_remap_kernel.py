"""Keyboard and mouse outputs, layers, ``profile use``, SIGTERM and rumble in a REAL Linux kernel
(Debian's, booted under qemu once per session by tests/kernel/vm.py); the guest checks are
tests/kernel/checks_runtime_remap.py. Skips, with the reason, only where qemu cannot be installed at all."""

from __future__ import annotations

import pytest
from conftest import passed

pytestmark = pytest.mark.kernel


def test_run_with_the_mouse_profile_moves_the_pointer_clicks_and_scrolls(guest):
    details = passed(guest, "checks_runtime_remap.check_mouse_profile_moves_the_pointer")
    assert details["rel"]["REL_X"] > 0 and details["rel"]["REL_Y"] < 0
    assert details["ID_INPUT_MOUSE"] == "1"


def test_run_with_the_switch_access_profile_presses_keys_and_releases_them(guest):
    details = passed(guest, "checks_runtime_remap.check_switch_access_presses_and_releases_keys")
    assert ["KEY_SPACE", 1] in details["keys"] and details["ID_INPUT_KEYBOARD"] == "1"


def test_a_layer_switch_and_profile_use_mid_run_then_sigterm_leave_nothing_pressed_on_any_device(guest):
    details = passed(guest, "checks_runtime_remap.check_layer_switch_profile_use_and_sigterm_leave_nothing_pressed")
    assert details["returned"] and details["profile_use"].startswith("switched to profile")


def test_profile_use_of_a_profile_with_new_keys_makes_the_keyboard_again(guest):
    details = passed(guest, "checks_runtime_remap.check_profile_use_of_new_keys_makes_the_keyboard_again")
    assert details["returned"] and details["profile_use"].startswith("switched to profile")


def test_sdl_sees_a_gamecontroller_with_rumble(guest):
    details = passed(guest, "checks_runtime_remap.check_sdl_sees_a_gamecontroller_with_rumble")
    assert details["is_controller"] and details["rumble"]
