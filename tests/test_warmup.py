"""A first run on a cold numba cache (neurotouch_hid/service/warmup.py): what is cold, the interpreted
kernels, the children that compile into the cache, the progress said before the first state,
and a simulated source that waits instead of dropping data."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from helpers import EARLY_NICE, niced, reap, run_main

from neurotouch_hid.core.estimate import GestureEstimate
from neurotouch_hid.engine.engine import Engine, RunParts
from neurotouch_hid.engine.mode import RunMode, RunOptions
from neurotouch_hid.mapping.profile import load_profile
from neurotouch_hid.service import warmup
from neurotouch_hid.sources import EVENT_DTYPE

CLI = [sys.executable, "-m", "neurotouch_hid.cli"]


def _env(cache) -> dict:
    return dict(os.environ, NUMBA_CACHE_DIR=str(cache), PYTHONPATH=os.pathsep.join(sys.path))


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


def test_a_group_is_cold_until_its_child_compiled_it_into_the_cache(tmp_path):
    check = [sys.executable, "-c", "from neurotouch_hid.service import warmup as w; print(w.is_cold(w.SIMULATOR))"]
    assert subprocess.run(check, env=_env(tmp_path), capture_output=True, text=True).stdout.strip() == "True"
    child = subprocess.run(
        [sys.executable, "-m", "neurotouch_hid.service.warmup", "simulator"],
        env=_env(tmp_path),
        capture_output=True,
        text=True,
    )
    assert child.returncode == 0, child.stderr
    assert "neurotouch_hid.sources.esim.esim_chunk" in child.stdout.split()  # its progress lines
    assert subprocess.run(check, env=_env(tmp_path), capture_output=True, text=True).stdout.strip() == "False"


#: The paper pipeline's child (:func:`_start_paper_child`), once started: (its cache, the process).
_paper_child: list[tuple[Path, subprocess.Popen]] = []


def _paper_stderr(cache: Path) -> Path:
    """Where the paper pipeline's child compiling into ``cache`` writes its stderr: a file, not a
    pipe, which could fill while nobody reads it."""
    return cache.parent / f"{cache.name}-stderr.txt"


def _start_paper_child(cache: Path, nice: int = 0) -> None:
    """The paper pipeline's group compiled from nothing (~35 s of one core) into ``cache``, by its
    child (``warmup.child_command``), at niceness ``nice``."""
    command = niced(warmup.child_command(warmup.PAPER_PIPELINE), nice)
    with open(_paper_stderr(cache), "w") as stderr:
        proc = subprocess.Popen(command, env=_env(cache), stdout=subprocess.DEVNULL, stderr=stderr)
    _paper_child.append((cache, proc))


def start_early(request) -> None:
    """The paper pipeline's child started at the session's start (conftest.py, ``started_early``),
    niced: in a whole test run it takes the cores the other tests leave idle."""
    _start_paper_child(request.getfixturevalue("tmp_path_factory").mktemp("paper-cache"), nice=EARLY_NICE)


def stop_early() -> None:
    """Kill the child if it still runs (its test never came) and forget it."""
    reap(proc for _, proc in _paper_child)
    _paper_child.clear()


def test_the_paper_pipeline_s_child_leaves_no_kernel_of_its_group_cold(tmp_path):
    # its group is every kernel of the pipeline's package, the product's too: compiled alone, the
    # paper's method left them cold, and every later ``run --method paper`` compiled again
    check = [sys.executable, "-c", "from neurotouch_hid.service import warmup as w; print(w.is_cold(w.PAPER_PIPELINE))"]
    if not _paper_child:
        _start_paper_child(tmp_path)
    cache, child = _paper_child[0]
    try:
        child.wait(timeout=600)
    finally:
        stop_early()
    assert child.returncode == 0, _paper_stderr(cache).read_text()
    assert subprocess.run(check, env=_env(cache), capture_output=True, text=True).stdout.strip() == "False"


def test_the_child_compiles_the_installed_package_not_a_checkout_in_the_working_directory(tmp_path):
    # the README's first command runs from the source checkout: a child started with ``-m`` alone
    # imported the checkout's neurotouch_hid (here a copy that fails at import), not the run's
    checkout = tmp_path / "checkout"
    (checkout / "neurotouch_hid").mkdir(parents=True)
    (checkout / "neurotouch_hid" / "__init__.py").write_text('raise SystemExit("the checkout\'s copy was imported")\n')
    child = subprocess.run(
        warmup.child_command(warmup.SIMULATOR),
        cwd=checkout,
        env=_env(tmp_path / "cache"),
        capture_output=True,
        text=True,
    )
    assert child.returncode == 0, child.stderr
    assert "neurotouch_hid.sources.esim.esim_chunk" in child.stdout.split()


def test_the_child_compiles_at_a_lower_priority_than_the_run_that_started_it(tmp_path):
    """The run's first window (interpreted, 0.2-0.4 s of CPU) shared two cores with both
    children: it now comes first, and the children lose nothing they would have had."""
    niceness = "import os; from neurotouch_hid.service import warmup; "
    niceness += "warmup._call = lambda spec: print(os.nice(0), flush=True); warmup.main(['simulator'])"
    child = subprocess.run([sys.executable, "-c", niceness], env=_env(tmp_path), capture_output=True, text=True)
    assert child.returncode == 0, child.stderr
    assert int(child.stdout.split()[-1]) == min(os.nice(0) + warmup.CHILD_NICE, 19)


def test_the_child_refuses_an_unknown_group():
    child = subprocess.run(
        [sys.executable, "-m", "neurotouch_hid.service.warmup", "nope"], capture_output=True, text=True
    )
    assert child.returncode == 2
    assert "pipeline" in child.stderr and "Traceback" not in child.stderr


def test_a_cold_run_says_it_compiles_before_its_first_state_and_drops_nothing(tmp_path):
    """Cold cache, output piped (stdout and stderr in one pipe, in order): the compile is
    announced before the first state line; the simulated source waited instead of dropping."""
    proc = subprocess.Popen(
        [*CLI, "run", "--source", "sim", "--output", "term", "--seconds", "0.3"],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        env=_env(tmp_path),
    )
    out, _ = proc.communicate(timeout=600)
    assert proc.returncode == 0, out
    lines = out.splitlines()
    said = next(i for i, line in enumerate(lines) if "compiling the gesture pipeline, first run only" in line)
    first_state = next(i for i, line in enumerate(lines) if line.startswith("t "))
    assert said < first_state
    assert "dropped 0 items" in lines[-1]
    assert "╭" not in out  # piped: the plain lines, no panel
    assert "Traceback" not in out


class _SlowPipeline:
    """Takes longer per batch than the batch lasts (a pipeline still interpreted)."""

    def __init__(self):
        self.events = 0

    def process(self, item):
        time.sleep(0.004)
        self.events += len(item)
        return [GestureEstimate(t_us=int(item["timestamp"][-1]))]

    def process_newest(self, events):
        return self.process(events), []

    def set_resting(self, result, t_us):
        pass

    def restart(self):
        pass

    def set_type_wait(self, wait):
        pass


class _Recorder:
    wants_markers = False

    def publish(self, record):
        pass

    def neutralise(self):
        pass

    def prepare(self, profile):
        pass


def _batches(n: int):
    for i in range(n):
        batch = np.zeros(10, dtype=EVENT_DTYPE)
        batch["timestamp"] = i * 1000 + np.arange(10) * 100
        yield batch


@pytest.mark.parametrize("max_lag_us", [2_000, 50_000])
def test_a_source_that_waits_loses_nothing_to_a_slow_pipeline(max_lag_us):
    pipeline = _SlowPipeline()
    runtime = Engine(
        RunParts(_batches(300), pipeline),
        load_profile("default"),
        [_Recorder()],
        RunOptions(mode=RunMode.PACED_WAITING, max_lag_us=max_lag_us),
    )
    stats = runtime.run()
    assert stats.dropped_items == 0 and stats.dropped_events == 0
    assert pipeline.events == stats.events == 3000


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


def test_the_pipeline_s_groups_share_out_its_kernels_the_per_event_ones_first():
    """The tracker's group (compiled first, at full priority) and the rest (in the background)
    hold every kernel of the pipeline's package once; the paper's method's rest is the same."""
    tracker, rest = warmup.PIPELINE_OF["default"]
    everything = warmup.kernels(warmup.KernelGroup("all", tracker.imports, tracker.packages, tracker.warm))
    first, second = warmup.kernels(tracker), warmup.kernels(rest)
    assert set(first) == set(warmup.TRACKER_KERNELS) and not set(first) & set(second)
    assert set(first) | set(second) == set(everything)
    assert set(warmup.kernels(warmup.PIPELINE_OF["paper"][1])) == set(second)
    assert rest.background and not tracker.background and not warmup.SIMULATOR.background


