"""AEDAT4 recordings: read with the ``aedat`` decoder, write with dv-processing.

Reading goes through the ``aedat`` package (a decoder written in Rust, memory-safe: a damaged
file gives an error, never a hang or a crash) and writing through dv-processing's
``MonoCameraWriter`` (iniVation's own library, the format DV records; docs/dataset.md, section
SEQUENCE.aedat4). dv-processing 2.0's reader can hang for ever in LZ4 decompression or crash on
a damaged file (docs/performance.md, "Recording I/O", has the measurements and the choice).
This module adds:

- one clear :class:`~neurotouch_hid.core.errors.RecordingError` per bad file (missing, not AEDAT4,
  truncated, damaged, no frame stream, wrong resolution);
- reading what is readable of a cut or damaged file: packets that do not decode, or whose events
  lie outside the sensor or go back in time, are skipped (the numba pipeline does not check
  bounds), and the reader raises once after yielding the rest;
- the merged, time-ordered stream of event batches and :class:`Frame` values every source yields
  (docs/architecture.md, sources);
- conversion between dv-processing's containers and numpy arrays of :data:`EVENT_DTYPE`.

Time is int64 microseconds of the camera clock everywhere.
"""

from __future__ import annotations

import collections
import contextlib
import itertools
import os
import struct
import threading
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path
from typing import TYPE_CHECKING, Iterable, Iterator, TypeVar

import numpy as np

from neurotouch_hid.core.atomic import PathBeside
from neurotouch_hid.core.errors import RecordingError
from neurotouch_hid.core.limits import printable
from neurotouch_hid.sources import EVENT_DTYPE, Frame, Pacer, StreamItem, WrappedStream, join_events
from neurotouch_hid.sources.dv import DV_ERRORS, dv_error_text, store_from_events
from neurotouch_hid.sources.packet_bounds import Unbounded, inflated_bound

_Item = TypeVar("_Item")

if TYPE_CHECKING:  # pragma: no cover
    pass

#: The first bytes of every AEDAT4 file (the format's version line).
AEDAT4_MAGIC = b"#!AER-DAT4.0\r\n"
#: dv-processing refuses other file name endings (and its writer aborts the process on them).
AEDAT4_SUFFIX = ".aedat4"
#: Events per AEDAT4 packet written by :class:`RecordingWriter` (dv-processing writes one packet
#: per ``writeEvents`` call; this keeps packets few and truncation losses small).
PACKET_EVENTS = 10_000
#: The DAVIS-346's pixel array, (width, height) px.
DAVIS346_RESOLUTION = (346, 260)
#: The ``aedat`` decoder's event record: EVENT_DTYPE's layout (same offsets and sizes).
AEDAT_EVENT_DTYPE = np.dtype([("t", "<u8"), ("x", "<u2"), ("y", "<u2"), (("p", "on"), "?")])
#: The largest AEDAT4 header read (a real one is a few kB; a damaged size field must not make
#: the reader allocate gigabytes).
MAX_HEADER_BYTES = 16 << 20
#: Timestamps above this (us, ~146 000 years) are damaged data: they would overflow int64 maths.
MAX_TIMESTAMP_US = 1 << 62
#: A pass over a file ends after this many damaged packets in a row (nothing left to read).
MAX_CONSECUTIVE_ERRORS = 64
#: The most one packet may be, stored or inflated (bytes): the decoder holds a packet whole. A
#: DAVIS-346 packet is 10-200 KB (a 10 ms batch, or a 90 KB APS frame); 64 MiB is 5 million events.
MAX_PACKET_BYTES = 64 << 20
#: Inflated bytes (bounded from the packets' framing, packet_bounds.py) per stored byte, over the
#: file read so far, beyond :data:`MIN_INFLATE_BUDGET`: real event data compresses 3-10x, and the
#: bound counts up to a block's maximum for a tiny block (single-event packets reach ~2000x).
MAX_INFLATE_RATIO = 4096
#: Inflated bytes any recording may reach before :data:`MAX_INFLATE_RATIO` applies.
MIN_INFLATE_BUDGET = 1 << 30
#: Space a recording keeps free on its disk (bytes) beyond twice the data handed to
#: dv-processing at once: its writer thread writes behind the caller, and a write it cannot make
#: (a full disk) throws in that thread, which aborts the process (``std::terminate``). The writer
#: stops, with a RecordingError, before the disk is that full; the index table written at the end
#: takes :data:`TABLE_BYTES_PER_PACKET` per packet on top.
DISK_RESERVE_BYTES = 4 << 20
#: The index table's bytes per packet (an offset, a size and two timestamps, with framing).
TABLE_BYTES_PER_PACKET = 64
#: While the gel rests, a paced source reads this far ahead (us of camera time) in one go
#: (:func:`read_ahead`): 5 APS frame periods.
REST_READ_AHEAD_US = 200_000
#: The most one read ahead holds (bytes of events and APS frames' pixels).
REST_READ_AHEAD_BYTES = 4 << 20


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


