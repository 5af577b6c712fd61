"""A first run on a cold numba cache (neurotouch_hid/service/warmup.py): what is cold, the interpreted
kernels giving the compiled pipeline's windows, nothing compiled in the run's own process, the
simulator and the tracker interpreted for the first window then waited for, and a settled guard."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
from warmup_helpers import _env

from neurotouch_hid.service import warmup


def test_interpret_points_every_name_at_the_python_form_and_back():
    """Where a kernel is defined and where it is imported (``from ... import kernel``) alike."""
    found = warmup.kernels(warmup.PIPELINE)
    assert len(found) > 30
    names = [
        (module, attr, kernel)
        for kernel in found.values()
        for module in list(sys.modules.values())
        if getattr(module, "__name__", "").startswith("neurotouch_hid")
        for attr, value in list(vars(module).items())
        if value is kernel
    ]
    assert any(module.__name__ != kernel.py_func.__module__ for module, _, kernel in names)  # imported ones too
    warmup.interpret(found)
    try:
        assert all(getattr(module, attr) is kernel.py_func for module, attr, kernel in names)
    finally:
        warmup.compiled(found)
    assert all(getattr(module, attr) is kernel for module, attr, kernel in names)


def test_interpreted_pipeline_gives_the_compiled_pipelines_windows():
    """The kernels' Python form (what a cold run uses until compiled) computes the same windows."""
    from neurotouch_hid.pipeline.pipeline import GesturePipeline
    from neurotouch_hid.sources.simulator import SimulatedSource

    items = list(SimulatedSource(seed=3, gestures=["push"]).stream(seconds=1.6))

    def windows():
        pipeline = GesturePipeline(SimulatedSource(seed=3).sensor)
        return [e for item in items for e in pipeline.process(item)]

    compiled = windows()
    found = warmup.kernels(warmup.PIPELINE)
    warmup.interpret(found)
    try:
        with np.errstate(all="ignore"):
            interpreted = windows()
    finally:
        warmup.compiled(found)
    assert len(interpreted) == len(compiled) > 100
    assert any(e.gesture.value == "push" for e in compiled)
    assert [e.gesture for e in interpreted] == [e.gesture for e in compiled]
    np.testing.assert_allclose([e.intensity_mm for e in interpreted], [e.intensity_mm for e in compiled], atol=1e-6)


INTERPRETED_CHILD = """
import pickle, sys
from numba.core import event
from neurotouch_hid.service import warmup
from neurotouch_hid.engine.assembly import build_pipeline
from neurotouch_hid.core.sensor import SensorGeometry

warmup.child_command = lambda group: [sys.executable, "-c", "import time; time.sleep(600)"]  # never done
groups = list(warmup.PIPELINE_OF["default"])
run = warmup.Warmup(groups, say=lambda line: None).start()
compiled = []

class Compiled(event.Listener):
    def on_start(self, ev):
        pass

    def on_end(self, ev):
        function = ev.data["dispatcher"].py_func
        compiled.append(f"{function.__module__}.{function.__qualname__}")

pipeline, _ = build_pipeline(SensorGeometry(), 10_000, resting_beside=False)  # resting inline
guarded = warmup.GuardedPipeline(pipeline, run.guarded(*groups))
with event.install_listener("numba:compile", Compiled()):
    estimates = [e for item in pickle.load(open(sys.argv[1], "rb")) for e in guarded.process(item)]
run.close()
print(len(estimates), *sorted(set(compiled)))
"""


def test_a_cold_run_compiles_nothing_in_its_own_process_while_it_interprets(tmp_path):
    """Nothing compiled, an empty cache, the children not done: the pipeline interpreted through
    a push (its APS-frame correction, resting detection, contacts) makes numba compile nothing in
    the run's process. The kernels inlined into others (``inline="always"``) were left compiled:
    called from an interpreted kernel, numba compiled each in the run's own threads (0.5-1.4 s
    apiece, before the first state and before the first gesture)."""
    import pickle

    from neurotouch_hid.sources.simulator import SimulatedSource

    items = tmp_path / "items.pickle"
    items.write_bytes(pickle.dumps(list(SimulatedSource(seed=3, gestures=["push"]).stream(seconds=0.4))))
    out = subprocess.run(
        [sys.executable, "-c", INTERPRETED_CHILD, str(items)],
        capture_output=True,
        text=True,
        env=_env(tmp_path / "numba"),
        timeout=600,
    )
    assert out.returncode == 0, out.stderr[-2000:]
    windows, *compiled = out.stdout.split()
    assert int(windows) > 10 and compiled == []


