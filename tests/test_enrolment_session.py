"""The guided enrolment (``enrol``, neurotouch_hid/enrolment/session.py): the prompts shown, a
prompt not performed asked again, the labelled dataset written where it says.

The simulated hand performs a short plan of three prompts (``--plan``); ``--sim-miss N`` makes it
miss the N-th prompt asked."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
import time
import uuid
from pathlib import Path

import pytest
from helpers import run_cli
from kernel.vm import installed

from neurotouch_hid.core.dataset import list_sequences, read_labels
from neurotouch_hid.core.estimate import GestureType
from neurotouch_hid.enrolment.plan import Plan, Prompt, Script, read_plan, write_plan

PLAN = Plan(
    (
        Prompt(GestureType.PUSH, 2.0, 1.5, "up"),
        Prompt(GestureType.PINCH, 6.5, 0.4),
        Prompt(GestureType.TWIST_CW, 10.0, 1.5),
    )
)


class ScriptView:
    """A view of the session's script, as the prompt view reads it: what it would show at each
    record (the number of prompts, s from the stream's start, the notes); sets ``stop`` (Ctrl-C)
    once the record's time reaches ``stop_at_s``."""

    wants_markers = False

    def __init__(self, script: Script, stop_at_s: float | None = None, stop=None):
        self.script = script
        self.stop_at_s = stop_at_s
        self.stop = stop
        self.shown: list[tuple[int, float, list[str]]] = []

    def publish(self, record) -> None:
        t_s = (record.estimate.t_us - self.script.start_us) * 1e-6
        self.shown.append((len(self.script.prompts()), t_s, list(self.script.notes())))
        if self.stop_at_s is not None and t_s >= self.stop_at_s:
            self.stop.set()

    def neutralise(self) -> None:
        pass

    def prepare(self, profile) -> None:
        pass


def _runs(labels) -> list[GestureType]:
    kinds = [r.gesture for r in labels]
    return [k for i, k in enumerate(kinds) if k is not GestureType.NONE and (i == 0 or kinds[i - 1] is not k)]


def test_a_prompt_missed_twice_is_said_and_left_out_and_the_dataset_goes_to_the_data_folder(tmp_path):
    plan = write_plan(PLAN, tmp_path / "short.json")
    data = tmp_path / "data"
    result = run_cli(
        "enrol", "--source", "sim", "--plan", str(plan), "--fast", "--seed", "3", "--sim-miss", "2", "--sim-miss", "4",
        env={"XDG_DATA_HOME": str(data)},
    )  # fmt: skip
    assert result.returncode == 0, result.stderr
    lines = result.stdout.splitlines()
    folders = list((data / "neurotouch-hid" / "enrolments").iterdir())
    assert len(folders) == 1
    folder = folders[0]
    assert "0:02 prompt 1 of 3: push the gel up (away from you), hold 1.5 s, then let go" in lines
    assert any(line.startswith("prompt 2 (pinch): no gesture seen: asked again at 0:") for line in lines)
    assert "prompt 4 (pinch): no gesture seen when asked again: left out" in lines
    assert any(
        line.startswith("prompt 2 (pinch at 0:06): not seen; asked again as prompt 4 (pinch at 0:")
        and line.endswith("): not seen either: left out")
        for line in lines
    )
    assert any(line.startswith(f"labelled 2 of 4 prompts -> {folder} ") for line in lines)
    # the simulated hand's enrolment is adapted only into a file of its own, never as the user's model
    assert f"`neurotouch-hid adapt {folder} --out sim-model.yaml`" in result.stdout
    # the folder is a dataset eval reads, labelled from the prompts asked
    assert list_sequences(folder) == ["enrolment"]
    asked = read_plan(folder / "enrolment.plan.json")
    assert [p.gesture for p in asked.prompts] == [GestureType.PUSH, GestureType.PINCH, GestureType.TWIST_CW,
                                                  GestureType.PINCH]  # fmt: skip
    assert _runs(read_labels(folder / "enrolment.labels.csv")) == [GestureType.PUSH, GestureType.TWIST_CW]
    assert not [name for name in os.listdir(folder) if name.startswith(".")]  # no temporary file left


def test_a_bad_source_or_plan_is_one_clear_line(tmp_path):
    result = run_cli("enrol", "--source", "camera2")
    assert result.returncode == 2 and "--source 'camera2': expected davis" in result.stderr
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({"prompts": [{"gesture": "push", "cue_s": 1}]}))
    result = run_cli("enrol", "--source", "sim", "--plan", str(bad), "--out", str(tmp_path / "x"))
    assert result.returncode == 2
    assert f"{bad}: prompt 1: field 'seconds' is missing" in result.stderr
    assert "Traceback" not in result.stderr and not (tmp_path / "x").exists()


