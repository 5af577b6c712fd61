"""What the interactive terminal view shows beside the pad: the gel, the gesture, the profile.

``run`` and ``demo`` on a terminal draw, in 80x24 (:func:`live_layout`):

* the gel seen from outside (user frame, docs/dataset.md: x right, y up): one character per cell
  of a small grid over the gel's disc, each marker drawn where it is now, a dot when it rests
  and an arrow in the direction it moved, brighter the farther (mm); the contacts as ``●``;
* the gesture recognised (type, intensity in mm, contacts), and in the demo the gesture the
  simulated hand is performing (the simulator's label) beside it;
* the pad's outputs (sticks, triggers, d-pad, buttons, keys: :mod:`neurotouch_hid.output.term`);
* the active profile and what each gesture drives in it;
* while the kernels compile on a first run (:mod:`neurotouch_hid.warmup`), why the run is slow
  and how far the compile is.

The run hands what it sees to a :class:`LiveScene` through :class:`ScenePipeline` (the tracked
markers after each window) and :func:`labelled_simulation` (the simulator's labels); the
terminal view draws it. A pipe or a file gets none of this: the plain state lines stay as they
are (:func:`neurotouch_hid.output.term.state_line`).
"""

from __future__ import annotations

import collections
import contextlib
import math
import threading
from typing import TYPE_CHECKING, Any, Callable, Iterator, Optional

import numpy as np
from rich.console import Group
from rich.panel import Panel
from rich.table import Table
from rich.text import Text

from neurotouch_hid.controller import ControllerState
from neurotouch_hid.estimate import GestureEstimate, GestureType
from neurotouch_hid.output.term import BUTTON_LABELS, STICK_COLUMNS, TermView, axis_fraction, dpad_text, stick_grid

if TYPE_CHECKING:
    from neurotouch_hid.dataset import LabelRow
    from neurotouch_hid.mapping.profile import Profile
    from neurotouch_hid.sensor import SensorGeometry
    from neurotouch_hid.sources import Frame
    from neurotouch_hid.stats import RunStats

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
#: Width of the compile's progress bar (characters).
PROGRESS_WIDTH = 40
#: How many simulator labels are kept to match the windows shown (one per 40 ms frame: ~8 s).
LABELS_KEPT = 200


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
    """What each gesture drives in ``profile``: (input, output) per mapping, e.g.
    ``("push", "left_stick")``, in the profile's order; layer switches as ``(input, "layer NAME")``."""
    lines = []
    for mapping in profile.mappings.values():
        output = mapping.output
        if isinstance(output, (list, tuple)):
            output = "+".join(str(o) for o in output)
        lines.append((str(mapping.input), str(output)))
    for name, switch in profile.layers.items():
        lines.append((str(switch.input), f"layer {name}"))
    return lines


class LiveScene:
    """What the interactive view draws beside the pad, updated by the run's threads.

    Args:
        sensor: the gel's geometry (image px to user mm); may be set once the source is open.
        profile_name: the profile as the user named it; profile: the loaded profile.
        warmup: the first-run compile, shown while it lasts (None: nothing compiles).
        demo: the simulated hand performs the gestures (its labels are shown).
    """

    def __init__(
        self,
        sensor: Optional["SensorGeometry"],
        profile_name: str,
        profile: "Profile",
        *,
        warmup: Any = None,
        demo: bool = False,
    ):
        self.sensor = sensor
        self.warmup = warmup
        self.demo = demo
        self._lock = threading.Lock()
        self._profile_name = profile_name
        self._profile = profile
        self._rest_px: np.ndarray | None = None
        self._now_px: np.ndarray | None = None
        self._labels: collections.deque = collections.deque(maxlen=LABELS_KEPT)
        self._shown_us: int | None = None
        self._runtime: Any = None

    def follow(self, runtime: Any) -> None:
        """Show the profile ``runtime`` maps with (its ``profile`` and ``profile_name``), also
        after a switch (``profile use``, SIGHUP)."""
        with self._lock:
            self._runtime = runtime

    def observe(self, pipeline: Any, estimate: GestureEstimate) -> None:
        """After a window: the pipeline's rest and tracked marker positions (image px; lost
        markers NaN) and the window's end (us) for matching the simulator's label."""
        tracker = getattr(pipeline, "tracker", None)
        rest = getattr(pipeline, "rest_px", None)
        if tracker is None or rest is None:
            return
        now = tracker.positions_px
        now[~tracker.valid] = np.nan
        with self._lock:
            self._rest_px, self._now_px, self._shown_us = np.array(rest, dtype=np.float64), now, int(estimate.t_us)

    def performed(self, label: "LabelRow") -> None:
        """A label of the simulator (the gesture its hand performs from ``label.t_us`` on)."""
        with self._lock:
            self._labels.append(label)

    def performed_at(self, t_us: int | None) -> Optional["LabelRow"]:
        """The simulator's label in force at ``t_us`` (the last one at or before it), or None."""
        with self._lock:
            found = None
            for label in self._labels:
                if t_us is not None and label.t_us <= t_us:
                    found = label
            return found

    def snapshot(self) -> tuple[str, "Profile", np.ndarray | None, np.ndarray | None, int | None]:
        """(profile name, profile, rest px, now px, window end us), consistent with each other."""
        with self._lock:
            name, profile = self._profile_name, self._profile
            if self._runtime is not None:
                name, profile = self._runtime.profile_name, self._runtime.profile
            return name, profile, self._rest_px, self._now_px, self._shown_us