class BatchCut:
    """Where a source cuts its event batches: at every ``phase_us + k * length_us`` (us, camera
    time), read each time a source cuts a chunk of events, so its reader may change it as it
    goes. The runtime does while the gel rests (``runtime.Runtime``): one batch a window, cut at
    the window ends, instead of a window's worth of short batches, each a few microseconds of
    Python in every stage it passes (docs/performance.md, "At rest").

    Args:
        length_us: the batch length outside a rest (us), > 0.
    Attributes:
        value: (length_us, phase_us) now; set as one tuple, so a reader in another thread sees
            either the old cut or the new one.
    """

    def __init__(self, length_us: int) -> None:
        if length_us <= 0:
            raise ValueError(f"batch length must be positive, got {length_us} us")
        self.base_us = int(length_us)
        self.value = (self.base_us, 0)
        #: the last timestamp (us) of events cut otherwise than at the base length; -1: none
        #: waiting (:class:`CuttingStream` cuts those again once the base length is back)
        self.longer_until_us = -1

    def follow(self, rest: tuple[int, int] | None, after_us: int = 0) -> None:
        """Cut once a window of a rest, ``(window end, window length)`` in us, ``after_us`` after
        each window end (a batch then closes its window, as the 1 ms batch after the end did), or
        at the base length outside a rest (None)."""
        self.value = (self.base_us, 0) if rest is None else (rest[1], (rest[0] + after_us) % rest[1])

    @property
    def resting(self) -> bool:
        """Whether batches are cut once a window of a rest now (:meth:`follow`)."""
        return self.value[0] != self.base_us

    def index(self, ts: np.ndarray) -> np.ndarray:
        """(N,) int64: the batch each timestamp of ``ts`` ((N,) int64 us) falls in."""
        length_us, phase_us = self.value
        if length_us != self.base_us and len(ts):
            self.longer_until_us = max(self.longer_until_us, int(ts[-1]))
        return (ts - phase_us) // length_us if phase_us else ts // length_us


class CuttingStream(WrappedStream):
    """A source's stream whose batches are cut as ``batch_cut`` (:class:`BatchCut`) says, for its
    consumer to change (``runtime.Runtime``, while the gel rests), as ``PausingStream`` carries
    its ``poll_pause``. A source cuts a chunk of events (a file's packet, a simulated APS
    frame's events) at once: when the base length is back, the longer batches of a chunk cut
    before are cut again here at the base length, so that from then on every batch is as
    without a rest."""

    def __init__(self, items: Iterator[StreamItem], batch_cut: BatchCut) -> None:
        super().__init__(items)
        self.batch_cut = batch_cut
        self._parts: collections.deque = collections.deque()

    def __next__(self) -> StreamItem:
        if self._parts:
            return self._parts.popleft()
        item = next(self._items)
        cut = self.batch_cut
        if cut.longer_until_us < 0 or type(item) is not np.ndarray or cut.resting:
            return item
        if int(item["timestamp"][0]) > cut.longer_until_us:
            cut.longer_until_us = -1
            return item
        self._parts.extend(split_batches(item, cut.base_us))
        return self._parts.popleft()


