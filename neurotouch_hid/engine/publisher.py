"""The publisher: the one part of the engine that maps a window's estimate and calls the
subscribers (the targets and the views).

Every call to a subscriber (``publish``, ``neutralise``, ``prepare``) goes through one
:class:`Publisher`, under its one lock: the mapper, the state last written, the merged devices'
input and every subscriber are its own. It is called by the thread that holds the engine's
queue (the pipeline's thread, or the source's while the gel rests; never both at once:
:meth:`~neurotouch_hid.engine.queue.DropOldestQueue.claim`); for a profile switch, a merged
device's input and Ctrl-Z by the run's main thread (its loop, ``engine/loop.py``), for a lost
camera by the source's; the lock makes them one after the other, and a subscriber never sees two
calls at once.

At rest it skips what changes nothing: a resting window whose mapper rests at its fixed point
(``Mapper.resting_state``) and whose state is the one last published is neither mapped nor
published (docs/performance.md, "At rest"); the mapper is handed the last such estimate when the
rest ends, as if it had had every one.
"""

from __future__ import annotations

import collections
import dataclasses
import threading
from typing import TYPE_CHECKING, Callable, Sequence

from neurotouch_hid.core.controller import ControllerState
from neurotouch_hid.core.estimate import GestureEstimate, GestureType
from neurotouch_hid.core.stages import CompileProgress, WindowRecord

if TYPE_CHECKING:
    from neurotouch_hid.core.dataset import LabelRow
    from neurotouch_hid.core.sensor import SensorGeometry
    from neurotouch_hid.core.stages import Mapper, Merge, Pipeline, Subscriber
    from neurotouch_hid.core.stats import RunStats
    from neurotouch_hid.mapping.profile import Profile


class CompileWatch:
    """The first run's compile while it lasts (``compile_progress``, e.g.
    :meth:`neurotouch_hid.service.warmup.Warmup.progress_now`); once it has answered None it is over for
    good and is not asked again. Thread-safe."""

    def __init__(self, progress: Callable[[], CompileProgress | None] | None) -> None:
        self._progress = progress
        self._lock = threading.Lock()

    def now(self) -> CompileProgress | None:
        """How far the compile is, or None when nothing compiles (any more)."""
        with self._lock:
            if self._progress is None:
                return None
            progress = self._progress()
            if progress is None:
                self._progress = None
            return progress


def _same(state: ControllerState, last: ControllerState) -> bool:
    """``state`` writes nothing over ``last``: the same axes, buttons, keys and touches (a
    relative motion is an impulse and is not compared here)."""
    return (
        state.axes == last.axes
        and state.buttons == last.buttons
        and state.keys == last.keys
        and state.touches == last.touches
        and state.touch_click == last.touch_click
    )


