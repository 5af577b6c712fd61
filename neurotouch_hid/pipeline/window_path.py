"""The pipeline's window path (paper, "Marker Tracking" and "Methodology"; docs/method.md,
"Overview", "Noise filter" and "Resting"): what an event batch does to the gesture pipeline
(:class:`~neurotouch_hid.pipeline.pipeline.GesturePipeline`, which composes it with the frame path,
``frame_path.py``).

Events pass the noise filter (``noise.py``) to the event-blob tracker (``tracker.py``), cut at the
window ends; each window end crossed closes a window, whose estimate the pipeline makes
(``GesturePipeline._estimate``). While the resting verdict stands, a batch's whole path is one
compiled call (``rest_window.py``). Windows are ``window_us`` long, aligned on multiples of it
from the first event after the reference frame; a gap of more than :data:`GAP_US` emits its first
second of windows and skips the rest. Batches that queued up behind a real-time run are tracked
whole, and only the newest window they close is decided (:meth:`WindowPath.process_newest`).
"""

from __future__ import annotations

import numpy as np

from neurotouch_hid.core.estimate import GestureEstimate
from neurotouch_hid.pipeline.rest_window import OPEN, TOUCHED, rest_batch

__all__ = ["GAP_US", "WindowPath"]

#: A gap in the data (us) past which empty windows are no longer emitted but for the first
#: second of it (module docstring): a live DAVIS-346 sends background activity many times a
#: second, so only a recording's clock jumping (or a camera stalled for a second) makes one.
GAP_US = 1_000_000


