"""The typed seams between the stages: what the engine (:class:`~neurotouch_hid.engine.engine.Engine`)
asks of a source stream, a pipeline, a resting detector and a mapper, and what it publishes to its
subscribers.

The road goes one way: source -> pipeline -> mapper -> subscribers. The engine is the one place
that knows them all. After each window it publishes one :class:`WindowRecord` (the estimate, the
controller state, the markers the pipeline saw, the gesture the source performed when it knows it,
the run's counters, the first run's compile progress) to every :class:`Subscriber`: the uinput
pad, keyboard and mouse, the JSON-lines writer, the terminal and live views. A stage knows nothing
of who reads it; a subscriber knows only the record.

Each concrete stage satisfies one of these :class:`typing.Protocol` s structurally (no base class
to inherit): the gesture pipeline (:class:`~neurotouch_hid.pipeline.pipeline.GesturePipeline`) and
the replay of a predictions file (:class:`~neurotouch_hid.engine.assembly.EstimateReplay`) are
:class:`Pipeline` s. A type checker holds them to it.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Callable, Iterator, NamedTuple, Protocol, Union

from neurotouch_hid.core.controller import ControllerState, Feedback
from neurotouch_hid.core.estimate import GestureEstimate, MarkerPositions
from neurotouch_hid.sources import Frame, Performed, StreamItem

if TYPE_CHECKING:
    import numpy as np

    from neurotouch_hid.core.dataset import LabelRow
    from neurotouch_hid.core.sensor import SensorGeometry
    from neurotouch_hid.core.stats import RunStats
    from neurotouch_hid.mapping.profile import Profile
    from neurotouch_hid.pipeline.resting import RestingResult
    from neurotouch_hid.sources import PollPause
    from neurotouch_hid.sources.batches import BatchCut

#: One item of a source's stream: an event batch (``EVENT_DTYPE`` array) or an APS
#: :class:`~neurotouch_hid.sources.Frame`, a live camera's
#: :class:`~neurotouch_hid.sources.SourceStatus`, the simulated hand's
#: :class:`~neurotouch_hid.sources.Performed` label, or, from a predictions file, a window's
#: estimate itself.
SourceItem = Union[StreamItem, Performed, GestureEstimate]


class SourceStream(Protocol):
    """What a source yields, in time order (:data:`SourceItem` s), with the hooks the engine may
    set while the gel rests (docs/performance.md, "At rest"). ``sources.WrappedStream`` is the
    base every source's stream derives from (its hooks None); the engine wraps a plain iterable
    in one.

    Attributes:
        poll_pause: a live source's pause between polls that bring nothing
            (:class:`~neurotouch_hid.sources.PollPause`, whose ``decide`` the engine sets), or None.
        batch_cut: where the source cuts its event batches
            (:class:`~neurotouch_hid.sources.batches.BatchCut`, which the engine moves to the
            resting windows' ends), or None.
    """

    poll_pause: PollPause | None
    batch_cut: BatchCut | None

    def __iter__(self) -> Iterator[SourceItem]:
        """The stream itself."""

    def __next__(self) -> SourceItem:
        """The next item; StopIteration at the source's end."""

    def close(self) -> None:
        """Close the source (its ``finally``); idempotent."""


@dataclass(frozen=True)
class CompileProgress:
    """A first run's compile of the numba kernels (:mod:`neurotouch_hid.service.warmup`), while it lasts.

    Attributes:
        description: one line for the user: what compiles and why the run is slow meanwhile.
        fraction: how far it is, 0..1.
    """

    description: str
    fraction: float


class WindowRecord(NamedTuple):
    """What the engine publishes after each window, the same object to every subscriber (an
    immutable tuple: made 100 times a second, it costs a tenth of a frozen dataclass).

    Attributes:
        estimate: the window's gesture estimate (its end ``t_us``, type, intensity, contacts).
        state: the controller state the profile maps it to.
        state_changed: ``state`` differs from the last one published (axes, buttons, keys, or a
            relative motion, which is an impulse and always counts).
        gesture_changed: the estimate's type differs from the last window's.
        profile, profile_name: the profile mapping now, and its name as the user gave it.
        sensor: the gel's geometry (image px -> user mm), None for a predictions file.
        markers: the markers the pipeline saw, only when a subscriber asks for them
            (:attr:`Subscriber.wants_markers`) and the pipeline tracks markers; else None.
        performed: the gesture the source performs at the window's end, when it knows it (the
            simulated hand's label, docs/dataset.md); None otherwise.
        labelled: the source says what it performs (``performed`` may still be None before
            its first label).
        stats: the run's live counters.
        compile: the first run's compile while it lasts, else None.
    """

    estimate: GestureEstimate
    state: ControllerState
    state_changed: bool
    gesture_changed: bool
    profile: Profile
    profile_name: str
    sensor: SensorGeometry | None
    markers: MarkerPositions | None
    performed: LabelRow | None
    labelled: bool
    stats: RunStats
    compile: CompileProgress | None


class Pipeline(Protocol):
    """Stream items in, one :class:`GestureEstimate` per window out (paper, "Methodology")."""

    def process(self, item: StreamItem | GestureEstimate) -> list[GestureEstimate]:
        """The estimates of every window that ``item`` closes (often none)."""

    def process_newest(self, events: np.ndarray) -> tuple[list[GestureEstimate], list[int]]:
        """Event batches that queued up behind the pipeline, joined: every event tracked, only
        the newest window they close decided; (its estimates, the ends (us) of the windows closed
        without one)."""

    def set_resting(self, result: RestingResult | None, t_us: int) -> None:
        """A resting verdict for the APS frame at ``t_us`` (us), from another thread."""

    def restart(self) -> None:
        """A new session after the live camera came back (markers re-initialised at rest)."""

    def set_type_wait(self, wait: bool) -> None:
        """Whether a gesture whose windows show one contact waits for the fingers before its
        type is committed (``mapping/commitment.py``: False for a profile that reads no
        difference); from the next window, from any thread. A pipeline without types ignores it."""

    def markers(self) -> MarkerPositions | None:
        """The markers seen at the last window's end; None when there are none (before the
        first APS frame, or no tracker at all)."""


class RestingDetection(Protocol):
    """The Chamfer-distance resting detector run beside the event path (paper, "Resting
    Position Detection")."""

    def update(self, frame: Frame) -> RestingResult | None:
        """The verdict for one APS frame; None while there is no reference yet."""


class Mapper(Protocol):
    """A profile applied to the estimates, window after window (``mapping/mapper.py``)."""

    def update(self, estimate: GestureEstimate) -> ControllerState:
        """The controller state for one estimate."""

    @property
    def resting_state(self) -> ControllerState | None:
        """The state a resting estimate gives while the mapper rests at its fixed point, else
        None (then every window is mapped): the engine may then skip resting estimates and hand
        the mapper only the last one before the rest ends, with the same states after."""


class Subscriber(Protocol):
    """What listens to the run: the uinput devices, JSON lines, the terminal and live views.

    Attributes:
        wants_markers: the subscriber draws the markers: the engine then copies them into
            each record (nothing is copied when no subscriber asks).
    """

    wants_markers: bool

    def publish(self, record: WindowRecord) -> None:
        """One window's record, from the engine's publisher (one call at a time); return quickly."""

    def neutralise(self) -> None:
        """Centre every axis and release every button and key, at once."""

    def prepare(self, profile: Profile) -> None:
        """Get ready to map ``profile`` (e.g. create the keyboard it uses), after
        :meth:`neutralise`, before its first record."""


# --- the output and input seams ---------------------------------------------------------------
# Every device the system sees is a Target behind one subscriber; every device merged into the
# gel's pad is an InputDevice behind one Merge. docs/architecture.md, "Targets and inputs".


class Target(Protocol):
    """One device the system sees, fed from the controller state: the uinput pad, keyboard and
    mouse, a UHID device, a USB gadget function (HID joystick, Switch pad, XInput pad, keyboard,
    mouse). All targets of a run sit behind one :class:`Subscriber` (``targets.TargetOutputs``).

    Attributes:
        what: a short name for messages ("uinput pad", "USB gadget (xinput)", ...).
    """

    what: str

    def write(self, state: ControllerState) -> None:
        """Send ``state`` as one report (or one evdev frame), only where it changed."""

    def neutralise(self) -> None:
        """Send the neutral report now: axes centred, triggers 0, nothing pressed."""

    def prepare(self, profile: Profile) -> None:
        """Get ready for ``profile`` (after :meth:`neutralise`, before its first state)."""

    def fileno(self) -> int | None:
        """The readable side (force-feedback uploads, a host's output reports, ep0 events),
        or None when the target has none."""

    def feedback(self) -> list[Feedback]:
        """Called when :meth:`fileno` is readable: read and handle what arrived; returns the
        rumble and LED requests in it (possibly none)."""

    def close(self) -> None:
        """Neutral first, then remove the device. Idempotent, safe from any thread."""


class Merge(Protocol):
    """Devices merged into the gel's pad (a profile's ``copilot:``): read, grabbed, combined.

    The engine calls :meth:`merge` on each window's mapped state and publishes the result; the
    merge calls the ``on_input`` it was started with (from the run's loop,
    :class:`~neurotouch_hid.engine.loop.Loop`, which sleeps in ``select`` while no merged device
    sends anything) whenever a merged device's controls
    changed, and the engine then publishes ``merge(last gel state)`` at once, so a helper's
    press never waits for the gel's next window."""

    def grab(self) -> None:
        """Open and grab (and, where it may, hide) the devices there now and start reading them,
        before the gel's pad or target device is made (a game that enumerates controllers then
        sees one); idempotent. :meth:`start` does it when it was not done."""

    def start(self, on_input: Callable[[], None]) -> None:
        """Open, grab and start reading the devices (a missing one is waited for), unless
        :meth:`grab` did; from now on call ``on_input`` when their controls change."""

    def merge(self, gel: ControllerState) -> ControllerState:
        """The pad's state: ``gel`` combined with the merged devices' current controls."""

    def feedback(self, request: Feedback) -> None:
        """Forward a game's rumble to the merged pads that can rumble."""

    def stop(self) -> None:
        """Release every grab and stop reading; the merged controls count as neutral."""

    def status(self) -> tuple[tuple[str, ...], tuple[str, ...]]:
        """(the devices merged now, the devices waited for), as the profile names them."""