class ScenePipeline:
    """A :class:`~neurotouch_hid.stages.Pipeline` that shows its markers in a :class:`LiveScene`
    after each window, each call inside ``guard()`` (a first run's compile,
    :meth:`neurotouch_hid.warmup.Warmup.guard`: the kernels never switch form within a call)."""

    def __init__(self, pipeline: Any, scene: LiveScene | None, guard: Callable[[], Any] | None = None):
        self._pipeline = pipeline
        self._scene = scene
        self._guard = guard or contextlib.nullcontext

    def process(self, item: Any) -> list[GestureEstimate]:
        """The wrapped pipeline's estimates for ``item``."""
        with self._guard():
            estimates = self._pipeline.process(item)
            if estimates and self._scene is not None:
                self._scene.observe(self._pipeline, estimates[-1])
        return estimates

    def set_resting(self, result: Any, t_us: int) -> None:
        """Hands the resting verdict on."""
        self._pipeline.set_resting(result, t_us)

    def restart(self) -> None:
        """Restarts the wrapped pipeline."""
        self._pipeline.restart()

    def resting(self, detection: Any) -> Any:
        """``detection`` (a :class:`~neurotouch_hid.stages.RestingDetection`, or None) inside the
        same guard: its kernels are the pipeline's."""
        return None if detection is None else _GuardedResting(detection, self._guard)


class _GuardedResting:
    def __init__(self, detection: Any, guard: Callable[[], Any]):
        self._detection = detection
        self._guard = guard

    def update(self, frame: "Frame") -> Any:
        with self._guard():
            return self._detection.update(frame)


def labelled_simulation(
    sim: Any, scene: LiveScene | None, guard: Callable[[], Any] | None, seconds: float | None, batch_us: int
) -> Iterator[Any]:
    """The simulated gel's stream (as ``SimulatedSource.stream``), handing each frame period's
    label to ``scene`` and simulating inside ``guard()`` (see :class:`ScenePipeline`)."""
    from neurotouch_hid.sources.recording import split_batches

    guard = guard or contextlib.nullcontext
    chunks = iter(sim.chunks(seconds))
    while True:
        with guard():
            chunk = next(chunks, None)
        if chunk is None:
            return
        if scene is not None:
            scene.performed(chunk.label)
        yield chunk.frame
        yield from split_batches(chunk.events, batch_us)


def _gesture_line(label: str, gesture: GestureType, intensity_mm: float, n_contacts: int, style: str) -> Text:
    text = Text(f"{label:<11}", style="bold")
    text.append(f"{gesture.value:<10}", style=style)
    text.append(f"{intensity_mm:5.2f} mm  {n_contacts} contact{'s' if n_contacts != 1 else ''}")
    return text


def scene_panel(scene: LiveScene, estimate: GestureEstimate | None) -> Group:
    """The right-hand column: recognised (and performed) gesture, the profile and what each
    gesture drives, the compile's progress."""
    name, profile, _, _, shown_us = scene.snapshot()
    rows: list[Any] = []
    recognised = estimate.gesture if estimate is not None else GestureType.NONE
    intensity = estimate.intensity_mm if estimate is not None else 0.0
    contacts = estimate.n_contacts if estimate is not None else 0
    if scene.demo:
        label = scene.performed_at(shown_us)
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
    rows.append(Text.assemble(("profile ", "bold"), (name, "bold cyan")))
    drives = Table.grid(padding=(0, 1))
    for gesture, output in mapping_lines(profile)[:8]:
        style = "bold reverse" if gesture == recognised.value or recognised.value.startswith(gesture) else ""
        drives.add_row(Text(gesture, style=style), Text("→", style="dim"), Text(output))
    rows.append(drives)
    return Group(*rows)


