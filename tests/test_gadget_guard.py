"""The gadget's guard (neurotouch_hid.service.guard): a driver killed without closing its
``/dev/hidgN`` nodes still leaves the host the neutral reports; a run that ends in order leaves
nothing more. Here a pipe stands for the node (non-blocking, as the driver opens /dev/hidgN: a
full pipe refuses a write with EAGAIN as a node whose last report the host has not taken does);
tests/kernel/checks_gadget.py kills a real run and reads the host side."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

from helpers import exited, fill_unread, wait_until

from neurotouch_hid.service.guard import Guard

REPO = Path(__file__).resolve().parent.parent
NEUTRAL = bytes.fromhex("00000080008000800080")
KEYBOARD_NEUTRAL = bytes(8)


def _node() -> tuple[int, int]:
    """A pipe standing for /dev/hidgN: (the host's end, the driver's non-blocking end)."""
    host, node = os.pipe2(os.O_CLOEXEC)
    os.set_blocking(node, False)
    os.set_blocking(host, False)
    return host, node


def _read(fd: int, until, timeout_s: float = 30.0) -> bytes:
    """What the host's end reads until ``until(data)`` holds or ``timeout_s`` passes."""
    got = b""

    def more() -> bool:
        nonlocal got
        try:
            got += os.read(fd, 1 << 16)
        except BlockingIOError:
            pass
        return until(got)

    wait_until(more, timeout_s)
    return got


def _ends_with(report: bytes):
    return lambda data: data.endswith(report)


def _anything(data: bytes) -> bool:
    return bool(data)


#: SIGHUP, SIGINT and SIGTERM as bits of /proc/PID/status's SigIgn (bit N-1 for signal N).
STOP_SIGNALS = sum(1 << (number - 1) for number in (signal.SIGHUP, signal.SIGINT, signal.SIGTERM))


def _ignored(pid: int) -> int:
    """The signals process ``pid`` ignores, as /proc/PID/status's SigIgn mask."""
    with open(f"/proc/{pid}/status") as status:
        return next(int(line.split()[1], 16) for line in status if line.startswith("SigIgn:"))


def test_a_driver_killed_by_sigkill_leaves_the_host_every_nodes_neutral_report(tmp_path):
    """A real process holding the nodes and its guard, killed with SIGKILL (nothing in it runs):
    each node gets its neutral report, and the guard exits."""
    pad_host, pad = _node()
    keys_host, keys = _node()
    code = (
        "import os, sys, time\n"
        "from neurotouch_hid.service.guard import Guard\n"
        f"guard = Guard([(int(sys.argv[1]), {NEUTRAL!r}), (int(sys.argv[2]), {KEYBOARD_NEUTRAL!r})])\n"
        "print(guard.pid, flush=True)\n"
        "time.sleep(600)\n"
    )
    driver = subprocess.Popen(
        [sys.executable, "-c", code, str(pad), str(keys)],
        pass_fds=(pad, keys),
        stdout=subprocess.PIPE,
        text=True,
        env=dict(os.environ, PYTHONPATH=str(REPO)),
    )
    os.close(pad)
    os.close(keys)
    try:
        guard_pid = int(driver.stdout.readline())
        assert _read(pad_host, _anything, 0.5) == b""  # nothing while the driver lives
        driver.kill()
        driver.wait(30)
        assert _read(pad_host, _ends_with(NEUTRAL)) == NEUTRAL
        assert _read(keys_host, _ends_with(KEYBOARD_NEUTRAL)) == KEYBOARD_NEUTRAL
        assert wait_until(lambda: exited(guard_pid), 30.0), "the guard did not exit once it had sent them"
    finally:
        if driver.poll() is None:
            driver.kill()
            driver.wait()
        os.close(pad_host)
        os.close(keys_host)


def test_a_run_that_ends_in_order_releases_its_guard_which_sends_nothing():
    host, node = _node()
    guard = Guard([(node, NEUTRAL)])
    os.close(node)  # the guard has its own copy
    guard.release()
    assert guard._proc.returncode == 0
    assert _read(host, _anything, 0.5) == b""
    guard.release()  # again: nothing
    os.close(host)


def test_the_guard_outlives_ctrl_c_and_sigterm_and_waits_for_the_host_to_take_the_report():
    """Ctrl-C and systemd's stop signal the guard too: it stays to do its work. The host has
    not taken the last report (the node refuses with EAGAIN): the neutral one follows once it has."""
    host, node = _node()
    fill_unread(node)
    guard = Guard([(node, NEUTRAL)])
    os.close(node)
    assert wait_until(lambda: _ignored(guard.pid) & STOP_SIGNALS == STOP_SIGNALS, 30.0), "the guard ignores no signal"
    for number in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
        os.kill(guard.pid, number)
    os.close(guard._write_end)  # the driver dies: the kernel closes its end
    guard._write_end = -1
    time.sleep(0.2)
    assert guard._proc.poll() is None, "the guard ended before the host took the report"
    got = _read(host, _ends_with(NEUTRAL))
    assert got == b"\xff" * (len(got) - len(NEUTRAL)) + NEUTRAL  # the backlog, then the neutral report
    assert guard._proc.wait(30) == 0
    os.close(host)


def test_the_guard_gives_up_on_a_host_that_never_reads():
    host, node = _node()
    fill_unread(node)
    guard = Guard([(node, NEUTRAL)], give_up_s=0.2)
    os.close(node)
    os.close(guard._write_end)
    guard._write_end = -1
    assert guard._proc.wait(30) == 0  # it ended, having sent nothing
    os.close(host)


def test_the_guard_costs_no_wake_up_while_the_driver_runs():
    """benchmarks/bench_gadget_guard.py's measure: asleep in its read, the guard is never scheduled."""
    from helpers import load_benchmark

    figures = load_benchmark("bench_gadget_guard").measure(seconds=0.5)
    assert figures["rest_context_switches"] == 0 and figures["rest_cpu_s"] == 0.0, figures
    assert 0 < figures["anonymous_kib"] < figures["rss_kib"]


def test_a_guard_released_while_it_still_prepares_its_work_exits_by_itself():
    """The hidden devices' guard prepares what it runs after the driver's death (its imports) while
    the driver lives; a run that lets its devices go meanwhile (a profile switch right after a
    merge) must not wait for that, nor leave it to be killed."""
    guard = Guard(then=["-c", "import time\ntime.sleep(60)\ndef then():\n    pass\n"], what="the hidden devices")
    guard.release()
    assert guard._proc.returncode == 0


def test_the_guard_gives_up_on_a_write_that_blocks():
    """A FunctionFS endpoint's write returns once the host took the report: a host that never
    polls would hold the guard, and the gadget with it, for ever; a timer cuts it short."""
    host, node = _node()
    fill_unread(node)
    os.set_blocking(node, True)  # a write now blocks, as an endpoint's does
    guard = Guard([(node, NEUTRAL)], give_up_s=0.3)
    os.close(node)
    os.close(guard._write_end)  # the driver dies
    guard._write_end = -1
    assert guard._proc.wait(30) == 0
    os.close(host)