@pytest.mark.parametrize("interpreted", [True, False], ids=["run-goes-on", "run-waits"])
def test_a_background_group_s_child_starts_once_the_others_are_compiled(interpreted, monkeypatch):
    """While the run goes on, the simulator's and the tracker's children have both cores and the
    rest's starts after them; a run that waits for every group (the camera) starts all at once."""
    run = warmup.Warmup([warmup.SIMULATOR, *warmup.PIPELINE_OF["default"]], say=lambda line: None)
    run._interpreted = interpreted
    started: list[tuple[str, dict[str, str]]] = []

    def command(group):
        started.append((group.name, {name: p.state for name, p in run.progress.items()}))
        # a child that compiles nothing, successfully; the first ones take a while
        return [sys.executable, "-c", "pass" if group.background else "import time; time.sleep(3)"]

    monkeypatch.setattr(warmup, "cached_signatures", lambda dispatcher: [])
    user_cache = warmup.jit_cache.JitCache(warmup.jit_cache.USER_CACHE, None)
    monkeypatch.setattr(warmup.jit_cache, "chosen", lambda: user_cache)
    monkeypatch.setattr(warmup, "child_command", command)
    run.start()
    try:
        assert run.wait(60)
    finally:
        run.close()
    pipeline = next(states for name, states in started if name == "pipeline")
    others = {"simulator": pipeline["simulator"], "tracker": pipeline["tracker"]}
    assert others == (
        {"simulator": "ready", "tracker": "ready"} if interpreted else {"simulator": "cold", "tracker": "cold"}
    )


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