def compile_line(warmup: Any) -> Optional[Group]:
    """While the first-run compile lasts: why the run is slow and a bar of its progress; else None."""
    if warmup is None or not warmup.compiling:
        return None
    done = round(warmup.fraction() * PROGRESS_WIDTH)
    bar = Text("━" * done, style="bold yellow")
    bar.append("─" * (PROGRESS_WIDTH - done), style="dim")
    return Group(Text(warmup.describe(), style="bold yellow"), bar)


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
    rows: list[Any] = [sticks, buttons]
    if state.keys or state.rel:
        keys = Text("keys ", style="bold")
        keys.append(" ".join(k.removeprefix("KEY_") for k in sorted(state.keys)) or "-", style="bold magenta")
        keys.append("".join(f"  {name} {value:+d}" for name, value in state.rel.items()))
        rows.append(keys)
    return Group(*rows)


def live_layout(
    state: ControllerState, estimate: GestureEstimate | None, stats: Optional["RunStats"], scene: LiveScene
) -> Panel:
    """The whole interactive view, 80x24 at most: the gel plot on the left; the gestures, the
    profile and the pad on the right; the compile's progress and the counters at the bottom."""
    _, _, rest_px, now_px, _ = scene.snapshot()
    sensor = scene.sensor
    if sensor is None:  # the source is not open yet
        from neurotouch_hid.sensor import SensorGeometry

        sensor = SensorGeometry()
    if rest_px is None or now_px is None:
        rest_mm = now_mm = np.zeros((0, 2))
    else:
        rest_mm, now_mm = sensor.image_to_user(rest_px), sensor.image_to_user(now_px)
    contacts = estimate.contacts_mm if estimate is not None else np.zeros((0, 2))
    gel = Group(
        Text("the gel, seen from outside", style="bold"),
        gel_text(gel_cells(rest_mm, now_mm, contacts, sensor.gel_radius_mm)),
    )
    top = Table.grid(padding=(0, 2))
    top.add_row(gel, Group(scene_panel(scene, estimate), pad_text(state)))
    footer = Text(f"t {state.t_us / 1e6:.3f} s", style="dim")
    if stats is not None:
        footer.append(
            f"   windows {stats.windows}   dropped {stats.dropped_items} items",
            style="bold red" if stats.dropped_items else "dim",
        )
    rows: list[Any] = [top]
    progress = compile_line(scene.warmup)
    if progress is not None:
        rows.append(progress)
    rows.append(footer)
    return Panel(Group(*rows), title="NeuroTouch", expand=False, padding=(0, 1))


class LiveView(TermView):
    """The terminal view with the gel, the gestures and the profile (:func:`live_layout`) when
    drawn on a terminal; on a pipe or in a file, exactly :class:`TermView`'s plain lines."""

    def __init__(
        self, console: Any = None, *, scene: LiveScene | None = None, stats: Optional["RunStats"] = None, **kwargs: Any
    ):
        self.scene = scene  # None until the run has one: the pad alone meanwhile
        super().__init__(console, stats=stats, **kwargs)

    def __rich__(self) -> Panel:
        if self.scene is None:
            return super().__rich__()
        with self._lock:
            state, estimate = self._state, self._estimate
        return live_layout(state, estimate, self.stats, self.scene)


class ShownOutput:
    """An output (the virtual gamepad) with the live view drawn beside it on the terminal:
    every state goes to both; the view also gets the estimate."""

    accepts_estimate = True

    def __init__(self, output: Any, view: LiveView):
        self._output = output
        self._view = view

    def write(self, state: ControllerState, estimate: GestureEstimate | None = None) -> None:
        """Write ``state`` to the output, then show it (and ``estimate``)."""
        if self._output.accepts_estimate:
            self._output.write(state, estimate)
        else:
            self._output.write(state)
        self._view.write(state, estimate)

    def neutralise(self) -> None:
        """Neutralise the output, then the view."""
        self._output.neutralise()
        self._view.neutralise()

    def prepare(self, profile: Any) -> None:
        """Prepare the output for ``profile``."""
        self._output.prepare(profile)
