"""Recordings crafted to break the driver, and outputs that would destroy an input (docs/limits.md):
decompression bombs, a cut recording, a FIFO for a recording, ``--out`` over the source or through
a link. Each ends with exit 0 or 2, one short message, no traceback, and bounded memory."""

from __future__ import annotations

import json
import os

import pytest
from hostile_helpers import _predictions, assert_refused, cli
from hostile_inputs import bomb_recording


# --- recordings ---------------------------------------------------------------------------------
def test_a_decompression_bomb_is_refused_before_it_is_inflated(tmp_path):
    """~100 KB of zstd RLE blocks declaring 3 GiB in one packet: ``info`` refuses the packet from
    its framing, without inflating it."""
    path = bomb_recording(tmp_path / "bomb.aedat4", inflated=3 << 30)
    assert path.stat().st_size < 200_000
    assert_refused(cli("info", str(path)), "decompression bomb", "docs/limits.md")


def test_a_bomb_behind_a_table_position_the_packets_skip_over_is_refused_too(tmp_path):
    """The decoder stops at the index table only when a packet ends exactly on it: a header
    naming a byte inside a packet does not hide the packets after it from the checks."""
    path = bomb_recording(tmp_path / "bomb.aedat4", inflated=3 << 30, table_at=200)
    assert_refused(cli("info", str(path)), "decompression bomb")


def test_the_reader_refuses_a_bomb_after_yielding_what_comes_before(tmp_path):
    """The stream every command reads gives the packets before the bomb, then one RecordingError."""
    from neurotouch_hid.core.errors import RecordingError
    from neurotouch_hid.sources.recording import RecordingReader

    path = bomb_recording(tmp_path / "bomb.aedat4", inflated=256 << 20)
    read = []
    with RecordingReader(path) as reader, pytest.raises(RecordingError, match="would inflate to up to 268435456"):
        for item in reader.stream():
            read.append(len(item))
    assert sum(read) == 2000  # every event before the bomb


def test_a_bomb_spread_over_many_small_packets_meets_the_file_budget():
    """Packets of 32 MiB each stay under the packet bound; their total against the file's size
    does not (MAX_INFLATE_RATIO beyond MIN_INFLATE_BUDGET)."""
    from hostile_inputs import zstd_rle_bomb

    from neurotouch_hid.sources.packet_bounds import COMPRESSION_ZSTD, inflated_bound
    from neurotouch_hid.sources.recording_checks import MAX_INFLATE_RATIO, MAX_PACKET_BYTES, MIN_INFLATE_BUDGET

    payload = zstd_rle_bomb(32 << 20)
    bound = inflated_bound(payload, COMPRESSION_ZSTD)
    assert bound == 32 << 20 and bound <= MAX_PACKET_BYTES
    packets_to_budget = MIN_INFLATE_BUDGET // bound + 1
    assert packets_to_budget * bound > max(MIN_INFLATE_BUDGET, MAX_INFLATE_RATIO * packets_to_budget * len(payload))


# --- outputs never destroy an input -------------------------------------------------------------
def test_track_never_writes_over_its_recording_a_link_or_what_a_failure_would_lose(tmp_path, sim_gel_short_recording):
    """``track X --out X`` (the recording emptied), ``--out`` a symbolic link (written through
    to wherever it points), and a track that fails (a recording without APS frames): each is
    one line, and every file is as it was."""
    from hostile_inputs import small_events

    from neurotouch_hid.sources.recording_writer import RecordingWriter

    recording = tmp_path / "rec.aedat4"
    recording.write_bytes(sim_gel_short_recording.read_bytes())
    size = recording.stat().st_size
    assert_refused(cli("track", str(recording), "--out", str(recording)), "same file as the input")
    assert recording.stat().st_size == size
    hard = tmp_path / "hard.aedat4"
    os.link(recording, hard)
    assert_refused(cli("track", str(recording), "--out", str(hard)), "same file as the input")
    precious, link = tmp_path / "precious.txt", tmp_path / "link.jsonl"
    precious.write_text("keep me\n")
    link.symlink_to(precious)
    assert_refused(cli("track", str(recording), "--out", str(link)), "symbolic link")
    assert precious.read_text() == "keep me\n"
    no_frames = tmp_path / "noframes.aedat4"
    with RecordingWriter(no_frames, frames=False) as writer:
        writer.write_events(small_events())
    out = tmp_path / "pred.jsonl"
    out.write_text("earlier predictions\n")
    code, _, err, _ = cli("track", str(no_frames), "--out", str(out), timeout_s=300)
    assert code == 2 and "Traceback" not in err, err
    assert out.read_text() == "earlier predictions\n"
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")], "a temporary file was left"


def test_a_cut_recording_keeps_every_window_before_the_cut_and_says_where(tmp_path, sim_gel_short_recording):
    """A recording cut short: ``track`` writes the windows before the cut beside its output
    (``NAME.partial``: a failed run is never the output), exits 2, and says how many and up to
    when."""
    cut = tmp_path / "cut.aedat4"
    data = sim_gel_short_recording.read_bytes()
    cut.write_bytes(data[: len(data) * 2 // 3])
    out = tmp_path / "pred.jsonl"
    code, _, err, _ = cli("track", str(cut), "--out", str(out), timeout_s=300)
    assert code == 2 and "Traceback" not in err, err
    windows = len(out.with_name("pred.jsonl.partial").read_text().splitlines())
    assert not out.exists(), "a failed run's windows at the output's name"
    assert windows > 10 and f"the {windows} windows before it are in {out}.partial" in err and "up to t=" in err, err


def test_run_never_writes_its_states_over_its_source_or_through_a_link(tmp_path):
    """``run --source P.jsonl --output jsonl --out P.jsonl`` replaced the source it was
    replaying; a link as ``--out`` was written through."""
    preds = _predictions(tmp_path, 0.5)
    before = preds.read_bytes()
    run = ["run", "--fast", "--profile", "default", "--output", "jsonl"]
    assert_refused(cli(*run, "--source", str(preds), "--out", str(preds)), "same file as the input")
    assert preds.read_bytes() == before
    link = tmp_path / "states.jsonl"
    link.symlink_to(preds)
    assert_refused(cli(*run, "--source", str(preds), "--out", str(link)), "symbolic link")
    assert preds.read_bytes() == before
    states = tmp_path / "real-states.jsonl"
    states.write_text("old\n")
    code, _, err, _ = cli(*run, "--source", str(preds), "--out", str(states), timeout_s=300)
    assert code == 0, err
    assert [json.loads(line)["t_us"] for line in states.read_text().splitlines()][-1] >= 0


def test_info_on_a_fifo_is_refused_not_waited_on(tmp_path):
    fifo = tmp_path / "camera.aedat4"
    os.mkfifo(fifo)
    assert_refused(cli("info", str(fifo)), "not a regular file")
