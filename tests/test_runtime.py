"""The runtime's real stages end to end, through the CLI (simulated gel -> pipeline -> default profile
-> JSON lines): a push moves the stick and the run ends neutral, SIGTERM, the demo without uinput,
a bad profile, deterministic fast replays, a predictions file replayed through the mapper."""

from __future__ import annotations

# --- the real stages, through the CLI -----------------------------------------------------------
import json  # noqa: E402
import os
import signal
import subprocess  # noqa: E402
import sys  # noqa: E402

import numpy as np
import pytest
from helpers import read_states, run_cli

from neurotouch_hid.core.controller import ControllerState
from neurotouch_hid.core.errors import ProfileError
from neurotouch_hid.core.estimate import GestureEstimate, GestureType

CLI = [sys.executable, "-c", "from neurotouch_hid.cli import main; main()"]


ENV = dict(os.environ, PYTHONUNBUFFERED="1", COLUMNS="160")


def is_neutral(line: dict) -> bool:
    from neurotouch_hid.core.controller import AXES

    return all(line["axes"][n] == AXES[n][2] for n in AXES) and not any(line["buttons"].values())


def test_run_on_a_recording_moves_the_stick_during_the_push_and_ends_neutral(sim_push_only_recording, tmp_path):
    out = tmp_path / "states.jsonl"
    proc = run_cli(
        "run", "--source", str(sim_push_only_recording), "--output", "jsonl", "--fast", "--out", str(out), columns=160
    )
    assert proc.returncode == 0, proc.stderr
    states = read_states(out.read_text())
    pushes = [s for s in states if s["gesture"] == "push"]
    assert pushes, "no push recognised"
    # the default profile puts a push on the left stick
    assert any(abs(s["axes"]["ABS_X"]) + abs(s["axes"]["ABS_Y"]) > 3000 for s in pushes)
    # after the release the pipeline itself brings the stick back (before the final neutralise)
    assert is_neutral(states[-2]) and is_neutral(states[-1])
    assert [s["t_us"] for s in states] == sorted(s["t_us"] for s in states)
    assert "dropped 0 items" in proc.stderr  # --fast drops nothing


def test_sigterm_ends_a_live_run_with_a_neutral_state_and_exit_0():
    proc = subprocess.Popen(
        [*CLI, "run", "--source", "sim", "--output", "jsonl"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=ENV,
    )
    try:
        lines = []
        for line in proc.stdout:  # wait for the first gesture moving the pad
            lines.append(json.loads(line))
            if not is_neutral(lines[-1]):
                break
        assert lines and not is_neutral(lines[-1]), proc.stderr.read() if proc.poll() is not None else ""
        proc.send_signal(signal.SIGTERM)
        rest, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0, err
    final = read_states(rest)
    assert final and is_neutral(final[-1])


def test_demo_without_uinput_shows_the_terminal_view_and_says_why(tmp_path):
    if os.access("/dev/uinput", os.W_OK):
        pytest.skip(reason="/dev/uinput is writable here: the demo uses the real gamepad")
    proc = run_cli("demo", "--seconds", "3", columns=160)
    assert proc.returncode == 0, proc.stderr
    assert "no writable /dev/uinput (" in proc.stderr
    assert "showing the gamepad in the terminal instead; see `neurotouch-hid doctor`" in proc.stderr
    # no TTY: plain state lines, not escape codes
    assert "\x1b[" not in proc.stdout
    lines = [line for line in proc.stdout.splitlines() if line.strip()]
    assert lines and all(line.startswith("t ") and "L(" in line for line in lines)


def test_a_bad_profile_raises_before_any_output_or_source_exists(tmp_path, monkeypatch):
    import neurotouch_hid.engine.assembly as assembly
    import neurotouch_hid.engine.driver as driver

    opened = []
    monkeypatch.setattr(driver, "open_output", lambda *a, **k: opened.append("output"))
    monkeypatch.setattr(assembly, "open_source", lambda *a, **k: opened.append("source"))
    bad = tmp_path / "bad.yaml"
    bad.write_text("mappings:\n  push: {input: nonsense, output: left_stick}\n")
    with pytest.raises(ProfileError, match="bad.yaml"):
        driver.run_driver("sim", bad, "gamepad")
    assert opened == []


def test_fast_replays_are_deterministic(sim_push_only_recording, tmp_path):
    from neurotouch_hid.engine.driver import DriverOptions, run_driver

    runs = []
    for k in range(2):
        out = tmp_path / f"states{k}.jsonl"
        stats = run_driver(str(sim_push_only_recording), "default", "jsonl", DriverOptions(fast=True, out=out))
        assert stats.dropped_items == 0 and stats.windows > 0
        runs.append(out.read_text())
    assert runs[0] == runs[1] and runs[0]


def test_a_predictions_file_replays_through_the_mapper_state_for_state(tmp_path):
    """``--source FILE.jsonl`` (no pipeline): the states written are the Mapper's for the same
    estimates, one line per change, ending neutral."""
    from neurotouch_hid.core.dataset import read_predictions, write_predictions
    from neurotouch_hid.engine.driver import DriverOptions, run_driver
    from neurotouch_hid.mapping.profile import load_profile
    from neurotouch_hid.mapping.replay import replay

    estimates = []
    for k in range(120):
        level = 6.0 * np.sin(np.pi * k / 119)  # a push ramping up and back down
        estimates.append(
            GestureEstimate(
                t_us=1_000_000 + 10_000 * k,
                gesture=GestureType.PUSH,
                resting=False,
                intensity_mm=level,
                translation_mm=np.array([level, 0.0]),
            )
        )
    estimates += [GestureEstimate(t_us=2_200_000 + 10_000 * k) for k in range(20)]
    preds = tmp_path / "p.jsonl"
    write_predictions(preds, estimates)
    out = tmp_path / "states.jsonl"
    stats = run_driver(str(preds), "default", "jsonl", DriverOptions(fast=True, out=out))
    got = [(d["axes"], d["buttons"]) for d in read_states(out.read_text())]
    neutral = (ControllerState.neutral().axes, ControllerState.neutral().buttons)
    expected = [neutral]  # the runtime starts from the neutral state and writes changes only
    for s in replay(load_profile("default"), read_predictions(preds)):  # as stored (rounded)
        if expected[-1] != (s.axes, s.buttons):
            expected.append((s.axes, s.buttons))
    assert got[-1] == neutral  # the final neutralise
    # JSON lines are also written when only the gesture changes: compare the state changes
    changes = [neutral]
    for g in got:
        if changes[-1] != g:
            changes.append(g)
    assert changes == expected
    assert stats.windows == len(estimates) and stats.events == 0
    assert any(a["ABS_X"] > 0 for a, _ in got)


def test_the_run_s_pipeline_runs_opencv_without_its_thread_pool():
    """A run's pipeline calls OpenCV on one APS frame or a few hundred points at a time: its
    pool's thread, woken at every call, cost more than it shared out (25 times a second at rest)."""
    import cv2

    from neurotouch_hid.core.sensor import SensorGeometry
    from neurotouch_hid.engine.assembly import build_pipeline

    previous = cv2.getNumThreads()
    cv2.setNumThreads(2)
    try:
        build_pipeline(SensorGeometry(), 10_000)
        assert cv2.getNumThreads() == 1
    finally:
        cv2.setNumThreads(previous)
