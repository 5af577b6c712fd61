"""The real-kernel harness's own bookkeeping (tests/kernel/vm.py), on the host: which guest runs
which checks, and when a boot's folder is kept for a look; and the guest checks' forked commands
(tests/kernel/guestlib.py, ``forked``)."""

from __future__ import annotations

import contextlib
import os
import shutil
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
from kernel import vm


def test_every_check_module_runs_in_exactly_one_guest_of_the_default_run_or_the_slow_tier():
    modules = sorted(path.stem for path in vm.HERE.glob("checks_*.py"))
    default = [m for part in vm.guest_parts() for m in part]
    assert sorted(default + list(vm.SLOW_MODULES)) == modules
    assert len(set(default)) == len(default)
    first = vm.guest_parts()[0]
    assert set(vm.CAMERA_MODULES) <= set(first)
    # the camera's checks run first in their guest (guest.py: name order), before anything else loads the kernel
    assert sorted(first)[: len(vm.CAMERA_MODULES)] == sorted(vm.CAMERA_MODULES)
    # the modules that plug gadgets of their own or list the cameras never share the camera's guest
    assert not {"checks_packaging", "checks_gadget", "checks_devices"} & set(first)


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


def _booted(
    monkeypatch, parts: list[tuple[str, ...]], fail: str | None = None, hold_s: float = 0.2
) -> tuple[list, list[str]]:
    """Replace vm.boot by one that lasts ``hold_s`` (less once every part is running), records how
    many guests run at once at each start, and raises for the part whose first module is ``fail``;
    returns (that record, the parts booted in order)."""
    running, at_once, booted = set(), [], []
    lock, all_running = threading.Lock(), threading.Event()

    def boot(cancelled, modules):
        with lock:
            running.add(modules)
            at_once.append(len(running))
            booted.append(modules[0])
            if len(running) == len(parts):
                all_running.set()
        all_running.wait(hold_s)
        with lock:
            running.discard(modules)
        if modules[0] == fail:
            raise RuntimeError(f"{fail} wrote no result")
        return {f"{modules[0]}.check": {"ok": True, "seconds": hold_s}, "_boot": {"seconds": hold_s}}

    monkeypatch.setattr(vm, "guest_parts", lambda: parts)
    monkeypatch.setattr(vm, "boot", boot)
    return at_once, booted


def test_the_guests_boot_one_after_the_other_beside_the_hosts_tests_and_side_by_side_alone(monkeypatch):
    parts = [("checks_a",), ("checks_b",)]
    at_once, booted = _booted(monkeypatch, parts)
    result = vm.BackgroundBoot().result()
    assert at_once == [1, 1] and booted == ["checks_a", "checks_b"]  # in guest_parts' order: the camera's guest first
    assert result["checks_a.check"]["ok"] and result["checks_b.check"]["ok"]
    at_once, _ = _booted(monkeypatch, parts, hold_s=30.0)  # ends as soon as both run
    result = vm.BackgroundBoot(side_by_side=True).result()
    assert max(at_once) == 2 and result["checks_b.check"]["ok"]


def test_a_guest_that_fails_fails_the_result_and_boots_no_other(monkeypatch):
    _, booted = _booted(monkeypatch, [("checks_a",), ("checks_b",)], fail="checks_a")
    with pytest.raises(RuntimeError, match="checks_a wrote no result"):
        vm.BackgroundBoot().result()
    assert booted == ["checks_a"]


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


