"""The engine: source -> gesture pipeline -> mapping -> subscribers, in threads, with clean shutdown.

Following the paper (section "Runtime Performance"), the event path and the resting detection run
beside each other: one thread reads the source (pacing recordings and the simulated gel in real
time), one runs the gesture pipeline and publishes each window, and one runs the resting detector
(Chamfer distance on APS frames, paper, section "Resting Position Detection") and hands its
results to the pipeline (``pipeline.set_resting``). numpy, OpenCV and numba release the GIL in
their heavy parts, so on two cores the resting detection does not hold up the event path.

The engine's parts own their state: the run's :class:`~neurotouch_hid.engine.mode.RunMode` and
:class:`~neurotouch_hid.engine.mode.RunOptions`; the queues between the threads
(:class:`~neurotouch_hid.engine.queue.DropOldestQueue`: of the windows that queued up behind the
pipeline only the newest is decided, ``Pipeline.process_newest``, every event tracked; a ``FAST``
run drops nothing, and runs the resting detection inline so that a replay is deterministic); the
rest hand-over (:class:`~neurotouch_hid.engine.rest.RestHandover`: while the gel rests, one
wake-up a window, the source's thread processing a window's items itself); and the publisher
(:class:`~neurotouch_hid.engine.publisher.Publisher`), the only caller of the subscribers. Every
way out of :meth:`Engine.run` first neutralises every subscriber.

A live camera that is unplugged, fails or stalls does not end the run: its stream says so
(:class:`~neurotouch_hid.sources.SourceStatus`, see ``sources/davis.py``). On ``"lost"`` the source
thread neutralises the output at once, drops the data still queued and says why; nothing is
written until the camera is back. On ``"resumed"`` the pipeline restarts (``pipeline.restart()``:
the markers are re-initialised on the first APS frame at rest) with a fresh mapper. SIGTERM is a
clean stop (``run`` returns normally, the CLI exits 0); SIGHUP reloads the profile from its file
(a bad profile keeps the old one and logs why); SIGTSTP (Ctrl-Z) releases every output before the
process stops, and SIGCONT resumes from a neutral state (:meth:`Engine.suspend`). The control
socket and the games watcher (``service/``) are the driver's: they call :meth:`Engine.use_profile`.
During the run the main thread serves the run's one loop (:class:`~neurotouch_hid.engine.loop.Loop`:
the signals, the devices' feedback, the merged devices, the control socket, the games watcher's
timer) until the pipeline's thread ends.
"""

from __future__ import annotations

import contextlib
import logging
import os
import signal
import threading
import time
from dataclasses import dataclass
from typing import TYPE_CHECKING, Callable, Iterable

import numpy as np

from neurotouch_hid.core.errors import NeurotouchError
from neurotouch_hid.core.stages import CompileProgress, Pipeline, RestingDetection, SourceStream, Subscriber
from neurotouch_hid.core.stats import RunStats
from neurotouch_hid.engine.loop import Loop
from neurotouch_hid.engine.mode import RunMode, RunOptions
from neurotouch_hid.engine.publisher import CompileWatch, Publisher
from neurotouch_hid.engine.queue import DEFAULT_FRAME_QUEUE, MAX_JOINED_EVENTS, DropOldestQueue, item_end_us
from neurotouch_hid.engine.rest import REST_WAKE_AFTER_END_US, RestHandover
from neurotouch_hid.engine.signals import handled, switch_interval
from neurotouch_hid.mapping.commitment import waits_for_type
from neurotouch_hid.mapping.profile import Profile
from neurotouch_hid.sources import Frame, Pacer, Performed, SourceStatus, StatusKind, StreamItem, WrappedStream

if TYPE_CHECKING:
    from neurotouch_hid.core.sensor import SensorGeometry

log = logging.getLogger(__name__)

#: A thread waiting for queued items waits until one comes or the queue closes (no time-out:
#: nothing wakes at rest that has nothing to do).
_IDLE_WAIT_S = None
_JOIN_S = _GRACE_S = 2.0  # how long a thread's end is waited for; a stalled live run's grace