def read_ahead(
    items: Iterable[StreamItem],
    cut: BatchCut,
    *,
    span_us: int = REST_READ_AHEAD_US,
    max_bytes: int = REST_READ_AHEAD_BYTES,
) -> Iterator[StreamItem]:
    """``items`` in the same order, read in bursts while the gel rests.

    Whenever none is left over and ``cut`` says the gel rests (:attr:`BatchCut.resting`), the
    next items are read at once until they span ``span_us`` (us of camera time) or hold
    ``max_bytes`` (:func:`item_span`); otherwise one at a time. A paced source waits between
    windows, and what it reads after a wait runs on a cold core, several times its cost back to
    back (an AEDAT4 packet's decoding 340 against 80 us, docs/performance.md, "At rest"): read in
    a burst, the items after the first are read hot. The items are handed on as paced as before.

    Args:
        items: a source's stream items (event batches, APS frames, a simulation's labels), in
            time order.
        cut: the source's :class:`BatchCut`, which the runtime sets while the gel rests.
        span_us, max_bytes: a burst's bounds: it ends with the first item that starts
            ``span_us`` or more after its first one, or brings what it holds to ``max_bytes``.
    Yields:
        the items; an error raised while reading a burst is raised once the items read before it
        are yielded. Closing this closes ``items``.
    """
    source = iter(items)
    ahead: collections.deque = collections.deque()
    failed: Exception | None = None  # met in the last burst, raised once its items are yielded
    try:
        while True:
            if not ahead:
                if failed is not None:
                    raise failed
                try:
                    ahead.append(next(source))
                    if cut.resting:
                        first = None
                        held = 0
                        while True:
                            span = item_span(ahead[-1])
                            if span is not None:
                                first = span[0] if first is None else first
                                held += span[1]
                                if span[0] - first >= span_us or held >= max_bytes:
                                    break
                            ahead.append(next(source))
                except StopIteration:
                    if not ahead:
                        return
                except Exception as exc:  # (an interrupt is not held back)
                    if not ahead:
                        raise
                    failed = exc
            yield ahead.popleft()
    finally:
        close = getattr(source, "close", None)
        if close is not None:
            close()  # the source's own ``finally`` now, not when collected


def item_span(item: object) -> tuple[int, int] | None:
    """A stream item's first timestamp (us) and the bytes it holds (an event batch's, an APS
    frame's pixels), None for any other item (a burst's bounds in :func:`read_ahead`)."""
    if type(item) is np.ndarray:
        return (int(item["timestamp"][0]), item.nbytes) if len(item) else None
    if type(item) is Frame:
        return item.t_us, item.image.nbytes
    return None


def _cut_of(batch: int | BatchCut) -> BatchCut:
    return batch if isinstance(batch, BatchCut) else BatchCut(batch)


def split_batches(events: np.ndarray, batch_us: int | BatchCut) -> list[np.ndarray]:
    """Cut time-ordered events at every multiple of ``batch_us`` (us), or where a
    :class:`BatchCut` says; empty pieces are dropped.

    Returns views of ``events``. Used for the batches every source yields.
    """
    if len(events) == 0:
        return []
    batch = _cut_of(batch_us).index(np.ascontiguousarray(events["timestamp"]))  # a gap costs nothing
    cuts = np.flatnonzero(batch[1:] != batch[:-1]) + 1
    return np.split(events, cuts)


def grey_image(image: np.ndarray) -> np.ndarray:
    """An APS frame's image as a 2-D uint8 array (colour DAVIS frames become grey, OpenCV)."""
    if image.ndim == 3:
        import cv2

        image = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY if image.shape[2] == 3 else cv2.COLOR_BGRA2GRAY)
    return image


# --- opening a file ---------------------------------------------------------------------------
def _check_path(path: Path) -> None:
    """Raise RecordingError unless ``path`` is an existing, readable regular file named ``*.aedat4``."""
    try:
        path.stat()
    except OSError as exc:  # missing, a name too long, a loop of links
        why = "no such file" if isinstance(exc, FileNotFoundError) else exc.strerror
        raise RecordingError(f"{path}: {why}") from None
    if not path.is_file():  # a pipe would block the reader, a device never ends
        what = "a directory" if path.is_dir() else "not a regular file (a pipe or a device)"
        raise RecordingError(f"{path}: is {what}, not an AEDAT4 recording")
    if not os.access(path, os.R_OK):
        raise RecordingError(f"{path}: cannot read the file (permission denied)")
    if path.suffix != AEDAT4_SUFFIX:
        raise RecordingError(
            f"{path}: not an AEDAT4 recording (its name must end in '{AEDAT4_SUFFIX}', which dv-processing requires)"
        )


