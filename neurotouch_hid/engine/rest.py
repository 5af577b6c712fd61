"""The rest hand-over: while the gel rests, a window's items go on once a window, not once a batch.

While the gel rests, a paced source hands its items on once per window instead of once per 1 ms
batch: at each window's end plus :data:`REST_WAKE_AFTER_END_US` (the batch that closes the
window), with everything due by then, its event batches joined into one. Each window closes when
it would have; the first events of a touch wait at most one window; the engine's threads run once
per window instead of once per batch (docs/performance.md, "At rest"). A live source's polls that
bring nothing wait until the next window's end instead (:meth:`RestHandover.live_pause`).

:class:`RestHandover` owns that state: which windows rest (set by the thread that processes the
windows, read by the source's thread, behind one lock) and the items held meanwhile.
"""

from __future__ import annotations

import threading
from typing import TYPE_CHECKING, Callable

import numpy as np

from neurotouch_hid.engine.mode import DEFAULT_BATCH_US
from neurotouch_hid.sources import StreamItem, join_events

if TYPE_CHECKING:
    from neurotouch_hid.core.estimate import GestureEstimate
    from neurotouch_hid.sources import Pacer

#: While the gel rests, items are handed on at each window's end plus this much (us): the batch
#: that closes the window.
REST_WAKE_AFTER_END_US = DEFAULT_BATCH_US

#: (the last window's end, the window's length) (us, camera clock) while the gel rests.
RestWindows = tuple[int, int]


