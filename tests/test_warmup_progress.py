"""A first run on a cold numba cache as the user sees it (neurotouch_hid/service/warmup.py): the
progress said before the first state, a compile seen in a log saying how far it is, and a simulated
source that waits instead of dropping data."""

from __future__ import annotations

import subprocess
import sys
import time

import numpy as np
import pytest
from warmup_helpers import _env

from neurotouch_hid.core.estimate import GestureEstimate
from neurotouch_hid.engine.engine import Engine, RunParts
from neurotouch_hid.engine.mode import RunMode, RunOptions
from neurotouch_hid.mapping.profile import load_profile
from neurotouch_hid.service import warmup
from neurotouch_hid.sources import EVENT_DTYPE

CLI = [sys.executable, "-m", "neurotouch_hid.cli"]


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
