"""The run's mode and options: what the engine (:class:`~neurotouch_hid.engine.engine.Engine`) is
told before it starts, as two values instead of a score of flags.

:class:`RunMode` says how the source's time relates to the wall clock and what happens when the
pipeline falls behind; :class:`RunOptions` holds everything else a run is given (the profile's
name, the queue's bounds, the mapper's factory, the clock, where the run is counted).
"""

from __future__ import annotations

import enum
import logging
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Callable

from neurotouch_hid.mapping.mapper import Mapper
from neurotouch_hid.mapping.profile import Profile, load_profile

if TYPE_CHECKING:
    from neurotouch_hid.core.stages import Mapper as MapperStage
    from neurotouch_hid.core.stages import Merge
    from neurotouch_hid.core.stats import RunStats
    from neurotouch_hid.engine.loop import Loop
    from neurotouch_hid.engine.stopping import EarlyStop
    from neurotouch_hid.sources import Pacer

log = logging.getLogger(__name__)

#: Source batch length (us): 1 ms batches keep the event-to-output latency well under a window.
DEFAULT_BATCH_US = 1_000
#: How far (us of camera time) the pipeline may fall behind a live or paced source before the
#: oldest queued data is dropped: the controller lags by at most about this much.
DEFAULT_MAX_LAG_US = 200_000
#: Input queue bound (items): a memory guard only; ``max_lag_us`` is the bound that acts.
DEFAULT_QUEUE_ITEMS = 100_000


class RunMode(enum.Enum):
    """How a run's source relates to the wall clock.

    - ``LIVE``: the camera, real time by itself: not paced; when the pipeline falls behind, the
      oldest queued data is dropped (the controller never lags more than ``max_lag_us``).
    - ``PACED``: a recording replayed in real time (item timestamps follow wall time); dropped
      as a live source's when the pipeline falls behind.
    - ``PACED_WAITING``: paced, by a source that can wait (the simulated gel, which is not a
      camera): when the pipeline falls more than ``max_lag_us`` behind (a first run still
      compiling), the source waits instead of data being dropped, and catches up after; its
      clock starts when the run does.
    - ``FAST``: as fast as possible (``--fast``): nothing waits on the clock, nothing is dropped
      (the source waits for the pipeline), so a replay is deterministic.
    """

    LIVE = "live"
    PACED = "paced"
    PACED_WAITING = "paced-waiting"
    FAST = "fast"

    @classmethod
    def of(cls, *, pace: bool, live: bool = False, waits: bool = False) -> RunMode:
        """The mode a command's flags name: ``live`` (the camera) before ``pace`` (real time),
        ``waits`` only with ``pace``."""
        if live:
            return cls.LIVE
        if pace:
            return cls.PACED_WAITING if waits else cls.PACED
        return cls.FAST

    @property
    def realtime(self) -> bool:
        """The source keeps the wall clock's pace (live or paced)."""
        return self is not RunMode.FAST

    @property
    def paced(self) -> bool:
        """The engine sleeps so that item timestamps follow wall time."""
        return self in (RunMode.PACED, RunMode.PACED_WAITING)

    @property
    def waits(self) -> bool:
        """A pipeline that falls behind makes the source wait (nothing dropped, real time kept after)."""
        return self is RunMode.PACED_WAITING

    @property
    def drops(self) -> bool:
        """A pipeline that falls behind makes the oldest queued data go."""
        return self in (RunMode.LIVE, RunMode.PACED)


@dataclass(frozen=True)
class RunOptions:
    """Everything a run is given besides its stages (:class:`~neurotouch_hid.engine.engine.RunParts`),
    the profile and the subscribers.

    Attributes:
        mode: :class:`RunMode` (default: paced).
        profile_ref: the name or path the profile came from, reloaded on SIGHUP (None: none).
        queue_items: bound of the input queue (items; a memory guard).
        max_lag_us: real time only: how far (us of camera time) the queued data may reach back
            before the oldest is dropped (a waiting source waits instead).
        mapper_factory, profile_loader: the mapping's ``Mapper`` and ``load_profile``
            (replaceable in tests).
        say: tells the user what happens to a live source (camera lost, back; one line each).
        stats: where the run is counted (:class:`~neurotouch_hid.core.stats.RunStats`, e.g. shared
            with the terminal view that shows it); None: a new one.
        pacer: the :class:`~neurotouch_hid.sources.Pacer` that paces and times the run (one on a
            clock a test controls); None: a new wall-clock one.
        merge: the copilot of the profile the run starts with, already grabbed (None: asked of
            ``merge_for``).
        merge_for: the copilot of a profile switched to (None: nothing is merged).
        early_stop: the SIGTERM handler that stood before this run's own
            (:class:`~neurotouch_hid.engine.stopping.EarlyStop`): quieted when the run installs its
            own handlers, and a SIGTERM it saw meanwhile stops the run at once.
        loop: the :class:`~neurotouch_hid.engine.loop.Loop` the devices and services already wait
            on (the driver's; the run's main thread takes it over); None: one of the run's own.
    """

    mode: RunMode = RunMode.PACED
    profile_ref: str | Path | None = None
    queue_items: int = DEFAULT_QUEUE_ITEMS
    max_lag_us: int = DEFAULT_MAX_LAG_US
    mapper_factory: Callable[[Profile], MapperStage] = Mapper
    profile_loader: Callable[[str | Path], Profile] = load_profile
    say: Callable[[str], None] = field(default=log.warning)
    stats: RunStats | None = None
    pacer: Pacer | None = None
    merge: Merge | None = None
    merge_for: Callable[[Profile], Merge | None] | None = None
    early_stop: EarlyStop | None = None
    loop: Loop | None = None
