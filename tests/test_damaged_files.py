"""Damaged files (property-based, hypothesis): reading one always ends, with a clear error or
with what was readable; never a hang, a crash or a traceback.

Recordings: copies of a DAVIS-346 street recording, the real one where it is and a simulated one
(LZ4), and of a simulated gel recording (ZSTD), with 1-32 flipped bits, cut short, or with two
neighbouring packets swapped, read by ``info`` and ``track`` in a subprocess with a time limit (a
hang fails the test, a crash shows as a negative exit code), and through RecordingReader in this
process. Profiles: mutated YAML (characters changed, lines dropped or repeated, values replaced)
through ``profile validate`` and load_profile: one error naming the file, the line and the field,
never a traceback.
"""

from __future__ import annotations

import subprocess
import tempfile
from pathlib import Path

import numpy as np
import pytest
from helpers import STREET, run_cli
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from recording_damage import damage

from neurotouch_hid.core.errors import ProfileError, RecordingError
from neurotouch_hid.mapping.profile import load_profile, shipped_profiles_dir
from neurotouch_hid.sources import Frame
from neurotouch_hid.sources.recording import RecordingReader
from neurotouch_hid.sources.recording_writer import RecordingWriter
from neurotouch_hid.sources.simulator import SimulatedSource

TIME_LIMIT_S = 120  # a hang, not a slow machine: reading these files takes a few seconds


@pytest.fixture(scope="module")
def originals(sim_street_recording, tmp_path_factory) -> dict[str, bytes]:
    """The undamaged files: the real street recording where it is, the simulated street (LZ4)
    and 1 s of the simulated gel (ZSTD)."""
    gel = tmp_path_factory.mktemp("gel") / "gel.aedat4"
    with RecordingWriter(gel, compression="ZSTD") as writer:
        for item in SimulatedSource(seed=3).stream(seconds=1.0, batch_us=10_000):
            writer.write_frame(item) if isinstance(item, Frame) else writer.write_events(item)
    found = {"gel": gel.read_bytes(), "simulated street": sim_street_recording.path.read_bytes()}
    if STREET.exists():
        found["street"] = STREET.read_bytes()
    return found


damages = st.tuples(st.sampled_from(["flip", "flip", "cut", "swap"]), st.integers(0, 2**32))
settings_subprocess = settings(
    max_examples=12, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.function_scoped_fixture]
)


@settings_subprocess
@given(
    base=st.sampled_from(["street", "simulated street", "gel"]),
    command=st.sampled_from(["info", "track"]),
    what=damages,
)
def test_damaged_recording_cli_ends_cleanly(originals, base, command, what):
    """`info` / `track` on a damaged copy: exit 0 or 2, one clear error line, no traceback,
    within the time limit (dv-processing 2.0 hung for ever in LZ4, or crashed, on such files)."""
    if base not in originals:  # no real street recording here
        base = "simulated street"
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / f"damaged-{base.replace(' ', '-')}.aedat4"
        path.write_bytes(damage(originals[base], *what))
        args = [command, str(path)] + (["--out", str(Path(tmp) / "pred.jsonl")] if command == "track" else [])
        try:
            result = run_cli(*args, timeout=TIME_LIMIT_S)
        except subprocess.TimeoutExpired:
            pytest.fail(f"{command} hung on {base} with damage {what}")
    assert result.returncode in (0, 2), f"{command} {base} {what}: exit {result.returncode}\n{result.stderr}"
    assert "Traceback" not in result.stderr, result.stderr
    if result.returncode == 2:
        errors = [line for line in result.stderr.splitlines() if line.startswith("error:")]
        assert len(errors) == 1 and str(path) in errors[0], result.stderr


