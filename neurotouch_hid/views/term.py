"""A live terminal view of the gamepad: sticks, triggers, d-pad, buttons, gesture, dropped data.

The same ``write(state[, estimate])`` / ``neutralise()`` / ``close()`` shape as the virtual gamepad,
so ``neurotouch-hid run --output term`` and ``demo`` (without a writable /dev/uinput) show what a
game would get. On a terminal it redraws in place with :class:`rich.live.Live`; without one (CI,
a pipe, a log file) it prints one plain state line whenever a button, key or d-pad direction goes
down or up (so a press shorter than a line period still shows), otherwise at most one line every
``line_period_s`` seconds for the analogue axes, with the mouse motion summed since the previous
line, and a last one when it is neutralised or closed.

Buttons are labelled as the Xbox 360 pad (and Linux' xpad driver) names them: BTN_SOUTH A,
BTN_EAST B, BTN_NORTH X, BTN_WEST Y.

On a terminal whose encoding is not UTF-8 (a latin-1 or ASCII locale) every character it lacks is
drawn as its ASCII stand-in (:data:`ASCII_FALLBACK`, else ``?``; :func:`encodable`), the boxes
as rich draws them there (ASCII).
"""

from __future__ import annotations

import dataclasses
import io
import logging
import threading
import time
from typing import TYPE_CHECKING, Callable, Optional

from rich.cells import cell_len
from rich.console import Console, ConsoleOptions, Group, RenderableType, RenderResult
from rich.live import Live
from rich.panel import Panel
from rich.progress_bar import ProgressBar
from rich.segment import Segment
from rich.table import Table
from rich.text import Text

from neurotouch_hid.core.controller import AXES, ControllerState
from neurotouch_hid.core.estimate import GestureEstimate

if TYPE_CHECKING:  # the runtime publishes its records; no import at run time (no cycle)
    from neurotouch_hid.core.stages import WindowRecord
    from neurotouch_hid.core.stats import RunStats
    from neurotouch_hid.mapping.profile import Profile

#: evdev button -> label on the pad.
BUTTON_LABELS: dict[str, str] = {
    "BTN_SOUTH": "A",
    "BTN_EAST": "B",
    "BTN_NORTH": "X",
    "BTN_WEST": "Y",
    "BTN_TL": "LB",
    "BTN_TR": "RB",
    "BTN_SELECT": "Back",
    "BTN_START": "Start",
    "BTN_MODE": "Guide",
    "BTN_THUMBL": "LS",
    "BTN_THUMBR": "RS",
}

#: The pad's (and mouse's) names of the outputs a profile drives, as the views draw them.
PAD_NAMES: dict[str, str] = {
    "left_stick": "L stick",
    "right_stick": "R stick",
    "ABS_X": "L stick X",
    "ABS_Y": "L stick Y",
    "ABS_RX": "R stick X",
    "ABS_RY": "R stick Y",
    "ABS_Z": "LT",
    "ABS_RZ": "RT",
    "dpad_up": "d-pad up",
    "dpad_down": "d-pad down",
    "dpad_left": "d-pad left",
    "dpad_right": "d-pad right",
    "pointer": "mouse pointer",
    "REL_X": "mouse X",
    "REL_Y": "mouse Y",
    "REL_WHEEL": "mouse wheel",
    "REL_HWHEEL": "mouse wheel sideways",
    "BTN_LEFT": "left click",
    "BTN_RIGHT": "right click",
    "BTN_MIDDLE": "middle click",
    "BTN_SIDE": "mouse side button",
    "BTN_EXTRA": "mouse extra button",
    **BUTTON_LABELS,
}


