"""The runtime: source -> gesture pipeline -> mapping -> output, in threads, with clean shutdown.

Following the paper (section "Runtime Performance"), the event path and the resting detection run
beside each other: one thread reads the source (pacing recordings and the simulated gel in real
time), one runs the gesture pipeline and the mapping and writes the output, and one runs the
resting detector (Chamfer distance on APS frames, paper, section "Resting Position Detection") and
hands its results to the pipeline (``pipeline.set_resting``). numpy, OpenCV and numba release the
GIL in their heavy parts, so on two cores the resting detection does not hold up the event path.

Between the threads sit bounded queues. When the pipeline falls behind a live or paced source, the
queue drops its OLDEST items (counted in :class:`RunStats`) instead of letting the controller lag;
with ``pace=False`` (``--fast``) nothing is dropped: the source waits for the pipeline instead,
and the pipeline runs the resting detection inline so that a replay is deterministic.

Sources (:func:`open_source`): the live camera, the simulated gel, an AEDAT4 recording, or a
predictions file (the pipeline's estimates, docs/dataset.md, replayed without the pipeline).

Every way out of :meth:`Runtime.run` (end of the source, :meth:`Runtime.stop`, SIGTERM, Ctrl-C, an
exception in any stage) first centres all axes and releases all buttons (``output.neutralise()``).

A live camera that is unplugged, fails or stalls does not end the run: its stream says so
(:class:`~neurotouch_hid.sources.SourceStatus`, see ``sources/davis.py``). On ``"lost"`` the source
thread neutralises the output at once, drops the data still queued and says why; nothing is
written until the camera is back. On ``"resumed"`` the pipeline restarts (``pipeline.restart()``:
the markers are re-initialised on the first APS frame at rest) with a fresh mapper (its filters
and hysteresis start neutral). SIGTERM is a clean stop (``run`` returns normally, the CLI exits 0);
SIGHUP reloads the profile from its file (a bad profile on reload keeps the old one and logs why).
With ``control=True`` the run listens on the control socket (:mod:`neurotouch_hid.control`):
``neurotouch-hid profile use NAME`` switches the profile while running, outputs neutral first.
"""

from __future__ import annotations

import collections
import contextlib
import logging
import signal
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterable, Iterator, Optional

import numpy as np

from neurotouch_hid.controller import ControllerState
from neurotouch_hid.errors import DeviceError, NeurotouchError, ProfileError
from neurotouch_hid.estimate import GestureEstimate, GestureType
from neurotouch_hid.sources import Frame, SourceStatus, StatusKind, StreamItem

log = logging.getLogger(__name__)

#: Source batch length (us): 1 ms batches keep the event-to-output latency well under a window.
DEFAULT_BATCH_US = 1_000
#: Input queue bound (items); with 1 ms batches about 0.2 s of data before the oldest is dropped.
DEFAULT_QUEUE_ITEMS = 200
#: Frame queue bound for the resting detector (APS frames, 25 Hz).
DEFAULT_FRAME_QUEUE = 2
#: How many latency samples are kept (a ring: memory stays flat over long sessions).
LATENCY_SAMPLES = 65_536
#: The interpreter's thread switch interval (s) during real-time runs, instead of Python's 5 ms:
#: a thread waiting for the GIL (the pipeline, while the resting thread runs Python code) gets it
#: within 0.5 ms. Measured (benchmarks/bench_latency.py): p99 processing latency 3.4 -> 1.7 ms.
REALTIME_SWITCH_INTERVAL_S = 0.0005

_POLL_S = 0.05
_JOIN_S = 2.0
_GRACE_S = 2.0


def item_end_us(item: StreamItem | GestureEstimate) -> Optional[int]:
    """The time (us, camera clock) at which a stream item is complete: a frame's timestamp, an event
    batch's last event timestamp, a replayed estimate's window end; None for an empty batch."""
    if isinstance(item, (Frame, GestureEstimate)):
        return int(item.t_us)
    if len(item) == 0:
        return None
    return int(item["timestamp"][-1])


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


