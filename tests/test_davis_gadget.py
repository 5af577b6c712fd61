"""The emulated DAVIS-346's word encoder (tests/kernel/davis_gadget.py), decoded the way libcaer's
``davisCommonEventTranslator`` reads the bulk data words; the kernel tests (checks_davis.py) then
check the same stream through dv-processing's own driver over USB."""

from __future__ import annotations

import errno
import os
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent / "kernel"))

from davis_gadget import (  # noqa: E402
    CHUNK_BYTES,
    HEIGHT,
    MAX_BACKLOG_BYTES,
    USB,
    USB_CLOCK_MHZ,
    USB_EARLY_PACKET_DELAY,
    WIDTH,
    DavisDevice,
    Replay,
    Stream,
    WordEncoder,
    process_events,
)


def decode(words: np.ndarray) -> tuple[list[tuple[int, int, int, int]], list[tuple[int, int, int, np.ndarray]]]:
    """(events as (t, x, y, polarity), frames as (start-of-exposure t, end t, frame-end t, uint8 image))."""
    wrap_add, current, last_y = 0, 0, 0
    events, frames = [], []
    counts = {0: 0, 1: 0}
    kind = 0
    frame = None
    for w in (int(v) for v in words):
        if w & 0x8000:
            current = wrap_add + (w & 0x7FFF)
            continue
        code, data = (w >> 12) & 7, w & 0xFFF
        if code == 7:
            wrap_add += 0x8000 * data
            current = wrap_add
        elif code == 1:
            last_y = data
        elif code in (2, 3):
            events.append((current, data, last_y, code & 1))
        elif code == 0:
            if data == 9:
                frame = {
                    "reset": np.zeros((HEIGHT, WIDTH), int),
                    "signal": np.zeros((HEIGHT, WIDTH), int),
                    "cols": {0: 0, 1: 0},
                    "roi": [],
                }
                counts = {0: 0, 1: 0}
            elif data == 14:
                frame["start"] = current
            elif data == 15:
                frame["end"] = current
            elif data in (11, 12):
                kind = data - 11
                counts[kind] = 0
            elif data == 13:
                frame["cols"][kind] += 1
            elif data == 10:
                assert frame["cols"] == {0: WIDTH, 1: WIDTH}
                value = np.clip(frame["reset"] - frame["signal"], 0, 1023) << 6
                frames.append((frame["start"], frame["end"], current, (value >> 8).astype(np.uint8)))
        elif code == 4:
            col, row = frame["cols"][kind], counts[kind]
            frame["signal" if kind else "reset"][row, col] = data
            counts[kind] += 1
        elif code == 5:
            frame["roi"].append(data)
    return events, frames


def test_events_round_trip_with_wraps_and_repeated_rows():
    rng = np.random.default_rng(1)
    t = np.sort(rng.integers(0, 200_000, 500)).astype(np.int64)
    t[10:20] = t[10]  # several events on one timestamp
    x = rng.integers(0, WIDTH, 500)
    y = rng.integers(0, HEIGHT, 500)
    y[30:40] = 7  # one row, several columns
    p = rng.integers(0, 2, 500)
    enc = WordEncoder()
    words = np.concatenate(
        [
            enc.events(t[:250], x[:250], y[:250], p[:250]),
            enc.idle(int(t[250]) - 1),
            enc.events(t[250:], x[250:], y[250:], p[250:]),
        ]
    )
    events, _ = decode(words)
    assert events == list(zip(t.tolist(), x.tolist(), y.tolist(), p.tolist()))


def test_a_frame_decodes_to_the_same_grey_levels_and_times():
    rng = np.random.default_rng(2)
    image = rng.integers(0, 256, (HEIGHT, WIDTH)).astype(np.uint8)
    image[0, 0], image[-1, -1] = 0, 255
    enc = WordEncoder()
    words = np.concatenate(
        [
            enc.frame_start(40_000),
            enc.events(np.array([41_000]), np.array([3]), np.array([4]), np.array([1])),
            enc.frame_end(44_000, image),
        ]
    )
    events, frames = decode(words)
    assert events == [(41_000, 3, 4, 1)]
    ((start, end, _, decoded),) = frames
    assert (start, end) == (40_000, 44_000)
    np.testing.assert_array_equal(decoded, image)


