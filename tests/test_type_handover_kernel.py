"""A gesture whose type changes mid-gesture, read back from the uinput pad in a REAL Linux kernel
(Debian's, booted under qemu once per session by tests/kernel/vm.py); the guest checks are
tests/kernel/checks_type_handover.py. Skips, with the reason, only where qemu cannot be installed at all."""

from __future__ import annotations

import pytest
from conftest import passed

pytestmark = pytest.mark.kernel


def test_the_stick_and_the_trigger_are_never_both_held_when_push_turns_pinch(guest):
    details = passed(guest, "checks_type_handover.check_default_stick_and_trigger_never_both_held")
    assert details["both_held"] == 0 and details["max_trigger"] > 0 and details["max_stick"] > 0


def test_a_toggle_flips_once_when_the_twist_is_read_as_pinch_for_a_moment(guest):
    details = passed(guest, "checks_type_handover.check_accessibility_toggle_flips_once_per_gesture")
    south = [k for k in details["keys"] if k[0] == "BTN_SOUTH"]
    assert south == [["BTN_SOUTH", 1], ["BTN_SOUTH", 0]]