def _tmux() -> str:
    found = installed("tmux", "tmux")
    if found is None:
        pytest.skip(reason="tmux is not installed and cannot be apt-installed here (needs root and apt-get)")
    return found


def test_the_prompts_show_in_a_real_80x24_terminal(tmp_path):
    tmux = _tmux()
    plan = write_plan(PLAN, tmp_path / "short.json")
    out = tmp_path / "enrolment"
    session = f"nt-enrol-{uuid.uuid4().hex[:8]}"
    env = {
        "PYTHONPATH": os.pathsep.join(sys.path),
        "XDG_CONFIG_HOME": os.environ.get("XDG_CONFIG_HOME", str(tmp_path / "config")),
        "TERM": "xterm-256color",
    }
    command = " ".join(f"{k}={v}" for k, v in env.items())
    command += f" {sys.executable} -m neurotouch_hid.cli enrol --source sim --plan {plan} --out {out} --seed 3"
    command += " --sim-miss 2; sleep 60"
    go, drawn = tmp_path / "go", tmp_path / "drawn"  # the enrolment starts once everything it draws is logged
    command = f"while [ ! -e {go} ]; do sleep 0.05; done; {command}"
    subprocess.run([tmux, "new-session", "-d", "-s", session, "-x", "80", "-y", "24", command], check=True)
    screens: list[str] = []
    try:
        subprocess.run([tmux, "pipe-pane", "-t", session, f"cat >> {drawn}"], check=True)
        go.touch()
        for _ in range(1200):  # a hang ends the test, a slow machine does not
            time.sleep(0.25)
            screen = subprocess.run([tmux, "capture-pane", "-p", "-t", session], capture_output=True, text=True).stdout
            screens.append(screen)
            if "labelled" in screen or "Traceback" in screen:
                break
    finally:
        subprocess.run([tmux, "kill-session", "-t", session], capture_output=True)
    # what was drawn, its escape sequences taken out: a prompt shown for less than a screen
    # capture's period on a loaded machine is in it even when no capture caught it
    escapes = r"\x1b(\[[0-9;?]*[ -/]*[@-~]|[()][0-9A-Za-z]|[=>78])"
    ever = re.sub(escapes, "", drawn.read_bytes().decode(errors="replace"))
    shown = "\n".join(screens)
    assert "Traceback" not in shown
    assert all(len(s.splitlines()) <= 24 and all(len(line) <= 80 for line in s.splitlines()) for s in screens)
    assert "enrol: teach the driver your gel and your hand" in shown
    assert "NOW  " in shown  # a prompt seen on the screen itself
    for prompt in PLAN.prompts:  # each prompt, what to do and for how long, counted down
        assert f"NOW  {prompt.what()}" in ever
        assert f"{prompt.how()}, then let go" in ever
        assert f"GET READY in 1: {prompt.what()}" in ever or f"GET READY in 2: {prompt.what()}" in ever
    assert "prompt 2 (pinch): no gesture seen: asked again at 0:" in shown
    assert "prompt 4 of 4" in shown  # the pinch asked again
    last = screens[-1]
    assert "prompt 2 (pinch at 0:06): not seen; asked again as prompt 4 (pinch at 0:" in last.replace("\n", "")
    assert "): seen" in last.replace("\n", "")
    assert f"labelled 3 of 4 prompts -> {out}" in last.replace("\n", "")
    assert _runs(read_labels(Path(out) / "enrolment.labels.csv")) == [
        GestureType.PUSH, GestureType.TWIST_CW, GestureType.PINCH,
    ]  # fmt: skip