def test_a_silence_longer_than_the_wrap_field_still_counts_every_wrap():
    enc = WordEncoder()
    t = np.array([5, 5 + 0x8000 * 5000 + 17], np.int64)  # more wraps than one word's 12 bits hold
    events, _ = decode(enc.events(t, np.array([1, 2]), np.array([3, 3]), np.array([0, 1])))
    assert [e[0] for e in events] == t.tolist()


@pytest.mark.parametrize("t_us", [0, 0x8000, 3 * 0x8000 + 1])
def test_idle_wraps_keep_the_decoder_on_device_time(t_us):
    enc = WordEncoder()
    words = np.concatenate(
        [enc.idle(t_us + 70_000), enc.events(np.array([t_us + 70_001]), np.array([0]), np.array([0]), np.array([0]))]
    )
    events, _ = decode(words)
    assert events[0][0] == t_us + 70_001


def test_no_timestamp_is_sent_twice_in_a_row():
    """dv-processing's parser stops on a timestamp equal to the last (a wrap sets the current one)."""
    enc = WordEncoder()
    t = np.array([0x8000 - 1, 0x8000, 0x8000, 2 * 0x8000, 2 * 0x8000 + 5], np.int64)
    words = np.concatenate(
        [
            enc.events(t[:3], np.zeros(3, int), np.zeros(3, int), np.zeros(3, int)),
            enc.idle(2 * 0x8000),
            enc.frame_start(2 * 0x8000),
            enc.events(t[4:], np.zeros(1, int), np.zeros(1, int), np.zeros(1, int)),
        ]
    )
    current, seen = 0, []
    for w in (int(v) for v in words):
        if w & 0x8000:
            current = (current // 0x8000) * 0x8000 + (w & 0x7FFF)
            seen.append(current)
        elif w >> 12 == 7:
            current = (current // 0x8000 + (w & 0xFFF)) * 0x8000
            seen.append(current)
    assert all(b > a for a, b in zip(seen, seen[1:])), seen
    assert [e[0] for e in decode(words)[0]] == [0x8000 - 1, 0x8000, 0x8000, 2 * 0x8000 + 5]


def _recording(path: Path) -> Path:
    """Events at 0, 100, ..., 9900 us (x = t / 100, so each says when it was recorded), no frames."""
    from neurotouch_hid.sources import EVENT_DTYPE
    from neurotouch_hid.sources.recording_writer import RecordingWriter

    events = np.zeros(100, EVENT_DTYPE)
    events["timestamp"] = 1_000_000 + 100 * np.arange(100)
    events["x"] = np.arange(100)
    events["y"] = 5
    events["polarity"] = 1
    with RecordingWriter(path, frames=False) as writer:
        writer.write_events(events)
    return path


def test_a_cued_gesture_plays_slowed_once_then_its_hold_loops(tmp_path):
    """SIGHUP's cue (--gesture, --hold, --slow): the looped rest stops at the cue, the gesture part
    follows at once N times slower, then the hold part repeats; device time never goes back."""
    path = _recording(tmp_path / "r.aedat4")
    rest = Replay(path, loop=True, to_s=0.002)  # events x = 0..19, looped every 2.9 ms
    gesture = Replay(path, loop=False, from_s=0.005, to_s=0.006, slow=10)  # x = 50..59, 1 ms apart
    hold = Replay(path, loop=True, from_s=0.009, to_s=0.01)  # x = 90..99
    stream = Stream(rest, t_dev0=0)
    words = stream.until(5_000, dvs=True, aps=False)
    stream.cue(5_000, [gesture, hold])
    words += stream.until(40_000, dvs=True, aps=False)
    events, _ = decode(np.concatenate(words))
    t = [e[0] for e in events]
    x = [e[1] for e in events]
    assert t == sorted(t)
    cue = x.index(50)
    assert set(x[:cue]) == set(range(20)) and t[cue - 1] <= 5_000  # the rest loop, up to the cue
    assert x[cue : cue + 10] == list(range(50, 60))  # the gesture, once, 10 times slower
    assert [b - a for a, b in zip(t[cue : cue + 10], t[cue + 1 : cue + 10])] == [1_000] * 9
    assert t[cue] == 5_000 and set(x[cue + 10 :]) == set(range(90, 100))  # then the hold, looped
    assert x.count(90) >= 2


class _Function:
    """FunctionFS's function as process_events sees it: each call to processEvents takes the next
    outcome (an OSError errno to raise, or None for events read)."""

    def __init__(self, outcomes: list[int | None]) -> None:
        self.outcomes = list(outcomes)
        self.calls = 0

    def processEvents(self) -> None:  # noqa: N802 - python-functionfs's name
        self.calls += 1
        outcome = self.outcomes.pop(0)
        if outcome is not None:
            raise OSError(outcome, os.strerror(outcome))


class _Device:
    def __init__(self) -> None:
        self.notes: list[str] = []

    def note(self, msg: str) -> None:
        self.notes.append(msg)


@pytest.mark.parametrize("code", [errno.EIDRM, errno.ESHUTDOWN])
def test_a_cancelled_control_transfer_is_noted_and_the_events_read_again(code):
    """FunctionFS fails one ep0 event read with EIDRM after the host gave up on a control transfer
    (seen in CI: it ended the gadget); the events behind it are read at once, not left queued."""
    function, device = _Function([code, None]), _Device()
    process_events(function, device)
    assert function.calls == 2
    assert len(device.notes) == 1 and "cancelled by the host" in device.notes[0]


def test_other_errors_and_a_read_that_keeps_failing_still_end_the_gadget():
    with pytest.raises(OSError) as exc:
        process_events(_Function([errno.EIO]), _Device())
    assert exc.value.errno == errno.EIO
    function = _Function([errno.EIDRM] * 3)
    with pytest.raises(OSError) as exc:
        process_events(function, _Device(), attempts=3)
    assert exc.value.errno == errno.EIDRM and function.calls == 3


def test_short_data_waits_the_early_packet_delay_the_host_wrote_and_full_transfers_go_at_once(tmp_path):
    """The FX3's early packet delay (USB module, parameter 1, in USB clock cycles as libcaer writes
    it): words that do not fill a transfer are held that long, then sent as one short transfer;
    a full transfer's worth goes at once; before the host writes it, libcaer's default 1 ms."""
    device = DavisDevice(Replay(_recording(tmp_path / "r.aedat4"), loop=True), verbose=False)
    assert device.early_packet_delay_s() == pytest.approx(0.001)
    device.registers.write(USB, USB_EARLY_PACKET_DELAY, 20_000 * USB_CLOCK_MHZ)  # 20 ms
    assert device.early_packet_delay_s() == pytest.approx(0.020)
    for _ in range(3):  # three short pumps' words: held, together
        device._queue(np.arange(10, dtype=np.uint16))
    # 0.1 ms either side of the delay: (t + 0.020) - t is below 0.020 for about a third of the
    # values time.monotonic() takes, so the boundary itself is not a time a test can give
    device._flush(device.pending_since + 0.0199)
    assert not device.backlog and len(device.pending) == 60
    device._flush(device.pending_since + 0.0201)
    assert [len(chunk) for chunk in device.backlog] == [60] and not device.pending
    device.backlog.clear()
    device._queue(np.zeros(CHUNK_BYTES // 2 + 5, np.uint16))  # a transfer and 10 bytes
    assert [len(chunk) for chunk in device.backlog] == [CHUNK_BYTES] and len(device.pending) == 10


def test_the_stats_line_says_the_events_queued_and_the_bytes_dropped(tmp_path):
    """The log line a guest measurement compares with what the host received: the events the
    stream queued (those sent while DVS runs, as decoded), its frames, and the bytes dropped
    because the host did not read them."""
    device = DavisDevice(Replay(_recording(tmp_path / "r.aedat4"), loop=True), verbose=False)
    device.stream = Stream(device.replay, t_dev0=0)
    events, _ = decode(np.concatenate(device.stream.until(25_000, dvs=True, aps=True)))
    device.stream.until(35_000, dvs=False, aps=True)  # DVS stopped: nothing queued, nothing counted
    assert len(events) == 233 == device.stream.events_sent  # 100 a lap of 10.9 ms: two laps and 33
    device.backlog_bytes = MAX_BACKLOG_BYTES  # the host stopped reading
    device._queue(np.zeros(10, np.uint16))
    assert device.stats().endswith("; queued 233 events, 0 frames; dropped 20 bytes")
