"""AEDAT4 read/write through dv-processing, `neurotouch-hid info`, and bad recordings.

The expected figures of the real DAVIS-346 recording come from its dataset README (an
independent source), not from this code.
"""

from __future__ import annotations

import itertools
import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from helpers import run_cli
from hypothesis import given, settings
from hypothesis import strategies as st

from neurotouch_hid.core.errors import RecordingError
from neurotouch_hid.sources import EVENT_DTYPE, Frame
from neurotouch_hid.sources.batches import merge_stream, split_batches
from neurotouch_hid.sources.recording import RecordingReader, read_info
from neurotouch_hid.sources.recording_writer import RecordingWriter, write_recording

REPO = Path(__file__).parents[1]


def synthetic(n: int = 20_000, duration_us: int = 400_000, seed: int = 1, t0: int = 1_000_000):
    rng = np.random.default_rng(seed)
    events = np.zeros(n, EVENT_DTYPE)
    events["timestamp"] = np.sort(rng.integers(t0, t0 + duration_us, n))
    events["x"] = rng.integers(0, 346, n)
    events["y"] = rng.integers(0, 260, n)
    events["polarity"] = rng.integers(0, 2, n)
    frames = [
        Frame(t, rng.integers(0, 256, (260, 346), dtype=np.uint8)) for t in range(t0 + 5, t0 + duration_us, 40_000)
    ]
    return events, frames


@pytest.fixture(scope="module")
def written(tmp_path_factory):
    """A synthetic recording written through RecordingWriter, and what was written."""
    events, frames = synthetic()
    path = tmp_path_factory.mktemp("rec") / "synthetic.aedat4"
    write_recording(path, events, frames, camera_name="test-camera")
    return path, events, frames


