"""Optional event noise filtering before the tracker, with dv-processing's noise filters.

A DAVIS-346 adds background activity (BA) to the events of the markers: isolated events at
random pixels and times, about 0.1 Hz per pixel in good light and up to a few Hz per pixel in
dim light (~9 k to ~300 k events/s over the 346 x 260 array), plus a few hot pixels. The blob
tracker (``tracker.py``) already ignores events far from every blob and gates isolated events
near a resting blob; a filter in front of it removes most of the noise before it gets there,
at the price of some marker events (a slowly moving marker's events are sparse too).

The filters are dv-processing's (iniVation's library, ``dv_processing.noise``, version 2.0.4),
each with its time parameter in microseconds:

- ``BackgroundActivityNoiseFilter`` (``backgroundActivityDuration``, library default 2000 us):
  an event is kept when one of its 8 neighbouring pixels had an event within that time;
- ``FastDecayNoiseFilter`` (``halfLife``, library default 10 000 us): an exponentially decaying
  event count per 4 x 4 pixel cell (the library's ``subdivisionFactor`` 4); an event is kept
  when its cell's count is above the library's ``noiseThreshold`` (6);
- ``KNoiseFilter`` (``timeDelta``, library default 1000 us): Khodamoradi's O(N)-memory
  filter (Khodamoradi and Kastner, "O(N)-space spatiotemporal filter for reducing noise in
  neuromorphic vision sensors", 2018): it stores the last event per row and per column only
  and keeps an event that has enough supporting neighbours within that time (library docs).

Which one (or none) the pipeline uses is ``PipelineConfig.noise.kind``; by default the
background-activity filter with 20 ms (docs/method.md, "Noise filter": on the simulated test
set at 0.1 Hz per pixel it moves no metric by more than 0.08 point or 0.06 mm, and at 3 Hz per
pixel it keeps the contact count accuracy at ~86-87 % where the tracker alone falls to ~80 %,
the contact distance at ~2.1 mm instead of ~2.8 mm). Through the library its cost is mostly
the conversion to and from dv-processing's ``EventStore`` (docs/method.md, "Noise
filter"; dv-processing 2.0.4 has no bulk path from numpy: one ``push_back`` per event); the
live camera delivers ``EventStore`` values, so ``DavisSource`` runs the library's filter
(:meth:`EventNoiseFilter.filter_store`) on them before any copy, and its pipeline has none.
On numpy batches (recordings, the simulated gel, ``track``, ``eval``) the background-activity
filter runs as a numba kernel instead (:func:`background_activity_keep`) that keeps exactly the
events dv-processing's ``BackgroundActivityNoiseFilter`` keeps on the same input (its rule
and time surface, re-implemented; ``tests/test_noise_filter.py`` compares the two on the street
recording and on simulated gels with noise), without the copies: 4-7x faster than the copies
and the library (docs/method.md, "Noise filter"). The other two
filters still go through the library and its copies.
"""

from __future__ import annotations

import datetime
from typing import TYPE_CHECKING

import numba
import numpy as np

from neurotouch_hid.core.limits import short

if TYPE_CHECKING:  # pragma: no cover
    import dv_processing as dv

#: The supported ``dv_processing.noise`` filters and the time parameter (us) each gets when
#: ``PipelineConfig.noise.time_us`` is None: the best of each on the simulated tuning set over
#: 0.1-3 Hz per pixel of background activity (docs/method.md, "Noise filter"; the library's
#: defaults, 2000 and 10 000 us, drop too many marker events); ``KNoiseFilter``: the library's
#: 1000 us (it keeps about a third of the marker events at any time tried).
NOISE_FILTERS: dict[str, int] = {
    "BackgroundActivityNoiseFilter": 20_000,
    "FastDecayNoiseFilter": 50_000,
    "KNoiseFilter": 1_000,
}