def _read_header(path: Path) -> tuple[int, str, int, int]:
    """Read the AEDAT4 header: ``(dataTablePosition, infoNode XML, compression, end of header)``.

    The header is the version line, a little-endian uint32 size and an ``IOHeader`` flatbuffer
    (fields: compression, dataTablePosition int64 default -1 = no table, infoNode string, the
    streams' description as XML). Raises RecordingError when the file is not AEDAT4 or its
    header is incomplete or corrupt.
    """
    with open(path, "rb") as fh:
        head = fh.read(len(AEDAT4_MAGIC) + 4)
        if not head.startswith(AEDAT4_MAGIC):
            if head.startswith(b"#!AER-DAT") and not AEDAT4_MAGIC.startswith(head):
                version = head.split(b"\r")[0].decode("ascii", "replace")[2:]
                raise RecordingError(f"{path}: is {version}, only AEDAT4 is supported")
            if not head or not AEDAT4_MAGIC.startswith(head):
                raise RecordingError(f"{path}: not an AEDAT4 recording (it does not start with '#!AER-DAT4.0')")
        if len(head) < len(AEDAT4_MAGIC) + 4:
            raise RecordingError(f"{path}: truncated: the file ends inside its AEDAT4 header ({len(head)} bytes)")
        (size,) = struct.unpack_from("<I", head, len(AEDAT4_MAGIC))
        header = fh.read(min(size, MAX_HEADER_BYTES))
    if len(header) < size:
        raise RecordingError(f"{path}: truncated or corrupt: the file ends inside its AEDAT4 header")

    def read(fmt: str, offset: int) -> tuple:
        # every offset checked: the decoder reads this header unchecked (a Rust panic, or an
        # abort, on an offset out of the buffer or a description that is not UTF-8)
        if offset < 0 or offset + struct.calcsize(fmt) > len(header):
            raise struct.error("out of the header")
        return struct.unpack_from(fmt, header, offset)

    try:
        (root,) = read("<I", 0)
        (vtable_back,) = read("<i", root)
        vtable = root - vtable_back
        (vtable_size,) = read("<H", vtable)
        read(f"<{vtable_size}s", vtable)
        fields = [read("<H", vtable + 4 + 2 * i)[0] if vtable_size >= 6 + 2 * i else 0 for i in range(3)]
        position = read("<q", root + fields[1])[0] if fields[1] else -1
        compression = read("<i", root + fields[0])[0] if fields[0] else 0
        xml = ""
        if fields[2]:
            start = root + fields[2] + read("<I", root + fields[2])[0]
            (length,) = read("<I", start)
            xml = read(f"<{length}s", start + 4)[0].decode("utf-8")
    except (struct.error, UnicodeDecodeError):
        raise RecordingError(f"{path}: corrupt AEDAT4 header") from None
    return position, xml, compression, len(AEDAT4_MAGIC) + 4 + size


def _camera_name(xml: str) -> str:
    """The event stream's ``source`` (the camera name) in the header's XML, or "unknown"."""
    import xml.etree.ElementTree as ElementTree

    try:
        root = ElementTree.fromstring(xml)
    except ElementTree.ParseError:
        return "unknown"
    for node in root.iter("node"):
        attrs = {a.get("key"): a.text for a in node.findall("attr")}
        if attrs.get("typeIdentifier") == "EVTS":
            for info in node.iter("node"):
                source = {a.get("key"): a.text for a in info.findall("attr")}.get("source")
                if source:
                    return source
    return "unknown"


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


class _InflateGuard:
    """Follows the decoder through the file (packets are int32 stream id, uint32 size, payload)
    and bounds each packet before the decoder reads it: its stored size, its inflated size (from
    its compression framing, :func:`~neurotouch_hid.sources.packet_bounds.inflated_bound`) and
    the inflated total so far (:data:`MAX_INFLATE_RATIO`)."""

    def __init__(self, path: Path, start: int, table_position: int, compression: int) -> None:
        self.path, self.pos, self.table, self.compression = path, start, table_position, compression
        self.fd = os.open(path, os.O_RDONLY | getattr(os, "O_CLOEXEC", 0))
        self.size = os.fstat(self.fd).st_size
        self.inflated = 0

    def close(self) -> None:
        os.close(self.fd)

    def check_next(self) -> str | None:
        """Why the next packet must not be read (the pass ends there), or None: read it. A packet
        that runs past the end of the file is not read either ("cut"): the decoder would reserve
        its declared size first."""
        if self.pos == self.table or self.pos + 8 > self.size:
            return None  # the decoder stops by itself here (it stops at the table only when exactly there)
        (length,) = struct.unpack("<I", os.pread(self.fd, 4, self.pos + 4))
        if self.pos + 8 + length > self.size:
            return "cut"
        if length > MAX_PACKET_BYTES:
            return f"a packet at byte {self.pos} stores {length} bytes (at most {MAX_PACKET_BYTES >> 20} MiB)"
        payload = os.pread(self.fd, length, self.pos + 8)
        try:
            bound = inflated_bound(payload, self.compression)
        except Unbounded as exc:
            return f"a packet at byte {self.pos} is {exc}, whose size cannot be bounded"
        if bound > MAX_PACKET_BYTES:
            return (
                f"a packet at byte {self.pos} of {length} bytes would inflate to up to {bound} bytes "
                f"(at most {MAX_PACKET_BYTES >> 20} MiB): a decompression bomb or a damaged file"
            )
        self.pos += 8 + length
        self.inflated += bound
        if self.inflated > max(MIN_INFLATE_BUDGET, MAX_INFLATE_RATIO * self.pos):
            return (
                f"its first {self.pos} bytes would inflate to up to {self.inflated} bytes (more than "
                f"{MAX_INFLATE_RATIO}x): a decompression bomb or a damaged file"
            )
        return None