@pytest.fixture(scope="module")
def street_half(any_street, tmp_path_factory):
    """A copy of a street recording (tests/conftest.py: the real one, a simulated one) cut to
    half its bytes."""
    data = any_street.path.read_bytes()
    path = tmp_path_factory.mktemp("half") / "half.aedat4"
    path.write_bytes(data[: len(data) // 2])
    return path


# --- a DAVIS-346 street recording: the real one (its README's figures), and a simulated one -----
def test_info_of_a_street_recording_is_what_is_known_of_it(any_street):
    info = read_info(any_street.path)
    assert info.camera_name == any_street.camera_name
    assert (info.width, info.height) == (346, 260)
    assert info.n_events == any_street.n_events
    assert info.n_frames == any_street.n_frames
    assert round(info.duration_us / 1e6, 2) == any_street.duration_s
    assert info.duration_us == info.end_us - info.start_us


def test_cli_info_json_and_table(any_street):
    known = any_street
    result = run_cli("info", str(known.path), "--json")
    assert result.returncode == 0, result.stderr
    data = json.loads(result.stdout)
    assert data["camera_name"] == known.camera_name
    assert (data["width"], data["height"], data["n_events"], data["n_frames"]) == (
        346,
        260,
        known.n_events,
        known.n_frames,
    )
    assert round(data["duration_s"], 2) == known.duration_s
    assert data["duration_us"] == data["end_us"] - data["start_us"]
    table = run_cli("info", str(known.path))
    assert table.returncode == 0, table.stderr
    for text in (
        known.camera_name,
        "346",
        "260",
        f"{known.n_events:,}",
        str(known.n_frames),
        f"{known.duration_s:.2f} s",
    ):
        assert text in table.stdout


def test_stream_of_a_street_recording_is_merged_in_time_order(any_street):
    with RecordingReader(any_street.path, require_frames=True, require_resolution=(346, 260)) as reader:
        items = list(reader.stream(batch_us=1000))
        all_events, all_frames = reader.read_all()
    frames = [item for item in items if isinstance(item, Frame)]
    batches = [item for item in items if not isinstance(item, Frame)]
    assert len(frames) == any_street.n_frames
    assert all(f.image.shape == (260, 346) and f.image.dtype == np.uint8 for f in frames)
    events = np.concatenate(batches)
    assert events.dtype == EVENT_DTYPE and len(events) == any_street.n_events
    assert np.array_equal(events, all_events)
    assert [f.t_us for f in frames] == [f.t_us for f in all_frames]
    assert np.all(np.diff(events["timestamp"]) >= 0)
    last_frame_us = None
    for item in items:
        if isinstance(item, Frame):
            last_frame_us = item.t_us
            continue
        ts = item["timestamp"]
        assert len(item) > 0
        assert ts[0] // 1000 == ts[-1] // 1000  # one 1 ms batch
        if last_frame_us is not None:
            assert ts[0] >= last_frame_us  # no event before the frame yielded ahead of it
    # every frame precedes all events at or after its timestamp, and follows all before it
    seen = np.zeros(0, np.int64)
    for item in items:
        if isinstance(item, Frame):
            assert np.all(seen < item.t_us)
            assert not np.any(events["timestamp"][len(seen) :] < item.t_us)
        else:
            seen = np.concatenate((seen, item["timestamp"]))


# --- round trip -----------------------------------------------------------------------------------
def test_write_read_round_trip_is_exact(written):
    path, events, frames = written
    with RecordingReader(path, require_frames=True, require_resolution=(346, 260)) as reader:
        got_events, got_frames = reader.read_all()
        assert reader.camera_name == "test-camera"
    assert got_events.dtype == EVENT_DTYPE
    for name in EVENT_DTYPE.names:
        assert np.array_equal(got_events[name], events[name]), name
    assert [f.t_us for f in got_frames] == [f.t_us for f in frames]
    assert all(np.array_equal(a.image, b.image) for a, b in zip(got_frames, frames))


def test_info_of_written_recording(written):
    path, events, frames = written
    info = read_info(path)
    assert (info.n_events, info.n_frames) == (len(events), len(frames))
    assert info.start_us == min(int(events["timestamp"][0]), frames[0].t_us)
    assert info.end_us == max(int(events["timestamp"][-1]), frames[-1].t_us)


def test_writer_buffers_small_writes_and_reader_restarts(tmp_path):
    events, _ = synthetic(n=5_000)
    path = tmp_path / "small.aedat4"
    with RecordingWriter(path, frames=False) as writer:
        for batch in np.array_split(events, 500):
            writer.write_events(batch)
    with RecordingReader(path) as reader:
        first = np.concatenate([b for b in reader.stream(batch_us=5_000)])
        second, frames = reader.read_all()
    assert np.array_equal(first, events) and np.array_equal(second, events) and frames == []


def test_a_stop_raised_between_two_packets_of_a_flush_leaves_a_file_that_closes(tmp_path, monkeypatch):
    """A termination signal unwinds ``simulate`` from wherever its main thread is (the CLI raises
    it there, as Ctrl-C does): once it came between two packets of a flush, and the writer's
    close wrote the first packet again, which dv-processing refused ("out-of-order timestamp"),
    so the command exited 2 with that error instead of dying by the signal. The packets written
    before the stop are not pending any more: the close writes only what was not written."""
    from neurotouch_hid.sources import recording_writer

    events, _ = synthetic(n=3 * recording_writer.PACKET_EVENTS)
    path = tmp_path / "stopped.aedat4"
    writes = []
    real = recording_writer.store_from_events

    def stopped_at_the_second(packet):
        writes.append(len(packet))
        if len(writes) == 2:
            raise KeyboardInterrupt  # the signal's exception, between the first packet and the second
        return real(packet)

    monkeypatch.setattr(recording_writer, "store_from_events", stopped_at_the_second)
    with pytest.raises(KeyboardInterrupt), RecordingWriter(path, frames=False) as writer:
        writer.write_events(events)
    with RecordingReader(path) as reader:  # no damaged packet: RecordingError otherwise
        read, _ = reader.read_all()
    first = recording_writer.PACKET_EVENTS
    assert np.array_equal(read[:first], events[:first])  # the packet written before the stop, once
    # then what no write had begun (the stop came before the second packet's write: it is lost)
    assert np.array_equal(read[first:], events[2 * first :])


def test_writer_rejects_bad_data(tmp_path):
    events, frames = synthetic(n=100)
    with RecordingWriter(tmp_path / "bad.aedat4") as writer:
        with pytest.raises(RecordingError, match="time order"):
            writer.write_events(events[::-1])
        off = events.copy()
        off["x"][3] = 346
        with pytest.raises(RecordingError, match="outside"):
            writer.write_events(off)
        with pytest.raises(RecordingError, match=r"uint8 of shape \(260, 346\)"):
            writer.write_frame(Frame(0, np.zeros((100, 100), np.uint8)))
        writer.write_frame(frames[1])
        with pytest.raises(RecordingError, match="time order"):
            writer.write_frame(frames[0])
    with pytest.raises(RecordingError, match=r"\.aedat4"):
        RecordingWriter(tmp_path / "bad.txt")
    with pytest.raises(RecordingError, match="does not exist"):
        RecordingWriter(tmp_path / "no" / "such.aedat4")


# --- joined batches -------------------------------------------------------------------------------
def test_join_events_is_concatenate_without_the_dtype_promotion():
    """Batches of EVENT_DTYPE joined as their bytes are the same records as np.concatenate's; a
    strided batch or one of another dtype goes through np.concatenate; nothing to join is refused."""
    from neurotouch_hid.sources import join_events

    rng = np.random.default_rng(0)
    events = np.zeros(100, EVENT_DTYPE)
    events["timestamp"] = np.sort(rng.integers(0, 10**12, 100))
    events["x"], events["y"] = rng.integers(0, 346, 100), rng.integers(0, 260, 100)
    events["polarity"] = rng.integers(0, 2, 100)
    parts = [events[:7], events[7:8], events[8:8], events[8:60], events[60:]]
    joined = join_events(parts)
    assert joined.dtype == EVENT_DTYPE and np.array_equal(joined, np.concatenate(parts))
    assert np.array_equal(join_events([events[::2], events[1::2]]), np.concatenate([events[::2], events[1::2]]))
    fields = {"names": EVENT_DTYPE.names, "formats": [EVENT_DTYPE[n] for n in EVENT_DTYPE.names]}
    padded = np.zeros(3, np.dtype({**fields, "itemsize": 16}))  # dv-processing's own records
    assert np.array_equal(join_events([events[:2], padded]), np.concatenate([events[:2], padded]))
    assert join_events([events]) is events
    with pytest.raises(ValueError, match="no event batches"):
        join_events([])


# --- the merged stream ------------------------------------------------------------------------------
def test_merge_stream_cuts_at_batches_and_frames():
    events = np.zeros(8, EVENT_DTYPE)
    events["timestamp"] = [5, 12, 15, 15, 31, 40, 41, 95]
    frames = [
        Frame(0, np.zeros((2, 2), np.uint8)),
        Frame(15, np.zeros((2, 2), np.uint8)),
        Frame(41, np.zeros((2, 2), np.uint8)),
        Frame(200, np.zeros((2, 2), np.uint8)),
    ]
    # chunks split unevenly, as file packets are
    chunks = [events[:2], events[2:3], events[3:7], events[7:]]
    out = [
        ("F", item.t_us) if isinstance(item, Frame) else item["timestamp"].tolist()
        for item in merge_stream(chunks, frames, batch_us=10)
    ]
    assert out == [("F", 0), [5], [12], ("F", 15), [15, 15], [31], [40], ("F", 41), [41], [95], ("F", 200)]


@settings(max_examples=60, deadline=None)
@given(
    times=st.lists(st.integers(0, 300), max_size=60),
    frame_times=st.lists(st.integers(-10, 320), max_size=6),
    cuts=st.lists(st.integers(0, 60), max_size=5),
    batch_us=st.integers(1, 50),
)
def test_merge_stream_invariants(times, frame_times, cuts, batch_us):
    events = np.zeros(len(times), EVENT_DTYPE)
    events["timestamp"] = sorted(times)
    events["x"] = np.arange(len(times))  # identifies each event
    frames = [Frame(t, np.zeros((1, 1), np.uint8)) for t in sorted(frame_times)]
    chunks = np.split(events, sorted(c for c in cuts if c <= len(events)))
    items = list(merge_stream(chunks, frames, batch_us))
    got_frames = [item for item in items if isinstance(item, Frame)]
    batches = [item for item in items if not isinstance(item, Frame)]
    assert got_frames == frames
    assert np.array_equal(np.concatenate(batches) if batches else events[:0], events)
    emitted: list[int] = []
    for item in items:
        if isinstance(item, Frame):
            assert all(t < item.t_us for t in emitted)
            assert all(t >= item.t_us for t in events["timestamp"][len(emitted) :])
        else:
            ts = item["timestamp"]
            assert len(ts) and ts[0] // batch_us == ts[-1] // batch_us
            emitted.extend(ts.tolist())


def test_split_batches():
    events = np.zeros(5, EVENT_DTYPE)
    events["timestamp"] = [0, 999, 1000, 2500, 2999]
    assert [b["timestamp"].tolist() for b in split_batches(events, 1000)] == [[0, 999], [1000], [2500, 2999]]
    assert split_batches(events[:0], 1000) == []


# --- bad recordings: one clear RecordingError, exit code 2 ------------------------------------------
def _bad_files(tmp: Path, written_path: Path) -> dict[str, tuple[Path, str]]:
    text = tmp / "notes.aedat4"
    text.write_text("these are notes, not events\n")
    png = tmp / "image.aedat4"
    import cv2

    cv2.imwrite(str(tmp / "image.png"), np.zeros((4, 4), np.uint8))
    shutil.copy(tmp / "image.png", png)
    empty = tmp / "empty.aedat4"
    empty.write_bytes(b"")
    head = tmp / "head.aedat4"
    head.write_bytes(written_path.read_bytes()[:20])
    return {
        "missing": (tmp / "missing.aedat4", "no such file"),
        "text": (text, "not an AEDAT4 recording"),
        "png": (png, "not an AEDAT4 recording"),
        "png name": (tmp / "image.png", "not an AEDAT4 recording"),
        "empty": (empty, "not an AEDAT4 recording"),
        "header cut": (head, "truncated"),
        "directory": (tmp, "directory"),
    }


def test_bad_files_raise_one_clear_error(tmp_path, written):
    for name, (path, what) in _bad_files(tmp_path, written[0]).items():
        with pytest.raises(RecordingError) as caught:
            read_info(path)
        message = str(caught.value)
        assert str(path) in message and what in message, (name, message)
        assert "Stacktrace" not in message and ".hpp" not in message, (name, message)


def test_cli_bad_files_exit_2(tmp_path, written):
    bad = _bad_files(tmp_path, written[0])
    for name in ("missing", "png name", "header cut"):  # the rest as read_info above: same path
        path, what = bad[name]
        result = run_cli("info", str(path))
        assert result.returncode == 2, (name, result.stdout, result.stderr)
        assert what in result.stderr and "Traceback" not in result.stderr, (name, result.stderr)
        assert len(result.stderr.strip().splitlines()) <= 3, (name, result.stderr)


def test_truncated_file_yields_what_was_read_then_raises(any_street, street_half):
    with RecordingReader(any_street.path) as reader:
        full_events, full_frames = reader.read_all()
    got = []
    with RecordingReader(street_half) as reader:
        with pytest.raises(RecordingError) as caught:
            for item in reader.stream(batch_us=10_000):
                got.append(item)
    assert str(street_half) in str(caught.value) and "truncated" in str(caught.value)
    frames = [item for item in got if isinstance(item, Frame)]
    events = np.concatenate([item for item in got if not isinstance(item, Frame)])
    assert len(events) > 0.3 * len(full_events) and len(frames) > 0.3 * len(full_frames)
    assert np.all(np.diff(events["timestamp"]) >= 0)
    assert np.array_equal(events, full_events[: len(events)])
    assert all(np.array_equal(a.image, b.image) and a.t_us == b.t_us for a, b in zip(frames, full_frames))


def test_truncated_file_info_and_cli(street_half):
    with pytest.raises(RecordingError, match="truncated"):
        read_info(street_half)
    result = run_cli("info", str(street_half))
    assert result.returncode == 2 and "truncated" in result.stderr and str(street_half.name) in result.stderr


def test_missing_frame_stream_and_wrong_resolution(tmp_path):
    events, _ = synthetic(n=200)
    no_frames = tmp_path / "events-only.aedat4"
    with RecordingWriter(no_frames, frames=False) as writer:
        writer.write_events(events)
    with pytest.raises(RecordingError, match="no APS frame stream") as caught:
        RecordingReader(no_frames, require_frames=True)
    assert str(no_frames) in str(caught.value)
    with RecordingReader(no_frames) as reader:  # allowed when frames are not required
        assert reader.info.n_frames == 0 and reader.info.n_events == 200

    big = tmp_path / "vga.aedat4"
    with RecordingWriter(big, width=640, height=480) as writer:
        writer.write_events(events)
    with pytest.raises(RecordingError, match="640x480 px but 346x260 is required") as caught:
        RecordingReader(big, require_resolution=(346, 260))
    assert str(big) in str(caught.value)


def test_a_batch_cut_follows_a_rest_s_windows_and_a_stream_cuts_again_at_the_base_length():
    """``BatchCut``: 1 ms batches, then while a rest's 10 ms windows (ending at 12 345 us) last one
    batch a window, cut 1 ms after each window end; back at 1 ms, what was cut longer is cut
    again at the 1 ms boundaries."""
    from neurotouch_hid.sources.batches import BatchCut, CuttingStream, split_batches

    events = np.zeros(60, EVENT_DTYPE)
    events["timestamp"] = np.arange(60) * 500  # 0 .. 29.5 ms
    cut = BatchCut(1000)
    assert [len(b) for b in split_batches(events[:6], cut)] == [2, 2, 2]
    cut.follow((12_345, 10_000), 1000)
    batches = split_batches(events, cut)
    firsts = [int(b["timestamp"][0]) for b in batches]
    assert firsts == [0, 3500, 13500, 23500]  # cuts at 3 345, 13 345, 23 345 us
    assert cut.longer_until_us == 29_500
    cut.follow(None)
    stream = CuttingStream(iter(batches), cut)
    again = list(stream)
    assert np.array_equal(np.concatenate(again), events)
    # no batch spans a 1 ms boundary any more (the window ends' cuts stay)
    assert all(int(b["timestamp"][0]) // 1000 == int(b["timestamp"][-1]) // 1000 for b in again)
    assert cut.longer_until_us == 29_500  # until a batch past it comes


def test_read_ahead_reads_in_bursts_only_while_the_gel_rests_and_keeps_every_item_and_error():
    """``read_ahead``: one item a read outside a rest; while the cut says the gel rests, the next
    items at once up to the span (us) or the bytes; the same items in the same order; an error
    met in a burst raised after the items read before it."""
    from neurotouch_hid.sources.batches import BatchCut, read_ahead

    def batch(t_us: int, n: int = 4) -> np.ndarray:
        events = np.zeros(n, EVENT_DTYPE)
        events["timestamp"] = t_us + np.arange(n)
        return events

    items = [batch(t) if t % 40_000 else Frame(t, np.zeros((260, 346), np.uint8)) for t in range(0, 400_000, 10_000)]
    pulled: list[int] = []

    def source(fail_at: int | None = None):
        for k, item in enumerate(items):
            if k == fail_at:
                raise RecordingError("damaged packet")
            pulled.append(k)
            yield item

    cut = BatchCut(1000)
    stream = read_ahead(source(), cut, span_us=50_000)
    got = [next(stream), next(stream)]
    assert len(pulled) == 2  # not resting: one at a time
    cut.follow((20_000, 10_000), 1000)
    got.append(next(stream))
    assert len(pulled) == 2 + 6  # items at 20 .. 70 ms: the last one 50 ms past the burst's first
    got.append(next(stream))
    assert len(pulled) == 8
    cut.follow(None)
    got += list(stream)
    assert len(got) == len(items) and all(a is b for a, b in zip(got, items))

    cut.follow((20_000, 10_000), 1000)  # bounded by bytes: two APS frames' pixels
    pulled.clear()
    stream = read_ahead(source(), cut, max_bytes=2 * 260 * 346)
    next(stream)
    assert len(pulled) == 5  # frame, 3 batches, frame

    pulled.clear()
    stream = read_ahead(source(fail_at=3), cut)
    assert all(next(stream) is item for item in items[:3])  # read in the burst that failed
    assert pulled == [0, 1, 2]
    with pytest.raises(RecordingError, match="damaged packet"):
        next(stream)

    closed = []

    def endless():
        try:
            yield from itertools.cycle(items)
        finally:
            closed.append(True)

    source_ = endless()  # held here too: collected, it would close anyway
    stream = read_ahead(source_, cut)
    next(stream)
    stream.close()
    assert closed == [True]  # the source's own finally, at once
