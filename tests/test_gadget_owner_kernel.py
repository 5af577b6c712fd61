"""``gadget setup --user USER`` in a REAL Linux kernel (Debian's under qemu, tests/kernel/vm.py):
the gadget's nodes are the user's alone; another user of the user's primary group cannot write
them. The guest check is tests/kernel/checks_gadget_owner.py. Skips, with the reason, only where
qemu cannot be installed at all."""

from __future__ import annotations

import errno

import pytest
from conftest import passed

pytestmark = pytest.mark.kernel


@pytest.mark.parametrize("protocol", ["hid", "xinput"])
def test_only_the_user_given_the_gadget_may_write_it_not_their_group(guest, protocol):
    """/dev/hidgN was mode 0660 with the user's primary group: another user in it (``users``
    where that is every user's) wrote a report and the host read it."""
    details = passed(guest, "checks_gadget_owner.check_gadget_nodes_are_the_users_alone")
    node = details[protocol]
    assert (node["mode"], node["uid"], node["gid"]) == ("0o600", details["bob"], 0), node
    assert node["owner_opens"] == 0, node
    assert node["group_member_opens"] == errno.EACCES, node