class _Damage:
    """What one pass over a file found wrong: skipped packets, whether the file was cut, and why
    it was refused (a bound of :class:`_InflateGuard`)."""

    def __init__(self) -> None:
        self.skipped = 0
        self.first: str | None = None
        self.cut = False
        self.consecutive = 0
        self.refused: str | None = None

    def refuse(self, problem: str) -> None:
        """End the pass: ``problem`` is "cut" or why a packet was not read."""
        if problem == "cut":
            self.cut = True
        else:
            self.refused = problem

    def add(self, problem: str) -> bool:
        """Count a damaged packet; True when the pass must end (the file ends inside a packet, or
        :data:`MAX_CONSECUTIVE_ERRORS` packets in a row are damaged)."""
        if "fill whole buffer" in problem:  # Rust's UnexpectedEof: the file ends inside a packet
            self.cut = True
            return True
        self.skipped += 1
        self.first = self.first or problem
        self.consecutive += 1
        return self.consecutive >= MAX_CONSECUTIVE_ERRORS

    def describe(self) -> str | None:
        parts = [f"refused: {self.refused} (docs/limits.md)"] if self.refused else []
        if self.skipped:
            parts.append(f"corrupt: {self.skipped} damaged packet(s) skipped (the first: {self.first})")
        if self.cut:
            parts.append(
                "truncated: the file ends inside a packet (cut short, or a damaged packet size); "
                "the rest of the recording is missing"
            )
        return "; ".join(parts) or None


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


def merge_stream(
    event_chunks: Iterable[np.ndarray], frames: Iterable[Frame], batch_us: int | BatchCut
) -> Iterator[StreamItem]:
    """Merge time-ordered event chunks and frames into the stream every source yields.

    Args:
        event_chunks: time-ordered EVENT_DTYPE arrays of any size (e.g. one per file packet).
        frames: time-ordered :class:`Frame` values.
        batch_us: batch length, us: batches are cut at multiples of it (or where a
            :class:`BatchCut` says when a chunk is cut) and at frame timestamps.

    Yields event batches (non-empty EVENT_DTYPE arrays, views of the chunks) and frames; a frame
    comes before the events with timestamp >= its ``t_us``. The last batch of a chunk is held
    back until a later chunk shows it is complete, or the events end. Cut positions are found
    for a whole chunk at once (numpy), so a batch costs about a microsecond.
    """
    cutter = _cut_of(batch_us)
    frame_iter = iter(frames)
    pending = next(frame_iter, None)
    leftover = np.zeros(0, EVENT_DTYPE)
    for chunk in itertools.chain(event_chunks, [None]):
        final = chunk is None
        if not final and len(chunk) == 0:
            continue
        if final or not len(leftover):
            ev = leftover if final else chunk
        else:
            ev = join_events((leftover, chunk))
        ts = np.ascontiguousarray(ev["timestamp"])
        n = len(ev)
        # Frames whose preceding events are all here: the events are time-ordered, so every
        # event before a frame at t <= ts[-1] is in this chunk or before.
        taken: list[Frame] = []
        while pending is not None and (final or pending.t_us <= ts[-1]):
            taken.append(pending)
            pending = next(frame_iter, None)
        frame_at = np.searchsorted(ts, np.array([f.t_us for f in taken], dtype=np.int64), side="left")
        batch = cutter.index(ts)
        batch_starts = np.flatnonzero(batch[1:] != batch[:-1]) + 1
        if final:
            stop = n
        else:  # hold back the last, maybe incomplete batch (except what precedes a frame)
            stop = int(batch_starts[-1]) if len(batch_starts) else 0
            stop = max(stop, int(frame_at[-1])) if len(taken) else stop
        cuts = np.unique(np.concatenate((batch_starts[batch_starts < stop], frame_at, [stop])))
        prev = fi = 0
        for cut in cuts.tolist():
            if cut > prev:
                yield ev[prev:cut]
                prev = cut
            while fi < len(taken) and frame_at[fi] == cut:
                yield taken[fi]
                fi += 1
        leftover = ev[stop:]


def read_info(path: str | os.PathLike) -> RecordingInfo:
    """Camera name, resolution, exact event and frame counts and time span of a recording.

    Raises RecordingError for a missing, non-AEDAT4, truncated or corrupt file.
    """
    with RecordingReader(path) as reader:
        return reader.info


