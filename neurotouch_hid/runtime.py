"""The engine: source -> gesture pipeline -> mapping -> subscribers, in threads, with clean shutdown.

Following the paper (section "Runtime Performance"), the event path and the resting detection run
beside each other: one thread reads the source (pacing recordings and the simulated gel in real
time), one runs the gesture pipeline and the mapping and publishes each window, and one runs the
resting detector (Chamfer distance on APS frames, paper, section "Resting Position Detection") and
hands its results to the pipeline (``pipeline.set_resting``). numpy, OpenCV and numba release the
GIL in their heavy parts, so on two cores the resting detection does not hold up the event path.

Between the threads sit bounded queues. When the pipeline falls behind a live or paced source, it
takes the event batches queued meanwhile in one call (the same events, its per-call cost paid
once: :meth:`DropOldestQueue.get_joined`), and of the windows they close only the newest is
decided and published (``Pipeline.process_newest``: every event tracked, the contact and gesture
steps run once, on the latest state, as a game reads the newest report; the others counted in
``RunStats.coalesced_windows``); when the queue is full all the same, it drops its
OLDEST items (counted in :class:`RunStats`) instead of letting the controller lag;
with ``pace=False`` (``--fast``) nothing is dropped: the source waits for the pipeline instead,
and the pipeline runs the resting detection inline so that a replay is deterministic.

The engine knows its stages only through their seams (:mod:`neurotouch_hid.stages`): it is the
one place that knows source, pipeline, mapper and subscribers. After each window it publishes one
:class:`~neurotouch_hid.stages.WindowRecord` to every subscriber (the uinput devices, JSON lines,
the terminal and live views); none of them is known to a stage. Which concrete source and
pipeline a command uses is opened by an assembly (:mod:`neurotouch_hid.driver`'s: the live
camera, the simulated gel, an AEDAT4 recording, or a predictions file replayed without the
pipeline) when the run starts.

Every way out of :meth:`Runtime.run` (end of the source, :meth:`Runtime.stop`, SIGTERM, Ctrl-C, an
exception in any stage) first centres all axes and releases all buttons (``neutralise()`` of every
subscriber).

A live camera that is unplugged, fails or stalls does not end the run: its stream says so
(:class:`~neurotouch_hid.sources.SourceStatus`, see ``sources/davis.py``). On ``"lost"`` the source
thread neutralises the output at once, drops the data still queued and says why; nothing is
written until the camera is back. On ``"resumed"`` the pipeline restarts (``pipeline.restart()``:
the markers are re-initialised on the first APS frame at rest) with a fresh mapper (its filters
and hysteresis start neutral). SIGTERM is a clean stop (``run`` returns normally, the CLI exits 0);
SIGHUP reloads the profile from its file (a bad profile on reload, whatever is wrong with it, keeps
the old one and logs why); SIGTSTP (Ctrl-Z) releases every output before the process stops, and
SIGCONT resumes from a neutral state (:meth:`Runtime.suspend`).
With ``control=True`` the run listens on the control socket (:mod:`neurotouch_hid.control`):
``neurotouch-hid profile use NAME`` switches the profile while running, outputs neutral first.
"""

from __future__ import annotations

import collections
import contextlib
import dataclasses
import logging
import os
import signal
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable, Iterator, Optional, Protocol, Sequence

import numpy as np

from neurotouch_hid.core.controller import ControllerState
from neurotouch_hid.core.errors import NeurotouchError
from neurotouch_hid.core.estimate import GestureEstimate, GestureType
from neurotouch_hid.core.stats import RunStats
from neurotouch_hid.mapping.commitment import waits_for_type
from neurotouch_hid.mapping.mapper import Mapper
from neurotouch_hid.mapping.profile import Profile, load_profile
from neurotouch_hid.sources import Frame, Pacer, Performed, SourceStatus, StatusKind, StreamItem, join_events
from neurotouch_hid.stages import CompileProgress, Pipeline, RestingDetection, SourceStream, Subscriber, WindowRecord
from neurotouch_hid.stages import Mapper as MapperStage

if TYPE_CHECKING:
    from neurotouch_hid.core.dataset import LabelRow
    from neurotouch_hid.core.sensor import SensorGeometry
    from neurotouch_hid.stages import Merge
    from neurotouch_hid.stopping import EarlyStop

log = logging.getLogger(__name__)

#: Source batch length (us): 1 ms batches keep the event-to-output latency well under a window.
DEFAULT_BATCH_US = 1_000
#: How far (us of camera time) the pipeline may fall behind a live or paced source before the
#: oldest queued data is dropped: the controller lags by at most about this much.
DEFAULT_MAX_LAG_US = 200_000
#: Input queue bound (items): a memory guard only; ``max_lag_us`` is the bound that acts.
DEFAULT_QUEUE_ITEMS = 100_000
#: At most this many events in one pipeline call when the pipeline catches up on queued batches
#: (:meth:`DropOldestQueue.get_joined`): about 0.1 s at the camera's 12 M events/s USB maximum.
MAX_JOINED_EVENTS = 1_000_000
#: While the gel rests, a paced source hands its items on once per window instead of once per
#: batch: at each window's end plus this much (the batch that closes the window), with everything
#: due by then, its event batches joined into one. Each window closes when it would have; the
#: first events of a touch wait at most one window; the pipeline's thread runs once per window
#: instead of once per batch (docs/performance.md, "At rest").
REST_WAKE_AFTER_END_US = DEFAULT_BATCH_US
#: Frame queue bound for the resting detector (APS frames, 25 Hz).
DEFAULT_FRAME_QUEUE = 2
#: The interpreter's thread switch interval (s) during real-time runs, instead of Python's 5 ms:
#: a thread waiting for the GIL (the pipeline, while the resting thread runs Python code) gets it
#: within 0.5 ms. Measured (benchmarks/bench_latency.py): p99 processing latency 3.4 -> 1.7 ms.
REALTIME_SWITCH_INTERVAL_S = 0.0005

