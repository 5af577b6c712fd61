"""The runtime's states and shutdown (unit tests with small fakes for the stages): states follow the
estimates and end neutral whatever stops the run (an error, a stop, SIGTERM), and a profile
switched or reloaded neutralises first."""

from __future__ import annotations

import os
import signal
import threading

import pytest
from runtime_fakes import FakePipeline, RecordingOutput, batch, endless, once, writes_of
from runtime_helpers import make_runtime

from neurotouch_hid.core.controller import ControllerState
from neurotouch_hid.core.errors import ProfileError
from neurotouch_hid.engine.mode import RunMode


def writes(output: RecordingOutput) -> list[ControllerState]:
    return [s for kind, s in output.calls if kind == "write"]


# --- states, shutdown ---------------------------------------------------------------------------
def test_states_follow_the_estimates_and_end_neutral():
    rt, _, out = make_runtime(batch(i * 1000) for i in range(10))
    stats = rt.run()
    states = writes(out)
    xs = [s.axes["ABS_X"] for s in states]
    assert xs[:5] == [1000, 2000, 3000, 4000, 5000]  # one write per change
    assert states[5].is_neutral()
    assert len(states) == 6 == stats.states_written  # unchanged states are not written again
    assert out.calls[-1] == ("neutralise", None)
    assert stats.windows == 10 and len(stats.latency) == 10


def test_exception_in_the_pipeline_still_neutralises_the_output():
    rt, _, out = make_runtime((batch(i * 1000) for i in range(10)), pipeline=FakePipeline(fail_at=3))
    with pytest.raises(RuntimeError, match="pipeline failure"):
        rt.run()
    assert any(not s.is_neutral() for s in writes(out))  # a button was held when it failed
    assert out.calls[-1] == ("neutralise", None)


def test_error_in_the_source_processes_what_was_read_then_neutralises_and_raises():
    from neurotouch_hid.core.errors import RecordingError

    def truncated():
        for i in range(4):
            yield batch(i * 1000)
        raise RecordingError("rec.aedat4: truncated")

    rt, pipeline, out = make_runtime(truncated())
    with pytest.raises(RecordingError, match="truncated"):
        rt.run()
    assert len(pipeline.seen) == 4
    assert out.calls[-1] == ("neutralise", None)


def test_stop_from_another_thread_ends_a_paced_endless_source_neutral():
    rt, pipeline, out = make_runtime(endless(), mode=RunMode.PACED, pipeline=FakePipeline(push_batches=10**9))
    once(lambda: writes(out), rt.stop)
    rt.run()
    assert pipeline.seen and out.calls[-1] == ("neutralise", None)
    assert writes(out) and not writes(out)[-1].is_neutral()  # stopped in the middle of a push


def test_sigterm_is_a_clean_stop():
    rt, pipeline, out = make_runtime(endless(), mode=RunMode.PACED, pipeline=FakePipeline(push_batches=10**9))
    previous = signal.getsignal(signal.SIGTERM)
    once(lambda: writes(out), lambda: os.kill(os.getpid(), signal.SIGTERM))
    stats = rt.run()  # returns normally
    assert stats.windows > 0 and out.calls[-1] == ("neutralise", None)
    assert signal.getsignal(signal.SIGTERM) is previous  # handler restored


# --- profiles -----------------------------------------------------------------------------------
def test_switch_profile_neutralises_then_maps_with_the_new_profile():
    rt, pipeline, out = make_runtime(endless(), mode=RunMode.PACED, pipeline=FakePipeline(push_batches=10**9))
    seen_switch = threading.Event()

    def switch():
        rt.switch_profile({"sign": -1})
        seen_switch.set()

    once(lambda: len(writes_of(out.calls)) >= 3, switch)

    def written_after_switch() -> int:
        calls = list(out.calls)
        kinds = [k for k, _ in calls]
        return len(writes_of(calls[kinds.index("neutralise") + 1 :])) if "neutralise" in kinds else 0

    once(lambda: seen_switch.is_set() and written_after_switch() >= 3, rt.stop)
    rt.run()
    assert seen_switch.is_set()
    kinds = [k for k, _ in out.calls]
    i = kinds.index("neutralise")
    before, after = writes_of(out.calls[:i]), writes_of(out.calls[i + 1 :])
    assert before and after
    assert all(s.axes["ABS_X"] > 0 for s in before)
    assert all(s.axes["ABS_X"] < 0 for s in after)


def test_reload_keeps_the_old_profile_when_the_new_one_is_bad():
    def bad_loader(ref):
        raise ProfileError(f"profile {ref} is invalid (1 problem): ...")

    rt, _, out = make_runtime([], profile_ref="mine.yaml", profile_loader=bad_loader)
    assert rt.reload_profile() is False
    assert rt.profile == {"sign": 1} and out.calls == []


def test_sighup_reloads_the_profile():
    loads = []

    def loader(ref):
        loads.append(ref)
        return {"sign": -1}

    rt, _, out = make_runtime(
        endless(),
        mode=RunMode.PACED,
        pipeline=FakePipeline(push_batches=10**9),
        profile_ref="mine.yaml",
        profile_loader=loader,
    )
    once(lambda: len(writes(out)) >= 3, lambda: os.kill(os.getpid(), signal.SIGHUP))
    once(lambda: loads and len(writes(out)) >= 3 and writes(out)[-1].axes["ABS_X"] < 0, rt.stop)
    rt.run()
    assert loads == ["mine.yaml"] and rt.profile == {"sign": -1}
    assert writes(out)[-1].axes["ABS_X"] < 0
