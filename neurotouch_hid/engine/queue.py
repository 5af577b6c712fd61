"""The bounded queues between the engine's threads (:class:`DropOldestQueue`), and the camera-time
extent of a stream item.

Between the source's thread and the pipeline's (and the resting detector's) sit bounded queues.
When the pipeline falls behind a live or paced source, it takes the event batches queued
meanwhile in one call (the same events, its per-call cost paid once:
:meth:`DropOldestQueue.get_joined`); when the queue is full all the same, it drops its OLDEST
items (counted by its ``on_drop``) instead of letting the controller lag. A ``--fast`` run drops
nothing: the source waits for room.
"""

from __future__ import annotations

import collections
import threading
from typing import Callable, Optional

import numpy as np

from neurotouch_hid.core.estimate import GestureEstimate
from neurotouch_hid.sources import Frame, StreamItem, join_events

#: At most this many events in one pipeline call when the pipeline catches up on queued batches
#: (:meth:`DropOldestQueue.get_joined`): about 0.1 s at the camera's 12 M events/s USB maximum.
MAX_JOINED_EVENTS = 1_000_000
#: Frame queue bound for the resting detector (APS frames, 25 Hz).
DEFAULT_FRAME_QUEUE = 2
#: A producer waiting for room looks again at least this often (s); a consumer's default wait.
POLL_S = 0.05


def item_start_us(item: StreamItem | GestureEstimate) -> Optional[int]:
    """The time (us, camera clock) at which a stream item starts: a frame's or estimate's
    timestamp, an event batch's first event timestamp; None for an empty batch."""
    if isinstance(item, (Frame, GestureEstimate)):
        return int(item.t_us)
    if len(item) == 0:
        return None
    return int(item["timestamp"][0])


def item_end_us(item: StreamItem | GestureEstimate) -> Optional[int]:
    """The time (us, camera clock) at which a stream item is complete: a frame's timestamp, an event
    batch's last event timestamp, a replayed estimate's window end; None for an empty batch."""
    if isinstance(item, (Frame, GestureEstimate)):
        return int(item.t_us)
    if len(item) == 0:
        return None
    return int(item["timestamp"][-1])


class DropOldestQueue:
    """A bounded FIFO between two threads.

    ``put`` on a full queue drops the oldest item (counted in ``stats``) when ``drop_oldest``, else
    waits for room. With ``drop_oldest`` (or ``span_waits``: then ``put`` waits) the queue is also
    full when it would span more than ``max_span_us`` of camera time (from the oldest item's
    start to the new one's end). ``close``
    ends the stream: ``get`` returns None once a closed queue is empty. Items are
    ``(arrival_ns, StreamItem)`` pairs.
    """

    def __init__(
        self,
        maxlen: int,
        *,
        drop_oldest: bool = True,
        on_drop: Callable[[StreamItem], None] | None = None,
        max_span_us: int | None = None,
        span_waits: bool = False,
    ):
        if maxlen < 1:
            raise ValueError("a queue needs room for at least one item")
        self._items: collections.deque = collections.deque()
        self._maxlen = maxlen
        self._drop_oldest = drop_oldest
        self._on_drop = on_drop
        self._max_span_us = max_span_us
        self._span_waits = span_waits
        #: the condition's own lock, taken alone where nothing waits or is notified (each item of a
        #: resting run is claimed and done: no Python-level ``Condition.__enter__`` then)
        self._lock = threading.RLock()
        self._cond = threading.Condition(self._lock)
        self._closed = False
        self._taken = False  # an item is being processed (:meth:`done` ends it)
        #: how many queued items the last :meth:`get_joined` returned as one (the consumer's to read)
        self.joined = 0

    def _too_long(self, item: StreamItem) -> bool:
        if self._max_span_us is None or not (self._drop_oldest or self._span_waits) or not self._items:
            return False
        start, end = item_start_us(self._items[0][1]), item_end_us(item)
        return start is not None and end is not None and end - start > self._max_span_us

    def put(self, entry: tuple[int, StreamItem]) -> None:
        with self._cond:
            while (len(self._items) >= self._maxlen or self._too_long(entry[1])) and not self._closed:
                if self._drop_oldest:
                    _, old = self._items.popleft()
                    if self._on_drop is not None:
                        self._on_drop(old)
                else:
                    self._cond.wait(POLL_S)
            if self._closed:
                return
            self._items.append(entry)
            self._cond.notify_all()

    def get(self, timeout: float = POLL_S) -> tuple[int, StreamItem] | None:
        """The oldest entry; None when closed and empty or when ``timeout`` (s) passed."""
        return self.get_joined(timeout)

    def get_joined(self, timeout: float = POLL_S, max_events: int = 0) -> tuple[int, StreamItem] | None:
        """Like :meth:`get`, but an event batch comes with the event batches queued right behind it
        joined on (one EVENT_DTYPE array, in order, at most ``max_events`` events; APS frames and
        other items are never joined, nor passed), and the first one's arrival time.

        So a consumer that fell behind pays its per-call cost once for all it missed, instead of
        the queue dropping data: the same events in the same order (a slow machine, e.g. the
        emulated test kernel, then tracks everything at a coarser pace)."""
        with self._cond:
            if not self._items and not self._closed:
                self._cond.wait(timeout)
            if not self._items:
                return None
            arrival_ns, item = self._items.popleft()
            self._taken = True
            parts = [item]
            if isinstance(item, np.ndarray):
                n = len(item)
                while self._items and isinstance(self._items[0][1], np.ndarray):
                    if n + len(self._items[0][1]) > max_events:
                        break
                    parts.append(self._items.popleft()[1])
                    n += len(parts[-1])
            self.joined = len(parts)
            self._cond.notify_all()
        return arrival_ns, (join_events(parts) if len(parts) > 1 else item)

    def done(self) -> None:
        """The consumer is done with the entry it took (:meth:`get_joined`, :meth:`claim`)."""
        with self._lock:
            self._taken = False

    def claim(self) -> bool:
        """Whether the caller may process an item itself, in the consumer's place: nothing is
        queued or being processed (then the queue counts it as taken until :meth:`done`, and the
        consumer takes nothing meanwhile)."""
        with self._lock:
            if self._items or self._taken or self._closed:
                return False
            self._taken = True
            return True

    def clear(self) -> None:
        """Drop every queued item (each counted like a drop-oldest one)."""
        with self._cond:
            while self._items:
                _, old = self._items.popleft()
                if self._on_drop is not None:
                    self._on_drop(old)
            self._cond.notify_all()

    def close(self) -> None:
        """No more puts; wakes every waiting thread."""
        with self._cond:
            self._closed = True
            self._cond.notify_all()

    @property
    def finished(self) -> bool:
        """Closed and empty."""
        with self._cond:
            return self._closed and not self._items

    @property
    def busy(self) -> bool:
        """Something is queued or being processed (taken and not yet :meth:`done`)."""
        with self._cond:
            return bool(self._items) or self._taken

    def __len__(self) -> int:
        return len(self._items)
