"""The real-kernel harness's own bookkeeping (tests/kernel/vm.py), on the host: which guest runs
which checks, and when a boot's folder is kept for a look."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import threading

import pytest
from kernel import vm


def test_every_check_module_runs_in_exactly_one_guest_of_the_default_run_or_the_slow_tier():
    modules = sorted(path.stem for path in vm.HERE.glob("checks_*.py"))
    default = [m for part in vm.guest_parts() for m in part]
    assert sorted(default + list(vm.SLOW_MODULES)) == modules
    assert len(set(default)) == len(default)
    assert vm.guest_parts()[0] == vm.CAMERA_MODULES


def test_a_part_failing_inside_a_check_that_passed_counts_as_a_failure():
    passed_with_a_failed_part = {
        "setup": {"ok": True},
        "checks_davis.check_emulated_davis": {
            "ok": True,
            "details": {"record": {"ok": False, "error": "AssertionError"}},
        },
    }
    assert vm._failed_anywhere(passed_with_a_failed_part)
    assert not vm._failed_anywhere(
        {
            "setup": {"ok": True},
            "_guest": {"seconds": 1.0},
            "checks_gamepad.check_device_appears": {"ok": True, "details": {"path": "x"}},
        }
    )


@pytest.mark.skipif(
    os.geteuid() != 0 or shutil.which("apt-get") is None, reason="apt-get runs as root only (CI's user)"
)
def test_apt_waits_for_a_lock_another_apt_holds_instead_of_failing(tmp_path):
    # real apt-get on a lists folder of its own (no sources: no network, the machine's lists untouched),
    # whose lock another process holds, as unattended-upgrades does on a freshly booted machine
    lists = tmp_path / "lists"
    (lists / "partial").mkdir(parents=True)
    update = [
        "-o", f"Dir::State::lists={lists}",
        "-o", "Dir::Etc::sourcelist=/dev/null",
        "-o", "Dir::Etc::sourceparts=-",
        "update",
    ]  # fmt: skip
    holder = subprocess.Popen([sys.executable, "-c", HOLD_LOCK, str(lists / "lock")], stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline() == "locked\n"
        at_once = vm.apt_get(update, wait_s=0)
        assert at_once.returncode != 0 and vm.APT_LOCKED in at_once.stderr  # apt-get alone fails
        threading.Timer(3.0, holder.terminate).start()  # the other apt finishes 3 s later
        waited = vm.apt_get(update, wait_s=120)
    finally:
        holder.terminate()
        holder.wait()
    assert waited.returncode == 0, waited.stderr


#: Holds an fcntl lock (apt's kind) on the file argv[1] until killed, after saying "locked".
HOLD_LOCK = """
import fcntl, sys, time
f = open(sys.argv[1], "w")
fcntl.lockf(f, fcntl.LOCK_EX)
print("locked", flush=True)
time.sleep(600)
"""
