"""JSON-lines files: the pipeline's predictions (docs/dataset.md, "Predictions (JSON lines)").

One :meth:`GestureEstimate.to_json_dict` object a line, ordered by time. :class:`JsonlWriter`
is the shared line writer (a path or an open text stream, ``-`` = stdout), so other JSON-lines
outputs write the same way.
"""

from __future__ import annotations

import json
import sys
from collections.abc import Iterable
from pathlib import Path
from typing import IO, Any

from neurotouch_hid.controller import ControllerState
from neurotouch_hid.errors import DatasetError
from neurotouch_hid.estimate import GestureEstimate, GestureType


class JsonlWriter:
    """Writes one JSON object a line. Context manager.

    Args:
        out: a file path (created or truncated), ``"-"`` for stdout, or an open text stream
            (not closed by :meth:`close`).
        flush: flush after every line (for live outputs read by another process).
    Raises:
        DatasetError: the file cannot be opened for writing (names it and why).
    """

    def __init__(self, out: str | Path | IO[str], *, flush: bool = False) -> None:
        self._flush = flush
        if isinstance(out, (str, Path)) and str(out) == "-":
            self._fh, self._owned = sys.stdout, False
        elif isinstance(out, (str, Path)):
            try:
                self._fh, self._owned = open(out, "w"), True
            except OSError as exc:
                raise DatasetError(f"{out}: cannot write JSON lines: {exc.strerror}") from None
        else:
            self._fh, self._owned = out, False

    def write_dict(self, data: dict) -> None:
        """Write ``data`` as one compact JSON line."""
        self._fh.write(json.dumps(data, separators=(", ", ": ")) + "\n")
        if self._flush:
            self._fh.flush()

    def close(self) -> None:
        """Flush, and close the file if this writer opened it."""
        if self._owned:
            self._fh.close()
        else:
            self._fh.flush()

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()


class PredictionsWriter(JsonlWriter):
    """Writes a predictions file (docs/dataset.md): one :class:`GestureEstimate` a line."""

    def write(self, estimate: GestureEstimate) -> None:
        """Write ``estimate.to_json_dict()`` as one line."""
        self.write_dict(estimate.to_json_dict())


def write_predictions(path: str | Path, estimates: Iterable[GestureEstimate]) -> int:
    """Write a whole predictions file; returns the number of lines written."""
    n = 0
    with PredictionsWriter(path) as writer:
        for estimate in estimates:
            writer.write(estimate)
            n += 1
    return n


def read_predictions(path: str | Path) -> list[GestureEstimate]:
    """Read a predictions file (docs/dataset.md) back into estimates.

    Blank lines are skipped.
    Raises:
        DatasetError: the file cannot be read, a line is not JSON, lacks a field or has a bad
            value (the message names the file, the line number and the problem), or the lines
            are not ordered by time.
    """
    path = Path(path)
    try:
        text = path.read_text()
    except OSError as exc:
        raise DatasetError(f"{path}: cannot read the predictions file: {exc.strerror}") from None
    estimates: list[GestureEstimate] = []
    for number, line in enumerate(text.splitlines(), start=1):
        if not line.strip():
            continue
        try:
            data = json.loads(line)
        except json.JSONDecodeError as exc:
            raise DatasetError(f"{path}:{number}: not a JSON object: {exc.msg}") from None
        if not isinstance(data, dict):
            raise DatasetError(f"{path}:{number}: expected a JSON object, found {type(data).__name__}")
        missing = [k for k in ("t_us", "gesture", "resting", "intensity_mm") if k not in data]
        if missing:
            raise DatasetError(f"{path}:{number}: missing field(s) {', '.join(missing)} (docs/dataset.md, Predictions)")
        try:
            estimate = GestureEstimate.from_json_dict(data)
        except (TypeError, ValueError, KeyError) as exc:
            raise DatasetError(f"{path}:{number}: bad value: {exc}") from None
        if estimate.contacts_px.shape != estimate.contacts_mm.shape:
            raise DatasetError(f"{path}:{number}: contacts_px and contacts_mm have different numbers of points")
        if estimates and estimate.t_us < estimates[-1].t_us:
            raise DatasetError(f"{path}:{number}: t_us {estimate.t_us} goes back in time (previous line: {estimates[-1].t_us})")
        estimates.append(estimate)
    return estimates


class StateJsonlWriter(JsonlWriter):
    """Controller states as JSON lines (``neurotouch-hid run --output jsonl``), one per change.

    Each line: ``{"t_us": int, "gesture": str, "intensity_mm": float, "axes": {evdev name: int},
    "buttons": {evdev name: bool}, "keys": [evdev name], "rel": {evdev name: int}}``, every axis
    and button of the pad (:mod:`neurotouch_hid.controller`), the keyboard keys and mouse buttons
    that are down (sorted) and the mouse motion of this step (non-zero codes only);
    ``gesture`` and ``intensity_mm`` are those of the window's estimate. :meth:`neutralise`
    writes a neutral line (gesture ``none``), so a stopped run always ends on one. Lines are
    flushed as written (another process reads them live).

    Args:
        out: a file path, ``"-"`` or None for stdout, or an open text stream.
    Raises:
        DatasetError: the file cannot be opened for writing.
    """

    #: The runtime hands this output each window's estimate too (its gesture and intensity).
    accepts_estimate = True

    def __init__(self, out: str | Path | IO[str] | None = None) -> None:
        super().__init__("-" if out is None else out, flush=True)
        self._t_us = 0

    def write(self, state: ControllerState, estimate: GestureEstimate | None = None) -> None:
        """Write ``state`` (with the estimate's gesture and intensity) as one line."""
        self._t_us = int(state.t_us)
        self.write_dict({
            "t_us": int(state.t_us),
            "gesture": (estimate.gesture if estimate is not None else GestureType.NONE).value,
            "intensity_mm": round(float(estimate.intensity_mm), 4) if estimate is not None else 0.0,
            "axes": {name: int(v) for name, v in state.axes.items()},
            "buttons": {name: bool(v) for name, v in state.buttons.items()},
            "keys": sorted(state.keys),
            "rel": {name: int(v) for name, v in state.rel.items()},
        })

    def prepare(self, profile: Any) -> None:
        """Nothing to get ready: every profile's states are written alike
        (:class:`~neurotouch_hid.stages.Output`)."""

    def neutralise(self) -> None:
        """Write the neutral state (all axes centred, all buttons released) at the last time."""
        self.write(ControllerState.neutral(self._t_us))