def check_noise_filter(name: str | None, time_us: int | None) -> None:
    """Validate a filter choice (``PipelineConfig.noise``: ``kind`` and ``time_us``).

    Args:
        name: None (no filter) or a key of :data:`NOISE_FILTERS`.
        time_us: None (that filter's time in :data:`NOISE_FILTERS`) or the filter's time
            parameter (us, >= 1).
    Raises:
        ValueError: unknown name (the message lists the supported ones), a time parameter that
            is not a positive whole number of microseconds, or a time parameter without a filter.
    """
    if name is not None and name not in NOISE_FILTERS:
        raise ValueError(f"noise.kind must be None or one of {', '.join(NOISE_FILTERS)}, got {short(name)}")
    if time_us is None:
        return
    if name is None:
        raise ValueError(f"noise.time_us={time_us} is set but noise.kind is None (no filter to apply it to)")
    if isinstance(time_us, bool) or not isinstance(time_us, (int, np.integer)) or time_us < 1:
        raise ValueError(f"noise.time_us must be a whole number of microseconds >= 1 or None, got {short(time_us)}")


#: The time stamped on the border of the numba filter's padded time surface: so far in the past
#: that a border cell never supports an event (the library skips the neighbours outside the array).
_NEVER_US = -(2**62)


def time_surface(width: int, height: int) -> np.ndarray:
    """A fresh time surface for :func:`background_activity_keep`: (height + 2, width + 2) int64
    us, 0 inside (as the library's ``TimeSurface``), :data:`_NEVER_US` on the one-pixel border."""
    surface = np.zeros((height + 2, width + 2), dtype=np.int64)
    surface[0, :] = surface[-1, :] = surface[:, 0] = surface[:, -1] = _NEVER_US
    return surface


@numba.njit(cache=True, nogil=True)
def background_activity_keep(events, surface, duration_us, keep):
    """dv-processing's ``BackgroundActivityNoiseFilter.retain`` over a batch, in numba.

    An event is kept when one of its 8 neighbouring pixels had an event less than
    ``duration_us`` before it: ``t - surface[y', x'] < duration_us``, the surface starting at 0
    as the library's ``TimeSurface``, pixels outside the array never supporting; then the
    event's own pixel gets its time, kept or not (dv-processing 2.0.4,
    ``noise/background_activity_noise_filter.hpp``). The surface is padded by one pixel of
    :data:`_NEVER_US` on every side, so the 8 neighbours are read without bounds checks (the
    newest of them decides: twice as fast as testing them one by one with the library's
    border cases).

    Args:
        events: (E,) EVENT_DTYPE structured array (``timestamp`` int64 us, ``x``/``y`` int16 px
            inside the array), time-ordered.
        surface: (H + 2, W + 2) int64 (:func:`time_surface`): the last event time (us) of pixel
            (x, y) at [y + 1, x + 1]; updated in place.
        duration_us: the background-activity duration (us).
        keep: (E,) bool, written: which events are kept.
    Returns:
        the number of kept events.
    """
    ts = events["timestamp"]
    xs = events["x"]
    ys = events["y"]
    n = 0
    for i in range(ts.shape[0]):
        t = ts[i]
        x = np.int64(xs[i]) + 1
        y = np.int64(ys[i]) + 1
        up = surface[y - 1]
        row = surface[y]
        down = surface[y + 1]
        newest = max(
            max(max(up[x - 1], up[x]), max(up[x + 1], row[x - 1])),
            max(max(row[x + 1], down[x - 1]), max(down[x], down[x + 1])),
        )
        supported = t - newest < duration_us
        row[x] = t
        keep[i] = supported
        n += supported
    return n