def test_a_run_that_cannot_wait_compiles_in_the_children_before_it_starts(monkeypatch):
    """The camera and ``--fast``: the same children (both cores), nothing interpreted, and
    :meth:`Warmup.start` returns once every group is compiled; a failed child is compiled here."""
    import neurotouch_hid.pipeline.tracker_kernels as kernels

    track = warmup.kernels(warmup.TRACKER)["neurotouch_hid.pipeline.tracker_kernels._track"]
    said: list[str] = []
    run = warmup.Warmup(list(warmup.PIPELINE_OF["default"]), say=said.append, interpreted=False)
    children: list[str] = []
    here: list[str] = []

    def child(group):
        children.append(group.name)
        assert kernels._track is track  # not interpreted meanwhile
        if group.name == "pipeline":
            run._failed(group, "the pipeline compile failed (a test)")
        else:
            run.progress[group.name].state = "ready"
            run._settled[group.name].set()

    def compile_here(group):
        here.append(group.name)
        run.progress[group.name].state = "ready"

    monkeypatch.setattr(warmup, "cached_signatures", lambda dispatcher: [])
    user_cache = warmup.jit_cache.JitCache(warmup.jit_cache.USER_CACHE, None)
    monkeypatch.setattr(warmup.jit_cache, "chosen", lambda: user_cache)
    monkeypatch.setattr(run, "_child", child)
    monkeypatch.setattr(run, "_compile_here", compile_here)
    run.start()
    assert sorted(children) == ["pipeline", "tracker"] and here == ["pipeline"]  # at once: nothing runs
    assert not run.compiling
    assert any("before the run starts" in line for line in said)
    assert any("compiling it in this process instead" in line for line in said)


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


