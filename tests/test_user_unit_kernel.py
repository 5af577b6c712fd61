"""The packaged user unit as a user runs it, in a REAL Linux kernel (Debian's, under qemu,
tests/kernel/vm.py): installed by ``install.sh --user`` as a user (not root), under that user's own
``systemd --user``, Debian 12's (252) and a newer one (254, Debian 12's backports), which from 253
puts a unit that asks for a namespace in a user namespace of its own, where no game is found. The
guest checks are tests/kernel/checks_user_unit.py. Skips, with the reason, only where qemu cannot be
installed at all."""

from __future__ import annotations

import pytest
from conftest import passed

pytestmark = pytest.mark.kernel


@pytest.mark.parametrize(
    ("check", "version"),
    [
        ("checks_user_unit.check_the_user_unit_of_a_user_under_this_systemd", "systemd 252"),
        ("checks_user_unit.check_the_user_unit_of_a_user_under_a_newer_systemd", "systemd 254"),
    ],
)
def test_a_users_unit_switches_to_a_steam_games_profile_and_back(guest, check, version):
    details = passed(guest, check)
    assert details["version"].startswith(version), details["version"]
    assert details["running"] and not details["own_user_namespace"]  # it sees the user's processes
    game, base = details["said"]
    assert game.startswith("switched to profile everything (Steam app 4242 (pid ") and game.endswith("is running)")
    assert base.startswith("switched to profile ") and base.endswith("exited)")
    assert sorted(details["result"].splitlines()) == ["ExecMainStatus=0", "Result=success"]


def test_plugging_the_camera_in_starts_a_users_unit_and_unplugging_stops_it(guest):
    """The unit as installed (BindsTo= the camera's device unit, the udev rule's
    SYSTEMD_USER_WANTS), under the user's own systemd --user: the emulated camera's plug-in starts
    it, its unplugging stops it."""
    details = passed(guest, "checks_user_unit.check_plugging_the_camera_in_starts_a_users_unit")
    assert details["before"] == "inactive" and not details["invocation_before"]
    assert details["device"] and details["started"]
    assert details["stopped"] and details["after_unplug"] in ("inactive", "failed")