_POLL_S = 0.05
#: How often the main thread looks at the run (a reload or Ctrl-Z asked by a signal, a stalled
#: source's deadline), s: it sleeps in between (a signal's handler cannot wake it safely).
_MAIN_POLL_S = 0.25
#: A thread waiting for queued items wakes at least this often (s); closing the queue wakes it.
_IDLE_WAIT_S = 1.0
_JOIN_S = 2.0
_GRACE_S = 2.0


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
        self._cond = threading.Condition()
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
                    self._cond.wait(_POLL_S)
            if self._closed:
                return
            self._items.append(entry)
            self._cond.notify_all()

    def get(self, timeout: float = _POLL_S) -> tuple[int, StreamItem] | None:
        """The oldest entry; None when closed and empty or when ``timeout`` (s) passed."""
        return self.get_joined(timeout)

    def get_joined(self, timeout: float = _POLL_S, max_events: int = 0) -> tuple[int, StreamItem] | None:
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
        with self._cond:
            self._taken = False

    def claim(self) -> bool:
        """Whether the caller may process an item itself, in the consumer's place: nothing is
        queued or being processed (then the queue counts it as taken until :meth:`done`, and the
        consumer takes nothing meanwhile)."""
        with self._cond:
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

    def __len__(self) -> int:
        return len(self._items)


