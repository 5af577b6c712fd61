"""AEDAT4 recordings read with the ``aedat`` decoder.

Reading goes through the ``aedat`` package (a decoder written in Rust, memory-safe: a damaged
file gives an error, never a hang or a crash); writing is :mod:`neurotouch_hid.sources.recording_writer`
(dv-processing's ``MonoCameraWriter``, iniVation's own library, the format DV records;
docs/dataset.md, section SEQUENCE.aedat4). dv-processing 2.0's reader can hang for ever in LZ4
decompression or crash on a damaged file (docs/performance.md, "Recording I/O", has the
measurements and the choice). This module adds:

- one clear :class:`~neurotouch_hid.core.errors.RecordingError` per bad file (missing, not AEDAT4,
  truncated, damaged, no frame stream, wrong resolution; the checks are
  :mod:`neurotouch_hid.sources.recording_checks`);
- reading what is readable of a cut or damaged file: packets that do not decode, or whose events
  lie outside the sensor or go back in time, are skipped (the numba pipeline does not check
  bounds), and the reader raises once after yielding the rest;
- the merged, time-ordered stream of event batches and :class:`Frame` values every source yields
  (docs/architecture.md, sources; cut and merged by :mod:`neurotouch_hid.sources.batches`);
- conversion of the decoder's events to numpy arrays of :data:`EVENT_DTYPE`.

Time is int64 microseconds of the camera clock everywhere.
"""

from __future__ import annotations

import collections
import os
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path
from typing import Iterator

import numpy as np

from neurotouch_hid.core.errors import RecordingError
from neurotouch_hid.core.limits import printable
from neurotouch_hid.sources import EVENT_DTYPE, Frame, StreamItem

# split_batches (batches.py) and RecordingWriter (recording_writer.py) are importable from here too:
# the camera's source (davis.py) and the kernel checks (tests/kernel/) import them from here
from neurotouch_hid.sources.batches import (
    BatchCut,
    merge_stream,
    split_batches,  # noqa: F401
)
from neurotouch_hid.sources.recording_checks import (
    MAX_TIMESTAMP_US,
    _camera_name,
    _check_path,
    _Damage,
    _InflateGuard,
    _read_header,
)
from neurotouch_hid.sources.recording_writer import RecordingWriter  # noqa: F401

#: The DAVIS-346's pixel array, (width, height) px.
DAVIS346_RESOLUTION = (346, 260)
#: The ``aedat`` decoder's event record: EVENT_DTYPE's layout (same offsets and sizes).
AEDAT_EVENT_DTYPE = np.dtype([("t", "<u8"), ("x", "<u2"), ("y", "<u2"), (("p", "on"), "?")])


@dataclass(frozen=True)
class RecordingInfo:
    """What a recording holds (``neurotouch-hid info``).

    Attributes:
        path: the file.
        camera_name: the camera (source) name stored in the file, e.g. ``DAVIS346_00000002``.
        width, height: the event stream's resolution, px.
        start_us, end_us: first and last timestamp over the event and frame streams, us.
        duration_us: ``end_us - start_us``, us (0 for an empty recording).
        n_events: exact number of events.
        n_frames: exact number of APS frames (0 without a frame stream).
    """

    path: Path
    camera_name: str
    width: int
    height: int
    start_us: int
    end_us: int
    duration_us: int
    n_events: int
    n_frames: int

    @property
    def duration_s(self) -> float:
        """``duration_us`` in seconds (for display only)."""
        return self.duration_us / 1e6

    def to_json(self) -> dict:
        """The JSON object ``neurotouch-hid info --json`` prints (all keys of this record)."""
        return {
            "path": str(self.path),
            "camera_name": self.camera_name,
            "width": self.width,
            "height": self.height,
            "duration_s": round(self.duration_s, 6),
            "duration_us": self.duration_us,
            "n_events": self.n_events,
            "n_frames": self.n_frames,
            "start_us": self.start_us,
            "end_us": self.end_us,
        }