@pytest.mark.parametrize("command", ["track", "enrol --from", "profile test"])
def test_a_command_that_runs_the_pipeline_at_once_has_a_cold_cache_compiled_by_the_children_and_says_so(
    command, sim_push_only_recording, tmp_path, monkeypatch, capsys
):
    """``track``, ``enrol --from`` and ``profile test`` (like ``calibrate`` and ``enrol``) cannot interpret the
    pipeline: on a cold cache they wait for the same children as a camera run (both cores), and
    say so on stderr before anything else, instead of compiling in this process in silence."""
    children: list[str] = []

    def child(run, group):
        children.append(group.name)
        run.progress[group.name].state = "ready"
        run._settled[group.name].set()

    monkeypatch.setattr(warmup, "cached_signatures", lambda dispatcher: [])  # every group cold
    user_cache = warmup.jit_cache.JitCache(warmup.jit_cache.USER_CACHE, None)
    monkeypatch.setattr(warmup.jit_cache, "chosen", lambda: user_cache)
    monkeypatch.setattr(warmup.Warmup, "_child", child)
    if command == "track":
        args = ["track", str(sim_push_only_recording), "--out", str(tmp_path / "p.jsonl")]
    elif command == "profile test":  # it compiled for 77 s on its first run without a word
        args = ["profile", "test", "default", "--source", str(sim_push_only_recording), "--seconds", "1"]
    else:
        plan = tmp_path / "plan.json"
        plan.write_text('{"prompts": [{"gesture": "push", "cue_s": 1.0, "seconds": 1.0}]}')
        args = ["enrol", "--from", str(sim_push_only_recording), "--plan", str(plan), "--out", str(tmp_path / "d")]
    done = run_main(monkeypatch, capsys, args)
    err = done.stderr
    assert done.returncode == 0, err
    assert sorted(children) == ["pipeline", "tracker"]
    assert err.startswith(f"{warmup.COMPILING}: before the run starts"), err


RELEASE_CHILD = """
import numba, numpy as np
from neurotouch_hid.service import jit_cache
from neurotouch_hid.pipeline.moves import _largest_move_sq
rng = np.random.default_rng(0)
current, rest = rng.normal(size=(40, 2)), rng.normal(size=(40, 2))
valid = np.ones(40, dtype=np.bool_)
before = _largest_move_sq(current, valid, rest)
(library,) = [result.library for result in _largest_move_sq.overloads.values()]
assert library._shared_module is not None
assert jit_cache.release_linking_modules([_largest_move_sq]) == 1
assert library._shared_module is None
assert jit_cache.release_linking_modules([_largest_move_sq]) == 0
assert _largest_move_sq(current, valid, rest) == before

@numba.njit
def twice(current, valid, rest):
    return 2.0 * _largest_move_sq(current, valid, rest)

assert twice(current, valid, rest) == 2.0 * before
assert library._shared_module is not None
print("loaded" if sum(_largest_move_sq.stats.cache_hits.values()) else "compiled")
"""


def test_released_linking_modules_leave_kernels_working_and_linkable(tmp_path):
    """After :func:`jit_cache.release_linking_modules` a kernel runs as before, and a compile
    that links it (a new kernel calling it) parses its module back from the kept bitcode: a
    kernel compiled here, then the same loaded from numba's cache (whose library has no other
    module to link from)."""
    for expected in ("compiled", "loaded"):
        out = subprocess.run(
            [sys.executable, "-c", RELEASE_CHILD],
            capture_output=True,
            text=True,
            env=_env(tmp_path / "numba"),
            timeout=300,
        )
        assert out.returncode == 0, out.stderr[-2000:]
        assert out.stdout.strip() == expected