def pad_name(output: str) -> str:
    """What the pad calls a profile's ``output`` (``ABS_RX`` -> ``R stick X``, ``BTN_SOUTH`` ->
    ``A``); keys by their name (``KEY_LEFTSHIFT+KEY_TAB`` -> ``LEFTSHIFT+TAB key``)."""
    if output in PAD_NAMES:
        return PAD_NAMES[output]
    parts = output.split("+")
    if all(p.startswith("KEY_") for p in parts):
        return "+".join(p.removeprefix("KEY_") for p in parts) + " key"
    return "+".join(PAD_NAMES.get(p, p.removeprefix("KEY_")) for p in parts)


STICK_COLUMNS = 11
STICK_ROWS = 5

#: What the views draw for one of their characters where the terminal's encoding lacks it
#: (:func:`encodable`): dots, arrows (the d-pad's and the gel's markers'), bars, the spinner.
ASCII_FALLBACK: dict[str, str] = {
    "●": "o",
    "·": ".",
    "░": ":",
    "━": "=",
    "─": "-",
    "█": "#",
    "…": ".",
    "←": "<",
    "↑": "^",
    "↓": "v",
    "→": ">",
    "↗": "/",
    "↖": "\\",
    "↙": "/",
    "↘": "\\",
    **dict(zip("⠋⠙⠹⠸⠼⠴⠦⠧⠇⠏", "|/-\\|/-\\|/")),
}


def encodable(text: str, encoding: str) -> str:
    """``text`` as a terminal in ``encoding`` (a codec name, e.g. ``latin-1``) can show it: each
    character the encoding lacks replaced by its :data:`ASCII_FALLBACK`, else by ``?`` as many as
    the columns it takes. An encoding Python does not know: ``text`` unchanged."""
    try:
        text.encode(encoding)
        return text
    except LookupError:
        return text
    except UnicodeEncodeError:
        pass
    kept = []
    for char in text:
        try:
            char.encode(encoding)
            kept.append(char)
        except UnicodeEncodeError:
            kept.append(ASCII_FALLBACK.get(char, "?" * max(1, cell_len(char))))
    return "".join(kept)


class _InEncoding:
    """``renderable`` drawn with only the characters the console's encoding has (:func:`encodable`):
    rich writes text as it is, and a character the terminal's encoding lacks raised
    UnicodeEncodeError."""

    def __init__(self, renderable: RenderableType) -> None:
        self.renderable = renderable

    def __rich_console__(self, console: Console, options: ConsoleOptions) -> RenderResult:
        if options.encoding.startswith("utf"):  # rich's own test (ConsoleOptions.ascii_only)
            yield self.renderable
            return
        for segment in console.render(self.renderable, options):
            if segment.control is None and segment.text:
                segment = Segment(encodable(segment.text, options.encoding), segment.style)
            yield segment


def axis_fraction(name: str, value: int) -> float:
    """An axis value as a fraction of its range: sticks and d-pad in -1..1, triggers in 0..1."""
    lo, hi, neutral = AXES[name]
    if neutral == lo:
        return (value - lo) / (hi - lo)
    return max(-1.0, min(1.0, (value - neutral) / ((hi - lo) / 2)))


def stick_cell(x: int, y: int, columns: int = STICK_COLUMNS, rows: int = STICK_ROWS) -> tuple[int, int]:
    """The (column, row) of a stick position in a ``columns`` x ``rows`` grid, row 0 at the top
    (evdev sticks: +x right, +y down; -32768..32767)."""
    lo, hi, _ = AXES["ABS_X"]
    col = round((min(max(x, lo), hi) - lo) / (hi - lo) * (columns - 1))
    row = round((min(max(y, lo), hi) - lo) / (hi - lo) * (rows - 1))
    return col, row