def grey_image(image: np.ndarray) -> np.ndarray:
    """An APS frame's image as a 2-D uint8 array (colour DAVIS frames become grey, OpenCV)."""
    if image.ndim == 3:
        import cv2

        image = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY if image.shape[2] == 3 else cv2.COLOR_BGRA2GRAY)
    return image


def _converted(raw: np.ndarray) -> np.ndarray:
    """aedat's events (fields t, x, y, on) copied into EVENT_DTYPE, for a layout other than 13 bytes."""
    events = np.empty(len(raw), EVENT_DTYPE)
    events["timestamp"], events["x"], events["y"], events["polarity"] = raw["t"], raw["x"], raw["y"], raw["on"]
    return events


def _is_decoder_error(exc: BaseException) -> bool:
    """Whether aedat raised ``exc`` about the file: its errors are Exceptions, a panic of its Rust
    code is pyo3's ``PanicException`` (a BaseException); Ctrl-C and exits are not."""
    return isinstance(exc, Exception) or type(exc).__name__ == "PanicException"


# --- reading ------------------------------------------------------------------------------------
class RecordingReader:
    """Reads an AEDAT4 recording's events and APS frames (the ``aedat`` decoder, Rust).

    The decoder reads the file's packets in order (it needs no index table) and cannot crash
    or hang on damaged data: a packet that does not decompress, or whose events are out of the
    sensor or out of time order, is skipped (numba's pipeline must never index with them), the
    rest is read, and :meth:`stream` raises one RecordingError after yielding everything
    readable. A file cut short is read up to the cut (docs/performance.md, "Recording I/O").

    Args:
        path: the ``.aedat4`` file.
        require_frames: raise RecordingError when the file has no APS frame stream (the pipeline
            finds the markers on APS frames; paper, section Marker Tracking).
        require_resolution: (width, height) px the event (and frame) stream must have, e.g.
            ``(346, 260)`` for a DAVIS-346, or None for any.

    Raises:
        RecordingError: missing file, not AEDAT4, corrupt header, no event stream, a requirement
            not met. Damaged or cut data: from :meth:`stream`, :meth:`read_all` and :attr:`info`.

    Use as a context manager or call :meth:`close`. :meth:`stream` may be called more than once;
    each call reads the file from the start.
    """

    def __init__(
        self,
        path: str | os.PathLike,
        *,
        require_frames: bool = False,
        require_resolution: tuple[int, int] | None = None,
    ) -> None:
        self.path = Path(path)
        _check_path(self.path)
        table_position, xml, self._compression, self._data_start = _read_header(self.path)
        self._table_position = table_position
        size = self.path.stat().st_size
        self._truncated = (
            (
                f"truncated: the file is {size} bytes but its index table starts at byte "
                f"{table_position}; the rest of the recording is missing"
            )
            if table_position >= size
            else None
        )
        self._open = True
        self.camera_name: str = _camera_name(xml)
        streams = self._decoder().id_to_stream()
        kinds = {info.get("type"): info for info in streams.values()}
        if "events" not in kinds:
            names = ", ".join(sorted(str(k) for k in kinds)) or "none"
            raise RecordingError(f"{self.path}: has no event stream (streams: {names})")
        self.width, self.height = int(kinds["events"]["width"]), int(kinds["events"]["height"])
        self.has_frames: bool = "frame" in kinds
        self._frame_size = (int(kinds["frame"]["width"]), int(kinds["frame"]["height"])) if self.has_frames else None
        if require_frames and not self.has_frames:
            names = ", ".join(sorted(str(k) for k in kinds))
            raise RecordingError(
                f"{self.path}: has no APS frame stream (streams: {names}); frames are needed to "
                f"find the markers: record with the DAVIS frame output enabled"
            )
        if require_resolution is not None:
            want = (int(require_resolution[0]), int(require_resolution[1]))
            found = [("event", (self.width, self.height))] + ([("frame", self._frame_size)] if self.has_frames else [])
            for kind, got in found:
                if got != want:
                    raise RecordingError(
                        f"{self.path}: {kind} stream is {got[0]}x{got[1]} px but {want[0]}x{want[1]} "
                        f"is required (a DAVIS-346 records 346x260)"
                    )

    # context manager
    def __enter__(self) -> "RecordingReader":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        """Mark the reader closed (each read opens its own decoder and closes it at its end)."""
        self._open = False

    @property
    def truncated(self) -> str | None:
        """Why the file is truncated, as its header tells (index table past the end), or None."""
        return self._truncated

    def _decoder(self):
        """A fresh ``aedat.Decoder`` on the file, so reads never share a position."""
        import aedat

        if not self._open:
            raise RecordingError(f"{self.path}: the reader is closed")
        try:
            str(self.path).encode("utf-8")
        except UnicodeEncodeError:  # aedat takes a Rust string: such a name reads as no file
            raise RecordingError(
                f"{printable(self.path, 200)}: a file name that is not UTF-8 cannot be opened by the AEDAT4 "
                "decoder; rename the file"
            ) from None
        try:
            return aedat.Decoder(str(self.path))
        except BaseException as exc:
            if not _is_decoder_error(exc):
                raise
            raise RecordingError(f"{self.path}: corrupt AEDAT4 file ({exc})") from None

    def _packets(self, damage: "_Damage") -> Iterator[np.ndarray | Frame]:
        """The file's event arrays (EVENT_DTYPE) and Frames in file order, each checked.

        Damaged packets are skipped and counted in ``damage``; a cut ends the pass.
        """
        decoder = iter(self._decoder())
        guard = _InflateGuard(self.path, self._data_start, self._table_position, self._compression)
        try:
            yield from self._checked_packets(decoder, guard, damage)
        finally:
            guard.close()

    def _checked_packets(self, decoder, guard: "_InflateGuard", damage: "_Damage") -> Iterator[np.ndarray | Frame]:
        last_event_us = last_frame_us = 0
        while True:
            refused = guard.check_next()
            if refused is not None:
                damage.refuse(refused)
                return
            try:
                packet = next(decoder)
            except StopIteration:
                return
            except BaseException as exc:
                if not _is_decoder_error(exc):
                    raise
                if damage.add(str(exc)):
                    return
                continue
            damage.consecutive = 0
            if "events" in packet:
                raw = packet["events"]
                if not len(raw):
                    continue
                # aedat's event record (t u64, x u16, y u16, on bool; 13 bytes) has EVENT_DTYPE's
                # layout: a view, no copy; checked before anything downstream indexes with it.
                events = raw.view(EVENT_DTYPE) if raw.dtype == AEDAT_EVENT_DTYPE else _converted(raw)
                t = events["timestamp"]
                problem = (
                    "events outside the sensor"
                    if int(raw["x"].max()) >= self.width
                    or int(raw["y"].max()) >= self.height
                    or int(events["polarity"].view(np.uint8).max()) > 1
                    else "events out of time order"
                    if t[0] < last_event_us or int(raw["t"][-1]) > MAX_TIMESTAMP_US or bool(np.any(t[1:] < t[:-1]))
                    else None
                )
                if problem:
                    damage.add(problem)
                    continue
                last_event_us = int(t[-1])
                yield events
            elif "frame" in packet:
                frame = packet["frame"]
                pixels, t_us = frame["pixels"], int(frame["t"])
                width, height = self._frame_size or (-1, -1)
                if pixels.dtype != np.uint8 or pixels.shape[:2] != (height, width) or pixels.ndim not in (2, 3):
                    damage.add(f"an APS frame of {pixels.dtype} {pixels.shape}, not {height}x{width} uint8")
                    continue
                if t_us < last_frame_us or t_us > MAX_TIMESTAMP_US:
                    damage.add("APS frames out of time order")
                    continue
                last_frame_us = t_us
                yield Frame(t_us, grey_image(pixels))

    def _raise_if_damaged(self, damage: "_Damage", n_events: int, n_frames: int, last_us: int | None) -> None:
        why = damage.describe() or self._truncated
        if why is not None:
            upto = f" up to t={last_us} us" if last_us is not None else ""
            raise RecordingError(f"{self.path}: {why} (read {n_events} events and {n_frames} frames{upto})")

    @cached_property
    def info(self) -> RecordingInfo:
        """Exact counts and time span, from one pass over the file (cached).

        Raises RecordingError for a truncated or damaged file (counts would not be the recording's).
        """
        damage = _Damage()
        n_events = n_frames = 0
        first = last = None
        for item in self._packets(damage):
            if isinstance(item, Frame):
                n_frames += 1
                lo = hi = item.t_us
            else:
                n_events += len(item)
                lo, hi = int(item["timestamp"][0]), int(item["timestamp"][-1])
            first = lo if first is None else min(first, lo)
            last = hi if last is None else max(last, hi)
        self._raise_if_damaged(damage, n_events, n_frames, last)
        start, end = (first, last) if first is not None else (0, 0)
        return RecordingInfo(
            self.path, self.camera_name, self.width, self.height, start, end, end - start, n_events, n_frames
        )

    def stream(self, batch_us: int | BatchCut = 10_000) -> Iterator[StreamItem]:
        """Events and APS frames merged in time order, as every source yields them.

        Yields:
            event batches (arrays of :data:`EVENT_DTYPE`, time-ordered, never empty) cut at every
            multiple of ``batch_us`` (us) and at every frame's timestamp, and :class:`Frame` values;
            a frame comes before the events whose timestamp is >= its ``t_us``.

        Raises:
            RecordingError: after yielding everything readable, when the file is truncated or
                damaged.
        """
        if isinstance(batch_us, int) and batch_us <= 0:
            raise ValueError(f"batch_us must be positive, got {batch_us}")
        damage = _Damage()
        events, frames = _by_kind(self._packets(damage), with_frames=self.has_frames)
        n_events = n_frames = 0
        last_us = None
        for item in merge_stream(events, frames, batch_us):
            if isinstance(item, Frame):
                n_frames += 1
                last_us = item.t_us if last_us is None else max(last_us, item.t_us)
            else:
                n_events += len(item)
                last_us = int(item["timestamp"][-1]) if last_us is None else max(last_us, int(item["timestamp"][-1]))
            yield item
        self._raise_if_damaged(damage, n_events, n_frames, last_us)

    def read_all(self) -> tuple[np.ndarray, list[Frame]]:
        """All events (one EVENT_DTYPE array, time-ordered) and all APS frames (time-ordered).

        Raises RecordingError for a truncated or damaged file.
        """
        damage = _Damage()
        chunks, frames = [], []
        for item in self._packets(damage):
            (frames if isinstance(item, Frame) else chunks).append(item)
        events = np.concatenate(chunks) if chunks else np.zeros(0, EVENT_DTYPE)
        last = max([int(t) for t in events["timestamp"][-1:]] + [f.t_us for f in frames[-1:]], default=None)
        self._raise_if_damaged(damage, len(events), len(frames), last)
        return events, frames


def _by_kind(items: Iterator[np.ndarray | Frame], *, with_frames: bool) -> tuple[Iterator[np.ndarray], Iterator[Frame]]:
    """Split one pass of event arrays and Frames into an event iterator and a frame iterator,
    each reading ahead in the shared pass only as far as it needs (merge_stream's two inputs)."""
    queues: dict[bool, collections.deque] = {True: collections.deque(), False: collections.deque()}

    def side(frames: bool) -> Iterator:
        own = queues[frames]
        while True:
            while not own:
                item = next(items, None)
                if item is None:
                    return
                queues[isinstance(item, Frame)].append(item)
            yield own.popleft()

    return side(False), side(True) if with_frames else iter(())


def read_info(path: str | os.PathLike) -> RecordingInfo:
    """Camera name, resolution, exact event and frame counts and time span of a recording.

    Raises RecordingError for a missing, non-AEDAT4, truncated or corrupt file.
    """
    with RecordingReader(path) as reader:
        return reader.info