class Runtime:
    """Source -> pipeline -> mapper -> subscribers, with a resting detector beside the event path.

    The stages are known only through their seams (:mod:`neurotouch_hid.stages`).

    Args:
        source: the stream items in time order (:data:`~neurotouch_hid.stages.SourceStream`),
            e.g. ``RecordingReader.stream()``, ``SimulatedSource.stream()``.
        pipeline: a :class:`~neurotouch_hid.stages.Pipeline` (``GesturePipeline``).
        profile: the loaded profile; the mapper is ``mapper_factory(profile)``.
        subscribers: the :class:`~neurotouch_hid.stages.Subscriber` s each window's
            :class:`~neurotouch_hid.stages.WindowRecord` is published to, in this order. The
            runtime does not close them (their owner does; the gamepad device outlives profile
            switches).
        resting: a :class:`~neurotouch_hid.stages.RestingDetection` run in its own thread on
            APS frames; its results go to ``pipeline.set_resting(result, frame.t_us)``
            (thread-safe). None when the pipeline does its own resting detection.
        pace: sleep so that item timestamps follow wall time (recordings, the simulated gel).
        live: the source is real time by itself (the camera): not paced, but like a paced source
            its data is dropped, oldest first, when the pipeline falls behind. With neither
            ``pace`` nor ``live`` (``--fast``) everything is processed as fast as possible and
            nothing is dropped: the source waits for the pipeline.
        waits: a paced source that can wait (the simulated gel, which is not a camera): when the
            pipeline falls more than ``max_lag_us`` behind (a first run still compiling), the
            source waits instead of data being dropped, and catches up after; ``seconds`` then
            counts its time, not the wall clock's. Its clock starts when the run does: a first
            item that takes a while (the simulated gel compiling) is caught up after too.
        profile_ref: name or path the profile came from, reloaded on SIGHUP.
        queue_items: bound of the input queue (items; a memory guard).
        max_lag_us: real time only: how far (us of camera time) the queued data may reach back
            before the oldest is dropped (the controller's lag behind the camera, at most).
        mapper_factory, profile_loader: the mapping's ``Mapper`` and ``load_profile`` (replaceable
            in tests).
        say: tells the user what happens to a live source (camera lost, back; one line each).
        control: serve the control socket while running (``profile use``, :meth:`use_profile`).
        games: with ``control``, switch to a game's profile while it runs
            (:class:`~neurotouch_hid.games.GameProfiles`, the user's games.yaml).
        serial: the camera's serial (None: none known): its own control socket
            (:func:`~neurotouch_hid.control.socket_path`) and its own games.yaml where it has one
            (:mod:`neurotouch_hid.service.serials`).
        early_stop: the SIGTERM handler that stood before this run's own
            (:class:`~neurotouch_hid.stopping.EarlyStop`): quieted when the run installs its own
            handlers, and a SIGTERM it saw meanwhile stops the run at once.
        stats: where the run is counted (:class:`RunStats`; e.g. shared with the terminal view
            that shows it); a new one by default.
        pacer: the :class:`~neurotouch_hid.sources.Pacer` that paces and times the run (one on
            a clock a test controls); a new wall-clock one by default.
        sensor: the gel's geometry, handed on in each record (None: a predictions file).
        compile_progress: the first run's compile, asked after each window while it lasts
            (:meth:`neurotouch_hid.service.warmup.Warmup.progress_now`); None when nothing compiles.
        labelled: the source says what it performs (:class:`~neurotouch_hid.sources.Performed`
            items: the simulated hand).
    """

    def __init__(
        self,
        source: SourceStream,
        pipeline: Pipeline,
        profile: Profile,
        subscribers: Sequence[Subscriber],
        *,
        resting: RestingDetection | None = None,
        pace: bool = True,
        live: bool = False,
        profile_ref: str | Path | None = None,
        queue_items: int = DEFAULT_QUEUE_ITEMS,
        max_lag_us: int = DEFAULT_MAX_LAG_US,
        mapper_factory: Callable[[Profile], MapperStage] = Mapper,
        profile_loader: Callable[[str | Path], Profile] = load_profile,
        say: Callable[[str], None] = log.warning,
        control: bool = False,
        games: bool = False,
        stats: RunStats | None = None,
        pacer: Pacer | None = None,
        waits: bool = False,
        sensor: SensorGeometry | None = None,
        compile_progress: Callable[[], CompileProgress | None] | None = None,
        labelled: bool = False,
        merge: Merge | None = None,
        merge_for: Callable[[Profile], Merge | None] | None = None,
        serial: str | None = None,
        early_stop: EarlyStop | None = None,
    ):
        self._serial = serial
        self._early_stop = early_stop  # a SIGTERM before the run started (driver.run_driver)
        self._merge_for = merge_for  # the copilot of a profile switched to (None: merges nothing)
        self._merge = merge if merge is not None or merge_for is None else merge_for(profile)
        self._last_gel = ControllerState.neutral()  # the mapped state before the merge
        self._last_record: WindowRecord | None = None
        self._control = control
        self._games = games
        self._waits = waits and pace and not live
        self._source = source
        self._pipeline = pipeline
        self.profile = profile
        self._commit_for(self._type_wait(profile))
        self._mapper_factory = mapper_factory
        self._mapper = mapper_factory(profile)
        self._subscribers = tuple(subscribers)
        self._wants_markers = any(s.wants_markers for s in self._subscribers)
        #: a subscriber wants every window's record, even one that changes nothing
        self._every_window = self._wants_markers or any(getattr(s, "every_window", False) for s in self._subscribers)
        #: the last resting estimate not handed to the mapper (:meth:`_unchanged_at_rest`)
        self._skipped: GestureEstimate | None = None
        #: the mapper known to rest at the state last published (:meth:`_unchanged_at_rest`);
        #: forgotten when a record is published or the state forgotten
        self._quiet_mapper: MapperStage | None = None
        self._first_us: int | None = None  # the first item's end (us), for ``stats.stream_us``
        self._sensor = sensor
        self._compile_progress = compile_progress
        self._labelled = labelled
        self._labels: collections.deque[LabelRow] = collections.deque()  # performed, not yet reached
        self._performed: LabelRow | None = None
        self._resting = resting
        self._pace = pace and not live
        self._live = live
        self._realtime = pace or live
        self._profile_ref = profile_ref
        self._profile_loader = profile_loader
        self.stats = stats if stats is not None else RunStats()
        self.stats.profile = str(profile_ref) if profile_ref is not None else ""
        self._items = DropOldestQueue(
            queue_items,
            drop_oldest=self._realtime and not self._waits,
            on_drop=self._count_drop,
            max_span_us=max_lag_us,
            span_waits=self._waits,
        )
        self._frames = DropOldestQueue(
            DEFAULT_FRAME_QUEUE, drop_oldest=self._realtime, on_drop=self._count_resting_drop
        )
        self._stop = threading.Event()
        self._reload = threading.Event()
        self._lock = threading.Lock()  # mapper + output: the worker vs. profile switches
        self._verdict_lock = threading.Lock()  # the resting detector: its thread vs. the source's at rest
        self._last_verdict_us: int | None = None
        self._errors: list[BaseException] = []
        self._last_state = ControllerState.neutral()
        self._last_gesture: GestureType | None = None
        self._limit_us: int | None = None
        self._clock = pacer or Pacer()  # the first item read anchors pacing, limits and latencies
        self._ran = False
        self._say = say
        self._paused = False  # the live camera is lost: write nothing (under self._lock)
        self._suspend = threading.Event()  # SIGTSTP arrived: the main thread suspends the run
        self._suspended = False  # stopped by SIGTSTP: write nothing (under self._lock)
        self._restart = threading.Event()  # it is back: restart the pipeline before its data
        #: (the last window's end, the window's length) (us) while the gel rests, else None:
        #: set by the worker, read by the source thread (:meth:`_hand_on_us`)
        self._rest_windows: tuple[int, int] | None = None
        #: a resting gel's items, held by the source's thread until ``_held_us`` (camera time,
        #: us; a live source: until its poll brings nothing new), then handed on at once
        self._held: list[StreamItem] = []
        self._held_us = 0
        self._held_for: tuple[int, int] | None = None  # the ``_rest_windows`` they were held at
        self._held_before_us = 2**62  # a batch ending there or later is past the run's ``seconds``
        self._read_us = self._read_ns = 0  # a live source's last item: its end (us), when read (pacer ns)
        self._last_end_us: int | None = None

    @property
    def profile_name(self) -> str:
        """The profile in use as the user named it (name or path), for display."""
        return str(self._profile_ref) if self._profile_ref is not None else "(given)"

    # --- control ----------------------------------------------------------------------------
    def stop(self) -> None:
        """Ask every thread to stop; :meth:`run` then neutralises every subscriber and returns.
        Safe from any thread and from a signal handler."""
        self._stop.set()
        self._items.close()
        self._frames.close()

    def switch_profile(self, profile: Profile) -> None:
        """Neutralise every subscriber, then map with ``profile`` from the next window on.
        The output devices are kept (the pad's name and ids stay those it was created with); a
        keyboard or mouse the new profile needs is created (``prepare(profile)``). The old
        profile's merged devices are released, the new one's grabbed.

        Raises:
            NeurotouchError: the run is stopping or over (every output released, the merged
                devices let go): nothing is switched.
        """
        if self._stop.is_set():
            raise NeurotouchError("the driver is stopping: the profile is not switched")
        self._switch_merge(profile)
        wait = self._type_wait(profile)  # its probe (~0.1 s) outside the lock the worker maps under
        with self._lock:
            self._neutralise()
            for subscriber in self._subscribers:
                subscriber.prepare(profile)
            self._mapper = self._mapper_factory(profile)
            self.profile = profile
            self._commit_for(wait)
            self._forget_state()

    @staticmethod
    def _type_wait(profile: Profile) -> bool | None:
        """Whether the pipeline should wait for the fingers before committing a type under
        ``profile`` (``mapping/commitment.py``), None for a profile that is not a :class:`Profile`."""
        return waits_for_type(profile) if isinstance(profile, Profile) else None

    def _commit_for(self, wait: bool | None) -> None:
        """Set the pipeline's type wait (:meth:`_type_wait`; None, or a pipeline without the
        setting: left as it is)."""
        set_wait = getattr(self._pipeline, "set_type_wait", None)
        if set_wait is not None and wait is not None:
            set_wait(wait)

    def _forget_state(self) -> None:
        """The subscribers were neutralised or the mapping starts afresh: the next state is
        compared with a neutral one (caller holds ``self._lock``)."""
        self._quiet_mapper = None
        self._last_state = ControllerState.neutral(self._last_state.t_us)
        self._last_gel = ControllerState.neutral(self._last_state.t_us)
        self._last_record = None  # a merged device's input waits for the next window's record
        self._last_gesture = None

    def reload_profile(self) -> bool:
        """Load the profile again from ``profile_ref`` (the user edited it) and switch to it.
        A bad profile keeps the current one and logs every problem; returns whether it switched."""
        if self._profile_ref is None:
            log.warning("no profile file to reload")
            return False
        try:
            profile = self._profile_loader(self._profile_ref)
            self.switch_profile(profile)
        except NeurotouchError as exc:
            log.error("profile not reloaded, keeping the current one: %s", exc)
            return False
        except Exception as exc:  # the driver keeps running on its current profile, whatever the file
            log.error("profile not reloaded, keeping the current one: %s: %s", type(exc).__name__, str(exc)[:200])
            return False
        log.warning("profile reloaded from %s", self._profile_ref)
        return True

    def use_profile(self, ref: str, reason: str | None = None) -> str:
        """``profile use`` and the profile per game: load ``ref`` (name or path), switch to it
        (:meth:`switch_profile`), and reload it on SIGHUP from now on; returns the line said on
        the log (with ``reason``, e.g. the game that started). Raises ProfileError (nothing
        changes) for a missing or invalid profile."""
        profile = self._profile_loader(ref)
        self.switch_profile(profile)
        self._profile_ref = ref
        self.stats.profile = str(ref)
        line = f"switched to profile {ref}" + (f" ({reason})" if reason else "")
        log.warning("%s", line)
        return line

    def suspend(self) -> None:
        """SIGTSTP (Ctrl-Z): release every output, then stop the process as SIGTSTP's default
        action does; after SIGCONT (``fg``) map again from a neutral state, pacing shifted by
        the time stopped (a paced source does not rush to catch up). Main thread only."""
        with self._lock:
            self._suspended = True
            self._neutralise()
            self._forget_state()
        log.warning("stopped: every output released (fg or SIGCONT resumes)")
        stopped_ns = time.perf_counter_ns()
        previous = signal.signal(signal.SIGTSTP, signal.SIG_DFL)
        try:
            os.kill(os.getpid(), signal.SIGTSTP)  # the process stops here until SIGCONT
        finally:
            signal.signal(signal.SIGTSTP, previous)
        if self._clock.first_us is not None:
            self._clock.first_ns += time.perf_counter_ns() - stopped_ns
        with self._lock:
            self._forget_state()
            self._suspended = False
        log.warning("resumed")

    # --- the run ----------------------------------------------------------------------------
    def run(self, seconds: float | None = None) -> RunStats:
        """Run until the source ends, ``seconds`` of camera time have been read, :meth:`stop`,
        SIGTERM or Ctrl-C; neutralise every subscriber on every way out.

        Returns the :class:`RunStats`. Re-raises the first exception of any stage (after
        neutralising); a KeyboardInterrupt is re-raised too, its ``stats`` attribute the run's
        :class:`RunStats`. SIGTERM returns normally. Installs
        SIGTERM and SIGHUP handlers while running when called from the main thread.
        """
        if self._ran:
            raise RuntimeError("a Runtime runs once")
        self._ran = True
        self._limit_us = None if seconds is None else int(round(seconds * 1e6))
        threads = [
            threading.Thread(target=self._read_source, name="nt-source", daemon=True),
            threading.Thread(target=self._work, name="nt-pipeline", daemon=True),
        ]
        if self._resting is not None:
            threads.append(threading.Thread(target=self._rest, name="nt-resting", daemon=True))
        interrupted = False
        start = time.perf_counter()
        with self._signal_handlers(), self._switch_interval(), self._control_socket():
            try:
                if self._early_stop is not None:  # this run's handlers are in place: its SIGTERM only flags
                    self._early_stop.quiet()
                    if self._early_stop.requested.is_set():
                        self.stop()
                if self._merge is not None:
                    self._merge.start(self._on_input)
                    self.stats.merged, self.stats.missing = self._merge.status()
                for t in threads:
                    t.start()
                worker = threads[1]
                while worker.is_alive():
                    worker.join(_MAIN_POLL_S)
                    if self._reload.is_set():
                        self._reload.clear()
                        self.reload_profile()
                    if self._suspend.is_set():
                        self._suspend.clear()
                        self.suspend()
                    if seconds is not None and self._realtime and not self._waits:
                        # a real-time source that stalls still ends: wall deadline from its first item
                        first = self._clock.first_ns / 1e9 if self._clock.first_ns else start
                        if time.perf_counter() > first + seconds + _GRACE_S:
                            self.stop()
            except KeyboardInterrupt:
                interrupted = True
            finally:
                self.stop()
                for t in threads:
                    if t.ident is not None:  # a Ctrl-C while they were being started: not all were
                        t.join(_JOIN_S)
                self.stats.wall_s = time.perf_counter() - start
                unfinished = self._compiling()
                if unfinished is not None:  # it stops with the run: say how far it got
                    self.stats.compile_ended_at = unfinished.fraction
                try:
                    if self._merge is not None:
                        self._merge.stop()
                finally:  # the outputs neutral even when a merged device's release fails
                    with self._lock:
                        self._neutralise()
        if self._errors:
            raise self._errors[0]
        if interrupted:
            interrupt = KeyboardInterrupt()
            interrupt.stats = self.stats  # what the run did, for its summary (how far the compile got)
            raise interrupt
        return self.stats

    @contextlib.contextmanager
    def _control_socket(self) -> Iterator[None]:
        if not self._control:
            yield
            return
        from neurotouch_hid.control import ControlServer

        games = None
        if self._games and self._profile_ref is not None:
            from neurotouch_hid.games import GameProfiles, games_file
            from neurotouch_hid.service.serials import sensor_file

            path = sensor_file(self._serial, "games", games_file())
            games = GameProfiles(self.use_profile, str(self._profile_ref), path=path, on_game=self._follow_game)
            games.start()
        from neurotouch_hid.control import socket_path

        server = ControlServer(
            games.manual_use if games is not None else self.use_profile,
            socket_path(self._serial),
            status=lambda: f"profile {self.profile_name}",
        )
        server.start()
        try:
            yield
        finally:
            server.stop()
            if games is not None:
                games.stop()

    def _follow_game(self, game: Any) -> None:
        self.stats.game = game.label() if game is not None else ""

    @contextlib.contextmanager
    def _switch_interval(self) -> Iterator[None]:
        previous = sys.getswitchinterval()
        if self._realtime:
            sys.setswitchinterval(min(previous, REALTIME_SWITCH_INTERVAL_S))
        try:
            yield
        finally:
            sys.setswitchinterval(previous)

    @contextlib.contextmanager
    def _signal_handlers(self) -> Iterator[None]:
        if threading.current_thread() is not threading.main_thread():
            yield
            return
        previous = {signal.SIGTERM: signal.signal(signal.SIGTERM, lambda *_: self.stop())}
        if hasattr(signal, "SIGHUP"):
            previous[signal.SIGHUP] = signal.signal(signal.SIGHUP, lambda *_: self._reload.set())
        if hasattr(signal, "SIGTSTP"):
            previous[signal.SIGTSTP] = signal.signal(signal.SIGTSTP, lambda *_: self._suspend.set())
        try:
            yield
        finally:
            for sig, handler in previous.items():
                signal.signal(sig, handler)

    # --- threads ----------------------------------------------------------------------------
    def _count_drop(self, item: StreamItem) -> None:
        self.stats.dropped_items += 1
        if isinstance(item, Frame):
            self.stats.dropped_frames += 1
        elif isinstance(item, np.ndarray):
            self.stats.dropped_events += len(item)

    def _count_resting_drop(self, item: StreamItem) -> None:
        self.stats.resting_dropped_frames += 1

    def _read_source(self) -> None:
        """Source thread: read, pace, stamp the arrival time, enqueue."""
        if self._waits:  # its stream starts now, even when its first item takes a while
            self._clock.anchor_now()
        iterator = iter(self._source)
        held = self._held  # items of a resting gel, handed on at self._held_us, batches joined
        # a live source's polls that bring nothing wait as the runtime decides (:meth:`_live_pause`)
        pause = getattr(iterator, "poll_pause", None) if self._live else None
        holds = self._pace or pause is not None
        # a source whose batches may be cut at the resting windows' ends (one batch a window)
        cut = getattr(iterator, "batch_cut", None) if self._pace else None
        cut_for = None
        try:
            if pause is not None:
                pause.decide = self._live_pause
            for item in iterator:
                rest = self._rest_windows
                if cut is not None and rest is not cut_for:
                    cut_for = rest
                    cut.follow(rest, REST_WAKE_AFTER_END_US)  # each batch then closes a window
                if held and rest is not None and rest is self._held_for and type(item) is np.ndarray and len(item):
                    t_us = int(item["timestamp"][-1])  # an event batch of the resting window being held:
                    if t_us <= self._held_us and t_us < self._held_before_us:  # as below, in fewer steps
                        held.append(item)
                        if pause is not None:
                            self._read_us, self._read_ns = t_us, self._clock.now_ns()
                        continue
                if self._stop.is_set():
                    break
                if isinstance(item, SourceStatus):
                    self._source_status(item)
                    continue
                if isinstance(item, Performed):
                    self._labels.append(item.label)  # the worker reaches it at its window
                    continue
                t_us = item_end_us(item)
                if t_us is not None:
                    self._clock.due_ns(t_us)  # the first item anchors the clock
                    if self._limit_us is not None and t_us - self._clock.first_us >= self._limit_us:
                        break
                    if pause is not None:
                        self._read_us, self._read_ns = t_us, self._clock.now_ns()
                    if holds:
                        due_us = self._hand_on_us(t_us)
                        joins = due_us > t_us or bool(held and due_us == self._held_us)
                        if held and not (joins and due_us == self._held_us) and self._hand_on_held():
                            break
                        if joins:
                            held.append(item)
                            self._held_us, self._held_for = due_us, self._rest_windows
                            if self._limit_us is not None:  # (a batch from there on ends the run)
                                self._held_before_us = self._clock.first_us + self._limit_us
                            continue
                        if self._pace and self._clock.wait(due_us, self._stop):
                            break
                self._hand_on(item)
            if held and not self._stop.is_set():
                self._hand_on_held()
        except BaseException as exc:  # a truncated recording, a lost camera: what was read is
            self._errors.append(exc)  # still processed, then run() neutralises and re-raises
        finally:
            if pause is not None:
                pause.decide = None
            close = getattr(iterator, "close", None)
            if close is not None:
                with contextlib.suppress(Exception):
                    close()
            self._items.close()
            self._frames.close()

    def _hand_on_us(self, t_us: int) -> int:
        """Source thread: when (camera time, us) the item ending at ``t_us`` is handed on: then,
        or while the gel rests, at the first window end + :data:`REST_WAKE_AFTER_END_US` not before it."""
        rest = self._rest_windows
        if rest is None:
            return t_us
        end, window_us = rest
        wake = end + REST_WAKE_AFTER_END_US
        return t_us if t_us <= wake else wake + -(-(t_us - wake) // window_us) * window_us

    def _hand_on_held(self) -> bool:
        """Source thread: the held items (a paced source: at ``self._held_us``, camera time),
        each run of event batches as one (in order; the pipeline's windows close inside a batch
        as between batches), the held list emptied. While nothing is queued or being processed
        (a resting gel), this thread processes them itself (:meth:`_inline`): one wake-up a
        window. Returns whether the run was stopped meanwhile (nothing is handed on then)."""
        held = self._held
        if self._pace and self._clock.wait(self._held_us, self._stop):
            return True
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
        held.clear()
        for item in items:
            self._hand_on(item)
        return False

    def _live_pause(self) -> float:
        """Source thread, a live source's poll brought nothing new: what it holds handed on, and
        how long its next poll waits (s): while the gel rests, until the camera's clock reaches
        the next window's end + :data:`REST_WAKE_AFTER_END_US` (estimated from when the last
        item was read, at most a window and that; at least that much when the window's closing
        data are late, which a camera sends at its own pace: not at once, again and again),
        else the source's own pause."""
        if self._held:
            self._hand_on_held()
        rest = self._rest_windows
        if rest is None or self._stop.is_set():
            return self._source.poll_pause.default_s
        end, window_us = rest
        camera_us = self._read_us + (self._clock.now_ns() - self._read_ns) // 1000  # about now
        wake_us = end + window_us + REST_WAKE_AFTER_END_US
        return max(REST_WAKE_AFTER_END_US, min(wake_us - end, wake_us - camera_us)) / 1e6

    def _hand_on(self, item: StreamItem) -> None:
        """Source thread: one item to the pipeline: processed here while nothing is queued or
        being processed and the gel rests (:meth:`_inline`), else queued for the pipeline's
        thread (an APS frame also for the resting thread's)."""
        entry = (time.perf_counter_ns(), item)
        if self._rest_windows is not None and self._items.claim():
            try:
                self._inline(entry)
            finally:
                self._items.done()
            return
        if isinstance(item, Frame) and self._resting is not None:
            self._frames.put(entry)
        self._items.put(entry)

    def _inline(self, entry: tuple[int, StreamItem]) -> None:
        """Source thread, the gel at rest, the pipeline's thread idle: the item processed in this
        thread, an APS frame's resting verdict first (the resting thread is not woken)."""
        item = entry[1]
        if isinstance(item, Frame) and self._resting is not None:
            self._rest_verdict(item)
        self._handle(entry)

    def _source_status(self, status: SourceStatus) -> None:
        """Source thread: the live camera was lost (neutralise now, drop the stale queue; merged
        devices go on driving the pad) or is back (the worker restarts the pipeline before its
        data); tell the user."""
        if status.kind == StatusKind.LOST:
            with self._lock:
                self._paused = True
                self._neutralise()
                self._forget_state()
                if self._merge is not None:  # what a merged device holds goes on over a gel at rest
                    self._publish_merged(self._merge)
            self._items.clear()
            self._held.clear()
            self.stats.camera_losses += 1
        elif status.kind == StatusKind.RESUMED:
            self._restart.set()
        self._say(status.message)

    def _rest(self) -> None:
        """Resting thread: run the detector on APS frames, hand each verdict to the pipeline."""
        try:
            while not self._stop.is_set():
                entry = self._frames.get(_IDLE_WAIT_S)
                if entry is None:
                    if self._frames.finished:
                        break
                    continue
                self._rest_verdict(entry[1])
        except BaseException as exc:
            self._errors.append(exc)
            self.stop()

    def _rest_verdict(self, frame: Frame) -> None:
        """The resting detector's verdict on ``frame``, handed to the pipeline. The resting thread
        and, at rest, the source's thread both call this: one at a time (the detector keeps state),
        and an older frame's verdict is not handed on after a newer one's (it would replace it)."""
        t_us = int(frame.t_us)
        with self._verdict_lock:
            result = self._resting.update(frame)
            if self._last_verdict_us is not None and t_us <= self._last_verdict_us:
                return
            self._last_verdict_us = t_us
            if result is not None:
                self._pipeline.set_resting(result, t_us)
                self.stats.resting_updates += 1

    def _work(self) -> None:
        """Pipeline thread: items -> estimates -> controller states -> records published."""
        # real time only: there the alternative is dropping data; a --fast run waits for the
        # pipeline and keeps its batches as the source made them
        joined_max = MAX_JOINED_EVENTS if self._realtime else 0
        try:
            while not self._stop.is_set():
                entry = self._items.get_joined(_IDLE_WAIT_S, max_events=joined_max)
                if entry is None:
                    if self._items.finished:
                        break
                    continue
                try:
                    self._handle(entry, newest=self._items.joined > 1)
                finally:
                    self._items.done()
        except BaseException as exc:
            self._errors.append(exc)
            self.stop()

    def _handle(self, entry: tuple[int, StreamItem], newest: bool = False) -> None:
        """One item -> estimates -> controller states -> records published: in the pipeline's
        thread, or in the source's while the gel rests (:meth:`_hand_on`), never both at once.
        ``newest``: the item joins event batches that queued up behind the pipeline: of the
        windows it closes only the newest is decided and published (``Pipeline.process_newest``:
        every event tracked, nothing dropped; the others are counted in ``stats.coalesced_windows``
        and their latency runs to this output, which covers them)."""
        stats = self.stats
        arrival_ns, item = entry
        if self._restart.is_set():
            self._resume()
        skipped: Sequence[int] = ()
        if newest and isinstance(item, np.ndarray):
            estimates, skipped = self._pipeline.process_newest(item)
        else:
            estimates = self._pipeline.process(item)
        if isinstance(item, Frame):
            stats.frames += 1
        elif isinstance(item, np.ndarray):
            stats.events += len(item)
        t_us = item_end_us(item)
        if t_us is not None:
            self._first_us = t_us if self._first_us is None else self._first_us
            stats.stream_us = t_us - self._first_us
        if skipped:
            stats.coalesced_windows += len(skipped)
            self._last_end_us = skipped[-1]
        for estimate in estimates:
            if not self._unchanged_at_rest(estimate):
                self._emit(estimate)
            stats.windows += 1
            previous, self._last_end_us = self._last_end_us, estimate.t_us
            resting = estimate.resting and previous is not None and estimate.t_us > previous
            self._rest_windows = (estimate.t_us, estimate.t_us - previous) if resting else None
        if estimates:
            done_ns = time.perf_counter_ns()
            compiling = self._compiling() is not None
            stats.add_latency(len(estimates), done_ns - arrival_ns, compiling=compiling, waiting=len(self._items))
            if self._pace:
                for end_us in skipped:
                    stats.window_latency.add(done_ns - self._clock.due_ns(end_us))
                for estimate in estimates:
                    stats.window_latency.add(done_ns - self._clock.due_ns(estimate.t_us))

    def _compiling(self) -> CompileProgress | None:
        """The first run's compile while it lasts (``compile_progress``); once it has answered
        None it is over for good (``warmup.Warmup.progress_now``) and is not asked again."""
        if self._compile_progress is None:
            return None
        progress = self._compile_progress()
        if progress is None:
            self._compile_progress = None
        return progress

    def _unchanged_at_rest(self, estimate: GestureEstimate) -> bool:
        """Whether ``estimate`` changes nothing: the gel rests, the mapper rests at its fixed point
        (``Mapper.resting_state``: a resting estimate gives that state again) and that state is
        the one last published, no subscriber wants every window (markers drawn), nothing
        compiles. Then neither the mapper nor a subscriber is called; the mapper is handed the
        last such estimate when the rest ends (:meth:`_emit`), as if it had had every one."""
        if not estimate.resting or self._every_window or estimate.gesture is not self._last_gesture:
            return False
        if self._quiet_mapper is self._mapper:  # known since the rest's first skipped window
            self._skipped = estimate
            return True
        with self._lock:
            kept = getattr(self._mapper, "resting_state", None)
            last = self._last_state
            unchanged = (
                kept is not None
                and kept.axes == last.axes
                and kept.buttons == last.buttons
                and kept.keys == last.keys
                and kept.touches == last.touches
                and kept.touch_click == last.touch_click
                and self._compiling() is None
                # a merged device's input is published with the last window's record: one must exist
                and (self._merge is None or self._last_record is not None)
            )
            if unchanged:
                self._skipped = estimate
                self._quiet_mapper = self._mapper
        return unchanged

    def _resume(self) -> None:
        """Worker thread, first item after the camera came back: a new session of the pipeline
        and the mapper; writing resumes."""
        self._restart.clear()
        self._pipeline.restart()
        with self._verdict_lock:
            self._last_verdict_us = None  # a new session's frames may start its clock again
        with self._lock:
            self._mapper = self._mapper_factory(self.profile)
            self._forget_state()
            self._paused = False

    def _neutralise(self) -> None:
        """Every subscriber neutral at once (caller holds ``self._lock``): each one, even when an
        earlier one fails; the first failure is raised after."""
        failure: BaseException | None = None
        for subscriber in self._subscribers:
            try:
                subscriber.neutralise()
            except Exception as exc:
                failure = failure or exc
        if failure is not None:
            raise failure

    def _performed_at(self, t_us: int) -> LabelRow | None:
        """The source's label in force at ``t_us`` (us): the last one at or before it."""
        labels = self._labels
        while labels and labels[0].t_us <= t_us:
            self._performed = labels.popleft()
        return self._performed

    def _emit(self, estimate: GestureEstimate) -> None:
        """Map one window's estimate and publish its record (a relative motion is an impulse:
        its state always counts as changed)."""
        with self._lock:
            if self._stop.is_set() or self._paused or self._suspended:  # run() neutralises (under this
                return  # lock): nothing after that; a lost camera, Ctrl-Z: nothing until back
            self._quiet_mapper = None
            if self._skipped is not None:  # the rest it skipped ends: the mapper's clocks to its end
                skipped, self._skipped = self._skipped, None
                self._mapper.update(skipped)
            state = self._last_gel = self._mapper.update(estimate)
            if self._merge is not None:
                state = self._merge.merge(state)
            last = self._last_state
            state_changed = (
                state.axes != last.axes
                or state.buttons != last.buttons
                or state.keys != last.keys
                or bool(state.rel)
                or state.touches != last.touches
                or state.touch_click != last.touch_click
            )
            markers = self._pipeline.markers() if self._wants_markers else None
            progress = self._compiling()
            record = WindowRecord(
                estimate=estimate,
                state=state,
                state_changed=state_changed,
                gesture_changed=estimate.gesture != self._last_gesture,
                profile=self.profile,
                profile_name=self.profile_name,
                sensor=self._sensor,
                markers=markers,
                performed=self._performed_at(estimate.t_us) if self._labelled else None,
                labelled=self._labelled,
                stats=self.stats,
                compile=progress,
            )
            for subscriber in self._subscribers:
                subscriber.publish(record)
            if state_changed:
                self.stats.states_written += 1
            self._last_state = state
            self._last_gesture = estimate.gesture
            self._last_record = record

    def _on_input(self) -> None:
        """A merged device's controls changed, or a device came or went (the merge's thread):
        publish the merged state of the gel's last one at once, when it changed (the last window's
        record with that state; the gel's relative motion is not repeated). With no window of the
        gel to go on (no camera yet, the camera lost, a profile just switched to), over a gel at
        rest: the merged devices are grabbed, so they must drive the pad meanwhile."""
        with self._lock:
            merge = self._merge
            if merge is None:
                return
            self.stats.merged, self.stats.missing = merge.status()
            self._publish_merged(merge)

    def _publish_merged(self, merge) -> None:
        """Publish ``merge``'s devices over the gel's last state, if that changes what was written
        (caller holds ``self._lock``; see :meth:`_on_input`)."""
        if self._stop.is_set() or self._suspended:
            return
        state = merge.merge(dataclasses.replace(self._last_gel, rel={}))
        last = self._last_state
        if state.axes == last.axes and state.buttons == last.buttons and state.keys == last.keys:
            return
        record = self._last_record if self._last_record is not None else self._record_at_rest()
        record = record._replace(state=state, state_changed=True, gesture_changed=False)
        for subscriber in self._subscribers:
            subscriber.publish(record)
        self.stats.states_written += 1
        self._last_state = state

    def _record_at_rest(self) -> WindowRecord:
        """A record for a gel with no window to go on: a resting estimate at the last state's time
        (us, camera clock), the gel's state neutral (caller holds ``self._lock``)."""
        t_us = self._last_state.t_us
        return WindowRecord(
            estimate=GestureEstimate(t_us=t_us),
            state=ControllerState.neutral(t_us),
            state_changed=False,
            gesture_changed=False,
            profile=self.profile,
            profile_name=self.profile_name,
            sensor=self._sensor,
            markers=None,
            performed=None,
            labelled=self._labelled,
            stats=self.stats,
            compile=self._compiling(),
        )

    def _switch_merge(self, profile: Profile) -> None:
        """Release the merged devices of the profile in use, grab those of ``profile`` (outside
        ``self._lock``: the merge's thread may be waiting for it in :meth:`_on_input`)."""
        if self._merge_for is None:
            return
        old, self._merge = self._merge, None
        if old is not None:
            old.stop()
        new = self._merge_for(profile)
        if new is not None and self._ran:
            new.start(self._on_input)
        self._merge = new
        if new is not None and self._stop.is_set():  # the run stopped meanwhile: it may not have seen this one
            new.stop()
        self.stats.merged, self.stats.missing = new.status() if new is not None else ((), ())


@dataclass(frozen=True)
class RunParts:
    """What an assembly opened for one run (:func:`run_assembled`).

    Attributes:
        stream: the source's items in time order.
        pipeline: the gesture pipeline (or a predictions file's replay).
        resting: the resting detector run beside it, or None (the pipeline runs its own).
        sensor: the gel's geometry; None for a predictions file.
        live: the source is real time by itself (the camera).
        labelled: the source says what it performs.
        compile_progress: the first run's compile, while it lasts (None: nothing compiles).
    """

    stream: SourceStream
    pipeline: Pipeline
    resting: RestingDetection | None
    sensor: SensorGeometry | None
    live: bool
    labelled: bool
    compile_progress: Callable[[], CompileProgress | None] | None


class Assembly(Protocol):
    """What a run opens when it starts: the source, the pipeline and its resting detector
    (``driver.RunAssembly``)."""

    def open(self, stack: contextlib.ExitStack) -> RunParts:
        """Open everything, closed by ``stack``."""


def run_assembled(
    assembly: Assembly,
    profile: Profile,
    subscribers: Sequence[Subscriber],
    seconds: float | None = None,
    **options: Any,
) -> RunStats:
    """Open what ``assembly`` names, then run it (:class:`Runtime`, with ``options``) to the end,
    publishing to ``subscribers``; everything opened is closed on every way out.

    Returns the run's :class:`RunStats`; raises what the assembly's opening or the run raises."""
    with contextlib.ExitStack() as stack:
        parts = assembly.open(stack)
        runtime = Runtime(
            parts.stream,
            parts.pipeline,
            profile,
            subscribers,
            resting=parts.resting,
            live=parts.live,
            sensor=parts.sensor,
            compile_progress=parts.compile_progress,
            labelled=parts.labelled,
            **options,
        )
        return runtime.run(seconds)
