"""Pacing and batching: how a source's events are cut into batches and merged with its APS
frames into the stream every source yields (docs/architecture.md, sources), and read ahead in
bursts while the gel rests (docs/performance.md, "At rest").

Time is int64 microseconds of the camera clock; events are arrays of
:data:`~neurotouch_hid.sources.EVENT_DTYPE`, cut with numpy (a whole chunk at once).
"""

from __future__ import annotations

import collections
import itertools
from typing import Iterable, Iterator

import numpy as np

from neurotouch_hid.sources import EVENT_DTYPE, Frame, StreamItem, WrappedStream, join_events

#: While the gel rests, a paced source reads this far ahead (us of camera time) in one go
#: (:func:`read_ahead`): 5 APS frame periods.
REST_READ_AHEAD_US = 200_000
#: The most one read ahead holds (bytes of events and APS frames' pixels).
REST_READ_AHEAD_BYTES = 4 << 20


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
