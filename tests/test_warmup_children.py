"""The children that compile a cold numba cache (neurotouch_hid/service/warmup.py): a group cold until
its child compiled it, the paper pipeline's child (started at the session's start: conftest.py,
``started_early``), the installed package compiled at a lower priority, the groups shared out, a run
or a command that cannot wait, and a stop while it waits."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

import pytest
from helpers import EARLY_NICE, niced, reap, run_main
from warmup_helpers import _env

from neurotouch_hid.service import warmup


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