class WindowPath:
    """The window half of the gesture pipeline: event batches cut at the window ends, through the
    noise filter and the tracker, each window closed with its estimate. A base of
    :class:`~neurotouch_hid.pipeline.pipeline.GesturePipeline`, which provides ``config``,
    ``tracker``, ``noise_filter``, ``rest_px``, ``on_window``, ``timings``, the resting verdict in
    force (``_resting``, the frame path's), the window's estimate (``_estimate``, ``_none``),
    whether a resting window may take the compiled path (``rests_compiled``), the stage clock
    (``_clock``, ``_record``) and ``process``.

    Attributes:
        _next_end: the open window's end (us), None before the first event after the reference.
    """

    def process_newest(self, events: np.ndarray) -> tuple[list[GestureEstimate], list[int]]:
        """Feed an event batch that joins several queued ones (a real-time run fell behind the
        source): every event goes through the noise filter and the tracker, window by window, but
        of the windows the batch closes only the newest gets a decision (the contact and gesture
        steps, the episode vote, the creep filter), on the tracker's state at its end, as
        :meth:`process` would make it; the windows before it close without one (no estimate).

        Args:
            events: (E,) EVENT_DTYPE, time-ordered.
        Returns:
            (the estimates, the ends (us, time order) of the windows closed without a decision):
            ``(process(events), [])`` when the batch closes at most one window, or reaches
            :data:`GAP_US` past the next window's end (a gap's windows are emitted as
            :meth:`process` emits them).
        """
        w = self.config.window_us
        last_us = int(events["timestamp"][-1]) if len(events) else 0
        end = self._next_end if self._next_end is not None or not len(events) else int(events["timestamp"][0]) + w
        if self.tracker is None or last_us < end + w or last_us - end >= GAP_US:
            return self.process(events), []
        newest = end + (last_us - end) // w * w  # the last window end the batch reaches
        ends = np.arange(end, newest, w, dtype=np.int64)  # the windows closed without a decision
        self._apply_pending()
        cut = int(np.searchsorted(events["timestamp"], newest - w, side="left"))  # the newest window's first
        head = events[:cut]
        if self.noise_filter is not None and len(head):
            begin = self._clock()
            head = self.noise_filter(head)
            self._record("noise_filter", begin)
        # the tracker's calls cut at the window ends, as :meth:`_process_events` cuts them
        for part in np.split(head, np.searchsorted(head["timestamp"], ends[:-1], side="left")):
            if len(part):
                begin = self._clock()
                self.tracker.update(part)
                self._record("tracker", begin)
        self._next_end = newest
        return self._process_events(events[cut:]), ends.tolist()

    def _process_events(self, events: np.ndarray, *, filtered: bool = False) -> list[GestureEstimate]:
        if self.tracker is None or len(events) == 0:
            return []
        if not filtered and self._resting.resting and self.rests_compiled:
            out = self._resting_events(events)
            if out is not None:
                return out
        if self.noise_filter is not None and not filtered:
            # the tracker gets the kept events; the windows start and close on the unfiltered
            # timestamps, as without a filter (a batch of noise only still ends its windows)
            last_us = int(events["timestamp"][-1])
            if self._next_end is None:
                self._next_end = int(events["timestamp"][0]) + self.config.window_us
            begin = self._clock()
            kept = self.noise_filter(events)
            self._record("noise_filter", begin)
            return self._process_events(kept, filtered=True) + self._close_windows_until(last_us)
        ts = events["timestamp"]
        if self._next_end is None:
            self._next_end = int(ts[0]) + self.config.window_us
        out: list[GestureEstimate] = self._across_gap(int(ts[0]))
        start = 0
        while True:
            cut = start + int(np.searchsorted(ts[start:], self._next_end, side="left"))
            if cut > start:
                begin = self._clock()
                self.tracker.update(events[start:cut])
                self._record("tracker", begin)
            if cut >= len(events):
                return out
            out.append(self._close_window())
            start = cut

    def _resting_events(self, events: np.ndarray) -> list[GestureEstimate] | None:
        """:meth:`_process_events` of a batch while the resting verdict stands, as one compiled
        call (``rest_window.rest_batch``: noise filter, tracker, the override's first test at the
        window's end); the same estimates and state. None (nothing done) when the batch is not one
        it takes (``rest_batch``) or stage timings are asked for."""
        if self._next_end is None:
            self._next_end = int(events["timestamp"][0]) + self.config.window_us
        end, c = self._next_end, self.config
        if self.timings is not None:
            return None
        moved_sq = c.motion_override_px * c.motion_override_px
        done = rest_batch(
            events, self.noise_filter, self.tracker, self.rest_px, end, c.window_us, moved_sq, c.override_min_markers
        )
        if done is None:
            return None
        answer, kept, cut = done
        if answer == OPEN:
            return []
        if answer == TOUCHED:  # the first sign of a touch: the window as the general path closes it
            return [self._close_window(), *self._process_events(kept[cut:], filtered=True)]
        self._next_end = end + c.window_us
        estimate = self._none(end, resting=True)
        if self.on_window is not None:
            self.on_window(estimate)
        return [estimate]

    def _close_windows_until(self, t_us: int) -> list[GestureEstimate]:
        out = self._across_gap(t_us)
        while self._next_end is not None and self._next_end <= t_us:
            out.append(self._close_window())
        return out

    def _across_gap(self, t_us: int) -> list[GestureEstimate]:
        """Before data at ``t_us``: when more than :data:`GAP_US` of window ends lie before it
        with no data, the windows of the first :data:`GAP_US` closed (emitted), the others
        skipped, keeping the windows' alignment. Memory and time follow the data, not the clock."""
        if self._next_end is None or t_us - self._next_end < GAP_US:
            return []
        w = self.config.window_us
        crossed = (t_us - self._next_end) // w + 1  # window ends at or before t_us
        keep = max(1, GAP_US // w)
        out = [self._close_window() for _ in range(keep)]
        self._next_end += (crossed - keep) * w
        return out

    def _close_window(self) -> GestureEstimate:
        t_us = self._next_end
        self._next_end += self.config.window_us
        estimate = self._estimate(t_us)
        if self.on_window is not None:
            self.on_window(estimate)
        return estimate