#: Stands in for vng in the tests of the boot's watchdog (a fake for those unit tests only: the real
#: boots are the kernel tests'). Each call appends its pid to $FAKE_VNG_CALLS; the calls listed in
#: $FAKE_VNG_PLAN (comma-separated, one word per call) behave as: "stuck" a boot that never starts
#: guest.py, "hangs" a guest.py that starts and never ends, "ok" one that writes its result.
FAKE_VNG = """
import os, sys, time
from pathlib import Path
calls = Path(os.environ["FAKE_VNG_CALLS"])
with calls.open("a") as f:
    f.write(f"{os.getpid()}\\n")
plan = os.environ["FAKE_VNG_PLAN"].split(",")
what = plan[min(len(calls.read_text().split()), len(plan)) - 1]
out = Path(next(a for a in sys.argv if a.startswith("--rwdir=")).split("=", 1)[1])
print(f"[    1.000000] fake kernel, call {len(calls.read_text().split())}: {what}", flush=True)
if what == "stuck":
    time.sleep(600)
(out / "guest-started").write_text("1\\n")
if what == "hangs":
    time.sleep(600)
(out / "result.json").write_text('{"setup": {"ok": true, "seconds": 0.1}}')
"""


@pytest.fixture
def fake_vng(tmp_path, monkeypatch):
    """vm.boot with :data:`FAKE_VNG` for vng; returns the file of its calls' pids (set FAKE_VNG_PLAN)."""
    script = tmp_path / "vng"
    script.write_text(f"#!{sys.executable}\n{FAKE_VNG}")
    script.chmod(0o755)
    monkeypatch.setattr(vm, "_vng", lambda: str(script))
    monkeypatch.setattr(vm, "ensure_host_packages", lambda: None)
    monkeypatch.setattr(vm, "ensure_kernel", lambda: (tmp_path, "0.0-fake"))
    monkeypatch.setenv("NEUROTOUCH_KERNEL_CACHE", str(tmp_path / "cache"))
    calls = tmp_path / "calls"
    monkeypatch.setenv("FAKE_VNG_CALLS", str(calls))
    return calls


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    return True


def test_a_boot_that_never_starts_the_guest_script_is_stopped_and_booted_again(fake_vng, monkeypatch):
    monkeypatch.setenv("FAKE_VNG_PLAN", "stuck,ok")
    data = vm.boot(modules=("checks_gamepad",), timeout_s=60, start_timeout_s=2)
    first, second = (int(pid) for pid in fake_vng.read_text().split())
    assert data["setup"]["ok"]
    retried = data["_boot"]["retried"]
    assert retried.startswith(f"{vm.NEVER_STARTED} within 2 s")
    assert "call 1: stuck" in retried  # the first boot's console, to see where it stopped
    assert not _alive(first)  # its whole process group was stopped
    assert not _alive(second)
    monkeypatch.setattr(vm, "_background", type("Done", (), {"finished": vm.merge_results([data])})())
    assert f"booted again: {vm.NEVER_STARTED} within 2 s" in vm.boot_summary()


def test_a_boot_that_never_starts_twice_fails_with_both_consoles(fake_vng, monkeypatch):
    monkeypatch.setenv("FAKE_VNG_PLAN", "stuck,stuck")
    with pytest.raises(RuntimeError, match="booted twice") as failed:
        vm.boot(modules=("checks_gamepad",), timeout_s=60, start_timeout_s=2)
    assert "call 1: stuck" in str(failed.value) and "call 2: stuck" in str(failed.value)
    assert len(fake_vng.read_text().split()) == 2


def test_a_guest_script_that_started_and_hangs_is_not_booted_again(fake_vng, monkeypatch):
    # once guest.py runs, a hang is the checks' own (their alarms, the boot's timeout): a second
    # boot would hide it
    monkeypatch.setenv("FAKE_VNG_PLAN", "hangs,ok")
    with pytest.raises(RuntimeError, match="vng timed out after 4 s") as failed:
        vm.boot(modules=("checks_gamepad",), timeout_s=4, start_timeout_s=1)
    assert "call 1: hangs" in str(failed.value) and "booted twice" not in str(failed.value)
    assert len(fake_vng.read_text().split()) == 1


