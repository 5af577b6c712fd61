"""A game starting and exiting switches the running driver's profile mid-push, in a REAL Linux
kernel (Debian's, booted under qemu once per session by tests/kernel/vm.py): every key, button and
axis the old profile held is released before the new one presses anything, both ways, and
nothing is held after SIGTERM. The guest check is tests/kernel/checks_runtime_remap_games.py.
Skips, with the reason, only where qemu cannot be installed at all."""

from __future__ import annotations

import pytest
from conftest import passed

pytestmark = pytest.mark.kernel


def test_a_game_switches_the_profile_mid_push_and_back_and_leaves_nothing_held(guest):
    details = passed(guest, "checks_runtime_remap_games.check_a_game_switches_profiles_leaving_nothing_held")
    assert ["KEY_ENTER", 0] == details["keyboard"][1] and ["KEY_LEFTCTRL", 1] == details["keyboard"][2]
    assert details["during_game"]["pad"] and details["during_game"]["mouse"]
    assert len(details["said"]) == 2