class Publisher:
    """Estimates -> controller states -> one :class:`~neurotouch_hid.core.stages.WindowRecord` a
    window to every subscriber, in their order.

    Args:
        subscribers: who reads the run (:class:`~neurotouch_hid.core.stages.Subscriber`); not closed
            here (their owner does).
        profile: the profile mapping now; ``mapper`` its mapper.
        profile_name: the profile's name as the user gave it (:attr:`profile_name`).
        pipeline: asked for its markers when a subscriber draws them.
        stats: the run's counters (``states_written``, the copilot's devices).
        stopped: set when the run stops: nothing is published from then on.
        sensor: the gel's geometry for the records (None: a predictions file).
        labelled: the source says what it performs (:meth:`label`).
        compile: the first run's compile (:class:`CompileWatch`).
        merge: the copilot of ``profile`` (None: nothing merged).
    """

    def __init__(
        self,
        subscribers: Sequence[Subscriber],
        profile: Profile,
        mapper: Mapper,
        profile_name: str,
        pipeline: Pipeline,
        stats: RunStats,
        stopped: threading.Event,
        *,
        sensor: SensorGeometry | None,
        labelled: bool,
        compile: CompileWatch,
        merge: Merge | None,
    ) -> None:
        self._subscribers = tuple(subscribers)
        self._wants_markers = any(s.wants_markers for s in self._subscribers)
        self._lock = threading.Lock()
        self.profile = profile
        self._mapper = mapper
        self._profile_name = profile_name  # (under the lock: a switch from another thread renames it)
        self._pipeline = pipeline
        self._stats = stats
        self._stopped = stopped
        self._sensor = sensor
        self._labelled = labelled
        self._compile = compile
        self._merge = merge
        self._labels: collections.deque[LabelRow] = collections.deque()  # performed, not yet reached
        self._performed: LabelRow | None = None
        self._last_state = ControllerState.neutral()
        self._last_gel = ControllerState.neutral()  # the mapped state before the merge
        self._last_gesture: GestureType | None = None
        self._last_record: WindowRecord | None = None
        #: the last resting estimate not handed to the mapper (:meth:`_unchanged_at_rest`)
        self._skipped: GestureEstimate | None = None
        #: the mapper known to rest at the state last published; forgotten when a record is
        #: published or the state forgotten
        self._quiet_mapper: Mapper | None = None
        self._paused = False  # the live camera is lost: nothing written until it is back
        self._suspended = False  # stopped by SIGTSTP: nothing written until SIGCONT

    # --- windows ---------------------------------------------------------------------------------
    def label(self, row: LabelRow) -> None:
        """The source's label of what it performs from ``row.t_us`` on (its stream's order)."""
        self._labels.append(row)

    def window(self, estimate: GestureEstimate) -> None:
        """One window's estimate: mapped and published, unless it changes nothing at rest."""
        if not self._unchanged_at_rest(estimate):
            self._emit(estimate)

    def _unchanged_at_rest(self, estimate: GestureEstimate) -> bool:
        """Whether ``estimate`` changes nothing: the gel rests, the mapper rests at its fixed point
        (``Mapper.resting_state``) and that state is the one last published, no subscriber draws
        the markers (they move at rest too), nothing compiles."""
        if not estimate.resting or self._wants_markers or estimate.gesture is not self._last_gesture:
            return False
        with self._lock:
            if self._quiet_mapper is self._mapper:  # known since the rest's first skipped window
                self._skipped = estimate
                return True
            kept = self._mapper.resting_state
            unchanged = (
                kept is not None
                and _same(kept, self._last_state)
                and self._compile.now() is None
                # a merged device's input is published with the last window's record: one must exist
                and (self._merge is None or self._last_record is not None)
            )
            if unchanged:
                self._skipped = estimate
                self._quiet_mapper = self._mapper
        return unchanged

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
            if self._stopped.is_set() or self._paused or self._suspended:
                return
            self._quiet_mapper = None
            if self._skipped is not None:  # the rest it skipped ends: the mapper's clocks to its end
                skipped, self._skipped = self._skipped, None
                self._mapper.update(skipped)
            state = self._last_gel = self._mapper.update(estimate)
            if self._merge is not None:
                state = self._merge.merge(state)
            state_changed = not _same(state, self._last_state) or bool(state.rel)
            record = WindowRecord(
                estimate=estimate,
                state=state,
                state_changed=state_changed,
                gesture_changed=estimate.gesture != self._last_gesture,
                profile=self.profile,
                profile_name=self._profile_name,
                sensor=self._sensor,
                markers=self._pipeline.markers() if self._wants_markers else None,
                performed=self._performed_at(estimate.t_us) if self._labelled else None,
                labelled=self._labelled,
                stats=self._stats,
                compile=self._compile.now(),
            )
            for subscriber in self._subscribers:
                subscriber.publish(record)
            if state_changed:
                self._stats.count(states_written=1)
            self._last_state = state
            self._last_gesture = estimate.gesture
            self._last_record = record

    # --- the merged devices ---------------------------------------------------------------------
    def set_merge(self, merge: Merge | None) -> None:
        """The copilot whose devices are merged from now on (None: none)."""
        with self._lock:
            self._merge = merge

    def merged_input(self) -> None:
        """A merged device's controls changed, or a device came or went: publish the merged
        state of the gel's last one at once, when it changed (the last window's record with that
        state; the gel's relative motion is not repeated). With no window of the gel to go on (no
        camera yet, the camera lost, a profile just switched to): over a gel at rest, as the
        merged devices are grabbed and must drive the pad meanwhile."""
        with self._lock:
            if self._merge is None:
                return
            merged, missing = self._merge.status()
            self._stats.note(merged=merged, missing=missing)
            self._publish_merged()

    def _publish_merged(self) -> None:
        """(caller holds the lock and checked ``self._merge``; :meth:`merged_input`)"""
        if self._stopped.is_set() or self._suspended:
            return
        state = self._merge.merge(dataclasses.replace(self._last_gel, rel={}))
        last = self._last_state
        if state.axes == last.axes and state.buttons == last.buttons and state.keys == last.keys:
            return
        record = self._last_record if self._last_record is not None else self._record_at_rest()
        record = record._replace(state=state, state_changed=True, gesture_changed=False)
        for subscriber in self._subscribers:
            subscriber.publish(record)
        self._stats.count(states_written=1)
        self._last_state = state

    def _record_at_rest(self) -> WindowRecord:
        """A record for a gel with no window to go on: a resting estimate at the last state's time
        (us, camera clock), the gel's state neutral (caller holds the lock)."""
        t_us = self._last_state.t_us
        return WindowRecord(
            estimate=GestureEstimate(t_us=t_us),
            state=ControllerState.neutral(t_us),
            state_changed=False,
            gesture_changed=False,
            profile=self.profile,
            profile_name=self._profile_name,
            sensor=self._sensor,
            markers=None,
            performed=None,
            labelled=self._labelled,
            stats=self._stats,
            compile=self._compile.now(),
        )

    # --- neutral ---------------------------------------------------------------------------------
    def neutralise(self) -> None:
        """Every subscriber neutral at once: each one, even when an earlier one fails; the first
        failure is raised after."""
        with self._lock:
            self._neutralise()

    def _neutralise(self) -> None:
        failure: BaseException | None = None
        for subscriber in self._subscribers:
            try:
                subscriber.neutralise()
            except Exception as exc:
                failure = failure or exc
        if failure is not None:
            raise failure

    def _forget_state(self) -> None:
        """The subscribers were neutralised or the mapping starts afresh: the next state is
        compared with a neutral one (caller holds the lock)."""
        self._quiet_mapper = None
        self._last_state = ControllerState.neutral(self._last_state.t_us)
        self._last_gel = ControllerState.neutral(self._last_state.t_us)
        self._last_record = None  # a merged device's input waits for the next window's record
        self._last_gesture = None

    @property
    def profile_name(self) -> str:
        """The profile in use as the user named it, for display."""
        with self._lock:
            return self._profile_name

    def switch(self, profile: Profile, mapper: Mapper, name: str | None = None) -> None:
        """Every subscriber neutral, then prepared for ``profile`` (e.g. a keyboard it uses made),
        which ``mapper`` maps from the next window on; ``name``: its name as the user gave it
        (None: the name stays)."""
        with self._lock:
            self._neutralise()
            for subscriber in self._subscribers:
                subscriber.prepare(profile)
            self._mapper = mapper
            self.profile = profile
            if name is not None:
                self._profile_name = name
            self._forget_state()

    def lost(self) -> None:
        """The live camera was lost: every subscriber neutral now, nothing written until
        :meth:`resumed`; a merged device goes on driving the pad, over a gel at rest."""
        with self._lock:
            self._paused = True
            self._neutralise()
            self._forget_state()
            if self._merge is not None:
                self._publish_merged()

    def resumed(self, mapper: Mapper) -> None:
        """The camera is back: a fresh ``mapper`` (its filters and hysteresis neutral), writing again."""
        with self._lock:
            self._mapper = mapper
            self._forget_state()
            self._paused = False

    def suspend(self) -> None:
        """Ctrl-Z: every subscriber neutral, nothing written until :meth:`unsuspend`."""
        with self._lock:
            self._suspended = True
            self._neutralise()
            self._forget_state()

    def unsuspend(self) -> None:
        """After SIGCONT: writing again, from a neutral state."""
        with self._lock:
            self._forget_state()
            self._suspended = False