#: A test process that boots :data:`FAKE_VNG` ("hangs": guest.py started, never ends) and waits;
#: argv: the fake vng's path, the kernel cache folder. The test kills it with SIGKILL, as a CI's or
#: a developer's kill would: none of its cleanup runs.
BOOTING_PROCESS = """
import sys
from pathlib import Path
sys.path.insert(0, sys.argv[3])
from kernel import vm
vm._vng = lambda: sys.argv[1]
vm.ensure_host_packages = lambda: None
vm.ensure_kernel = lambda: (Path(sys.argv[2]), "0.0-fake")
vm.boot(modules=("checks_gamepad",), timeout_s=600, start_timeout_s=600)
"""


def test_a_killed_test_process_leaves_no_guest_running(fake_vng, monkeypatch, tmp_path):
    monkeypatch.setenv("FAKE_VNG_PLAN", "hangs")
    tests_dir = str(Path(vm.__file__).resolve().parent.parent)
    booting = subprocess.Popen([sys.executable, "-c", BOOTING_PROCESS, vm._vng(), str(tmp_path), tests_dir])
    try:
        deadline = time.monotonic() + 60
        while not (fake_vng.exists() and fake_vng.read_text().split()) and time.monotonic() < deadline:
            assert booting.poll() is None, "the booting process ended before its guest started"
            time.sleep(0.2)
        (guest,) = (int(pid) for pid in fake_vng.read_text().split())
        assert _alive(guest)
        booting.kill()
        booting.wait()
        deadline = time.monotonic() + 30
        while _alive(guest) and time.monotonic() < deadline:
            time.sleep(0.2)
        assert not _alive(guest), "the guest outlived the test process that booted it"
    finally:
        booting.kill()
        booting.wait()
        with contextlib.suppress(ProcessLookupError, ValueError):
            os.killpg(int(fake_vng.read_text().split()[0]), signal.SIGKILL)


def _own_ids() -> dict:
    return {
        "pid": os.getpid(),
        "uid": os.getuid(),
        "gid": os.getgid(),
        "groups": os.getgroups(),
        "env": os.environ["X_K"],
    }


def _fails() -> None:
    raise ValueError("the child's own error")


def test_a_forked_command_is_a_process_of_its_own_with_its_env_and_answers_or_raises():
    from kernel import guestlib

    ids = guestlib.forked(_own_ids, env={"X_K": "set in the child"})
    assert ids["pid"] != os.getpid() and ids["env"] == "set in the child"
    assert "X_K" not in os.environ
    with pytest.raises(AssertionError, match="ValueError: the child's own error"):
        guestlib.forked(_fails)


def test_a_forked_command_that_hangs_is_killed_at_its_timeout(tmp_path):
    """The child would mark its file after its 60 s: forked reaps it before returning, so an
    unmarked file is a child killed, not waited for."""
    from kernel import guestlib

    marker = tmp_path / "slept"

    def sleeps() -> None:
        time.sleep(60)
        marker.write_text("the whole sleep")

    with pytest.raises(AssertionError, match="did not answer in 1 s"):
        guestlib.forked(sleeps, timeout_s=1.0)
    assert not marker.exists()


def test_a_forked_command_as_nobody_runs_as_uid_and_gid_65534_without_groups():
    """As root (the guest): the child is nobody. As another user the child cannot become nobody,
    and says why instead of running as that user."""
    from kernel import guestlib

    if os.geteuid() != 0:
        with pytest.raises(AssertionError, match="PermissionError"):
            guestlib.forked(_own_ids, as_nobody=True, env={"X_K": "x"})
        return
    ids = guestlib.forked(_own_ids, as_nobody=True, env={"X_K": "x"})
    assert (ids["uid"], ids["gid"], ids["groups"]) == (65534, 65534, [])


