"""What the interactive terminal view shows beside the pad: the gel, the gesture, the profile.

``run`` and ``demo`` on a terminal draw, in 80x24 (:func:`live_layout`):

* the gel seen from outside (user frame, docs/dataset.md: x right, y up): one character per cell
  of a small grid over the gel's disc, each marker drawn where it is now, a dot when it rests
  and an arrow in the direction it moved, brighter the farther (mm); the contacts as ``●``;
* the gesture recognised (type, intensity in mm, contacts), and in the demo the gesture the
  simulated hand is performing (the simulator's label) beside it;
* the pad's outputs (sticks, triggers, d-pad, buttons, keys: :mod:`neurotouch_hid.views.term`);
* the active profile and what each gesture drives in it;
* while the kernels compile on a first run (:mod:`neurotouch_hid.service.warmup`), why the run is slow
  and how far the compile is.

On a terminal it answers keys (:data:`HELP`): ``q`` stops the run cleanly (as SIGTERM: outputs
neutral, the run's summary; Ctrl-C too), ``h`` or ``?`` shows the keys, Space holds the picture
only: the pad goes on (a switch user's Space may be their switch, and an output frozen mid-press
would hold a button; the footer says "held: picture only").

The view is a subscriber of the run (:class:`~neurotouch_hid.core.stages.Subscriber`): it draws the
last :class:`~neurotouch_hid.core.stages.WindowRecord` the runtime published (the markers the
pipeline saw, the gesture the source performed, the profile, the counters, the compile's
progress) and reaches into no stage. A pipe or a file gets none of this: the plain state lines
stay as they are (:func:`neurotouch_hid.views.term.state_line`).
"""

from __future__ import annotations

import contextlib
import math
import os
import signal
import sys
import threading
import time
from typing import IO, TYPE_CHECKING, Callable, Optional

import numpy as np
from rich.console import Console, ConsoleRenderable, Group
from rich.panel import Panel
from rich.table import Table
from rich.text import Text

from neurotouch_hid.core.controller import ControllerState
from neurotouch_hid.core.estimate import GestureEstimate, GestureType
from neurotouch_hid.views.term import (
    BUTTON_LABELS,
    STICK_COLUMNS,
    TermView,
    axis_fraction,
    dpad_text,
    pad_name,
    stick_grid,
)

if TYPE_CHECKING:
    from neurotouch_hid.core.stages import CompileProgress, WindowRecord
    from neurotouch_hid.mapping.profile import Profile

#: The gel plot's size in characters (a terminal cell is about twice as tall as wide).
GEL_COLUMNS = 31
GEL_ROWS = 13
#: A marker that moved less than this (mm) is drawn at rest.
REST_MM = 0.3
#: Arrows by direction (user frame, counter-clockwise from +x, 45 degree sectors).
ARROWS = "→↗↑↖←↙↓↘"
#: Displacement (mm) at or above which an arrow is drawn in each style (the last wins).
ARROW_STYLES = ((REST_MM, "yellow"), (1.0, "bold yellow"), (2.5, "bold red"))
#: Rows of each stick's grid in the live view (the plain view's are taller).
PAD_STICK_ROWS = 3
#: The compile line's spinner (one step every 1/8 s).
SPINNER = "⠋⠙⠹⠸⠼⠴⠦⠧⠇⠏"
#: Most lines of "what each gesture drives" (the last says "+N more" when there are more).
MAPPINGS_SHOWN = 8
#: The keys the view answers (on a terminal), as its help shows them.
HELP = "keys: q or Ctrl-C quit (with the run's summary)  h/? help\n      Space hold the picture (the pad goes on)"
#: The footer's reminder of them.
KEYS_HINT = "q quit  h help"
#: Width of the compile's progress bar (characters).
PROGRESS_WIDTH = 40


