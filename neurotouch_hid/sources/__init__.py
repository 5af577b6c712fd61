"""Where events and APS frames come from: a live DAVIS-346, an AEDAT4 recording, the simulated gel.

Every source yields the same stream: event batches (numpy structured arrays of
:data:`EVENT_DTYPE`) and :class:`Frame` values, merged in time order.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Generator
from dataclasses import dataclass
from enum import StrEnum
from typing import TYPE_CHECKING, Callable, Iterator, Sequence, Union

import numpy as np

if TYPE_CHECKING:
    from neurotouch_hid.core.dataset import LabelRow
    from neurotouch_hid.sources.batches import BatchCut

#: dv-processing's ``EventStore.numpy()`` fields: timestamp us (int64), x, y px (int16),
#: polarity (int8, 1 = ON brighter, 0 = OFF darker). dv-processing pads each record to 16 bytes;
#: this is the packed (13-byte) form, which is what numpy itself makes of that dtype whenever
#: arrays are concatenated or promoted, so every array in the project has one dtype.
EVENT_DTYPE = np.dtype([("timestamp", "<i8"), ("x", "<i2"), ("y", "<i2"), ("polarity", "i1")])


def join_events(batches: Sequence[np.ndarray]) -> np.ndarray:
    """The event batches as one array, in order: (N,) :data:`EVENT_DTYPE`, N the sum of their
    lengths; the one batch itself when there is one.

    ``np.concatenate`` of structured arrays promotes their dtypes field by field in Python
    (~4 us a batch); batches of :data:`EVENT_DTYPE` are joined as their bytes instead, the same
    records. A batch of another dtype (or not contiguous) goes through ``np.concatenate``.
    Raises ValueError when ``batches`` is empty."""
    if not batches:
        raise ValueError("no event batches to join")
    if len(batches) == 1:
        return batches[0]
    if all(b.dtype == EVENT_DTYPE and b.flags.c_contiguous for b in batches):
        return np.concatenate([b.view(np.uint8) for b in batches]).view(EVENT_DTYPE)
    return np.concatenate(batches)


@dataclass(frozen=True)
class Frame:
    """One APS frame.

    Attributes:
        t_us: timestamp (int microseconds, camera clock; the exposure's start as DV records it).
        image: uint8 array of shape (260, 346) for a DAVIS-346, grey levels.
    """

    t_us: int
    image: np.ndarray


class StatusKind(StrEnum):
    """What changed in a live source (:class:`SourceStatus`)."""

    WAITING = "waiting"  #: no camera yet, waiting for one
    LOST = "lost"  #: unplugged, stalled or failing: no data follows until RESUMED
    RESUMED = "resumed"  #: a camera delivers data again (a new session; its clock may have restarted)


@dataclass(frozen=True)
class SourceStatus:
    """A change in a live source's state, in its stream between the data (only from a live camera
    asked to survive faults: :meth:`DavisSource.stream` with ``reconnect=True``).

    Attributes:
        kind: a :class:`StatusKind`.
        message: one line for the user: what happened and what the driver does about it.
    """

    kind: StatusKind
    message: str


@dataclass(frozen=True)
class Performed:
    """What a source that knows its truth (the simulated hand) performs from ``label.t_us`` on,
    in its stream just before the APS frame of that moment.

    Attributes:
        label: the simulator's label (:class:`~neurotouch_hid.core.dataset.LabelRow`: type,
            intensity in mm, contact points in image px; docs/dataset.md).
    """

    label: LabelRow


#: One item of a source's stream: an event batch (EVENT_DTYPE array, time-ordered), a frame, or
#: (live camera only) a :class:`SourceStatus`.
StreamItem = Union[np.ndarray, Frame, SourceStatus]
Stream = Iterator[StreamItem]


class PollPause:
    """How long a live source waits after a poll of its device that brought nothing new (s):
    ``default_s``, unless its consumer set ``decide`` (called, in the source's thread, each time
    instead). The runtime does while the gel rests: it hands on what it holds and waits until
    the next window's end, one wake-up a window (docs/performance.md, "At rest"). The consumer
    may also set ``resting``, which says whether the gel rests now, so that the source may let
    its device send less often meanwhile (the camera's USB early packet delay,
    ``sources/davis.py``).

    Attributes:
        default_s: the source's own pause (s).
        decide: None, or the consumer's ``() -> seconds``.
        resting: None, or the consumer's ``() -> the resting windows' length (us), or None
            while the gel does not rest``.
    """

    def __init__(self, default_s: float) -> None:
        self.default_s = default_s
        self.decide: Callable[[], float] | None = None
        self.resting: Callable[[], int | None] | None = None

    def __call__(self) -> float:
        decide = self.decide
        return self.default_s if decide is None else decide()

    def resting_window_us(self) -> int | None:
        """The resting windows' length (us) while the consumer says the gel rests, else None."""
        resting = self.resting
        return None if resting is None else resting()