@dataclass
class RunStats:
    """What a run did. Counters are updated live (the terminal view shows them).

    Attributes:
        windows: gesture estimates produced (one per window).
        events: events handed to the pipeline.
        frames: APS frames handed to the pipeline.
        states_written: controller states written to the output (state changes only).
        dropped_items, dropped_events, dropped_frames: input data dropped, oldest first, because the
            pipeline fell behind a live or paced source (items = event batches + frames).
        resting_updates: resting detector results handed to the pipeline.
        resting_dropped_frames: APS frames the resting detector skipped (it was still busy).
        camera_losses: times the live camera was lost (unplugged, failing, stalled).
        wall_s: wall time of the run (s).
        stream_us: camera time covered by the processed data (us).
        latency: processing latencies: from the moment the item that closed a window was read
            from the source (after pacing) to the output being up to date.
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
    camera_losses: int = 0
    wall_s: float = 0.0
    stream_us: int = 0
    latency: LatencyRing = field(default_factory=LatencyRing, repr=False)
    window_latency: LatencyRing = field(default_factory=LatencyRing, repr=False)

    def summary(self) -> str:
        """One line for the end of a run."""
        lat = ""
        if len(self.latency):
            lat = (f", latency p50 {self.latency.percentile_us(50) / 1e3:.2f} ms"
                   f" p99 {self.latency.percentile_us(99) / 1e3:.2f} ms")
        return (f"{self.windows} windows, {self.events} events, {self.frames} frames in {self.wall_s:.1f} s"
                f" ({self.stream_us / 1e6:.1f} s of data); dropped {self.dropped_items} items"
                f" ({self.dropped_events} events, {self.dropped_frames} frames),"
                f" resting detector skipped {self.resting_dropped_frames} frames"
                + (f", camera lost {self.camera_losses} time(s)" if self.camera_losses else "") + lat)


class DropOldestQueue:
    """A bounded FIFO between two threads.

    ``put`` on a full queue drops the oldest item (counted in ``stats``) when ``drop_oldest``, else
    waits for room. ``close`` ends the stream: ``get`` returns None once a closed queue is empty.
    Items are ``(arrival_ns, StreamItem)`` pairs.
    """

    def __init__(self, maxlen: int, *, drop_oldest: bool = True, on_drop: Callable[[StreamItem], None] | None = None):
        if maxlen < 1:
            raise ValueError("a queue needs room for at least one item")
        self._items: collections.deque = collections.deque()
        self._maxlen = maxlen
        self._drop_oldest = drop_oldest
        self._on_drop = on_drop
        self._cond = threading.Condition()
        self._closed = False

    def put(self, entry: tuple[int, StreamItem]) -> None:
        with self._cond:
            while len(self._items) >= self._maxlen and not self._closed:
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
        with self._cond:
            if not self._items and not self._closed:
                self._cond.wait(timeout)
            if not self._items:
                return None
            entry = self._items.popleft()
            self._cond.notify_all()
            return entry

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


def _load_profile(ref: str | Path):
    from neurotouch_hid.mapping.profile import load_profile

    return load_profile(ref)


def _make_mapper(profile):
    from neurotouch_hid.mapping.mapper import Mapper

    return Mapper(profile)


class Runtime:
    """Source -> pipeline -> mapper -> output, with a resting detector beside the event path.

    Args:
        source: an iterable of stream items (event batches of EVENT_DTYPE and :class:`Frame`, in
            time order), e.g. ``RecordingReader.stream()``, ``SimulatedSource.stream()``.
        pipeline: a ``GesturePipeline`` (``process(item) -> list[GestureEstimate]``,
            ``set_resting(result, t_us)``).
        profile: the loaded profile; the mapper is ``mapper_factory(profile)``.
        output: ``write(state[, estimate])``, ``neutralise()``; outputs with a true
            ``accepts_estimate`` attribute also get the window's estimate (gesture, intensity).
            The runtime does not close the output (its owner does; the gamepad device outlives
            profile switches).
        resting: a resting detector (``update(frame) -> result``, None = no verdict yet) run in
            its own thread on APS frames; its results go to ``pipeline.set_resting(result,
            frame.t_us)`` (thread-safe). None when the pipeline does its own resting detection.
        pace: sleep so that item timestamps follow wall time (recordings, the simulated gel).
        live: the source is real time by itself (the camera): not paced, but like a paced source
            its data is dropped, oldest first, when the pipeline falls behind. With neither
            ``pace`` nor ``live`` (``--fast``) everything is processed as fast as possible and
            nothing is dropped: the source waits for the pipeline.
        profile_ref: name or path the profile came from, reloaded on SIGHUP.
        queue_items: bound of the input queue (items).
        mapper_factory, profile_loader: the mapping's ``Mapper`` and ``load_profile`` (replaceable
            in tests).
        say: tells the user what happens to a live source (camera lost, back; one line each).
        control: serve the control socket while running (``profile use``, :meth:`use_profile`).
    """

    def __init__(
        self,
        source: Iterable[StreamItem],
        pipeline: Any,
        profile: Any,
        output: Any,
        *,
        resting: Any = None,
        pace: bool = True,
        live: bool = False,
        profile_ref: str | Path | None = None,
        queue_items: int = DEFAULT_QUEUE_ITEMS,
        mapper_factory: Callable[[Any], Any] = _make_mapper,
        profile_loader: Callable[[str | Path], Any] = _load_profile,
        say: Callable[[str], None] = log.warning,
        control: bool = False,
    ):
        self._control = control
        self._source = source
        self._pipeline = pipeline
        self.profile = profile
        self._mapper_factory = mapper_factory
        self._mapper = mapper_factory(profile)
        self._output = output
        self._takes_estimate = bool(getattr(output, "accepts_estimate", False))
        self._resting = resting
        self._pace = pace and not live
        self._realtime = pace or live
        self._profile_ref = profile_ref
        self._profile_loader = profile_loader
        self.stats = RunStats()
        self._items = DropOldestQueue(queue_items, drop_oldest=self._realtime, on_drop=self._count_drop)
        self._frames = DropOldestQueue(DEFAULT_FRAME_QUEUE, drop_oldest=self._realtime, on_drop=self._count_resting_drop)
        self._stop = threading.Event()
        self._reload = threading.Event()
        self._lock = threading.Lock()  # mapper + output: the worker vs. profile switches
        self._errors: list[BaseException] = []
        self._last_state = ControllerState.neutral()
        self._last_gesture: GestureType | None = None
        self._limit_us: int | None = None
        self._first_ns = 0  # perf_counter_ns of the first item read ...
        self._first_us = 0  # ... and its time (us, camera clock): the pacing anchor
        self._ran = False
        self._say = say
        self._paused = False  # the live camera is lost: write nothing (under self._lock)
        self._restart = threading.Event()  # it is back: restart the pipeline before its data

    # --- control ----------------------------------------------------------------------------
    def stop(self) -> None:
        """Ask every thread to stop; :meth:`run` then neutralises the output and returns.
        Safe from any thread and from a signal handler."""
        self._stop.set()
        self._items.close()
        self._frames.close()

    def switch_profile(self, profile: Any) -> None:
        """Neutralise the output, then map with ``profile`` from the next window on.
        The output devices are kept (the pad's name and ids stay those it was created with); a
        keyboard or mouse the new profile needs is created (``output.prepare(profile)``)."""
        with self._lock:
            self._output.neutralise()
            prepare = getattr(self._output, "prepare", None)
            if prepare is not None:
                prepare(profile)
            self._mapper = self._mapper_factory(profile)
            self.profile = profile
            self._forget_state()

    def _forget_state(self) -> None:
        """The output was neutralised or the mapping starts afresh: the next state written is
        compared with a neutral one (caller holds ``self._lock``)."""
        self._last_state = ControllerState.neutral(self._last_state.t_us)
        self._last_gesture = None

    def reload_profile(self) -> bool:
        """Load the profile again from ``profile_ref`` (the user edited it) and switch to it.
        A bad profile keeps the current one and logs every problem; returns whether it switched."""
        if self._profile_ref is None:
            log.warning("no profile file to reload")
            return False
        try:
            profile = self._profile_loader(self._profile_ref)
        except ProfileError as exc:
            log.error("profile not reloaded, keeping the current one: %s", exc)
            return False
        self.switch_profile(profile)
        log.warning("profile reloaded from %s", self._profile_ref)
        return True

    def use_profile(self, ref: str) -> str:
        """``profile use``: load ``ref`` (name or path), switch to it (:meth:`switch_profile`), and
        reload it on SIGHUP from now on; returns a line saying so. Raises ProfileError (nothing
        changes) for a missing or invalid profile."""
        profile = self._profile_loader(ref)
        self.switch_profile(profile)
        self._profile_ref = ref
        log.warning("switched to profile %s", ref)
        return f"switched to profile {ref}"

    # --- the run ----------------------------------------------------------------------------
    def run(self, seconds: float | None = None) -> RunStats:
        """Run until the source ends, ``seconds`` of camera time have been read, :meth:`stop`,
        SIGTERM or Ctrl-C; neutralise the output on every way out.

        Returns the :class:`RunStats`. Re-raises the first exception of any stage (after
        neutralising); a KeyboardInterrupt is re-raised too. SIGTERM returns normally. Installs
        SIGTERM and SIGHUP handlers while running when called from the main thread.
        """
        if self._ran:
            raise RuntimeError("a Runtime runs once")
        self._ran = True
        self._limit_us = None if seconds is None else int(round(seconds * 1e6))
        threads = [threading.Thread(target=self._read_source, name="nt-source", daemon=True),
                   threading.Thread(target=self._work, name="nt-pipeline", daemon=True)]
        if self._resting is not None:
            threads.append(threading.Thread(target=self._rest, name="nt-resting", daemon=True))
        interrupted = False
        start = time.perf_counter()
        with self._signal_handlers(), self._switch_interval(), self._control_socket():
            try:
                for t in threads:
                    t.start()
                worker = threads[1]
                while worker.is_alive():
                    worker.join(_POLL_S)
                    if self._reload.is_set():
                        self._reload.clear()
                        self.reload_profile()
                    if seconds is not None and self._realtime:
                        # a real-time source that stalls still ends: wall deadline from its first item
                        first = self._first_ns / 1e9 if self._first_ns else start
                        if time.perf_counter() > first + seconds + _GRACE_S:
                            self.stop()
            except KeyboardInterrupt:
                interrupted = True
            finally:
                self.stop()
                for t in threads:
                    t.join(_JOIN_S)
                self.stats.wall_s = time.perf_counter() - start
                with self._lock:
                    self._output.neutralise()
        if self._errors:
            raise self._errors[0]
        if interrupted:
            raise KeyboardInterrupt
        return self.stats

    @contextlib.contextmanager
    def _control_socket(self) -> Iterator[None]:
        if not self._control:
            yield
            return
        from neurotouch_hid.control import ControlServer

        server = ControlServer(self.use_profile)
        server.start()
        try:
            yield
        finally:
            server.stop()

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
        iterator = iter(self._source)
        first_us: int | None = None
        first_ns = 0
        try:
            for item in iterator:
                if self._stop.is_set():
                    break
                if isinstance(item, SourceStatus):
                    self._source_status(item)
                    continue
                t_us = item_end_us(item)
                if t_us is not None:
                    if first_us is None:
                        first_us, first_ns = t_us, time.perf_counter_ns()
                        self._first_ns, self._first_us = first_ns, first_us
                    if self._limit_us is not None and t_us - first_us >= self._limit_us:
                        break
                    if self._pace:
                        delay_ns = first_ns + (t_us - first_us) * 1000 - time.perf_counter_ns()
                        if delay_ns > 0 and self._stop.wait(delay_ns / 1e9):
                            break
                entry = (time.perf_counter_ns(), item)
                if isinstance(item, Frame) and self._resting is not None:
                    self._frames.put(entry)
                self._items.put(entry)
        except BaseException as exc:  # a truncated recording, a lost camera: what was read is
            self._errors.append(exc)    # still processed, then run() neutralises and re-raises
        finally:
            close = getattr(iterator, "close", None)
            if close is not None:
                with contextlib.suppress(Exception):
                    close()
            self._items.close()
            self._frames.close()

    def _source_status(self, status: SourceStatus) -> None:
        """Source thread: the live camera was lost (neutralise now, drop the stale queue) or is
        back (the worker restarts the pipeline before its data); tell the user."""
        if status.kind == StatusKind.LOST:
            with self._lock:
                self._paused = True
                self._output.neutralise()
                self._forget_state()
            self._items.clear()
            self.stats.camera_losses += 1
        elif status.kind == StatusKind.RESUMED:
            self._restart.set()
        self._say(status.message)

    def _rest(self) -> None:
        """Resting thread: run the detector on APS frames, hand each verdict to the pipeline."""
        try:
            while not self._stop.is_set():
                entry = self._frames.get()
                if entry is None:
                    if self._frames.finished:
                        break
                    continue
                frame = entry[1]
                result = self._resting.update(frame)
                if result is not None:
                    self._pipeline.set_resting(result, int(frame.t_us))
                    self.stats.resting_updates += 1
        except BaseException as exc:
            self._errors.append(exc)
            self.stop()

    def _work(self) -> None:
        """Pipeline thread: items -> estimates -> controller states -> output."""
        stats = self.stats
        first_us: int | None = None
        try:
            while not self._stop.is_set():
                entry = self._items.get()
                if entry is None:
                    if self._items.finished:
                        break
                    continue
                arrival_ns, item = entry
                if self._restart.is_set():
                    self._resume()
                estimates = self._pipeline.process(item)
                if isinstance(item, Frame):
                    stats.frames += 1
                elif isinstance(item, np.ndarray):
                    stats.events += len(item)
                t_us = item_end_us(item)
                if t_us is not None:
                    first_us = t_us if first_us is None else first_us
                    stats.stream_us = t_us - first_us
                for estimate in estimates:
                    self._emit(estimate)
                    stats.windows += 1
                if estimates:
                    done_ns = time.perf_counter_ns()
                    stats.latency.add(done_ns - arrival_ns)
                    if self._pace:
                        for estimate in estimates:
                            end_ns = self._first_ns + (estimate.t_us - self._first_us) * 1000
                            stats.window_latency.add(done_ns - end_ns)
        except BaseException as exc:
            self._errors.append(exc)
            self.stop()

    def _resume(self) -> None:
        """Worker thread, first item after the camera came back: a new session of the pipeline
        and the mapper; writing resumes."""
        self._restart.clear()
        self._pipeline.restart()
        with self._lock:
            self._mapper = self._mapper_factory(self.profile)
            self._forget_state()
            self._paused = False

    def _emit(self, estimate: GestureEstimate) -> None:
        with self._lock:
            if self._stop.is_set() or self._paused:  # run() neutralises (under this lock): nothing
                return                                # after that; a lost camera: nothing until back
            state = self._mapper.update(estimate)
            last = self._last_state
            changed = (state.axes != last.axes or state.buttons != last.buttons or state.keys != last.keys
                       or bool(state.rel))  # motion is an impulse: always written
            if self._takes_estimate:
                changed = changed or estimate.gesture != self._last_gesture
                if changed:
                    self._output.write(state, estimate)
            elif changed:
                self._output.write(state)
            if changed:
                self.stats.states_written += 1
            self._last_state = state
            self._last_gesture = estimate.gesture


# --- wiring the concrete stages (the `run` and `demo` commands) ------------------------------
OUTPUT_KINDS = ("gamepad", "jsonl", "term")


class EstimateReplay:
    """Stands in for the pipeline when the source is a predictions file: its items already are
    the windows' :class:`GestureEstimate` values (docs/dataset.md "Predictions"), handed on as they are."""

    def process(self, item: GestureEstimate) -> list[GestureEstimate]:
        return [item]

    def restart(self) -> None:  # pragma: no cover - a predictions file is never interrupted
        pass

    def set_resting(self, result: Any, t_us: int) -> None:  # pragma: no cover - no frames here
        pass


def open_source(spec: str, stack: contextlib.ExitStack, *, seconds: float | None = None,
                batch_us: int = DEFAULT_BATCH_US, sensor: str | Path | None = None,
                seed: int = 0, davis: Any = None, wait: bool = False,
                capture: Any = None) -> tuple[Iterable[Any], Any, bool]:
    """Open ``davis`` (the live camera), ``sim`` (the simulated gel), an AEDAT4 recording path, or
    a predictions file (``*.jsonl``, docs/dataset.md: the pipeline's estimates, replayed as they are).

    The camera's stream survives unplugs and stalls (it yields
    :class:`~neurotouch_hid.sources.SourceStatus` items); ``davis`` is its
    :class:`~neurotouch_hid.sources.davis.DavisConfig`, ``wait`` waits for a camera instead of
    failing, ``capture`` replaces dv-processing's camera backend (tests replay recordings through
    it). Its geometry is ``sensor``, else the user's calibration, else the built-in one. The
    pipeline's default noise filter runs in the camera's source, on dv-processing's own event
    stores (no copies; build the pipeline with ``filter_noise=False`` then).

    Returns ``(stream, sensor_geometry, live)``; ``live`` is True for the camera (never paced by
    the runtime); the geometry is None for a predictions file. Resources (camera, file) are
    closed by ``stack``. Raises RecordingError for a missing or unreadable recording,
    DatasetError for a bad predictions file, DeviceError when the camera cannot be opened (and
    ``wait`` is off).
    """
    from neurotouch_hid.sensor import SensorGeometry, default_sensor, find_sensor_file

    if spec.endswith(".jsonl"):
        from neurotouch_hid.output.jsonl import read_predictions

        return iter(read_predictions(spec)), None, False

    if spec == "davis":
        from neurotouch_hid.sources.davis import DavisSource

        from neurotouch_hid.pipeline.noise import EventNoiseFilter
        from neurotouch_hid.pipeline.pipeline import PipelineConfig
        from neurotouch_hid.sources.recording import DAVIS346_RESOLUTION

        defaults = PipelineConfig()
        noise = (EventNoiseFilter(defaults.noise_filter, *DAVIS346_RESOLUTION, defaults.noise_filter_us)
                 if defaults.noise_filter is not None else None)
        try:
            camera = stack.enter_context(DavisSource(davis, wait=wait, backend=capture, noise_filter=noise))
        except DeviceError as exc:
            raise DeviceError(f"{exc}; or start with --wait to wait for a camera") from None
        geometry = SensorGeometry.load(sensor) if sensor is not None else default_sensor()
        return camera.stream(seconds=seconds, batch_us=batch_us, reconnect=True), geometry, True
    if spec == "sim":
        from neurotouch_hid.sources.simulator import SimulatedSource

        sim = SimulatedSource(seed=seed) if sensor is None else SimulatedSource(SensorGeometry.load(sensor), seed=seed)
        return sim.stream(seconds=seconds, batch_us=batch_us), sim.sensor, False
    from neurotouch_hid.errors import RecordingError
    from neurotouch_hid.sources.recording import RecordingReader

    path = Path(spec)
    if not path.is_file():
        raise RecordingError(f"{path}: no such recording (--source takes davis, sim, an AEDAT4 file or a predictions .jsonl)")
    reader = stack.enter_context(RecordingReader(path))
    return reader.stream(batch_us=batch_us), find_sensor_file(path, sensor), False


def open_output(kind: str, profile: Any, stack: contextlib.ExitStack, *, out: str | Path | None = None,
                console: Any = None, say: Callable[[str], None] | None = None) -> Any:
    """Create the output: ``gamepad`` (the uinput pad with the profile's name and ids, and the
    keyboard and mouse if the profile uses them), ``jsonl`` (one state line per change to ``out``
    or stdout) or ``term`` (the terminal view). ``say`` tells the user about rumble effects games
    send to the pad (the gel has no motor; default: the log).
    Closed by ``stack``. Raises DeviceError when /dev/uinput cannot be used."""
    if kind == "gamepad":
        from neurotouch_hid.output.desktop import UinputOutputs
        from neurotouch_hid.output.gamepad import GamepadIdentity, VirtualGamepad

        dev = profile.device
        identity = GamepadIdentity(name=dev.name, vendor=dev.vendor, product=dev.product, version=dev.version)
        on_effect = None if say is None else (lambda line: say(f"rumble (the gel has no motor): {line}"))
        return stack.enter_context(UinputOutputs(VirtualGamepad(identity, on_effect=on_effect), profile))
    if kind == "jsonl":
        from neurotouch_hid.output.jsonl import StateJsonlWriter

        return stack.enter_context(StateJsonlWriter(out))
    from neurotouch_hid.output.term import TermView

    return stack.enter_context(TermView(console))


class PipelineResting:
    """The pipeline's own resting detector, run from the runtime's resting thread.

    ``GesturePipeline`` creates its :class:`~neurotouch_hid.pipeline.resting.RestingDetector` at
    its reference (first) APS frame; until then :meth:`update` has no verdict (None)."""

    def __init__(self, pipeline: Any):
        self._pipeline = pipeline

    def update(self, frame: Frame) -> Any:
        """The Chamfer-distance verdict for ``frame`` (``RestingResult``), or None."""
        detector = self._pipeline.resting_detector
        return None if detector is None else detector.update(frame)


def build_pipeline(geometry: Any, window_us: int, *, resting_beside: bool = True,
                   filter_noise: bool = True) -> tuple[Any, PipelineResting | None]:
    """A ``GesturePipeline`` with ``window_us`` windows, and the resting detector to run beside it.

    ``filter_noise``: the pipeline runs its default noise filter (``PipelineConfig.noise_filter``);
    False when the source already did (the live camera, :func:`open_source`).

    ``resting_beside``: the resting detection runs in the runtime's own thread (paper, section
    "Runtime Performance": one core for it, one for the gesture detection) and the pipeline does
    not run it (``detect_resting=False``). False: the pipeline runs it inline on each frame, and
    the run is deterministic (the same input gives the same estimates): what ``--fast`` replays
    use, as nothing there needs to keep up with the camera.
    """
    from neurotouch_hid.pipeline.pipeline import GesturePipeline, PipelineConfig

    config = PipelineConfig(window_us=window_us, detect_resting=not resting_beside)
    if not filter_noise:
        config.noise_filter = config.noise_filter_us = None
    pipeline = GesturePipeline(geometry, config)
    return pipeline, (PipelineResting(pipeline) if resting_beside else None)


def compile_pipeline() -> None:
    """Compile the pipeline's numba code before any source is opened
    (:meth:`GesturePipeline.compile_kernels`): on a fresh install that takes seconds, which a
    real-time run would otherwise spend dropping data, and a camera buffering it."""
    from neurotouch_hid.pipeline.pipeline import GesturePipeline
    from neurotouch_hid.sensor import SensorGeometry

    GesturePipeline(SensorGeometry()).compile_kernels()


def run_driver(source: str = "davis", profile: str | Path = "default", output: str = "gamepad", *,
               seconds: float | None = None, fast: bool = False, out: str | Path | None = None,
               window_us: int = 10_000, sensor: str | Path | None = None, seed: int = 0,
               console: Any = None, output_obj: Any = None, davis: Any = None, wait: bool = False,
               capture: Any = None, say: Callable[[str], None] = log.warning) -> RunStats:
    """``neurotouch-hid run``: load the profile (a bad one raises ProfileError before any device
    exists), open the source, build the pipeline, open the output, run until the end.

    Real time (the camera, or paced replays): the resting detector runs in its own thread and
    data is dropped, oldest first, if the pipeline falls behind. ``fast`` (recordings and the
    simulated gel only): as fast as possible, nothing dropped, resting detection inline, so the
    same input always gives the same states.

    ``output_obj`` replaces the output named by ``output`` (the demo's fallback, benchmarks).
    ``davis``, ``wait``, ``capture``: the live camera's settings (:func:`open_source`); ``say``
    tells the user when it is lost and back.
    Raises NeurotouchError subclasses for bad input (ProfileError, RecordingError, DeviceError,
    SensorError).
    """
    if output not in OUTPUT_KINDS:
        raise NeurotouchError(f"unknown output '{output}' (expected one of: {', '.join(OUTPUT_KINDS)})")
    if window_us < 1000:
        raise NeurotouchError(f"--window-us {window_us}: windows must be at least 1000 us")
    loaded = _load_profile(profile)
    if not source.endswith(".jsonl"):
        compile_pipeline()
    with contextlib.ExitStack() as stack:
        stream, geometry, live = open_source(source, stack, seconds=seconds,
                                             batch_us=min(DEFAULT_BATCH_US, window_us), sensor=sensor, seed=seed,
                                             davis=davis, wait=wait, capture=capture)
        if geometry is None:  # a predictions file: the estimates are already there
            pipeline, resting = EstimateReplay(), None
        else:
            pipeline, resting = build_pipeline(geometry, window_us, resting_beside=live or not fast,
                                               filter_noise=not live)
        out_obj = output_obj if output_obj is not None else open_output(output, loaded, stack, out=out, console=console,
                                                                        say=say)
        runtime = Runtime(stream, pipeline, loaded, out_obj, resting=resting, pace=not fast, live=live,
                          profile_ref=profile, say=say, control=True)
        if hasattr(out_obj, "stats"):
            out_obj.stats = runtime.stats
        return runtime.run(seconds)


def gamepad_or_terminal(profile: Any, stack: contextlib.ExitStack, *, console: Any = None,
                        say: Callable[[str], None] = print) -> Any:
    """The virtual gamepad where /dev/uinput is writable; else the terminal view, after saying
    why in one line (``say``)."""
    from neurotouch_hid.udev import uinput_help

    try:
        return open_output("gamepad", profile, stack)
    except DeviceError as exc:
        reason = str(exc).replace(": " + uinput_help(), "").strip()
        say(f"no writable /dev/uinput ({reason}): showing the gamepad in the terminal instead; "
            "see `neurotouch-hid doctor`")
        return open_output("term", profile, stack, console=console)


def run_demo(seconds: float | None = 30.0, *, console: Any = None,
             say: Callable[[str], None] = print) -> RunStats:
    """``neurotouch-hid demo``: the simulated gel performing every gesture, paced in real time,
    through the default profile, to the virtual gamepad (or the terminal view, see
    :func:`gamepad_or_terminal`)."""
    profile = _load_profile("default")
    with contextlib.ExitStack() as stack:
        out = gamepad_or_terminal(profile, stack, console=console, say=say)
        return run_driver("sim", "default", "gamepad", seconds=seconds, console=console, output_obj=out)