def gel_cells(
    rest_mm: np.ndarray,
    now_mm: np.ndarray,
    contacts_mm: np.ndarray,
    radius_mm: float,
    columns: int = GEL_COLUMNS,
    rows: int = GEL_ROWS,
) -> list[list[tuple[str, str]]]:
    """The gel plot as ``rows`` x ``columns`` (character, style) cells, row 0 at the top.

    Args:
        rest_mm, now_mm: (N, 2) float64 marker positions at rest and now, user frame (mm, x right,
            y up, origin at the gel's centre); rows of NaN (lost markers) are skipped.
        contacts_mm: (K, 2) float64 contact points, user frame (mm).
        radius_mm: the gel's radius (mm): the plot spans -radius..radius on both axes.

    Each marker is drawn in the cell of its current position: ``·`` when it moved less than
    :data:`REST_MM`, else the arrow of its displacement's direction; where several fall in one
    cell, the one that moved most. Contacts are ``●`` on top. Cells outside the disc are blank.
    """
    cells = [[(" ", "") for _ in range(columns)] for _ in range(rows)]

    def cell(point: np.ndarray) -> tuple[int, int] | None:
        col = int(round((point[0] / radius_mm + 1) / 2 * (columns - 1)))
        row = int(round((1 - point[1] / radius_mm) / 2 * (rows - 1)))
        return (col, row) if 0 <= col < columns and 0 <= row < rows else None

    for r in range(rows):
        for c in range(columns):
            x = (c / (columns - 1) * 2 - 1) * radius_mm
            y = (1 - r / (rows - 1) * 2) * radius_mm
            if math.hypot(x, y) > radius_mm * 1.02 and math.hypot(x, y) <= radius_mm * 1.2:
                cells[r][c] = ("░", "grey23")
    moved = np.linalg.norm(now_mm - rest_mm, axis=1)
    largest: dict[tuple[int, int], float] = {}
    for rest, now, size in zip(rest_mm, now_mm, moved):
        if not (np.all(np.isfinite(now)) and np.isfinite(size)):
            continue
        at = cell(now)
        if at is None or largest.get(at, -1.0) >= size:
            continue
        largest[at] = size
        if size < REST_MM:
            cells[at[1]][at[0]] = ("·", "dim")
            continue
        d = now - rest
        sector = int(round(math.atan2(d[1], d[0]) / (math.pi / 4))) % 8
        style = [s for limit, s in ARROW_STYLES if size >= limit][-1]
        cells[at[1]][at[0]] = (ARROWS[sector], style)
    for point in contacts_mm:
        at = cell(point)
        if at is not None:
            cells[at[1]][at[0]] = ("●", "bold magenta")
    return cells


def gel_text(cells: list[list[tuple[str, str]]]) -> Text:
    """The cells of :func:`gel_cells` as one rich Text (a line per row)."""
    text = Text(no_wrap=True)
    for r, row in enumerate(cells):
        for char, style in row:
            text.append(char, style=style or None)
        if r < len(cells) - 1:
            text.append("\n")
    return text


def mapping_lines(profile: "Profile") -> list[tuple[str, str]]:
    """What each gesture drives in ``profile``, in the profile's words and the pad's: (input, what)
    per mapping, in the profile's order, ``what`` the pad's name of the output (:func:`pad_name`)
    after the mapping's own name when that is not the input's, e.g. ``("twist", "roll (R stick
    X)")``, ``("push", "L stick")``; layer switches as ``(input, "layer NAME")``."""
    lines = []
    for name, mapping in profile.mappings.items():
        output = mapping.output
        if isinstance(output, (list, tuple)):
            output = "+".join(str(o) for o in output)
        on_pad = pad_name(str(output))
        lines.append((str(mapping.input), on_pad if name == mapping.input else f"{name} ({on_pad})"))
    for name, switch in profile.layers.items():
        lines.append((str(switch.input), f"layer {name}"))
    return lines


def _gesture_line(label: str, gesture: GestureType, intensity_mm: float, n_contacts: int, style: str) -> Text:
    text = Text(f"{label:<11}", style="bold")
    text.append(f"{gesture.value:<10}", style=style)
    text.append(f"{intensity_mm:5.2f} mm  {n_contacts} contact{'s' if n_contacts != 1 else ''}")
    return text