@dataclass(frozen=True)
class RunParts:
    """A run's stages, as an assembly opened them (:func:`~neurotouch_hid.engine.assembly.
    run_assembled`) or a test made them.

    Attributes:
        stream: the source's items in time order (:class:`~neurotouch_hid.core.stages.SourceStream`,
            or any iterable of them).
        pipeline: the gesture pipeline (or a predictions file's replay).
        resting: the resting detector run beside it in its own thread (results to
            ``pipeline.set_resting``), or None (the pipeline runs its own).
        sensor: the gel's geometry, handed on in each record; None for a predictions file.
        live: the source is real time by itself (the camera): ``run_assembled`` runs it
            :attr:`RunMode.LIVE`.
        labelled: the source says what it performs (:class:`~neurotouch_hid.sources.Performed`).
        compile_progress: the first run's compile, while it lasts (None: nothing compiles).
    """

    stream: SourceStream | Iterable
    pipeline: Pipeline
    resting: RestingDetection | None = None
    sensor: SensorGeometry | None = None
    live: bool = False
    labelled: bool = False
    compile_progress: Callable[[], CompileProgress | None] | None = None


class Engine:
    """Source -> pipeline -> mapper -> subscribers, with a resting detector beside the event path.

    Args:
        parts: the stages (:class:`RunParts`).
        profile: the loaded profile; the mapper is ``options.mapper_factory(profile)``.
        subscribers: who each window's :class:`~neurotouch_hid.core.stages.WindowRecord` is published
            to, in this order; not closed here (their owner does).
        options: the mode and the rest (:class:`~neurotouch_hid.engine.mode.RunOptions`).
    """

    def __init__(
        self,
        parts: RunParts,
        profile: Profile,
        subscribers: Iterable[Subscriber],
        options: RunOptions = RunOptions(),
    ) -> None:
        self.options = options
        self.mode = mode = options.mode
        #: what the main thread waits on during the run (signals, the merged devices, the targets'
        #: feedback, the control socket, the games watcher): the driver's, or one of its own
        self.loop = options.loop if options.loop is not None else Loop()
        self._own_loop = options.loop is None  # closed when the run ends
        stream = parts.stream
        self._source: SourceStream = stream if isinstance(stream, WrappedStream) else WrappedStream(iter(stream))
        self._pipeline = parts.pipeline
        self._resting = parts.resting
        self._profile_ref = options.profile_ref
        self.stats = options.stats if options.stats is not None else RunStats()
        self.stats.note(profile=str(options.profile_ref) if options.profile_ref is not None else "")
        self._stop = threading.Event()
        self._worked = threading.Event()  # the pipeline's thread is over: the main thread's loop ends
        self._restart = threading.Event()  # the camera is back: restart the pipeline before its data
        self._switching = threading.Lock()  # one profile switch at a time
        self._verdict_lock = threading.Lock()  # the resting detector: its thread vs. the source's at rest
        self._last_verdict_us: int | None = None
        self._errors: list[BaseException] = []
        self._limit_us: int | None = None
        self._clock = options.pacer or Pacer()  # the first item read anchors pacing, limits and latencies
        self._ran = self._merging = False  # run; its merged devices started (a switch starts its own)
        self._first_us: int | None = None  # the first item's end (us), for ``stats.stream_us``
        self._compile = CompileWatch(parts.compile_progress)
        merge = options.merge
        if merge is None and options.merge_for is not None:
            merge = options.merge_for(profile)
        self._merge = merge
        self._set_type_wait(self._type_wait(profile))
        self.publisher = Publisher(
            subscribers,
            profile,
            options.mapper_factory(profile),
            str(options.profile_ref) if options.profile_ref is not None else "(given)",
            self._pipeline,
            self.stats,
            self._stop,
            sensor=parts.sensor,
            labelled=parts.labelled,
            compile=self._compile,
            merge=merge,
        )
        self._items = DropOldestQueue(
            options.queue_items,
            drop_oldest=mode.drops,
            on_drop=self._count_drop,
            max_span_us=options.max_lag_us,
            span_waits=mode.waits,
        )
        self._frames = DropOldestQueue(DEFAULT_FRAME_QUEUE, drop_oldest=mode.realtime, on_drop=self._count_resting_drop)
        # a live source's polls that bring nothing wait as the rest decides
        self._pause = pause = self._source.poll_pause if mode is RunMode.LIVE else None
        default_s = pause.default_s if pause is not None else 0.0
        self.rest = RestHandover(self._clock, self._stop, self._hand_on, paced=mode.paced, default_pause_s=default_s)

    @property
    def profile(self) -> Profile:
        """The profile mapping now."""
        return self.publisher.profile

    @property
    def profile_name(self) -> str:
        """The profile in use as the user named it (name or path), for display."""
        return self.publisher.profile_name

    @property
    def busy(self) -> bool:
        """An item is queued for the pipeline or being processed."""
        return self._items.busy

    # --- control ---------------------------------------------------------------------------------
    def stop(self) -> None:
        """Ask every thread to stop; :meth:`run` then neutralises every subscriber and returns.
        Safe from any thread and from a signal handler."""
        self._stop.set()
        self._items.close()
        self._frames.close()
        self.loop.wake()

    def switch_profile(self, profile: Profile, name: str | None = None) -> None:
        """Neutralise every subscriber, then map with ``profile`` (named ``name`` from now on;
        None: the name stays) from the next window on. The output devices are kept; a keyboard
        or mouse the new profile needs is made (``prepare(profile)``). The old profile's merged
        devices are released, the new one's grabbed.

        Raises:
            NeurotouchError: the run is stopping or over: nothing is switched.
        """
        if self._stop.is_set():
            raise NeurotouchError("the driver is stopping: the profile is not switched")
        with self._switching:
            self._switch_merge(profile)
            wait = self._type_wait(profile)  # its probe (~0.1 s) outside the lock the worker maps under
            self.publisher.switch(profile, self.options.mapper_factory(profile), name)
            self._set_type_wait(wait)

    @staticmethod
    def _type_wait(profile: Profile) -> bool | None:
        """Whether the pipeline should wait for the fingers before committing a type under
        ``profile`` (``mapping/commitment.py``), None for a profile that is not a :class:`Profile`."""
        return waits_for_type(profile) if isinstance(profile, Profile) else None

    def _set_type_wait(self, wait: bool | None) -> None:
        if wait is not None:
            self._pipeline.set_type_wait(wait)

    def reload_profile(self) -> bool:
        """Load the profile again from its name or path (the user edited it) and switch to it.
        A bad profile keeps the current one and logs every problem; returns whether it switched."""
        if self._profile_ref is None:
            log.warning("no profile file to reload")
            return False
        try:
            profile = self.options.profile_loader(self._profile_ref)
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
        profile = self.options.profile_loader(ref)
        self.switch_profile(profile, str(ref))
        self._profile_ref = ref  # (the loop's thread only: reloaded on SIGHUP)
        self.stats.note(profile=str(ref))
        line = f"switched to profile {ref}" + (f" ({reason})" if reason else "")
        log.warning("%s", line)
        return line

    def suspend(self) -> None:
        """SIGTSTP (Ctrl-Z): release every output, then stop the process as SIGTSTP's default
        action does; after SIGCONT (``fg``) map again from a neutral state, pacing shifted by
        the time stopped (a paced source does not rush to catch up). Main thread only."""
        self.publisher.suspend()
        log.warning("stopped: every output released (fg or SIGCONT resumes)")
        stopped_ns = time.perf_counter_ns()
        previous = signal.signal(signal.SIGTSTP, signal.SIG_DFL)
        try:
            os.kill(os.getpid(), signal.SIGTSTP)  # the process stops here until SIGCONT
        finally:
            signal.signal(signal.SIGTSTP, previous)
        if self._clock.first_us is not None:
            self._clock.first_ns += time.perf_counter_ns() - stopped_ns
        self.publisher.unsuspend()
        log.warning("resumed")

    # --- the run ---------------------------------------------------------------------------------
    def run(self, seconds: float | None = None) -> RunStats:
        """Run until the source ends, ``seconds`` of camera time have been read, :meth:`stop`,
        SIGTERM or Ctrl-C; neutralise every subscriber on every way out.

        Returns the :class:`RunStats`. Re-raises the first exception of any stage (after
        neutralising); a KeyboardInterrupt is re-raised too, its ``stats`` attribute the run's
        :class:`RunStats`. SIGTERM returns normally. Installs SIGTERM, SIGHUP and SIGTSTP
        handlers while running when called from the main thread.
        """
        if self._ran:
            raise RuntimeError("an Engine runs once")
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
        early = self.options.early_stop
        signals = {"SIGTERM": self.stop, "SIGHUP": self.reload_profile, "SIGTSTP": self.suspend}
        with handled(self.loop, signals), switch_interval(self.mode.realtime):
            try:
                if early is not None:  # this run's handlers are in place: its SIGTERM only flags
                    early.quiet()
                    if early.requested.is_set():
                        self.stop()
                with self._switching:  # a profile switched meanwhile waits: it replaces this merge after
                    self._merging = True
                    if self._merge is not None:
                        self._merge.start(self.publisher.merged_input)
                        merged, missing = self._merge.status()
                        self.stats.note(merged=merged, missing=missing)
                for t in threads:
                    t.start()
                worker = threads[1]
                if seconds is not None and self.mode.drops:
                    self._stop_at_deadline(start, seconds)
                # the main thread: the loop, until the pipeline's thread ends (it wakes the loop)
                self.loop.run_until(lambda: self._worked.is_set() or not worker.is_alive())
            except KeyboardInterrupt:
                interrupted = True
            finally:
                self.stop()
                for t in threads:
                    if t.ident is not None:  # a Ctrl-C while they were being started: not all were
                        t.join(_JOIN_S)
                self.stats.note(wall_s=time.perf_counter() - start)
                unfinished = self._compile.now()
                if unfinished is not None:  # it stops with the run: say how far it got
                    self.stats.note(compile_ended_at=unfinished.fraction)
                with self._switching:
                    merge = self._merge
                try:
                    if merge is not None:
                        merge.stop()
                finally:  # the outputs neutral even when a merged device's release fails
                    try:
                        self.publisher.neutralise()
                    finally:
                        if self._own_loop:
                            self.loop.close()
        if self._errors:
            raise self._errors[0]
        if interrupted:
            interrupt = KeyboardInterrupt()
            interrupt.stats = self.stats  # what the run did, for its summary (how far the compile got)
            raise interrupt
        return self.stats

    def _stop_at_deadline(self, start: float, seconds: float) -> None:
        """A real-time source that stalls still ends: ``seconds`` + a grace after its first item
        (before it: after the run's start), a timer on the loop."""
        first = self._clock.first_ns / 1e9 if self._clock.first_ns else start
        left = first + seconds + _GRACE_S - time.perf_counter()
        if left <= 0:
            self.stop()
            return
        self.loop.call_later(left, lambda: self._stop_at_deadline(start, seconds))

    # --- the source's thread ---------------------------------------------------------------------
    def _count_drop(self, item: StreamItem) -> None:  # the queues' on_drop
        if isinstance(item, Frame):
            self.stats.count(dropped_items=1, dropped_frames=1)
        elif isinstance(item, np.ndarray):
            self.stats.count(dropped_items=1, dropped_events=len(item))
        else:
            self.stats.count(dropped_items=1)

    def _count_resting_drop(self, item: StreamItem) -> None:
        self.stats.count(resting_dropped_frames=1)

    def _read_source(self) -> None:
        """Source thread: read, pace, stamp the arrival time, enqueue (held while the gel rests:
        :class:`~neurotouch_hid.engine.rest.RestHandover`)."""
        mode, rest_handover, clock = self.mode, self.rest, self._clock
        if mode.waits:  # its stream starts now, even when its first item takes a while
            clock.anchor_now()
        source = self._source
        pause = self._pause
        holds = mode.paced or pause is not None
        # a source whose batches may be cut at the resting windows' ends (one batch a window)
        cut = source.batch_cut if mode.paced else None
        cut_for = None
        try:
            if pause is not None:
                pause.decide = rest_handover.live_pause
                pause.resting = rest_handover.window_us
            for item in source:
                rest = rest_handover.windows
                if cut is not None and rest is not cut_for:
                    cut_for = rest
                    cut.follow(rest, REST_WAKE_AFTER_END_US)  # each batch then closes a window
                if rest_handover.joins_held(item, rest):
                    if pause is not None:
                        rest_handover.read(int(item["timestamp"][-1]))
                    continue
                if self._stop.is_set():
                    break
                if isinstance(item, SourceStatus):
                    self._source_status(item)
                    continue
                if isinstance(item, Performed):
                    self.publisher.label(item.label)  # published with its window
                    continue
                t_us = item_end_us(item)
                if t_us is not None:
                    clock.due_ns(t_us)  # the first item anchors the clock
                    if self._limit_us is not None and t_us - clock.first_us >= self._limit_us:
                        break
                    if pause is not None:
                        rest_handover.read(t_us)
                    if holds:
                        due_us = rest_handover.due_us(t_us, rest)
                        releases, joins = rest_handover.place(t_us, due_us)
                        if releases and rest_handover.release():
                            break
                        if joins:
                            limit = None if self._limit_us is None else clock.first_us + self._limit_us
                            rest_handover.hold(item, due_us, rest, limit)
                            continue
                        if mode.paced and clock.wait(due_us, self._stop):
                            break
                self._hand_on(item)
            if rest_handover.holding and not self._stop.is_set():
                rest_handover.release()
        except BaseException as exc:  # a truncated recording, a lost camera: what was read is
            self._errors.append(exc)  # still processed, then run() neutralises and re-raises
        finally:
            if pause is not None:
                pause.decide = pause.resting = None
            with contextlib.suppress(Exception):
                source.close()
            self._items.close()
            self._frames.close()

    def _hand_on(self, item: StreamItem) -> None:
        """Source thread: one item to the pipeline: processed here while nothing is queued or
        being processed and the gel rests (:meth:`_inline`), else queued for the pipeline's
        thread (an APS frame also for the resting thread's)."""
        entry = (time.perf_counter_ns(), item)
        if self.rest.windows is not None and self._items.claim():
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
        """Source thread: the camera was lost (neutral now, the stale queue dropped; merged devices
        drive on) or is back (the pipeline restarts before its data); tell the user."""
        if status.kind == StatusKind.LOST:
            self.publisher.lost()
            self._items.clear()
            self.rest.drop()
            self.stats.count(camera_losses=1)
        elif status.kind == StatusKind.RESUMED:
            self._restart.set()
        self.options.say(status.message)

    # --- the resting detector's thread -----------------------------------------------------------
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
                self.stats.count(resting_updates=1)

    # --- the pipeline's thread -------------------------------------------------------------------
    def _work(self) -> None:
        """Pipeline thread: items -> estimates -> controller states -> records published."""
        # real time only: there the alternative is dropping data; a FAST run waits for the
        # pipeline and keeps its batches as the source made them
        joined_max = MAX_JOINED_EVENTS if self.mode.realtime else 0
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
        finally:
            self._worked.set()
            self.loop.wake()  # the main thread's loop ends with this thread

    def _handle(self, entry: tuple[int, StreamItem], newest: bool = False) -> None:
        """One item -> estimates -> records published, by whoever holds the queue (the pipeline's
        thread, or the source's at rest: :meth:`_hand_on`; never both at once). ``newest``: the
        item joins event batches that queued up behind the pipeline: of the windows it closes only
        the newest is decided and published (``Pipeline.process_newest``: every event tracked,
        nothing dropped; the others are counted in ``stats.coalesced_windows`` and their latency
        runs to this output, which covers them)."""
        stats = self.stats
        arrival_ns, item = entry
        if self._restart.is_set():
            self._resume()
        skipped: list[int] | tuple[()] = ()
        if newest and isinstance(item, np.ndarray):
            estimates, skipped = self._pipeline.process_newest(item)
        else:
            estimates = self._pipeline.process(item)
        t_us = item_end_us(item)
        stream_us = None
        if t_us is not None:
            self._first_us = t_us if self._first_us is None else self._first_us
            stream_us = t_us - self._first_us
        # counted once an item (the stats' lock once, not once an event)
        if isinstance(item, Frame):
            stats.count(stream_us, frames=1, coalesced_windows=len(skipped))
        else:
            stats.count(
                stream_us, events=len(item) if isinstance(item, np.ndarray) else 0, coalesced_windows=len(skipped)
            )
        if skipped:
            self.rest.windows_skipped(skipped[-1])
        for k, estimate in enumerate(estimates, 1):
            self.publisher.window(estimate)
            if k < len(estimates):  # the last one is counted with the latency, under the same lock
                stats.count(windows=1)  # before the next window's record shows it
            self.rest.window_closed(estimate)
        if estimates:
            done_ns = time.perf_counter_ns()
            compiling = self._compile.now() is not None
            window_ns: tuple[int, ...] = ()
            if self.mode.paced:
                due = self._clock.due_ns
                window_ns = tuple(done_ns - due(end_us) for end_us in skipped) if skipped else ()
                for estimate in estimates:  # (mostly one: no generator)
                    window_ns += (done_ns - due(estimate.t_us),)
            stats.add_latency(
                len(estimates),
                done_ns - arrival_ns,
                compiling=compiling,
                waiting=len(self._items),
                window_latencies_ns=window_ns,
                counted=1,
            )

    def _resume(self) -> None:
        """First item after the camera came back: a new session of the pipeline and the mapper."""
        self._restart.clear()
        self._pipeline.restart()
        with self._verdict_lock:
            self._last_verdict_us = None  # a new session's frames may start its clock again
        self.publisher.resumed(self.options.mapper_factory(self.profile))

    def _switch_merge(self, profile: Profile) -> None:
        """Release the merged devices of the profile in use, grab those of ``profile`` (outside
        the publisher's lock: the merge's thread may be waiting for it)."""
        merge_for = self.options.merge_for
        if merge_for is None:
            return
        old, self._merge = self._merge, None
        self.publisher.set_merge(None)
        if old is not None:
            old.stop()
        new = merge_for(profile)
        if new is not None and self._merging:
            new.start(self.publisher.merged_input)
        self._merge = new
        self.publisher.set_merge(new)
        if new is not None and self._stop.is_set():  # the run stopped meanwhile: it may not have seen this one
            new.stop()
        merged, missing = new.status() if new is not None else ((), ())
        self.stats.note(merged=merged, missing=missing)