# --- writing ------------------------------------------------------------------------------------
class RecordingWriter:
    """Writes an AEDAT4 recording with dv-processing's ``MonoCameraWriter`` (LZ4 by default).

    Args:
        path: the file to create (must end in ``.aedat4``; its folder must exist).
        width, height: the sensor resolution, px.
        camera_name: the camera (source) name stored in the file.
        frames: also create an APS frame stream (``DAVISConfig``); False writes events only.
        compression: the packets' compression, a ``dv_processing.CompressionType`` name: NONE,
            LZ4, LZ4_HIGH, ZSTD or ZSTD_HIGH.

    Events are buffered and written in packets of :data:`PACKET_EVENTS`. The file is complete
    (index table written) once :meth:`close` returns; use as a context manager.

    Raises:
        RecordingError: bad path, or data that is not time-ordered / out of the sensor / of the
            wrong shape.
    """

    def __init__(
        self,
        path: str | os.PathLike,
        *,
        width: int = 346,
        height: int = 260,
        camera_name: str = "NeuroTouch-sim_DAVIS346",
        frames: bool = True,
        compression: str = "LZ4",
    ) -> None:
        import dv_processing as dv

        self.path = Path(path)
        self.width, self.height = int(width), int(height)
        if self.path.suffix != AEDAT4_SUFFIX:
            raise RecordingError(f"{self.path}: an AEDAT4 recording's name must end in '{AEDAT4_SUFFIX}'")
        if not self.path.parent.is_dir():
            raise RecordingError(f"{self.path}: cannot write, folder {self.path.parent} does not exist")
        if self.path.is_dir():
            raise RecordingError(f"{self.path}: cannot write, it is a directory")
        make = dv.io.MonoCameraWriter.DAVISConfig if frames else dv.io.MonoCameraWriter.EventOnlyConfig
        config = make(camera_name, (self.width, self.height))
        if compression not in dv.CompressionType.__members__:
            raise RecordingError(
                f"compression {compression!r}: expected one of {', '.join(dv.CompressionType.__members__)}"
            )
        config.compression = dv.CompressionType.__members__[compression]
        self._packets = 0
        self._room(0)
        try:
            self._writer = dv.io.MonoCameraWriter(str(self.path), config)
        except DV_ERRORS as exc:
            raise RecordingError(f"{self.path}: cannot write ({dv_error_text(str(exc))})") from None
        self.frames = frames
        self._pending: list[np.ndarray] = []
        self._n_pending = 0
        self._last_event_us = np.iinfo(np.int64).min
        self._last_frame_us = np.iinfo(np.int64).min

    def __enter__(self) -> "RecordingWriter":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def write_events(self, events: np.ndarray) -> None:
        """Append events: an array with EVENT_DTYPE's fields, time-ordered, after those already
        written; x in [0, width), y in [0, height) px, polarity 0 or 1.

        Raises RecordingError otherwise (nothing of this call is written then).
        """
        self._check_open()
        if events.dtype.names is None or not set(EVENT_DTYPE.names) <= set(events.dtype.names):
            raise RecordingError(f"{self.path}: events must have the fields {EVENT_DTYPE.names}, got {events.dtype}")
        if len(events) == 0:
            return
        ts = events["timestamp"]
        if ts[0] < self._last_event_us or (len(ts) > 1 and np.any(np.diff(ts) < 0)):
            raise RecordingError(f"{self.path}: events are not in time order (from t={int(ts[0])} us)")
        x, y, p = events["x"], events["y"], events["polarity"]
        if x.min() < 0 or x.max() >= self.width or y.min() < 0 or y.max() >= self.height:
            raise RecordingError(f"{self.path}: events outside the {self.width}x{self.height} px sensor")
        if p.min() < 0 or p.max() > 1:
            raise RecordingError(f"{self.path}: polarity must be 0 (OFF) or 1 (ON)")
        self._last_event_us = int(ts[-1])
        self._pending.append(events)
        self._n_pending += len(events)
        if self._n_pending >= PACKET_EVENTS:
            self._flush(final=False)

    def write_frame(self, frame: Frame) -> None:
        """Append an APS frame: uint8 image of shape (height, width), ``t_us`` after the last frame's.

        The timestamp is stored as is (dv-processing ``Frame.timestamp``). Raises RecordingError
        for a wrong shape or dtype, a frame out of time order, or a writer without frame stream.
        """
        import dv_processing as dv

        self._check_open()
        if not self.frames:
            raise RecordingError(f"{self.path}: this writer has no frame stream (frames=False)")
        image = np.asarray(frame.image)
        if image.dtype != np.uint8 or image.shape != (self.height, self.width):
            raise RecordingError(
                f"{self.path}: an APS frame must be uint8 of shape ({self.height}, "
                f"{self.width}), got {image.dtype} {image.shape}"
            )
        if frame.t_us < self._last_frame_us:
            raise RecordingError(f"{self.path}: frames are not in time order (t={frame.t_us} us)")
        # Keep event packets interleaved with frames in time, as DV records them.
        self._flush(final=True)
        self._last_frame_us = int(frame.t_us)
        self._room(image.nbytes)
        try:
            self._writer.writeFrame(dv.Frame(int(frame.t_us), np.ascontiguousarray(image)))
        except DV_ERRORS as exc:
            raise RecordingError(f"{self.path}: cannot write an APS frame ({dv_error_text(str(exc))})") from None

    def _flush(self, final: bool) -> None:
        """Write pending events in packets of PACKET_EVENTS (all of them when ``final``).

        A packet leaves the pending events as its write begins: an exception raised on the way
        (a termination signal's, which the CLI raises wherever the main thread is) leaves pending
        only what no write began, so :meth:`close` never writes a packet twice (dv-processing
        refuses events out of time order). A packet whose write the exception came just before
        is lost then: the run is stopping."""
        if not self._pending:
            return
        events = join_events(self._pending)
        stop = len(events) if final else len(events) - len(events) % PACKET_EVENTS
        begun = 0
        try:
            for start in range(0, stop, PACKET_EVENTS):
                packet = events[start : min(start + PACKET_EVENTS, stop)]
                self._room(packet.nbytes)
                begun = start + len(packet)
                self._writer.writeEvents(store_from_events(packet))
        except DV_ERRORS as exc:
            raise RecordingError(f"{self.path}: cannot write events ({dv_error_text(str(exc))})") from None
        except RecordingError:  # no room: what was not written is dropped, the file ends before it
            begun = len(events)
            raise
        finally:
            rest = events[begun:]
            self._pending = [rest] if len(rest) else []
            self._n_pending = len(rest)

    def _check_open(self) -> None:
        if self._writer is None:
            raise RecordingError(f"{self.path}: the writer is closed")

    def _room(self, nbytes: int) -> None:
        """Before ``nbytes`` of data go to dv-processing: the disk must have room for twice that,
        the index table and :data:`DISK_RESERVE_BYTES` (``os.statvfs``, the space an
        unprivileged user may use). Raises RecordingError naming the disk's free space otherwise:
        a write that fails in dv-processing's own thread would abort the process. Another process
        filling the disk faster than the reserve between two checks is not caught."""
        self._packets += 1
        need = 2 * nbytes + DISK_RESERVE_BYTES + TABLE_BYTES_PER_PACKET * self._packets
        try:
            info = os.statvfs(self.path.parent)
        except OSError as exc:
            raise RecordingError(f"{self.path}: cannot write ({exc.strerror or exc})") from None
        free = info.f_bavail * info.f_frsize
        if free < need:
            raise RecordingError(
                f"{self.path}: the disk is full ({free / 1e6:.1f} MB free in {self.path.parent}; a recording stops "
                f"when less than {need / 1e6:.1f} MB is left): free some space or record elsewhere"
            )

    def close(self) -> None:
        """Write pending events and finish the file (index table); idempotent."""
        if self._writer is None:
            return
        try:
            self._flush(final=True)
        finally:
            self._writer = None  # dv-processing finishes the file when the writer is destroyed