def scene_panel(record: WindowRecord, estimate: GestureEstimate | None) -> Group:
    """The right-hand column: recognised (and, when the source knows it, performed) gesture, the
    profile and what each gesture drives."""
    rows: list[ConsoleRenderable] = []
    recognised = estimate.gesture if estimate is not None else GestureType.NONE
    intensity = estimate.intensity_mm if estimate is not None else 0.0
    contacts = estimate.n_contacts if estimate is not None else 0
    if record.labelled:
        label = record.performed
        performed = label.gesture if label is not None else GestureType.NONE
        right = performed == recognised
        rows.append(
            _gesture_line(
                "performed",
                performed,
                label.intensity_mm if label else 0.0,
                len(label.contacts_px) if label else 0,
                "bold",
            )
        )
        rows.append(_gesture_line("recognised", recognised, intensity, contacts, "bold green" if right else "bold red"))
    else:
        rows.append(_gesture_line("gesture", recognised, intensity, contacts, "bold green"))
    rows.append(Text(""))
    profile_line = Text.assemble(("profile ", "bold"), (record.profile_name, "bold cyan"))
    game = getattr(record.stats, "game", "")
    if game:
        profile_line.append(f"  for {game}", style="cyan")
    rows.append(profile_line)
    if record.profile.copilot:
        rows.append(copilot_line(*record.stats.copilot))
    drives = Table.grid(padding=(0, 1))
    lines = mapping_lines(record.profile)
    shown = lines if len(lines) <= MAPPINGS_SHOWN else lines[: MAPPINGS_SHOWN - 1]
    for gesture, output in shown:
        style = "bold reverse" if gesture == recognised.value or recognised.value.startswith(gesture) else ""
        drives.add_row(Text(gesture, style=style), Text("→", style="dim"), Text(output))
    if len(shown) < len(lines):
        drives.add_row(Text(f"+{len(lines) - len(shown)} more", style="dim"), Text(""), Text(""))
    rows.append(drives)
    return Group(*rows)


def copilot_line(merged: tuple[str, ...], missing: tuple[str, ...]) -> Text:
    """``merged: X; missing: Y``: the profile's ``copilot:`` devices merged into the pad now, and
    those the driver waits for (names as the profile writes them; "none" for an empty list)."""
    text = Text.assemble(("merged: ", "bold"), (", ".join(merged) or "none", "green"))
    text.append("; ")
    text.append("missing: ", style="bold")
    text.append(", ".join(missing) or "none", style="yellow" if missing else "")
    return text


def compile_line(progress: CompileProgress | None, wall_s: float | None = None) -> Optional[Group]:
    """While the first-run compile lasts: why the run is slow and a bar of its progress; else
    None. ``wall_s`` (s since the view started) ends the bar with a spinner and a clock that move
    at every redraw, even while no window comes (the run waits for a kernel): nothing looks frozen."""
    if progress is None:
        return None
    done = round(progress.fraction * PROGRESS_WIDTH)
    bar = Text("━" * done, style="bold yellow")
    bar.append("─" * (PROGRESS_WIDTH - done), style="dim")
    if wall_s is not None:
        bar.append(f" {SPINNER[int(wall_s * 8) % len(SPINNER)]} {wall_s:.0f} s since the start", style="yellow")
    return Group(Text(progress.description, style="bold yellow"), bar)


def pad_text(state: ControllerState) -> Group:
    """The pad in a column ~40 characters wide: both sticks, the triggers, the d-pad, the buttons
    (pressed ones lit) and, when the profile drives them, keys and mouse motion."""
    a = state.axes
    sticks = Table.grid(padding=(0, 2))
    sticks.add_row(Text("L stick", style="bold"), Text("R stick", style="bold"), Text("LT/RT", style="bold"))
    triggers = Text()
    for label, name in (("LT", "ABS_Z"), ("RT", "ABS_RZ")):
        frac = axis_fraction(name, a[name])
        triggers.append(f"{label} ")
        triggers.append("█" * round(frac * 8), style="bold green")
        triggers.append("·" * (8 - round(frac * 8)) + f" {a[name]:3d}\n", style="dim")
    triggers.append_text(dpad_text(a["ABS_HAT0X"], a["ABS_HAT0Y"]))
    sticks.add_row(
        stick_grid(a["ABS_X"], a["ABS_Y"], STICK_COLUMNS, PAD_STICK_ROWS),
        stick_grid(a["ABS_RX"], a["ABS_RY"], STICK_COLUMNS, PAD_STICK_ROWS),
        triggers,
    )
    buttons = Text()
    for name, label in BUTTON_LABELS.items():
        buttons.append(label, style="bold reverse cyan" if state.buttons.get(name) else "dim")
        buttons.append(" ")
    rows: list[ConsoleRenderable] = [sticks, buttons]
    if state.keys or state.rel:
        keys = Text("keys ", style="bold")
        keys.append(" ".join(k.removeprefix("KEY_") for k in sorted(state.keys)) or "-", style="bold magenta")
        keys.append("".join(f"  {name} {value:+d}" for name, value in state.rel.items()))
        rows.append(keys)
    return Group(*rows)


