"""The driver from the qemu guest's read-only root (tests/kernel/checks_readonly.py; one boot per test
session by tests/kernel/vm.py). The host side of a read-only install: tests/test_readonly_install.py."""

from __future__ import annotations

import pytest
from conftest import passed

pytestmark = pytest.mark.kernel


def test_jitted_modules_load_from_the_read_only_guest_root(guest):
    """The package is on a read-only root and no cache variable is set: the modules with numba
    ``cache=True`` functions load (they raised "no locator available") and doctor says where
    compiled code goes."""
    details = passed(guest, "checks_readonly.check_driver_starts_from_the_read_only_root")
    assert details["cache"] == "temporary", details  # nothing lasting writable, no XDG_RUNTIME_DIR
    assert "numba compiles the pipeline at every start" in details["said"], details
    assert "removed at exit" in details["doctor"], details