class EventNoiseFilter:
    """One dv-processing noise filter over numpy event batches, its state kept across calls.

    Args:
        name: a key of :data:`NOISE_FILTERS`.
        width, height: the sensor's pixel array (px), e.g. 346 x 260.
        time_us: the filter's time parameter (us); None = the filter's time in
            :data:`NOISE_FILTERS`.
    Raises:
        ValueError: as :func:`check_noise_filter`, or width/height < 1.

    Attributes:
        name, width, height, time_us: as given (``time_us`` None resolved from
            :data:`NOISE_FILTERS`).
        n_in, n_out: events offered and kept so far (since construction or the last reset).
    """

    def __init__(self, name: str, width: int, height: int, time_us: int | None = None) -> None:
        check_noise_filter(name, time_us)
        if width < 1 or height < 1:
            raise ValueError(f"the pixel array must be at least 1 x 1 px, got {width} x {height}")
        self.name = name
        self.width, self.height = int(width), int(height)
        self.time_us = int(NOISE_FILTERS[name] if time_us is None else time_us)
        self.n_in = 0
        self.n_out = 0
        self._last_us: int | None = None
        #: the library's filter, made on first use: numpy batches of the background-activity
        #: filter never need it (the numba kernel), and importing dv-processing costs ~25 ms
        self._filter = None
        #: the numba background-activity filter's padded time surface (:func:`time_surface`)
        self._surface = time_surface(self.width, self.height) if name == "BackgroundActivityNoiseFilter" else None

    def _library_filter(self):
        """The dv-processing filter (made now if not yet)."""
        if self._filter is None:
            import dv_processing as dv

            self._filter = getattr(dv.noise, self.name)(
                (self.width, self.height), datetime.timedelta(microseconds=self.time_us)
            )
        return self._filter

    def reset(self) -> None:
        """Forget every event seen (a new stream, e.g. whose clock restarts) and the counts."""
        self._filter = None
        if self._surface is not None:
            self._surface = time_surface(self.width, self.height)
        self._last_us = None
        self.n_in = self.n_out = 0

    def kernel_surface(self, first_us: int) -> np.ndarray | None:
        """The numba filter's time surface, for a compiled caller that filters a batch starting at
        ``first_us`` (us) itself (``rest_window.py``), then reports it (:meth:`count`); None when
        it cannot: the library's filter, or a clock gone back (this filter would reset first)."""
        if self._surface is None or (self._last_us is not None and first_us < self._last_us):
            return None
        return self._surface

    def count(self, last_us: int, n_in: int, n_out: int) -> None:
        """A batch a compiled caller filtered on :meth:`kernel_surface`: its last timestamp (us),
        the events offered and kept."""
        self._last_us = int(last_us)
        self.n_in += n_in
        self.n_out += n_out

    def filter_store(self, store: "dv.EventStore") -> "dv.EventStore":
        """Filter one batch as dv-processing holds it (no copy: what the live camera delivers).

        Args:
            store: a non-empty, time-ordered ``dv_processing.EventStore``. A batch that starts
                before the previous batch's last event (the camera's clock restarted, a recording
                looped) resets the filter first (:meth:`reset`): the library's filters compare
                time differences, and refuse events out of order.
        Returns:
            a ``dv_processing.EventStore`` of the kept events, in their order.
        """
        if self._last_us is not None and int(store.getLowestTime()) < self._last_us:
            self.reset()
        self._last_us = int(store.getHighestTime())
        library = self._library_filter()
        library.accept(store)
        kept = library.generateEvents()
        self.n_in += len(store)
        self.n_out += len(kept)
        return kept

    def __call__(self, events: np.ndarray) -> np.ndarray:
        """Filter one numpy batch. The background-activity filter runs in numba
        (:func:`background_activity_keep`: the library's decisions, no copies); the others run
        :meth:`filter_store` between two copies (``store_from_events``, ``events_from_store``),
        which cost ~90 % of their time (docs/method.md, "Noise filter"). An instance is
        meant for one kind of batch: the numba filter and the library's keep separate state.

        Args:
            events: (E,) EVENT_DTYPE (``timestamp`` int64 us, ``x``/``y`` int16 px inside the
                array, ``polarity``), time-ordered. A batch that starts before the previous
                batch's last event resets the filter first, as :meth:`filter_store`.
        Returns:
            (K,) EVENT_DTYPE, K <= E: the kept events, in their order (a new array; ``events``
            itself when it is empty).
        """
        if len(events) == 0:
            return events
        if self._surface is None:
            from neurotouch_hid.sources.dv import events_from_store, store_from_events

            return events_from_store(self.filter_store(store_from_events(events)))
        ts = events["timestamp"]
        if self._last_us is not None and int(ts[0]) < self._last_us:
            self.reset()
        self._last_us = int(ts[-1])
        keep = np.empty(len(events), dtype=np.bool_)
        n = background_activity_keep(events, self._surface, self.time_us, keep)
        self.n_in += len(events)
        self.n_out += n
        # through a same-size void view: a structured dtype's boolean index costs ~10x more
        # (60 against 5 us for a 1 ms batch at 4.5 M events/s); the same bytes
        return events.view(f"V{events.dtype.itemsize}")[keep].view(events.dtype)