def live_layout(
    state: ControllerState,
    estimate: GestureEstimate | None,
    record: WindowRecord,
    first_t_us: int = 0,
    *,
    help_shown: bool = False,
    held: bool = False,
    wall_s: float | None = None,
) -> Panel:
    """The whole interactive view, 80x24 at most: the gel plot on the left; the gestures, the
    profile and the pad on the right; the compile's progress and the counters at the bottom.
    ``state`` and ``estimate`` are what the pad shows now (neutral after a release); ``record``
    is the last window's; ``first_t_us`` the first window's end (the counters' ``t`` is the time
    since, s of camera time, so that it goes with the windows); ``help_shown``: the keys' help
    under it (h, ?); ``held``: the picture is held (Space), said in the footer; ``wall_s``: s
    since the view started, for the compile's clock (:func:`compile_line`)."""
    from neurotouch_hid.core.sensor import SensorGeometry

    sensor = record.sensor if record.sensor is not None else SensorGeometry()
    if record.markers is None:
        rest_mm = now_mm = np.zeros((0, 2))
    else:
        rest_mm, now_mm = sensor.image_to_user(record.markers.rest_px), sensor.image_to_user(record.markers.now_px)
    contacts = estimate.contacts_mm if estimate is not None else np.zeros((0, 2))
    gel = Group(
        Text("the gel, seen from outside", style="bold"),
        gel_text(gel_cells(rest_mm, now_mm, contacts, sensor.gel_radius_mm)),
    )
    top = Table.grid(padding=(0, 2))
    top.add_row(gel, Group(scene_panel(record, estimate), pad_text(state)))
    stats = record.stats
    footer = Text(f"t {(record.estimate.t_us - first_t_us) / 1e6:.3f} s", style="dim")
    footer.append(
        f"   windows {stats.windows}   dropped {stats.dropped_items} items",
        style="bold red" if stats.dropped_items else "dim",
    )
    if held:
        footer.append("   held: picture only (Space)", style="bold yellow")
    else:
        footer.append(f"   {KEYS_HINT}", style="dim")
    rows: list[ConsoleRenderable] = [top]
    progress = compile_line(record.compile, wall_s)
    if progress is not None:
        rows.append(progress)
    if help_shown:
        rows.append(Text(HELP, style="bold"))
    rows.append(footer)
    return Panel(Group(*rows), title="NeuroTouch", expand=False, padding=(0, 1))