def stick_grid(x: int, y: int, columns: int = STICK_COLUMNS, rows: int = STICK_ROWS) -> Text:
    """A small grid of dots with the stick's position as a filled circle (centre marked +)."""
    col, row = stick_cell(x, y, columns, rows)
    text = Text()
    for r in range(rows):
        for c in range(columns):
            if (c, r) == (col, row):
                text.append("●", style="bold green")
            elif (c, r) == (columns // 2, rows // 2):
                text.append("+", style="dim")
            else:
                text.append("·", style="dim")
        if r < rows - 1:
            text.append("\n")
    return text


def dpad_text(hat_x: int, hat_y: int) -> Text:
    """The d-pad as four arrows, the pressed ones lit (ABS_HAT0Y -1 is up)."""
    text = Text()
    for label, lit in (("←", hat_x < 0), ("↑", hat_y < 0), ("↓", hat_y > 0), ("→", hat_x > 0)):
        text.append(f" {label} ", style="bold reverse yellow" if lit else "dim")
    return text


def buttons_text(buttons: dict[str, bool]) -> Text:
    """Every button's label, pressed ones lit."""
    text = Text()
    for name, label in BUTTON_LABELS.items():
        text.append(f" {label} ", style="bold reverse cyan" if buttons.get(name) else "dim")
        text.append(" ")
    return text


def state_line(state: ControllerState, estimate: GestureEstimate | None, stats: Optional["RunStats"]) -> str:
    """One plain line: time, gesture and intensity, sticks (-1..1), triggers (0..255), d-pad,
    pressed buttons, windows and dropped data."""
    a = state.axes
    pressed = ",".join(BUTTON_LABELS[n] for n in BUTTON_LABELS if state.buttons.get(n)) or "-"
    gesture = f"{estimate.gesture.value} {estimate.intensity_mm:.2f} mm" if estimate is not None else "none"
    line = (
        f"t {state.t_us / 1e6:8.3f} s | {gesture:<16} | "
        f"L({axis_fraction('ABS_X', a['ABS_X']):+.2f},{axis_fraction('ABS_Y', a['ABS_Y']):+.2f}) "
        f"R({axis_fraction('ABS_RX', a['ABS_RX']):+.2f},{axis_fraction('ABS_RY', a['ABS_RY']):+.2f}) "
        f"LT {a['ABS_Z']:3d} RT {a['ABS_RZ']:3d} hat({a['ABS_HAT0X']:+d},{a['ABS_HAT0Y']:+d}) "
        f"buttons {pressed}"
    )
    if state.keys or state.rel:  # the keyboard and mouse, when the profile drives them
        line += f" keys {','.join(sorted(state.keys)) or '-'}"
        line += "".join(f" {name} {value:+d}" for name, value in state.rel.items())
    if stats is not None:
        line += f" | windows {stats.windows} dropped {stats.dropped_items}"
        if stats.game:
            line += f" | profile {stats.profile} for {stats.game}"
    return line


def discrete_outputs(state: ControllerState) -> tuple:
    """What of ``state`` is on or off: the pressed buttons, the keys down and the d-pad. The piped
    view prints a line whenever this changes."""
    pressed = tuple(sorted(name for name, down in state.buttons.items() if down))
    return pressed, tuple(sorted(state.keys)), state.axes["ABS_HAT0X"], state.axes["ABS_HAT0Y"]


class _LinesTo(io.TextIOBase):
    """A text stream that hands each whole line written to ``say``."""

    def __init__(self, say: Callable[[str], None]) -> None:
        self._say = say
        self._partial = ""

    def writable(self) -> bool:
        return True

    def write(self, text: str) -> int:
        self._partial += text
        while "\n" in self._partial:
            line, self._partial = self._partial.split("\n", 1)
            self._say(line)
        return len(text)


def logs_above(say: Callable[[str], None]) -> list[tuple[logging.StreamHandler, object]]:
    """While a view is drawn on a terminal: the root logger's handlers that write to a terminal
    (a profile switch, a camera lost, said by ``logging``) write through ``say`` instead, above
    the view (a line written around rich's Live is drawn over and leaves stale frames). Returns
    (handler, its stream) to put back (``handler.setStream``)."""
    swapped = []
    for handler in logging.getLogger().handlers:
        stream = getattr(handler, "stream", None)
        if type(handler) is logging.StreamHandler and stream is not None and getattr(stream, "isatty", bool)():
            swapped.append((handler, handler.setStream(_LinesTo(say))))
    return swapped


class TermView:
    """The gamepad state drawn in the terminal.

    Args:
        console: where to draw (default: a new stdout :class:`rich.console.Console`).
        stats: the runtime's live :class:`~neurotouch_hid.core.stats.RunStats` (windows, dropped
            data), shown under the pad; the records published bring it too.
        line_period_s: without a terminal, the shortest time (s) between two printed lines when
            only analogue axes change (a button, key or d-pad change is printed at once).
        refresh_per_second: redraw rate on a terminal.
    """

    #: Draws no markers (:class:`~neurotouch_hid.core.stages.Subscriber`).
    wants_markers = False

    def __init__(
        self,
        console: Console | None = None,
        *,
        stats: Optional["RunStats"] = None,
        line_period_s: float = 1.0,
        refresh_per_second: float = 20.0,
    ):
        self.console = console or Console()
        self.stats = stats
        self._state = ControllerState.neutral()
        self._estimate: GestureEstimate | None = None
        self._line_period_s = line_period_s
        self._last_line = float("-inf")
        self._printed_discrete: tuple = discrete_outputs(self._state)
        self._rel_since_line: dict[str, int] = {}
        self._pending = False  # a state written but not printed yet (piped view)
        self._timer: threading.Timer | None = None
        self._lock = threading.Lock()
        self._live: Live | None = None
        self._logs: list[tuple[logging.StreamHandler, object]] = []
        if self.console.is_terminal:
            self._live = Live(
                _InEncoding(self), console=self.console, refresh_per_second=refresh_per_second, transient=False
            )
            self._live.start()
            self._logs = logs_above(self.say)

    def say(self, line: str) -> None:
        """Print one line for the user: above the view while it is drawn on a terminal (rich's
        Live; a line written to stderr meanwhile would be drawn over), else to this console;
        in characters its encoding has (:func:`encodable`)."""
        self.console.print(encodable(line, self.console.encoding), markup=False, highlight=False, soft_wrap=True)

    def write(self, state: ControllerState, estimate: GestureEstimate | None = None) -> None:
        """Show ``state`` (and the estimate's gesture and intensity)."""
        with self._lock:
            self._state = state
            if estimate is not None:
                self._estimate = estimate
            for name, value in state.rel.items():
                self._rel_since_line[name] = self._rel_since_line.get(name, 0) + value
        if self._live is None:
            if (
                discrete_outputs(state) != self._printed_discrete
                or time.monotonic() - self._last_line >= self._line_period_s
            ):
                self._print_line()
            else:
                self._print_later()

    def publish(self, record: WindowRecord) -> None:
        """A window's record (:class:`~neurotouch_hid.core.stages.Subscriber`): shown when its state or
        its gesture changed; drawn on a terminal, its estimate (intensity, contacts) is drawn
        whatever changed (a stick held at the end of its travel, a button held)."""
        self.stats = record.stats
        if record.state_changed or record.gesture_changed:
            self.write(record.state, record.estimate)
        elif self._live is not None:
            with self._lock:
                self._estimate = record.estimate

    def prepare(self, profile: Profile) -> None:
        """Nothing to get ready: every profile's states draw alike (:class:`~neurotouch_hid.core.stages.Subscriber`)."""

    def neutralise(self) -> None:
        """Show all axes centred and all buttons released (and, without a terminal, print it)."""
        with self._lock:
            self._state = ControllerState.neutral(self._state.t_us)
            self._estimate = None
        if self._live is None:
            self._print_line()
        else:
            self._live.refresh()

    def close(self) -> None:
        """Stop redrawing (the last picture stays on screen); without a terminal, print the state
        not printed yet, if any."""
        with self._lock:
            timer, self._timer = self._timer, None
        if timer is not None:
            timer.cancel()
        if self._pending:
            self._print_line()
        if self._live is not None:
            self._live.stop()
            self._live = None
        for handler, stream in self._logs:
            handler.setStream(stream)
        self._logs = []

    def __enter__(self) -> "TermView":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def _print_later(self) -> None:
        """A state arrived within the line period: print it when the period is over, unless a
        newer line comes first (so the last state of a still stretch is never left unprinted)."""
        with self._lock:
            self._pending = True
            if self._timer is None:
                delay = max(0.0, self._last_line + self._line_period_s - time.monotonic())
                self._timer = threading.Timer(delay, self._print_pending)
                self._timer.daemon = True
                self._timer.start()

    def _print_pending(self) -> None:
        with self._lock:
            self._timer = None
        if self._pending:
            self._print_line()

    def _print_line(self) -> None:
        self._last_line = time.monotonic()
        with self._lock:
            self._pending = False
            state = dataclasses.replace(self._state, rel={k: v for k, v in self._rel_since_line.items() if v})
            self._rel_since_line = {}
            self._printed_discrete = discrete_outputs(state)
            line = encodable(state_line(state, self._estimate, self.stats), self.console.encoding)
        self.console.print(line, highlight=False, markup=False, soft_wrap=True)

    def __rich__(self) -> Panel:
        with self._lock:
            state, estimate = self._state, self._estimate
        a = state.axes
        pad = Table.grid(padding=(0, 3))
        pad.add_row(Text("left stick", style="bold"), Text("right stick", style="bold"), Text("triggers", style="bold"))
        triggers = Table.grid(padding=(0, 1))
        for label, name in (("LT", "ABS_Z"), ("RT", "ABS_RZ")):
            lo, hi, _ = AXES[name]
            triggers.add_row(label, ProgressBar(total=hi - lo, completed=a[name] - lo, width=16), f"{a[name]:3d}")
        pad.add_row(stick_grid(a["ABS_X"], a["ABS_Y"]), stick_grid(a["ABS_RX"], a["ABS_RY"]), triggers)
        pad.add_row(
            Text(f"{axis_fraction('ABS_X', a['ABS_X']):+.2f} {axis_fraction('ABS_Y', a['ABS_Y']):+.2f}"),
            Text(f"{axis_fraction('ABS_RX', a['ABS_RX']):+.2f} {axis_fraction('ABS_RY', a['ABS_RY']):+.2f}"),
            Text.assemble("d-pad ", dpad_text(a["ABS_HAT0X"], a["ABS_HAT0Y"])),
        )
        if estimate is None:
            gesture = Text("gesture none", style="dim")
        else:
            gesture = Text(
                f"gesture {estimate.gesture.value:<10} intensity {estimate.intensity_mm:5.2f} mm"
                f"  contacts {estimate.n_contacts}  {'resting' if estimate.resting else 'deformed'}"
            )
        desktop = Text()
        if state.keys or state.rel:  # the keyboard and mouse, when the profile drives them
            desktop.append("keys ", style="bold")
            for key in sorted(state.keys):
                desktop.append(f" {key.removeprefix('KEY_')} ", style="bold reverse magenta")
                desktop.append(" ")
            desktop.append("".join(f"  {name} {value:+d}" for name, value in state.rel.items()))
        counters = Text(f"t {state.t_us / 1e6:.3f} s", style="dim")
        if self.stats is not None:
            s = self.stats
            counters.append(
                f"   windows {s.windows}   dropped {s.dropped_items} items"
                f" ({s.dropped_events} events, {s.dropped_frames} frames)",
                style="bold red" if s.dropped_items else "dim",
            )
            if s.profile:
                counters.append(f"   profile {s.profile}" + (f" for {s.game}" if s.game else ""), style="bold")
        rows = [pad, Text(""), buttons_text(state.buttons), *([desktop] if desktop else []), gesture, counters]
        return Panel(Group(*rows), title="NeuroTouch gamepad", expand=False)