def test_a_person_at_the_camera_follows_the_prompts_and_is_labelled(tmp_path):
    """The live camera's path (the real DavisSource, its capture backend replaying a recording of a
    person following the plan, ``tests/camera_replay.py``, on a clock that moves when the source
    waits, so that a loaded machine sees the same): every prompt is seen and labelled, and nothing
    is asked again."""
    from camera_replay import ManualClock, ReplayWorld

    from neurotouch_hid.core.sensor import SensorGeometry
    from neurotouch_hid.enrolment.hand import simulate_enrolment
    from neurotouch_hid.enrolment.session import CameraSource, run_session
    from neurotouch_hid.pipeline.pipeline import GesturePipeline
    from neurotouch_hid.sources.davis import DavisConfig

    person = tmp_path / "person"
    simulate_enrolment(PLAN, person, seed=5, miss_rate=0.0, tail_s=3.0)
    sensor = SensorGeometry.load(person / "sensor.yaml")
    GesturePipeline(sensor).compile_kernels()  # as enrol does before the camera opens
    script = Script(PLAN)
    view = ScriptView(script)
    world = ReplayWorld(person / "enrolment.aedat4", clock=ManualClock())
    with CameraSource(DavisConfig(), backend=world, **world.source_clock()) as camera:
        result = run_session(script, camera, tmp_path / "out", sensor, [view])
    assert not result.asked_again and not result.not_seen and not result.stopped
    assert view.shown and all(n == 3 and not notes for n, _, notes in view.shown)
    assert _runs(read_labels(tmp_path / "out" / "enrolment.labels.csv")) == [p.gesture for p in PLAN.prompts]


def test_a_session_stopped_early_keeps_its_recording_and_labels_what_was_asked(tmp_path):
    """Ctrl-C (the stop event) during the second prompt: the recording is complete, the prompts
    cued so far are labelled, nothing is left half-written."""
    import threading

    from neurotouch_hid.enrolment.session import SimulatedHandSource, run_session
    from neurotouch_hid.sources.recording import read_info

    source = SimulatedHandSource(3, miss_rate=0.0)
    stop = threading.Event()
    script = Script(PLAN)
    view = ScriptView(script, stop_at_s=PLAN.prompts[1].cue_s + 1.0, stop=stop)
    result = run_session(script, source, tmp_path, source.sensor, [view], stop=stop)
    assert result.stopped
    assert [f.prompt for f in result.labelled.found] == list(PLAN.prompts[:2])
    assert read_info(tmp_path / "enrolment.aedat4").n_frames > 0
    assert read_plan(tmp_path / "enrolment.plan.json") == Plan(PLAN.prompts[:2])
    assert _runs(read_labels(tmp_path / "enrolment.labels.csv"))[:1] == [GestureType.PUSH]
    assert sorted(os.listdir(tmp_path)) == [
        "enrolment.aedat4", "enrolment.labels.csv", "enrolment.plan.json", "sensor.yaml",
    ]  # fmt: skip


def test_a_sessions_labels_are_those_enrol_from_gives_on_its_recording(tmp_path):
    """The session labels its recording as ``enrol --from`` does: the same recording and the
    prompts asked give the same labels, byte for byte."""
    from neurotouch_hid.enrolment.label import label_recording
    from neurotouch_hid.enrolment.session import SimulatedHandSource, run_session

    plan = Plan(PLAN.prompts[:2])
    source = SimulatedHandSource(3, miss_rate=0.0)
    session = tmp_path / "session"
    result = run_session(Script(plan), source, session, source.sensor, [])
    assert not result.stopped and not result.not_seen
    asked = read_plan(session / "enrolment.plan.json")
    assert asked == plan
    again = label_recording(session / "enrolment.aedat4", asked, tmp_path / "from", source.sensor)
    assert [f.seen for f in again.found] == [True, True]
    labels = (session / "enrolment.labels.csv").read_bytes()
    assert labels == (tmp_path / "from" / "enrolment.labels.csv").read_bytes()
    assert _runs(read_labels(session / "enrolment.labels.csv")) == [p.gesture for p in plan.prompts]