class LiveView(TermView):
    """The terminal view with the gel, the gestures and the profile (:func:`live_layout`) when
    drawn on a terminal; on a pipe or in a file, exactly :class:`TermView`'s plain lines. A
    subscriber of the run: it draws the last record published (before the first one, the pad
    alone), and asks for the markers only when it draws them (on a terminal)."""

    def __init__(
        self,
        console: Console | None = None,
        *,
        line_period_s: float = 1.0,
        refresh_per_second: float = 20.0,
        keys: IO[str] | None = None,
    ):
        self._record: WindowRecord | None = None  # before super().__init__: a terminal draws at once
        self._first_t_us: int | None = None
        self._help = False  # h, ?: the keys' help under the view
        self._held: tuple | None = None  # Space: the picture drawn while held (state, estimate, record)
        self._started_s = time.monotonic()
        super().__init__(console, line_period_s=line_period_s, refresh_per_second=refresh_per_second)
        self.wants_markers = self.console.is_terminal
        self._keys: KeyReader | None = None
        if self.console.is_terminal:
            stream = keys if keys is not None else sys.stdin
            if stream is not None and stream.isatty() and in_foreground(stream):
                self._keys = KeyReader(stream, self.key)

    def key(self, char: str) -> None:
        """A key typed on the terminal: ``q`` ends the run as SIGTERM does (a clean stop, every
        output neutral, the run's summary printed, exit 0); ``h`` or ``?`` shows or hides the
        keys' help; Space holds the picture (to read it; the pad goes on) and lets it go."""
        if char in ("q", "Q"):
            self.say("q: stopping")
            os.kill(os.getpid(), signal.SIGTERM)
        elif char in ("h", "H", "?"):
            with self._lock:
                self._help = not self._help
        elif char == " ":
            with self._lock:
                self._held = None if self._held is not None else (self._state, self._estimate, self._record)
        else:
            return
        if self._live is not None:
            self._live.refresh()

    def close(self) -> None:
        """Stop reading keys (the terminal's mode restored), then as :meth:`TermView.close`."""
        if self._keys is not None:
            self._keys.close()
            self._keys = None
        super().close()

    def publish(self, record: WindowRecord) -> None:
        """Keep ``record`` to draw (the pad's state as :class:`TermView` shows it)."""
        with self._lock:
            self._record = record
            if self._first_t_us is None:
                self._first_t_us = record.estimate.t_us
        super().publish(record)

    def __rich__(self) -> Panel:
        with self._lock:
            state, estimate, record, first = self._state, self._estimate, self._record, self._first_t_us
            help_shown, held = self._help, self._held
        if held is not None and held[2] is not None:
            state, estimate, record = held
        if record is None:
            return super().__rich__()
        return live_layout(
            state,
            estimate,
            record,
            first or 0,
            help_shown=help_shown,
            held=held is not None,
            wall_s=time.monotonic() - self._started_s,
        )


def in_foreground(stream: IO[str]) -> bool:
    """Whether this process is the terminal's foreground job: a background one (``run &``) that
    changed the terminal's mode or read it would be stopped (SIGTTOU, SIGTTIN: termios(3))."""
    try:
        return os.tcgetpgrp(stream.fileno()) == os.getpgrp()
    except OSError:
        return False


class KeyReader:
    """Single keys typed on a terminal, each handed to ``on_key`` (from a thread of its own):
    the terminal is put in cbreak mode (keys come without Enter, Ctrl-C and Ctrl-Z still send
    their signals: termios(3), ``tty.setcbreak``) and restored by :meth:`close`.

    Args:
        stream: the terminal (a text stream on a tty).
        on_key: called with each character read.
    """

    def __init__(self, stream: IO[str], on_key: Callable[[str], None]) -> None:
        import termios
        import tty

        self._fd = stream.fileno()
        self._on_key = on_key
        self._saved = termios.tcgetattr(self._fd)
        tty.setcbreak(self._fd)
        self._stop = threading.Event()
        self._wake_r, self._wake_w = os.pipe()  # written by close(): the reader waits on no timer
        self._thread = threading.Thread(target=self._read, name="nt-keys", daemon=True)
        self._thread.start()

    def _read(self) -> None:
        import select

        while not self._stop.is_set():
            ready, _, _ = select.select([self._fd, self._wake_r], [], [])
            if self._fd not in ready:
                continue
            try:
                if os.tcgetpgrp(self._fd) != os.getpgrp():  # sent to the background (Ctrl-Z, bg): not ours
                    self._stop.wait(0.5)
                    continue
                data = os.read(self._fd, 64)
            except OSError:  # the terminal is gone
                return
            if not data:
                return
            for char in data.decode("utf-8", "replace"):
                self._on_key(char)

    def close(self) -> None:
        """Stop reading and restore the terminal's mode."""
        import termios

        if self._stop.is_set():
            return
        self._stop.set()
        with contextlib.suppress(OSError):
            os.write(self._wake_w, b"x")
        if threading.current_thread() is not self._thread:
            self._thread.join(1.0)
        for fd in (self._wake_r, self._wake_w):
            with contextlib.suppress(OSError):
                os.close(fd)
        with contextlib.suppress(termios.error, OSError):
            termios.tcsetattr(self._fd, termios.TCSADRAIN, self._saved)