class WrappedStream:
    """A source's stream (:class:`~neurotouch_hid.core.stages.SourceStream`): the items of ``items``,
    as they come, closed with :meth:`close`, and the hooks its consumer may set, None where the
    source has none (:class:`PausingStream`'s poll pause, ``batches.CuttingStream``'s batch
    cut)."""

    #: a live source's pause between polls that bring nothing (:class:`PollPause`), or None
    poll_pause: PollPause | None = None
    #: where a source cuts its event batches (``batches.BatchCut``), or None
    batch_cut: BatchCut | None = None

    def __init__(self, items: Iterator[StreamItem]) -> None:
        self._items = items

    def __iter__(self) -> "WrappedStream":
        return self

    def __next__(self) -> StreamItem:
        return next(self._items)

    def close(self) -> None:
        """Close the underlying generator or stream (its source's ``finally``)."""
        if isinstance(self._items, (Generator, WrappedStream)):
            self._items.close()


class PausingStream(WrappedStream):
    """A live source's stream and the :class:`PollPause` its polls wait by, ``poll_pause``, for
    its consumer to set."""

    def __init__(self, items: Iterator[StreamItem], poll_pause: PollPause) -> None:
        super().__init__(items)
        self.poll_pause = poll_pause


#: Waits up to this long (s) are slept through (``time.sleep``; a stop is seen after it), longer
#: ones wait on the stop event: a wake-up from a plain sleep costs ~15 us less CPU on this VM
#: (docs/performance.md, "At rest"), and a paced source waits about a window at a time.
SHORT_SLEEP_S = 0.02


def _sleep_or_stop(stop: threading.Event, seconds: float) -> bool:
    """Wait ``seconds`` or until ``stop`` is set (a short wait: until it is over); returns whether
    ``stop`` is set."""
    if seconds <= SHORT_SLEEP_S:
        time.sleep(seconds)
        return stop.is_set()
    return stop.wait(seconds)


class Pacer:
    """Keeps a stream on time: item timestamps (us, camera clock) follow wall time
    (``time.perf_counter_ns``) from the first item on, as a camera delivers them. One pacing
    rule for the runtime (recordings and the simulated gel, ``run``) and for ``record``.

    Args:
        clock: the clock (ns) items are paced on; ``time.perf_counter_ns``, or one a test controls.
        sleep: ``sleep(stop, seconds)`` waits up to ``seconds`` on ``clock`` or until ``stop`` is
            set, returning whether it was; None = wall time: ``time.sleep`` up to
            :data:`SHORT_SLEEP_S`, ``stop.wait(seconds)`` beyond.

    Attributes:
        first_us: the first item's timestamp (us), the anchor; None before the first item.
        first_ns: ``clock()`` when the first item was seen (0 before).
    """

    def __init__(
        self,
        clock: Callable[[], int] = time.perf_counter_ns,
        sleep: Callable[[threading.Event, float], bool] | None = None,
    ) -> None:
        self.first_us: int | None = None
        self.first_ns = 0
        self._clock = clock
        self._anchor_ns: int | None = None  # anchor_now's
        self._sleep = sleep if sleep is not None else _sleep_or_stop

    def now_ns(self) -> int:
        """The clock's time now (ns)."""
        return self._clock()

    def anchor_now(self) -> None:
        """Anchor the clock now, before the first item: it is due now whenever it comes, and a
        source that waited for it (the simulated gel while a first run compiles it) catches up."""
        self._anchor_ns = self._clock()

    def due_ns(self, t_us: int) -> int:
        """The ``clock()`` (ns) at which an item stamped ``t_us`` is due; the first call
        anchors the clock at ``t_us`` = now (or when :meth:`anchor_now` was called)."""
        if self.first_us is None:
            self.first_us = t_us
            self.first_ns = self._clock() if self._anchor_ns is None else self._anchor_ns
        return self.first_ns + (t_us - self.first_us) * 1000

    def wait(self, t_us: int, stop: threading.Event) -> bool:
        """Sleep until an item stamped ``t_us`` is due, or until ``stop`` is set; returns
        whether ``stop`` was set (the caller then stops)."""
        delay_ns = self.due_ns(t_us) - self._clock()
        return delay_ns > 0 and self._sleep(stop, delay_ns / 1e9)
