"""Property-based fuzzing (hypothesis) of every loader of outside input: the recording reader,
profiles, sensor.yaml, games.yaml, ``--set``, the control protocol and the control socket itself
(a real server, bytes on its socket). Each input gives a result or the one
error of its kind with a short message, never another exception (docs/limits.md). A short run
here; benchmarks/fuzz_inputs.py runs the same targets long and reports the counts."""

from __future__ import annotations

import tempfile
from pathlib import Path

import hostile_inputs as targets
import pytest
from hypothesis import HealthCheck, given, settings

STRATEGIES = targets.strategies()
#: No deadline (a loaded machine must not make a test flaky); few examples (the long run is the
#: benchmark's).
SHORT = settings(
    max_examples=60,
    deadline=None,
    database=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
)


@pytest.mark.parametrize(
    "name, target",
    [("profile", targets.fuzz_profile), ("set", targets.fuzz_set), ("control", targets.fuzz_control)],
    ids=["profile-loader", "set-conversion", "control-protocol"],
)
def test_loader(name, target):
    SHORT(given(STRATEGIES[name])(target))()


@SHORT
@given(STRATEGIES["sensor"])
def test_sensor_loader(text):
    with tempfile.TemporaryDirectory() as folder:
        targets.fuzz_sensor(text, Path(folder))


@SHORT
@given(STRATEGIES["games"])
def test_games_loader(text):
    with tempfile.TemporaryDirectory() as folder:
        targets.fuzz_games(text, Path(folder))


def test_control_socket():
    """A real server: each input sent on its socket, then a valid request still answered."""
    with tempfile.TemporaryDirectory() as folder:
        server = targets.control_server(Path(folder))
        try:
            settings(SHORT, max_examples=40)(
                given(STRATEGIES["socket"])(lambda data: targets.fuzz_control_socket(server.path, data))
            )()
        finally:
            server.stop()


@pytest.fixture(scope="module")
def recordings(tmp_path_factory):
    folder = tmp_path_factory.mktemp("fuzz-recordings")
    return {c: targets.small_recording(folder, c) for c in ("LZ4", "ZSTD", "NONE")}


@settings(SHORT, max_examples=30)
@given(STRATEGIES["recording"])
def test_recording_reader(recordings, case):
    compression, edits, cut = case
    with tempfile.TemporaryDirectory() as folder:
        targets.fuzz_recording(recordings[compression], edits, cut, Path(folder))
