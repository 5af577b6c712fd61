"""What a run did: :class:`RunStats`, counted live by the runtime and shown by the terminal view.

Its own module so that the engine (:mod:`neurotouch_hid.engine`) and the outputs that show it
(:mod:`neurotouch_hid.views.term`) both import it without importing each other.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass, field, fields

import numpy as np

#: How many latency samples are kept (a ring: memory stays flat over long sessions).
LATENCY_SAMPLES = 65_536


class LatencyRing:
    """The last ``capacity`` event-to-output latencies (ns, int64), in a fixed numpy ring."""

    def __init__(self, capacity: int = LATENCY_SAMPLES):
        self._buf = np.zeros(capacity, dtype=np.int64)
        self._n = 0

    def add(self, latency_ns: int) -> None:
        self._buf[self._n % len(self._buf)] = latency_ns
        self._n += 1

    def __len__(self) -> int:
        return min(self._n, len(self._buf))

    def values_us(self) -> np.ndarray:
        """The kept samples in microseconds (float64, unordered)."""
        return self._buf[: len(self)] / 1e3

    def percentile_us(self, q: float) -> float:
        """The q-th percentile (0..100) of the kept samples in us; NaN without samples."""
        return float(np.percentile(self.values_us(), q)) if len(self) else float("nan")


#: The counters of :class:`RunStats` that :meth:`RunStats.count` adds to.
COUNTERS = frozenset(
    {
        "windows",
        "events",
        "frames",
        "states_written",
        "dropped_items",
        "dropped_events",
        "dropped_frames",
        "resting_updates",
        "resting_dropped_frames",
        "coalesced_windows",
        "camera_losses",
    }
)


@dataclass
class RunStats:
    """What a run did. Counters are updated live (the terminal view shows them).

    Thread-safety: the engine's threads (the source's, the pipeline's, the resting detector's)
    and the run's loop write here through :meth:`count`, :meth:`add_latency` and :meth:`note`,
    each under one lock taken once per call (once per item or window, never per event); a
    reader reads one attribute, or :attr:`copilot` for the two that go together.

    Attributes:
        windows: gesture estimates produced (one per window, but for ``coalesced_windows``).
        coalesced_windows: windows closed without an estimate of their own because event batches
            had queued up behind the pipeline: their events were tracked and the newest window
            of the queue was decided and published for them (``Pipeline.process_newest``).
        events: events handed to the pipeline.
        frames: APS frames handed to the pipeline.
        states_written: controller states written to the output (state changes only).
        dropped_items, dropped_events, dropped_frames: input data dropped, oldest first, because the
            pipeline fell behind a live or paced source (items = event batches + frames).
        resting_updates: resting detector results handed to the pipeline.
        resting_dropped_frames: APS frames the resting detector skipped (it was still busy).
        camera_losses: times the live camera was lost (unplugged, failing, stalled).
        profile: the profile mapping now (a name or path, as given).
        game: the running game whose profile is on (``neurotouch_hid.service.games``), or "".
        merged, missing: the profile's ``copilot:`` devices merged into the pad now, and those
            waited for (as the profile names them).
        wall_s: wall time of the run (s).
        stream_us: camera time covered by the processed data (us).
        latency: processing latencies: from the moment the item that closed a window was read
            from the source (after pacing) to the output being up to date.
        interpreted_windows: windows made while the first run's compile went on (the pipeline
            interpreted, slowly: the latency's tail is theirs).
        queued_windows: windows made once the pipeline was compiled from the items that had
            queued up behind the compile (until the queue was first empty): their latency is the
            compile's too.
        compiled_latency: ``latency`` of the windows made once the pipeline was compiled and the
            queue it left was worked off: what every later run sees.
        compile_ended_at: how far the first run's compile was (0..1) when the run ended before
            it; None when it was done or there was none. The compile stops with the run (what it
            cached stays: :meth:`neurotouch_hid.service.warmup.Warmup.close`); the next run goes on with it.
        window_latency: paced sources only: from the window's end in wall time (the camera clock
            mapped to wall time by the pacing) to the output being up to date; adds the wait for
            the source batch that shows the window is over (up to one batch).
    """

    windows: int = 0
    events: int = 0
    frames: int = 0
    states_written: int = 0
    dropped_items: int = 0
    dropped_events: int = 0
    dropped_frames: int = 0
    resting_updates: int = 0
    resting_dropped_frames: int = 0
    coalesced_windows: int = 0
    camera_losses: int = 0
    profile: str = ""
    game: str = ""
    merged: tuple[str, ...] = ()
    missing: tuple[str, ...] = ()
    wall_s: float = 0.0
    stream_us: int = 0
    latency: LatencyRing = field(default_factory=LatencyRing, repr=False)
    window_latency: LatencyRing = field(default_factory=LatencyRing, repr=False)
    interpreted_windows: int = 0
    queued_windows: int = 0
    compiled_latency: LatencyRing = field(default_factory=LatencyRing, repr=False)
    compile_ended_at: float | None = None
    _behind_compile: bool = field(default=False, repr=False)
    _lock: threading.Lock = field(default_factory=threading.Lock, repr=False, compare=False)

    def count(self, stream_us: int | None = None, **increments: int) -> None:
        """Add ``increments`` (counter name -> how many, ints >= 0, e.g. ``windows=1, events=512``)
        to the counters, and set :attr:`stream_us` (us) when given, all under the lock at once.

        Raises:
            ValueError: a name that is not one of :data:`COUNTERS`.
        """
        if not COUNTERS.issuperset(increments):  # (each item of a run comes here: no set made)
            unknown = increments.keys() - COUNTERS
            raise ValueError(f"RunStats.count: not a counter: {', '.join(sorted(unknown))} (one of {sorted(COUNTERS)})")
        with self._lock:
            for name, n in increments.items():
                setattr(self, name, getattr(self, name) + n)
            if stream_us is not None:
                self.stream_us = stream_us

    def note(self, **values: object) -> None:
        """Set what the run shows now (``profile``, ``game``, ``merged``, ``missing``, ``wall_s``,
        ``compile_ended_at``: see the attributes) under the lock, all at once.

        Raises:
            ValueError: a name that is not one of those.
        """
        unknown = values.keys() - _NOTES
        if unknown:
            raise ValueError(
                f"RunStats.note: not a noted value: {', '.join(sorted(unknown))} (one of {sorted(_NOTES)})"
            )
        with self._lock:
            for name, value in values.items():
                setattr(self, name, value)

    @property
    def copilot(self) -> tuple[tuple[str, ...], tuple[str, ...]]:
        """(:attr:`merged`, :attr:`missing`) as one consistent pair."""
        with self._lock:
            return self.merged, self.missing

    def add_latency(
        self,
        windows: int,
        latency_ns: int,
        *,
        compiling: bool,
        waiting: int,
        window_latencies_ns: tuple[int, ...] = (),
        counted: int = 0,
    ) -> None:
        """Count the latency (ns) of one item that closed ``windows`` (>= 1) windows: in
        :attr:`latency`, and by when it was made: while the first run's compile went on
        (``compiling``: :attr:`interpreted_windows`), after it from the items that queued up behind
        it (:attr:`queued_windows`, until ``waiting``, the items still queued after this one, is
        first 0), or once the pipeline is compiled and caught up (:attr:`compiled_latency`).
        ``window_latencies_ns``: the closed windows' :attr:`window_latency` samples (ns; paced
        sources only). ``counted``: windows added to :attr:`windows` too (the item's last
        window, published). Under the lock, once for the item."""
        with self._lock:
            self.windows += counted
            self.latency.add(latency_ns)
            for sample in window_latencies_ns:
                self.window_latency.add(sample)
            if compiling:
                self.interpreted_windows += windows
                self._behind_compile = True
            elif self._behind_compile:
                self.queued_windows += windows
                self._behind_compile = waiting > 0
            else:
                self.compiled_latency.add(latency_ns)

    def summary(self) -> str:
        """One line for the end of a run."""
        lat = ""
        if len(self.latency):
            lat = (
                f", latency p50 {self.latency.percentile_us(50) / 1e3:.2f} ms"
                f" p99 {self.latency.percentile_us(99) / 1e3:.2f} ms"
            )
        if self.interpreted_windows:  # say why the latency is what it is
            if self.compile_ended_at is not None:
                after = (
                    f": the run ended with the compile {self.compile_ended_at * 100:.0f} % done: what it compiled"
                    " is cached, the next run compiles the rest)"
                )
            elif len(self.compiled_latency):
                after = (
                    f": first run only; once compiled: p50 {self.compiled_latency.percentile_us(50) / 1e3:.2f} ms"
                    f" p99 {self.compiled_latency.percentile_us(99) / 1e3:.2f} ms)"
                )
            else:
                after = ": first run only; the next run starts compiled)"
            lat += (
                f" ({self.interpreted_windows} windows ran interpreted, slowly, while the pipeline compiled"
                + (f", {self.queued_windows} more from the items queued meanwhile" if self.queued_windows else "")
                + after
            )
        return (
            f"{self.windows} windows, {self.events} events, {self.frames} frames in {self.wall_s:.1f} s"
            f" ({self.stream_us / 1e6:.1f} s of data); dropped {self.dropped_items} items"
            f" ({self.dropped_events} events, {self.dropped_frames} frames),"
            f" resting detector skipped {self.resting_dropped_frames} frames"
            + (f", {self.coalesced_windows} queued windows decided with a newer one" if self.coalesced_windows else "")
            + (f", camera lost {self.camera_losses} time(s)" if self.camera_losses else "")
            + lat
        )


_NOTES = (
    frozenset(f.name for f in fields(RunStats) if not f.name.startswith("_"))
    - COUNTERS
    - {
        "stream_us",
        "latency",
        "window_latency",
        "compiled_latency",
        "interpreted_windows",
        "queued_windows",
    }
)