def test_a_warm_group_s_linking_modules_are_freed_as_it_is_loaded_before_the_next_loads(monkeypatch):
    """On a warm cache each group's linking modules are freed right after its own load and before
    the next group loads (so that the start never holds two groups' modules: its peak memory),
    not seconds after the last."""
    seen: list[tuple[str, list]] = []
    found = {g.name: {f"{g.name}.k{i}": object() for i in range(3)} for g in warmup.PIPELINE_OF["default"]}
    monkeypatch.setattr(warmup, "kernels", lambda group: found[group.name])
    monkeypatch.setattr(warmup, "cached_signatures", lambda dispatcher: ["(float64,)"])
    monkeypatch.setattr(warmup, "_call", lambda where: seen.append(("load", [where])))
    released = lambda dispatchers: seen.append(("release", list(dispatchers))) or 0  # noqa: E731
    monkeypatch.setattr(warmup.jit_cache, "release_linking_modules", released)
    run = warmup.Warmup(list(warmup.PIPELINE_OF["default"]), say=lambda line: None, interpreted=False)
    try:
        run.start()
    finally:
        run.close()
    tracker, pipeline = warmup.PIPELINE_OF["default"]
    assert seen[:4] == [
        ("load", [tracker.warm]),
        ("release", list(found["tracker"].values())),
        ("load", [pipeline.warm]),
        ("release", list(found["pipeline"].values())),
    ], seen
    assert not run.compiling


@pytest.mark.parametrize("lines", [True, False])
def test_a_compile_seen_in_a_log_says_how_far_it_is_at_each_quarter(lines):
    """Without a terminal (a service's journal, a pipe) no progress bar shows: the compile says
    its progress at 25, 50 and 75 %, once each, whichever child's kernel passes it."""
    said: list[str] = []
    run = warmup.Warmup([warmup.TRACKER, warmup.PIPELINE], say=said.append, lines=lines)
    run.progress = {"tracker": warmup.GroupProgress("tracker", 4), "pipeline": warmup.GroupProgress("pipeline", 8)}
    for k in range(8):
        for name in ("tracker", "pipeline") if k < 4 else ("pipeline",):
            run.progress[name].add(f"kernel{k}")
            run._progressed()
    assert [line.split(": ")[1].split(",")[0] for line in said] == (["25%", "50%", "75%"] if lines else [])


def test_a_stop_while_the_run_waits_for_its_compile_stops_the_children(monkeypatch):
    """A SIGTERM while a run that cannot wait (the camera, ``--fast``) waits for its compile raises
    in :meth:`Warmup.start`, before the run has its :meth:`Warmup.close`: the children compiled on
    (80 MB each; in the test kernel three stopped first runs left six, and the guest ran out of
    memory). They are stopped on the way out."""
    from neurotouch_hid.engine.stopping import StopRequested

    run = warmup.Warmup(list(warmup.PIPELINE_OF["default"]), say=lambda line: None, interpreted=False)
    started = []

    def child(group):  # a compile that takes its time, as under emulation
        proc = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(120)"])
        run._children.append(proc)
        started.append(proc)
        proc.wait()

    def stopped(timeout=None):  # the SIGTERM's StopRequested, raised in the wait
        while len(started) < len(run._threads):
            time.sleep(0.01)
        raise StopRequested()

    monkeypatch.setattr(warmup, "cached_signatures", lambda dispatcher: [])
    user_cache = warmup.jit_cache.JitCache(warmup.jit_cache.USER_CACHE, None)
    monkeypatch.setattr(warmup.jit_cache, "chosen", lambda: user_cache)
    monkeypatch.setattr(run, "_child", child)
    monkeypatch.setattr(run, "wait", stopped)
    try:
        with pytest.raises(StopRequested):
            run.start()
        assert started and all(proc.poll() is not None for proc in started)  # stopped, and reaped
    finally:
        for proc in started:
            proc.kill()
            proc.wait()