def write_recording(path: str | os.PathLike, events: np.ndarray, frames: Iterable[Frame], **kw) -> None:
    """Write events and APS frames to an AEDAT4 file in one call (keywords: RecordingWriter's).

    Events and frames are interleaved in time order, as a camera delivers them.
    Raises RecordingError (see :class:`RecordingWriter`).
    """
    with RecordingWriter(path, **kw) as writer:
        ts = np.ascontiguousarray(events["timestamp"])
        start = 0
        for frame in frames:
            k = int(np.searchsorted(ts, frame.t_us, side="left"))
            if k > start:
                writer.write_events(events[start:k])
            start = max(start, k)
            writer.write_frame(frame)
        if start < len(events):
            writer.write_events(events[start:])


def recorded(stream: Iterable[_Item], writer: RecordingWriter) -> Iterator[_Item]:
    """``stream``'s items, each APS :class:`Frame` and non-empty event batch written to
    ``writer`` before it is handed on (a tee: whoever reads the stream, the recording holds what
    it read); other items (a camera's status, the simulated hand's labels) pass unwritten.

    Raises RecordingError as :class:`RecordingWriter` does (the item is not handed on)."""
    for item in stream:
        if isinstance(item, Frame):
            writer.write_frame(item)
        elif isinstance(item, np.ndarray) and len(item):
            writer.write_events(item)
        yield item


