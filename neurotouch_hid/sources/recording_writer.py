"""AEDAT4 recordings written with dv-processing, and a live source recorded.

Writing goes through dv-processing's ``MonoCameraWriter`` (iniVation's own library, the format DV
records; docs/dataset.md, section SEQUENCE.aedat4): events and APS frames checked (time order,
inside the sensor, the frame's shape), the disk's room checked before each write (a write that
fails in dv-processing's own thread aborts the process), and a live source recorded beside its
path, renamed in place (``neurotouch-hid record``, :func:`record_stream`). Reading is
:mod:`neurotouch_hid.sources.recording`.

Time is int64 microseconds of the camera clock everywhere.
"""

from __future__ import annotations

import contextlib
import os
import threading
from dataclasses import dataclass
from pathlib import Path
from typing import Iterable, Iterator, TypeVar

import numpy as np

from neurotouch_hid.core.atomic import PathBeside
from neurotouch_hid.core.errors import RecordingError
from neurotouch_hid.sources import EVENT_DTYPE, Frame, Pacer, StreamItem, join_events
from neurotouch_hid.sources.dv import DV_ERRORS, dv_error_text, store_from_events
from neurotouch_hid.sources.recording_checks import AEDAT4_SUFFIX

_Item = TypeVar("_Item")

#: Events per AEDAT4 packet written by :class:`RecordingWriter` (dv-processing writes one packet
#: per ``writeEvents`` call; this keeps packets few and truncation losses small).
PACKET_EVENTS = 10_000
#: Space a recording keeps free on its disk (bytes) beyond twice the data handed to
#: dv-processing at once: its writer thread writes behind the caller, and a write it cannot make
#: (a full disk) throws in that thread, which aborts the process (``std::terminate``). The writer
#: stops, with a RecordingError, before the disk is that full; the index table written at the end
#: takes :data:`TABLE_BYTES_PER_PACKET` per packet on top.
DISK_RESERVE_BYTES = 4 << 20
#: The index table's bytes per packet (an offset, a size and two timestamps, with framing).
TABLE_BYTES_PER_PACKET = 64


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
