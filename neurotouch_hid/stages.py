"""The typed seams between the stages: what the engine (:class:`~neurotouch_hid.runtime.Runtime`)
asks of a source stream, a pipeline, a resting detector, a mapper and an output.

Each concrete stage satisfies one of these :class:`typing.Protocol` s structurally (no base class
to inherit): the gesture pipeline (:class:`~neurotouch_hid.pipeline.pipeline.GesturePipeline`) and
the replay of a predictions file (:class:`~neurotouch_hid.driver.EstimateReplay`) are
:class:`Pipeline` s; the uinput devices, the JSON-lines writer and the terminal view are
:class:`Output` s. A type checker holds them to it; the engine never asks an object what it can do.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Iterable, Protocol, Union

from neurotouch_hid.controller import ControllerState
from neurotouch_hid.estimate import GestureEstimate
from neurotouch_hid.sources import Frame, StreamItem

if TYPE_CHECKING:
    from neurotouch_hid.mapping.profile import Profile
    from neurotouch_hid.pipeline.resting import RestingResult

#: What a source yields, in time order: event batches (``EVENT_DTYPE`` arrays) and APS
#: :class:`~neurotouch_hid.sources.Frame` s, a live camera's
#: :class:`~neurotouch_hid.sources.SourceStatus` items, or, from a predictions file, the
#: windows' estimates themselves.
SourceStream = Iterable[Union[StreamItem, GestureEstimate]]


class Pipeline(Protocol):
    """Stream items in, one :class:`GestureEstimate` per window out (paper, "Methodology")."""

    def process(self, item: StreamItem | GestureEstimate) -> list[GestureEstimate]:
        """The estimates of every window that ``item`` closes (often none)."""

    def set_resting(self, result: RestingResult | None, t_us: int) -> None:
        """A resting verdict for the APS frame at ``t_us`` (us), from another thread."""

    def restart(self) -> None:
        """A new session after the live camera came back (markers re-initialised at rest)."""


class RestingDetection(Protocol):
    """The Chamfer-distance resting detector run beside the event path (paper, "Resting
    Position Detection")."""

    def update(self, frame: Frame) -> RestingResult | None:
        """The verdict for one APS frame; None while there is no reference yet."""


class Mapper(Protocol):
    """A profile applied to the estimates, window after window (``mapping/mapper.py``)."""

    def update(self, estimate: GestureEstimate) -> ControllerState:
        """The controller state for one estimate."""


class Output(Protocol):
    """Where controller states go: the uinput devices, JSON lines, the terminal view.

    Attributes:
        accepts_estimate: True when the output also shows the window's estimate (gesture,
            intensity): it is then written whenever the gesture changes too, not only the state.
    """

    accepts_estimate: bool

    def write(self, state: ControllerState, estimate: GestureEstimate | None = None) -> None:
        """Show ``state`` (and ``estimate`` where ``accepts_estimate``)."""

    def neutralise(self) -> None:
        """Centre every axis and release every button and key, at once."""

    def prepare(self, profile: Profile) -> None:
        """Get ready to map ``profile`` (e.g. create the keyboard it uses), after
        :meth:`neutralise`, before its first state."""