# --- recording a live source ----------------------------------------------------------------------
@dataclass(frozen=True)
class RecordSummary:
    """What :func:`record_stream` wrote.

    Attributes:
        path: the AEDAT4 file (complete and readable, however the recording ended).
        events, frames: numbers written.
        duration_us: from the first to the last timestamp written (us, camera clock).
        stopped: True when ``stop`` ended it (Ctrl-C), False when the source or ``seconds`` did.
    """

    path: Path
    events: int
    frames: int
    duration_us: int
    stopped: bool


def record_stream(
    stream: Iterable[StreamItem],
    path: str | os.PathLike,
    *,
    camera_name: str,
    pace: bool = False,
    stop: threading.Event | None = None,
    on_progress=None,
) -> RecordSummary:
    """Write a source's events and APS frames to an AEDAT4 file (``neurotouch-hid record``).

    Args:
        stream: time-ordered event batches (EVENT_DTYPE) and :class:`Frame` values, e.g.
            ``DavisSource.stream(seconds)`` or ``SimulatedSource.stream(seconds)``; its end ends the
            recording.
        path: the ``.aedat4`` file to create (its folder must exist).
        camera_name: the camera (source) name stored in the file.
        pace: sleep so that the items' timestamps follow wall time (the simulated gel: a
            recording of N s takes N s, as with a camera); a camera paces itself.
        stop: set it (e.g. from a SIGINT handler) to end the recording after the current item.
        on_progress: called as ``on_progress(duration_us, events, frames)`` after each item.

    Returns:
        :class:`RecordSummary`. Whatever ends the recording (the stream's end, ``stop``, an error
        of the source such as a lost camera), the file is closed complete and readable first.

    Raises:
        RecordingError: the file cannot be written, or the disk is nearly full
            (:data:`DISK_RESERVE_BYTES`). It is written beside ``path``: renamed over it at the
            first item when nothing was there (a recording cut by the disk is then complete up to
            the cut), at the end only when a recording was there (``record --force``: it is kept
            as it was unless the new one is complete). OutputError: ``path`` is a link or a
            folder; the source's own errors once the file is in place.
    """
    if Path(path).suffix != AEDAT4_SUFFIX:  # said of ``path``, not of the temporary file beside it
        raise RecordingError(f"{path}: a recording's name must end in '{AEDAT4_SUFFIX}' (dv-processing requires it)")
    stop = stop or threading.Event()
    events = frames = 0
    first_us = last_us = None
    clock = Pacer()
    with PathBeside(path, what="recording") as out:
        # nothing there: the file is published at its first item (a crash keeps what was recorded);
        # a recording there (--force) is replaced only once the new one is complete
        early = not os.path.lexists(path)
        writer_failed = False
        try:
            writer = RecordingWriter(out.tmp, camera_name=camera_name)
        except RecordingError as exc:
            raise RecordingError(str(exc).replace(str(out.tmp), str(path))) from None
        try:
            for item in stream:
                try:
                    if isinstance(item, Frame):
                        writer.write_frame(item)
                        frames += 1
                        t_us = item.t_us
                    else:
                        writer.write_events(item)
                        events += len(item)
                        t_us = int(item["timestamp"][-1])
                except RecordingError as exc:  # the disk: the file ends before this item
                    with contextlib.suppress(RecordingError):
                        writer.close()
                    said = str(exc).replace(str(out.tmp), str(path))
                    if not out.published:
                        said = f"{said}; nothing recorded is kept, {path} is as it was"
                    else:
                        seconds = ((last_us or 0) - (first_us or 0)) / 1e6
                        said = f"{said}; the {seconds:.1f} s recorded until then are complete in {path}"
                    writer_failed = True  # not published below: what was there stays
                    raise RecordingError(said) from None
                if early:
                    out.publish()  # the writer goes on in the same file
                first_us = t_us if first_us is None else min(first_us, t_us)
                last_us = t_us if last_us is None else max(last_us, t_us)
                if on_progress is not None:
                    on_progress(last_us - first_us, events, frames)
                if pace:
                    clock.wait(last_us, stop)
                if stop.is_set():
                    break
        except BaseException:  # the source's error (a lost camera): the file is closed complete and kept
            with contextlib.suppress(RecordingError):
                writer.close()
            if not writer_failed and (events or frames):
                out.publish()
            raise
        writer.close()
    return RecordSummary(Path(path), events, frames, 0 if first_us is None else last_us - first_us, stop.is_set())
