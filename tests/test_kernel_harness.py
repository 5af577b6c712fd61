"""The real-kernel harness's own bookkeeping (tests/kernel/vm.py), on the host: which guest runs
which checks, and when a boot's folder is kept for a look."""

from __future__ import annotations

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