def test_a_thread_asleep_on_descriptors_with_no_timeout_is_told_from_one_with_a_timer():
    """What the copilot's check reads of its thread at rest (/proc/self/task/TID/syscall)."""
    import select
    import threading

    from helpers import wait_until
    from kernel import guestlib

    r, w = os.pipe()
    try:
        for timeout, expected in ((None, True), (60.0, False)):
            asleep = threading.Thread(target=select.select, args=([r], [], [], timeout), daemon=True)
            asleep.start()
            tid = asleep.native_id
            if expected:
                assert wait_until(lambda tid=tid: guestlib.waits_without_timeout(tid), 60)
            else:  # in its select (a system call's number), but with a timer
                assert wait_until(lambda tid=tid: _in_a_call(tid), 60)
                assert guestlib.waits_without_timeout(tid) is None
            os.write(w, b"x")
            asleep.join(60)
            os.read(r, 1)
    finally:
        os.close(r)
        os.close(w)


def _in_a_call(native_id: int) -> bool:
    return Path(f"/proc/self/task/{native_id}/syscall").read_text().split()[0].isdigit()


def test_a_touchpad_stroke_is_whole_only_from_its_touch_to_its_lift_with_no_events_dropped_between(monkeypatch):
    """The DualSense checks' reading of slot 0: a touch (tracking id >= 0), its moves and its lift
    (-1). Where the kernel dropped events because the reader fell behind (SYN_DROPPED, marked
    ``("dropped", 0)``), a lift and the next touch may be lost, and two strokes would read as one
    that jumps back: that stroke is not whole, the one before it still is."""
    monkeypatch.syspath_prepend(str(Path(__file__).parent / "kernel"))  # the guest's import path
    from checks_gadget_ffs import _stroke

    first = [("id", 1), ("x", 560), ("x", 900), ("id", -1)]
    merged = [("id", 2), ("x", 600), ("x", 1343), ("dropped", 0), ("x", 603), ("x", 1354), ("id", -1)]
    assert _stroke(first + merged) == [560, 900]
    assert _stroke(merged) is None
    assert _stroke(first + merged + [("id", 3), ("x", 610), ("x", 700), ("id", -1)]) == [610, 700]
    assert _stroke([("id", 4), ("x", 610)]) is None
    stalled = [("id", 2), ("x", 600), ("x", 1343), ("stalled", 1100), ("x", 733), ("x", 1354), ("id", -1)]
    assert _stroke(first + stalled) == [560, 900]  # a host that missed the lift: not whole


def test_the_touchpad_watcher_marks_a_pause_of_the_kernels_reports_longer_than_a_lift(monkeypatch):
    """Two strokes read as one in CI (host load ~10): the starved emulated host never read the
    lift between them. The watcher marks every pause of the Touchpad's reports of STALL_S or more
    (the kernel's own report times), in every slot, so that such a stroke is not taken as whole."""
    monkeypatch.syspath_prepend(str(Path(__file__).parent / "kernel"))
    import checks_dualsense
    from checks_gadget_ffs import _stroke

    X, ID = checks_dualsense.ABS_MT_POSITION_X, checks_dualsense.ABS_MT_TRACKING_ID
    sent = [([(3, ID, 1)], 10.0), ([(3, X, 560)], 10.04), ([(3, X, 600)], 10.08)]
    sent += [([(3, X, 733)], 11.2), ([(3, X, 760)], 11.24), ([(3, ID, -1)], 11.28)]

    class Reader:  # guestlib.EventReader as the watcher reads it: reports and their kernel times
        def __init__(self, path):
            self.axes, self.reports, self.report_times, self.gone = {}, [], [], False

        def pump(self, timeout_s, until):
            for report, t in sent:
                self.reports.append(report)
                self.report_times.append(t)
            self.gone = True

        def close(self):
            pass

    monkeypatch.setattr(checks_dualsense.guestlib, "EventReader", Reader)
    watcher = checks_dualsense.TouchWatcher("/dev/input/event-test")
    watcher.thread.join(5)
    assert watcher.slots[0] == [
        ("id", 1),
        ("x", 560),
        ("x", 600),
        ("stalled", 1120),
        ("x", 733),
        ("x", 760),
        ("id", -1),
    ]
    assert ("stalled", 1120) in watcher.slots[1]
    assert _stroke(watcher.slots[0]) is None