@settings(
    max_examples=100, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(base=st.sampled_from(["street", "simulated street", "gel"]), what=damages)
def test_damaged_recording_reader_gives_valid_data_or_recording_error(originals, base, what):
    """In this process: RecordingReader raises nothing but RecordingError, and everything it
    yields before is what the pipeline may index with: in the sensor, time-ordered."""
    if base not in originals:  # no real street recording here
        base = "simulated street"
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "damaged.aedat4"
        path.write_bytes(damage(originals[base], *what))
        last_us = -1
        try:
            with RecordingReader(path) as reader:
                for item in reader.stream(batch_us=10_000):
                    if isinstance(item, Frame):
                        assert item.image.shape == (reader.height, reader.width) and item.image.dtype == np.uint8
                        continue
                    assert 0 <= item["x"].min() and item["x"].max() < reader.width
                    assert 0 <= item["y"].min() and item["y"].max() < reader.height
                    assert set(np.unique(item["polarity"]).tolist()) <= {0, 1}
                    assert item["timestamp"][0] >= last_us and np.all(np.diff(item["timestamp"]) >= 0)
                    last_us = int(item["timestamp"][-1])
        except RecordingError as exc:
            assert str(path) in str(exc) and "\n" not in str(exc)


# --- profiles ----------------------------------------------------------------------------------
SHIPPED = sorted(p.name for p in shipped_profiles_dir().glob("*.yaml"))


def mutate(text: str, edits: list[tuple[int, int, int]]) -> str:
    """Apply edits to a profile's text: (kind, position, value) with kind 0 = replace a character,
    1 = drop a line, 2 = repeat a line, 3 = replace a value after a colon, 4 = cut the file."""
    for kind, pos, value in edits:
        lines = text.splitlines(keepends=True)
        if kind == 0 and text:
            i = pos % len(text)
            text = text[:i] + chr(value % 0x250 or 10) + text[i + 1 :]
        elif kind == 1 and lines:
            del lines[pos % len(lines)]
            text = "".join(lines)
        elif kind == 2 and lines:
            i = pos % len(lines)
            text = "".join(lines[: i + 1] + lines[i:])
        elif kind == 3 and lines:
            i = pos % len(lines)
            key, colon, _ = lines[i].partition(":")
            replacement = ["-1", "1e309", "[]", "{}", "yes", "null", "'x'", "0x10", "&a [*a]", "!!binary 00"][
                value % 10
            ]
            lines[i] = f"{key}{colon} {replacement}\n" if colon else lines[i]
            text = "".join(lines)
        elif kind == 4:
            text = text[: pos % (len(text) + 1)]
    return text


edits = st.lists(st.tuples(st.integers(0, 4), st.integers(0, 10**6), st.integers(0, 10**6)), min_size=1, max_size=4)


def assert_clear(message: str, path: Path) -> None:
    assert path.name in message and "Traceback" not in message, message
    for line in message.splitlines()[1:]:  # each listed problem: file:line: field: ...
        assert line.strip().startswith(f"{path}:") or line.strip().startswith(f"{path.name}:"), message


@settings(
    max_examples=150, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(name=st.sampled_from(SHIPPED), changes=edits)
def test_mutated_profile_loads_or_gives_a_clear_error(tmp_path, name, changes):
    path = tmp_path / "mutated.yaml"
    path.write_text(mutate((shipped_profiles_dir() / name).read_text(encoding="utf-8"), changes), encoding="utf-8")
    try:
        load_profile(path)
    except ProfileError as exc:
        assert_clear(str(exc), path)


@settings(max_examples=8, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(name=st.sampled_from(SHIPPED), changes=edits)
def test_mutated_profile_validate_cli(tmp_path, name, changes):
    path = tmp_path / "mutated.yaml"
    path.write_bytes(
        mutate((shipped_profiles_dir() / name).read_text(encoding="utf-8"), changes).encode("utf-8", "replace")
    )
    result = run_cli("profile", "validate", str(path), timeout=TIME_LIMIT_S)
    assert result.returncode in (0, 2) and "Traceback" not in result.stderr, result.stderr
    if result.returncode == 2:
        assert result.stderr.startswith("error:") and str(path.name) in result.stderr, result.stderr


def test_track_writes_what_is_readable_of_a_cut_recording_before_its_error(sim_push_recording, tmp_path):
    """The progress total's pass meets the damage first; the windows before it are still
    tracked and written beside the output (``OUT.partial``, never in its place), then the one
    error (exit 2), which names both."""
    cut = tmp_path / "cut.aedat4"
    cut.write_bytes(sim_push_recording.read_bytes()[: int(sim_push_recording.stat().st_size * 0.7)])
    (tmp_path / "sensor.yaml").write_bytes((sim_push_recording.parent / "sensor.yaml").read_bytes())
    out = tmp_path / "pred.jsonl"
    proc = run_cli("track", str(cut), "--out", str(out))
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    assert str(cut) in proc.stderr
    partial = out.with_name(out.name + ".partial")
    assert not out.exists() and str(partial) in proc.stderr, proc.stderr
    assert len(partial.read_text().splitlines()) > 10
