"""The bounded reader's one translation of a failed read into a user's error line
(``limits.read_outside_text``), as every reader of a file from outside tells it."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from neurotouch_hid.core.dataset import read_labels, read_predictions
from neurotouch_hid.core.errors import DatasetError, ProfileError, SensorError
from neurotouch_hid.core.limits import read_outside_text
from neurotouch_hid.core.sensor import SensorGeometry
from neurotouch_hid.enrolment.model import ModelError, load_model
from neurotouch_hid.enrolment.plan import read_plan
from neurotouch_hid.mapping.profile import read_profile_text
from neurotouch_hid.service.games import GameMapError, load_game_map

#: Every reader of an outside file: (its name, the function, the error it raises, the kind of
#: file its messages name, its size bound in bytes).
READERS = [
    ("plan", read_plan, DatasetError, "session plan", 1 << 20),
    ("model", load_model, ModelError, "model file", 64 * 1024),
    ("sensor", SensorGeometry.load, SensorError, "sensor file", 256 * 1024),
    ("labels", read_labels, DatasetError, "labels file", 1 << 30),
    ("predictions", read_predictions, DatasetError, "predictions file", 1 << 30),
    ("games", load_game_map, GameMapError, "games file", 256 * 1024),
    ("profile", read_profile_text, ProfileError, "profile", 256 * 1024),
]


def _bad_files(tmp_path: Path, max_bytes: int) -> dict[str, tuple[Path, str]]:
    """A file for each way a read fails, and what its message must say."""
    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)
    huge = tmp_path / "huge"
    with open(huge, "wb") as fh:  # sparse: its size says too large before a byte is read
        fh.truncate(max_bytes + 1)
    binary = tmp_path / "binary"
    binary.write_bytes(b"\xff\xfe{}")
    plain = tmp_path / "plain"
    plain.write_text("x")
    return {
        "not a regular file": (fifo, "not a regular file"),
        "too large": (huge, "larger than"),
        "not UTF-8": (binary, "(not UTF-8 text)"),
        "unreadable": (plain / "below", "cannot read the {kind}: Not a directory"),
    }


@pytest.mark.parametrize(("name", "read", "error", "kind", "max_bytes"), READERS, ids=[r[0] for r in READERS])
def test_every_outside_reader_tells_a_failed_read_in_one_line_naming_file_and_kind(
    tmp_path, name, read, error, kind, max_bytes
):
    for way, (path, says) in _bad_files(tmp_path, max_bytes).items():
        with pytest.raises(error) as caught:
            read(path)
        message = str(caught.value)
        # a reader line by line names the line where the text stops being UTF-8
        at = f"{path}:1: " if (name, way) == ("predictions", "not UTF-8") else f"{path}: "
        assert message.startswith(at), (way, message)
        assert says.format(kind=kind) in message, (way, message)
        assert kind in message and "\n" not in message, (way, message)


def test_a_missing_file_says_what_to_do_where_the_reader_knows_and_is_no_file_for_games(tmp_path):
    missing = tmp_path / "missing.yaml"
    with pytest.raises(SensorError, match=r"missing.yaml: no such sensor file \(expected a sensor.yaml"):
        SensorGeometry.load(missing)
    with pytest.raises(ModelError, match=r"missing.yaml: no such model file \(write one with `neurotouch-hid adapt`"):
        load_model(missing)
    with pytest.raises(DatasetError, match="missing.yaml: cannot read the session plan: No such file or directory"):
        read_plan(missing)
    assert load_game_map(missing).steam == {}  # no games.yaml yet: an empty map


def test_the_path_in_the_message_reaches_the_terminal_escaped(tmp_path):
    path = tmp_path / "a\x1b]0;pwned\x07.yaml"
    path.write_bytes(b"\xff")
    with pytest.raises(ProfileError) as caught:
        read_outside_text(path, 1024, "profile", ProfileError)
    assert "\x1b" not in str(caught.value) and "\\x1b]0;pwned\\x07.yaml: not a profile" in str(caught.value)
    with pytest.raises(FileNotFoundError):
        read_outside_text(tmp_path / "none", 1024, "games file", GameMapError, missing=None)
