"""The engine's one loop (``engine/loop.py``): what a run waits on that has a file descriptor (the
targets' feedback, the merged devices, the control socket, signals) and its few timers (the games
watcher) are served by the run's main thread, not by a thread and a timer each."""

from __future__ import annotations

import os
import threading
import time

import pytest
from copilot_helpers import SHORT_FORM
from helpers import wait_until
from runtime_fakes import EstimatesThrough
from test_targets import PipeTarget

from neurotouch_hid.core.estimate import GestureEstimate, GestureType
from neurotouch_hid.engine.engine import Engine, RunParts
from neurotouch_hid.engine.loop import Loop
from neurotouch_hid.engine.mode import RunMode, RunOptions
from neurotouch_hid.inputs.copilot import Copilot
from neurotouch_hid.mapping.profile import parse_profile
from neurotouch_hid.service.control import request_use, socket_path
from neurotouch_hid.service.serve import served
from neurotouch_hid.targets import TargetOutputs

#: The threads a run has of its own at most (the issue's target for a gamepad service run with a
#: copilot): the main thread (the loop), the source's, the pipeline's, the resting detector's.
OWN_THREADS = {"MainThread", "nt-source", "nt-pipeline", "nt-resting"}


@pytest.fixture
def runtime_dir(tmp_path, monkeypatch):
    folder = tmp_path / "xdg"
    folder.mkdir(mode=0o700)
    monkeypatch.setenv("XDG_RUNTIME_DIR", str(folder))
    monkeypatch.setenv("XDG_CONFIG_HOME", str(tmp_path / "config"))
    return folder


def test_at_rest_a_run_with_a_device_a_copilot_the_socket_and_the_games_watcher_has_only_its_own_threads(
    tmp_path, runtime_dir
):
    """A run as ``run_driver`` wires it (one loop, a thread of its own until the run's main thread
    takes it over): the targets' feedback, a copilot waiting for its devices, the control socket
    and the games watcher add no thread; ``profile use`` is answered on the loop and a target's
    feedback is read there."""
    profile = parse_profile(SHORT_FORM, "copilot.yaml")
    others = {
        t for t in threading.enumerate() if t is not threading.main_thread()
    }  # the test session's own (its kernel boots)
    loop = Loop()
    loop.run_in_thread("nt-loop")
    log: list = []
    target = PipeTarget("pad", log)
    outputs = TargetOutputs([target], loop=loop)
    copilot = Copilot(profile.copilot, input_dir=tmp_path / "input", sysfs=tmp_path / "sys", loop=loop)
    copilot.grab()  # before the device, as run_driver does: none of its devices is there (waited for)
    at_rest, sampled = threading.Event(), threading.Event()
    seen: dict = {}

    def source():
        yield GestureEstimate(t_us=10_000, gesture=GestureType.PUSH, resting=False, intensity_mm=3.0)
        for k in range(2, 6):
            yield GestureEstimate(t_us=k * 10_000)
        at_rest.set()
        sampled.wait(60)  # the gel rests: nothing comes until the test has looked

    engine = Engine(
        RunParts(source(), EstimatesThrough()),
        profile,
        [outputs],
        RunOptions(mode=RunMode.PACED, merge=copilot, loop=loop, profile_loader=lambda ref: profile),
    )

    def look() -> None:
        try:
            assert wait_until(at_rest.is_set, 60) and wait_until(socket_path().exists, 60)
            seen["answer"] = request_use("mine")  # answered by the main thread's loop
            os.write(target.write_fd, b"rumble\n")
            seen["feedback"] = wait_until(lambda: outputs.feedbacks >= 1, 30)
            time.sleep(0.2)
            current = threading.current_thread()
            seen["threads"] = {t.name for t in threading.enumerate() if t is not current and t not in others}
        finally:
            sampled.set()

    looker = threading.Thread(target=look, name="looker")
    looker.start()
    try:
        with served(engine, "mine", games=True):
            engine.run()
    finally:
        looker.join(60)
        copilot.stop()
        outputs.close()
        loop.close()
    assert seen["answer"] == "switched to profile mine" and seen["feedback"]
    assert seen["threads"] <= OWN_THREADS, seen["threads"]
    assert {"MainThread", "nt-source", "nt-pipeline"} <= seen["threads"]


def test_the_loop_calls_what_is_ready_its_timers_in_order_and_what_other_threads_hand_it():
    loop = Loop()
    read_fd, write_fd = os.pipe()
    calls: list = []
    loop.add_reader(read_fd, lambda: calls.append(("read", os.read(read_fd, 10))))
    now = time.monotonic()
    loop.call_at(now + 0.02, lambda: calls.append("second"))
    loop.call_at(now + 0.01, lambda: calls.append("first"))
    cancelled = loop.call_at(now, lambda: calls.append("cancelled"))
    cancelled.cancel()
    threading.Thread(target=lambda: loop.call_soon(lambda: calls.append("soon"))).start()
    os.write(write_fd, b"x")
    loop.run_until(lambda: len(calls) >= 4)
    assert set(calls) == {("read", b"x"), "soon", "first", "second"}
    assert calls.index("first") < calls.index("second")
    loop.remove_reader(read_fd)
    loop.close()
    os.close(read_fd)
    os.close(write_fd)


def test_a_failing_callback_is_logged_and_the_loop_goes_on(caplog):
    loop = Loop()
    calls: list = []
    loop.call_soon(lambda: 1 / 0)
    loop.call_soon(lambda: calls.append("after"))
    loop.run_until(lambda: calls)
    assert calls == ["after"] and "ZeroDivisionError" in caplog.text
    loop.close()


def test_the_loop_s_own_thread_hands_over_to_the_thread_that_runs_it_and_call_and_wait_waits():
    loop = Loop()
    loop.run_in_thread("nt-loop")
    ran_in: list = []
    loop.call_and_wait(lambda: ran_in.append(threading.current_thread().name))
    assert ran_in == ["nt-loop"]
    done = threading.Event()
    loop.call_later(0.05, done.set)
    loop.run_until(done.is_set)  # the loop's thread stops; this one serves
    assert not any(t.name == "nt-loop" for t in threading.enumerate())
    loop.call_and_wait(lambda: ran_in.append(threading.current_thread().name))  # nobody runs it: here
    assert ran_in[-1] == threading.current_thread().name
    loop.close()
