"""JSON lines of controller states (``neurotouch-hid run --output jsonl``).

Written with the line writer of the predictions files (:class:`neurotouch_hid.core.jsonl_writer.JsonlWriter`).
"""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path
from typing import IO, TYPE_CHECKING

from neurotouch_hid.core.controller import ControllerState
from neurotouch_hid.core.estimate import GestureEstimate, GestureType
from neurotouch_hid.core.jsonl_writer import JsonlWriter

if TYPE_CHECKING:
    from neurotouch_hid.core.stages import WindowRecord
    from neurotouch_hid.mapping.profile import Profile


class StateJsonlWriter(JsonlWriter):
    """Controller states as JSON lines (``neurotouch-hid run --output jsonl``), one per change.

    Each line: ``{"t_us": int, "gesture": str, "intensity_mm": float, "axes": {evdev name: int},
    "buttons": {evdev name: bool}, "keys": [evdev name], "rel": {evdev name: int}, "touches":
    [{"slot": int, "id": int, "x": int, "y": int}], "touch_click": bool}``, every axis and button
    of the pad (:mod:`neurotouch_hid.core.controller`), the keyboard keys and mouse buttons that are
    down (sorted), the mouse motion of this step (non-zero codes only), the touchpad's active
    touch points by slot (a profile's ``touchpad:``; ``id`` 0..127, ``x`` 0..1919 and ``y``
    0..1079 in the DualSense's touchpad units, :class:`~neurotouch_hid.core.controller.TouchPoint`;
    a lifted point is left out) and its click; ``gesture`` and ``intensity_mm`` are those of the
    window's estimate. :meth:`neutralise`
    writes a neutral line (gesture ``none``), so a stopped run always ends on one. Lines are
    flushed as written (another process reads them live). A file is written beside its name and
    renamed over it at the first line when nothing is there, else at the run's end (Ctrl-C and
    SIGTERM end it too); a run that fails part-way leaves what was there byte-identical and its
    lines in ``NAME.partial``, and says both (:class:`~neurotouch_hid.core.jsonl_writer.JsonlWriter`); a
    FIFO is written in place.

    Args:
        out: a file path, ``"-"`` or None for stdout, or an open text stream.
        inputs: the run's input files (source, profile, sensor.yaml): ``out`` may not be one.
    Raises:
        DatasetError: the file cannot be opened for writing.
        OutputError: ``out`` is a symbolic link, a folder or one of ``inputs``.
    """

    #: Writes no markers (:class:`~neurotouch_hid.core.stages.Subscriber`).
    wants_markers = False

    def __init__(self, out: str | Path | IO[str] | None = None, inputs: Iterable[str | Path | None] = ()) -> None:
        super().__init__(
            "-" if out is None else out,
            flush=True,
            live=True,
            inputs=inputs,
            keep_partial=True,
            stops=(KeyboardInterrupt,),
        )
        self._t_us = 0

    def write(self, state: ControllerState, estimate: GestureEstimate | None = None) -> None:
        """Write ``state`` (with the estimate's gesture and intensity) as one line."""
        self._t_us = int(state.t_us)
        self.write_dict(
            {
                "t_us": int(state.t_us),
                "gesture": (estimate.gesture if estimate is not None else GestureType.NONE).value,
                "intensity_mm": round(float(estimate.intensity_mm), 4) if estimate is not None else 0.0,
                "axes": {name: int(v) for name, v in state.axes.items()},
                "buttons": {name: bool(v) for name, v in state.buttons.items()},
                "keys": sorted(state.keys),
                "rel": {name: int(v) for name, v in state.rel.items()},
                "touches": [
                    {"slot": slot, "id": int(point.id), "x": int(point.x), "y": int(point.y)}
                    for slot, point in enumerate(state.touches)
                    if point is not None and point.active
                ],
                "touch_click": bool(state.touch_click),
            }
        )

    def publish(self, record: WindowRecord) -> None:
        """A window's record (:class:`~neurotouch_hid.core.stages.Subscriber`): one line when its state
        or its gesture changed."""
        if record.state_changed or record.gesture_changed:
            self.write(record.state, record.estimate)

    def prepare(self, profile: Profile) -> None:
        """Nothing to get ready: every profile's states are written alike
        (:class:`~neurotouch_hid.core.stages.Subscriber`)."""

    def neutralise(self) -> None:
        """Write the neutral state (all axes centred, all buttons released) at the last time."""
        self.write(ControllerState.neutral(self._t_us))