def test_a_run_that_ends_before_its_compile_leaves_the_compiled_kernels_named(tmp_path, monkeypatch):
    """The run's process goes on (tests, a second run): nothing stays interpreted after close."""
    import neurotouch_hid.pipeline.gesture as gesture

    found = warmup.kernels(warmup.PIPELINE)
    area = found["neurotouch_hid.pipeline.gesture._area_motion"]
    run = warmup.Warmup([warmup.PIPELINE], say=lambda line: None)
    monkeypatch.setattr(warmup, "cached_signatures", lambda dispatcher: [])  # cold, whatever is cached
    monkeypatch.setattr(run, "_child", lambda group: None)  # a compile that never ends
    run.start()
    assert gesture._area_motion is area.py_func and run.compiling
    run.close()
    assert gesture._area_motion is area and not run.compiling


@pytest.mark.parametrize("group", [warmup.SIMULATOR, warmup.TRACKER], ids=lambda g: g.name)
def test_the_simulator_and_the_tracker_run_interpreted_for_the_first_window_then_are_waited_for(group, monkeypatch):
    """Interpreted, the simulator gives ~0.1 s of gel a second and the tracker ~0.5 s of events:
    a run waits for their compiles, but only once its first window is out (the first state at
    once, not after the compile: it came after 7-9 s on a first run)."""
    import importlib
    import threading

    found = warmup.kernels(group)
    run = warmup.Warmup([group], say=lambda line: None)
    release = threading.Event()

    def child(group):  # the child's compile, done when the test says so
        release.wait(60)
        with run._locks[group.name]:
            warmup.compiled(found)
            run.progress[group.name].state = "ready"
        run._settled[group.name].set()

    monkeypatch.setattr(warmup, "cached_signatures", lambda dispatcher: [])
    monkeypatch.setattr(run, "_child", child)
    run.start()
    assert run.compiling
    try:
        for name, kernel in found.items():  # interpreted meanwhile
            module, attr = name.rsplit(".", 1)
            assert getattr(importlib.import_module(module), attr) is kernel.py_func
        with run.guarded(group)():  # before the first window: at once, interpreted
            pass
        assert run.progress_now() is not None  # the runtime asks it once its first window is out
        entered = threading.Event()

        def call():
            with run.guarded(group)():
                entered.set()

        thread = threading.Thread(target=call, daemon=True)
        thread.start()
        assert not entered.wait(0.3)  # now it waits for the compile
        release.set()
        assert entered.wait(60)  # the bound only ends a hang
        thread.join(60)
        for name, kernel in found.items():  # compiled once done
            module, attr = name.rsplit(".", 1)
            assert getattr(importlib.import_module(module), attr) is kernel
    finally:
        release.set()
        run.close()


def test_a_settled_guard_costs_nothing_and_never_waits(monkeypatch):
    """Once every group of a guard is settled (warm, compiled or given up: for good), a call
    takes no lock: a run at rest pays no guard per window. Before that it takes the group's."""
    import threading

    run = warmup.Warmup([warmup.PIPELINE], say=lambda line: None)
    monkeypatch.setattr(warmup, "cached_signatures", lambda dispatcher: [])
    monkeypatch.setattr(run, "_child", lambda group: None)  # a compile that has not ended
    run.start()
    guard = run.guarded(warmup.SIMULATOR, warmup.PIPELINE)  # the simulator: not compiled here
    entered = threading.Event()

    def call():
        with guard():
            entered.set()

    with run._locks["pipeline"]:  # the switch to compiled code, under way
        thread = threading.Thread(target=call, daemon=True)
        thread.start()
        assert not entered.wait(0.3)  # a cold group's call waits for the switch
    assert entered.wait(10)
    thread.join(10)
    run.close()  # the run ended first: the group given up, its names back on the compiled kernels
    assert run.progress["pipeline"].state == "failed"
    with run._locks["pipeline"]:  # settled: the lock is never taken again
        with guard():
            pass
        assert guard() is guard()  # one shared empty context, nothing made per call
