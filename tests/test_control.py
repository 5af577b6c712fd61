"""``profile use``: the control socket between the CLI and a running driver (real Unix sockets,
the real runtime with small fakes for the pipeline and the output), and the runtime's handling of
the keyboard and mouse states (motion always written, keys compared)."""

from __future__ import annotations

import threading

import numpy as np
import pytest
from helpers import read_states, run_cli, wait_until
from runtime_fakes import FakeMapper, FakePipeline, RecordingOutput, endless, writes_of

from neurotouch_hid.core.errors import NeurotouchError, ProfileError
from neurotouch_hid.core.estimate import GestureEstimate, GestureType
from neurotouch_hid.engine.engine import Engine, RunParts
from neurotouch_hid.engine.mode import RunMode, RunOptions
from neurotouch_hid.service.control import ControlServer, request_use, socket_path
from neurotouch_hid.service.serve import served


@pytest.fixture
def runtime_dir(tmp_path, monkeypatch):
    folder = tmp_path / "run"
    folder.mkdir(mode=0o700)
    monkeypatch.setenv("XDG_RUNTIME_DIR", str(folder))
    return folder


def test_profile_use_without_a_driver_says_so_in_one_line_exit_2(runtime_dir):
    proc = run_cli("profile", "use", "mouse")
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "no neurotouch-hid driver is running" in lines[0] and "Traceback" not in proc.stderr
    proc = run_cli("profile", "use", "mouse", env={"XDG_RUNTIME_DIR": None})
    assert proc.returncode == 2 and "XDG_RUNTIME_DIR is not set" in proc.stderr


def test_a_stale_socket_file_counts_as_no_driver_and_is_replaced(runtime_dir):
    import socket

    stale = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    socket_path().parent.mkdir(mode=0o700)
    stale.bind(str(socket_path()))
    stale.close()  # the file stays, nobody listens
    with pytest.raises(NeurotouchError, match="no neurotouch-hid driver is running"):
        request_use("mouse")
    server = ControlServer(lambda ref: f"switched to {ref}")
    assert server.start()
    try:
        assert request_use("mouse") == "switched to mouse"
    finally:
        server.stop()
    assert not socket_path().exists()


def test_a_profile_name_over_the_request_bound_gets_the_drivers_refusal(runtime_dir):
    """The driver answers a request over its size bound and closes before the rest is sent: the
    CLI reads that answer instead of reporting the broken pipe."""
    server = ControlServer(lambda ref: f"switched to {ref}")
    assert server.start()
    try:
        with pytest.raises(NeurotouchError, match="request longer than 8192 bytes"):
            request_use("a" * 5_000_000)
        assert request_use("mouse") == "switched to mouse"
    finally:
        server.stop()


def test_a_second_driver_leaves_the_first_ones_socket_alone(runtime_dir):
    first, second = ControlServer(lambda ref: "first"), ControlServer(lambda ref: "second")
    assert first.start()
    try:
        assert not second.start()
        assert request_use("x") == "first"
    finally:
        second.stop()
        first.stop()


def test_profile_use_of_a_broken_profile_file_prints_why_and_asks_no_driver(runtime_dir, tmp_path):
    """``profile use ./broken.yaml`` answered only that it was invalid and to run ``profile
    validate``: the driver does not echo a file it was pointed at (it may be any file the driver
    can read). The command reads the file as its user first and prints the problem itself, line
    and field (docs/profiles.md: "prints why")."""
    asked = []
    server = ControlServer(lambda ref: asked.append(ref) or f"switched to {ref}")
    assert server.start()
    broken = tmp_path / "broken.yaml"
    broken.write_text("mappings:\n  push:\n    input: push\n    output: left_stick\n    deadzone_mm: lots\n")
    try:
        proc = run_cli("profile", "use", str(broken))
    finally:
        server.stop()
    assert proc.returncode == 2, proc
    assert f"{broken}:5: mappings.push.deadzone_mm" in " ".join(proc.stderr.split()), proc.stderr
    assert "Traceback" not in proc.stderr and asked == []


def test_profile_use_switches_a_running_runtime_outputs_neutral_first(runtime_dir):
    loads = []

    def loader(ref):
        loads.append(ref)
        if ref == "broken":
            raise ProfileError("profile broken.yaml is invalid (1 problem):\n  broken.yaml:2: ...")
        return {"sign": -1}

    out = RecordingOutput()
    rt = Engine(
        RunParts(endless(), FakePipeline(push_batches=10**9)),
        {"sign": 1},
        [out],
        RunOptions(mode=RunMode.PACED, mapper_factory=FakeMapper, profile_loader=loader),
    )
    answers: dict = {}

    def written_after_switch() -> int:
        calls = list(out.calls)
        kinds = [k for k, _ in calls]
        return len(writes_of(calls[kinds.index("neutralise") + 1 :])) if "neutralise" in kinds else 0

    def client():
        try:
            assert wait_for_socket(30.0)
            # act on what the runtime did, not after fixed delays a loaded machine can overrun
            assert wait_until(lambda: writes_of(list(out.calls)))
            with pytest.raises(NeurotouchError) as bad:
                request_use("broken")
            answers["bad"] = str(bad.value)
            answers["ok"] = request_use("mine")
            assert wait_until(lambda: written_after_switch() >= 3)
        finally:
            rt.stop()

    thread = threading.Thread(target=client)
    thread.start()
    with served(rt, None):
        rt.run()
    thread.join(10)
    assert "broken.yaml:2" in answers["bad"] and answers["ok"] == "switched to profile mine"
    assert loads == ["broken", "mine"] and rt.profile == {"sign": -1}
    kinds = [k for k, _ in out.calls]
    i = kinds.index("neutralise")
    before, after = writes_of(out.calls[:i]), writes_of(out.calls[i + 1 :])
    assert before and after and all(s.axes["ABS_X"] > 0 for s in before) and all(s.axes["ABS_X"] < 0 for s in after)
    assert not socket_path().exists()  # removed when the run ended


def wait_for_socket(timeout_s: float = 5.0) -> bool:
    return wait_until(lambda: socket_path().exists(), timeout_s)


def test_mouse_profile_run_writes_every_motion_and_ends_neutral(tmp_path, runtime_dir):
    """``run --profile mouse --output jsonl`` on a push: one line per window with motion, the
    pointer moving right and up, the last line neutral with no motion."""
    from neurotouch_hid.core.dataset import write_predictions
    from neurotouch_hid.engine.driver import DriverOptions, run_driver

    estimates = [
        GestureEstimate(
            t_us=1_000_000 + 10_000 * k,
            gesture=GestureType.PUSH,
            resting=False,
            intensity_mm=6.0,
            translation_mm=np.array([3.0, 3.0]),
        )
        for k in range(50)
    ]
    estimates += [GestureEstimate(t_us=1_500_000 + 10_000 * k) for k in range(10)]
    preds = tmp_path / "p.jsonl"
    write_predictions(preds, estimates)
    out = tmp_path / "states.jsonl"
    run_driver(str(preds), "mouse", "jsonl", DriverOptions(fast=True, out=out))
    lines = read_states(out.read_text())
    moving = [d for d in lines if d["rel"]]
    assert len(moving) > 30
    assert sum(d["rel"].get("REL_X", 0) for d in lines) > 100 and sum(d["rel"].get("REL_Y", 0) for d in lines) < -100
    assert lines[-1]["rel"] == {} and lines[-1]["keys"] == []