class RestHandover:
    """Which windows rest, and the items a resting gel's source holds until its next window's end.

    Args:
        clock: the run's :class:`~neurotouch_hid.sources.Pacer` (camera time -> wall time).
        stopped: set when the run stops (a held wait ends; nothing is handed on).
        hand_on: hands one item on to the pipeline (the engine's), from the source's thread.
        paced: the source is paced (held items wait for their time on ``clock``).
        default_pause_s: a live source's own poll pause (s), used outside a rest.

    Thread-safety: :meth:`window_closed` and :meth:`windows_skipped` come from the thread that
    processes the windows; the rest from the source's thread; the state both read is behind one
    lock.
    """

    def __init__(
        self,
        clock: Pacer,
        stopped: threading.Event,
        hand_on: Callable[[StreamItem], None],
        *,
        paced: bool,
        default_pause_s: float = 0.0,
    ) -> None:
        self._clock = clock
        self._stopped = stopped
        self._hand_on = hand_on
        self._paced = paced
        self._default_pause_s = default_pause_s
        self._lock = threading.Lock()
        self._windows: RestWindows | None = None
        self._last_end_us: int | None = None  # the last window's end (us)
        #: a resting gel's items, held until ``_held_us`` (camera time, us; a live source: until
        #: its poll brings nothing new), then handed on at once
        self._held: list[StreamItem] = []
        self._held_us = 0
        self._held_for: RestWindows | None = None  # the windows they were held at
        self._held_before_us = 2**62  # a batch ending there or later is past the run's ``seconds``
        self._read_us = self._read_ns = 0  # a live source's last item: its end (us), when read (clock ns)

    # --- the windows' side -----------------------------------------------------------------------
    def window_closed(self, estimate: GestureEstimate) -> None:
        """A window closed with ``estimate``: the gel rests from it on when it rests and a window
        closed before it (the window's length is then known), else it moves."""
        with self._lock:
            previous, self._last_end_us = self._last_end_us, estimate.t_us
            resting = estimate.resting and previous is not None and estimate.t_us > previous
            self._windows = (estimate.t_us, estimate.t_us - previous) if resting else None

    def windows_skipped(self, last_end_us: int) -> None:
        """Windows closed without an estimate (coalesced), the last ending at ``last_end_us`` (us)."""
        with self._lock:
            self._last_end_us = last_end_us

    @property
    def windows(self) -> RestWindows | None:
        """(the last window's end, the window's length) (us) while the gel rests, else None; the
        same object until a window changes it."""
        with self._lock:
            return self._windows

    def window_us(self) -> int | None:
        """The resting windows' length (us) while the gel rests, else None (a live source's
        :attr:`~neurotouch_hid.sources.PollPause.resting`)."""
        with self._lock:
            return None if self._windows is None else self._windows[1]

    # --- the source's side -----------------------------------------------------------------------
    def due_us(self, t_us: int, rest: RestWindows | None) -> int:
        """When (camera time, us) the item ending at ``t_us`` is handed on: then, or while the gel
        rests (``rest``), at the first window end + :data:`REST_WAKE_AFTER_END_US` not before it."""
        if rest is None:
            return t_us
        end, window_us = rest
        wake = end + REST_WAKE_AFTER_END_US
        return t_us if t_us <= wake else wake + -(-(t_us - wake) // window_us) * window_us

    def read(self, t_us: int) -> None:
        """A live source's item ending at ``t_us`` (us) was read now."""
        self._read_us, self._read_ns = t_us, self._clock.now_ns()

    @property
    def holding(self) -> bool:
        """Items are held."""
        with self._lock:
            return bool(self._held)

    @property
    def held_events(self) -> int:
        """How many items are held (an event batch counts its events, anything else 1)."""
        with self._lock:
            return sum(len(item) if isinstance(item, np.ndarray) else 1 for item in self._held)

    def joins_held(self, item: StreamItem, rest: RestWindows | None) -> bool:
        """Holds ``item`` with the held ones when it is an event batch of the resting window being
        held, within the run's limit (the common case at rest, in fewer steps); returns whether."""
        # only the source's thread changes what is held: nothing held is seen before the lock
        if rest is None or rest is not self._held_for or not self._held:
            return False
        if type(item) is not np.ndarray or not len(item):
            return False
        t_us = int(item["timestamp"][-1])
        if t_us > self._held_us or t_us >= self._held_before_us:
            return False
        with self._lock:
            if not self._held:
                return False
            self._held.append(item)
        return True

    def place(self, t_us: int, due_us: int) -> tuple[bool, bool]:
        """Where the item ending at ``t_us``, due at ``due_us``, goes: (whether the held items go
        on before it (it does not join them), whether it waits with the held items)."""
        with self._lock:
            held = bool(self._held)
            joins = due_us > t_us or (held and due_us == self._held_us)
            return held and not (joins and due_us == self._held_us), joins

    def hold(self, item: StreamItem, due_us: int, rest: RestWindows | None, before_us: int | None) -> None:
        """Hold ``item`` until ``due_us`` (camera time, us), at the windows ``rest``; a batch ending
        at ``before_us`` or later is past the run's ``seconds`` (None: no limit)."""
        with self._lock:
            self._held.append(item)
            self._held_us, self._held_for = due_us, rest
            if before_us is not None:
                self._held_before_us = before_us

    def release(self) -> bool:
        """The held items (a paced source: at their time), each run of event batches as one (in
        order; the pipeline's windows close inside a batch as between batches), handed on.
        Returns whether the run was stopped meanwhile (nothing is handed on then)."""
        if self._paced and self._clock.wait(self._held_us, self._stopped):
            return True
        with self._lock:
            held, self._held = self._held, []
        if len(held) == 1:  # a resting window's one batch (a batch cut at its end): as it is
            self._hand_on(held[0])
            return False
        items: list[StreamItem] = []
        run: list[np.ndarray] = []
        for item in held:
            if isinstance(item, np.ndarray):
                run.append(item)
                continue
            if run:
                items.append(join_events(run))
                run = []
            items.append(item)
        if run:
            items.append(join_events(run))
        for item in items:
            self._hand_on(item)
        return False

    def drop(self) -> None:
        """Forget the held items (the live camera was lost: they are stale)."""
        with self._lock:
            self._held.clear()

    def live_pause(self) -> float:
        """A live source's poll brought nothing new: what is held handed on, and how long its next
        poll waits (s): while the gel rests, until the camera's clock reaches the next window's
        end + :data:`REST_WAKE_AFTER_END_US` (estimated from when the last item was read, at most
        a window and that; at least that much when the window's closing data are late, which a
        camera sends at its own pace: not at once, again and again), else the source's own pause."""
        if self.holding:
            self.release()
        rest = self.windows
        if rest is None or self._stopped.is_set():
            return self._default_pause_s
        end, window_us = rest
        camera_us = self._read_us + (self._clock.now_ns() - self._read_ns) // 1000  # about now
        wake_us = end + window_us + REST_WAKE_AFTER_END_US
        return max(REST_WAKE_AFTER_END_US, min(wake_us - end, wake_us - camera_us)) / 1e6
