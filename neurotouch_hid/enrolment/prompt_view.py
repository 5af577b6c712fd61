"""What an enrolment shows: the prompts, with a countdown, what to do and for how long.

A view that subscribes to the run (:class:`~neurotouch_hid.core.stages.Subscriber`): from each
window's record (:class:`~neurotouch_hid.core.stages.WindowRecord`) and the session's script
(:class:`~neurotouch_hid.enrolment.plan.Script`) it draws the prompts (the plan's and those
asked again) at the record's time (s from the stream's first event), what the pipeline sees
(:class:`Seen`: the gel's motion from the record's markers, the gesture read) and the notes so
far (a prompt not seen, asked again). It reaches into no source and no pipeline.

On a terminal it is a panel redrawn in place (rich ``Live``, 80x24 at least; at most every
:data:`DRAW_EVERY_US` of stream time); elsewhere (a pipe, a file) it prints one plain line per
prompt as it is cued and one per note, exactly, never wrapped.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from rich.console import Group
from rich.panel import Panel
from rich.text import Text

from neurotouch_hid.core.estimate import GestureType
from neurotouch_hid.core.stages import WindowRecord
from neurotouch_hid.enrolment.label import REST_MM, motion_mm
from neurotouch_hid.enrolment.plan import MAX_SESSION_S, Prompt, Script

#: The countdown before a cue (s): "in 3, 2, 1".
COUNTDOWN_S = 3.0
#: Width of the bar of a held gesture's remaining time (characters).
BAR_WIDTH = 20
#: The panel is redrawn at most this often (us of stream time): the APS frames' 25 Hz.
DRAW_EVERY_US = 40_000


@dataclass(frozen=True)
class Seen:
    """What the pipeline sees now.

    Attributes:
        moved_mm: the gel's motion (mm; :func:`~neurotouch_hid.enrolment.label.motion_mm`).
        gesture: the type the pipeline reads (NONE when none).
        intensity_mm: its intensity (mm).
    """

    moved_mm: float = 0.0
    gesture: GestureType = GestureType.NONE
    intensity_mm: float = 0.0


def clock(t_s: float) -> str:
    """``m:ss`` of a time in seconds (clamped at 0)."""
    t = max(0, int(t_s))
    return f"{t // 60}:{t % 60:02d}"


def current(prompts: Sequence[Prompt], t_s: float) -> tuple[int | None, int | None]:
    """The index of the prompt cued last at ``t_s`` (None before the first cue) and of the next one
    (None after the last)."""
    last = None
    for i, p in enumerate(prompts):
        if p.cue_s <= t_s:
            last = i
        else:
            return last, i
    return last, None


def prompt_lines(prompts: Sequence[Prompt], t_s: float) -> list[Text]:
    """The prompt part of the panel: what to do now (and for how long), or the countdown to the next."""
    last, nxt = current(prompts, t_s)
    lines: list[Text] = []
    if last is not None and t_s < prompts[last].end_s:
        p = prompts[last]
        left = p.end_s - t_s
        done = int(round(BAR_WIDTH * min(1.0, (t_s - p.cue_s) / p.seconds)))
        lines.append(Text.assemble(("NOW", "bold reverse green"), "  ", (p.what(), "bold")))
        lines.append(
            Text.assemble(
                f"     {p.how()}, then let go  ",
                ("█" * done, "green"),
                ("░" * (BAR_WIDTH - done), "dim"),
                f" {left:.1f} s",
            )
        )
    elif last is not None:
        lines.append(Text("let go, hands off the gel: rest", style="bold"))
        lines.append(Text(""))
    else:
        lines.append(Text("hands off the gel: it is seen at rest first", style="bold"))
        lines.append(Text(""))
    if nxt is not None:
        p = prompts[nxt]
        wait = p.cue_s - t_s
        if wait <= COUNTDOWN_S:
            lines.append(Text.assemble(("GET READY", "bold yellow"), f" in {math.ceil(wait)}: {p.what()}"))
        else:
            lines.append(Text(f"next, in {wait:.0f} s: {p.what()}", style="dim"))
    else:
        lines.append(Text("last prompt", style="dim"))
    return lines


def seen_line(seen: Seen | None) -> Text:
    """What the gel does, as the pipeline sees it."""
    if seen is None:
        return Text("gel: waiting for the camera", style="dim")
    if seen.moved_mm <= REST_MM:
        return Text("gel: at rest", style="dim")
    read = f", read as {seen.gesture.value} {seen.intensity_mm:.1f} mm" if seen.gesture is not GestureType.NONE else ""
    return Text(f"gel: moving {seen.moved_mm:.1f} mm{read}", style="cyan")


class PromptView:
    """The enrolment's prompts on ``console`` (a ``rich.console.Console``): a live panel on a
    terminal, plain lines elsewhere (module docstring). A subscriber and a context manager.

    Args:
        console: where to draw.
        script: the session's prompts and notes.
        by_hand: the person at the gel performs the prompts (False: the simulated hand does, said
            in the title).
    """

    wants_markers = True

    def __init__(self, console: Any, script: Script, by_hand: bool = True) -> None:
        self.console = console
        self.script = script
        self.by_hand = by_hand
        self._live = None
        self._drawn_us: int | None = None
        self._last: tuple[float, Seen | None] = (0.0, None)  # the time and what was seen, drawn last
        self._said_cues = 0
        self._said_notes = 0
        self._said_labelling = False

    def __enter__(self) -> "PromptView":
        if self.console.is_terminal:
            from rich.live import Live

            self._live = Live(console=self.console, auto_refresh=False, transient=False)
            self._live.__enter__()
            self._live.update(self.panel(self.script.prompts(), 0.0, None, ()), refresh=True)
        return self

    def __exit__(self, *exc) -> None:
        if self._live is not None:
            self._live.__exit__(*exc)
            self._live = None

    def panel(
        self, prompts: Sequence[Prompt], t_s: float, seen: Seen | None, notes: Sequence[str], status: str = ""
    ) -> Panel:
        """The panel for these inputs (what :meth:`publish` draws on a terminal), ``status`` last."""
        last, _ = current(prompts, t_s)
        number = 0 if last is None else last + 1
        who = "" if self.by_hand else "    the simulated hand performs them"
        head = Text(f"{clock(t_s)} of at most {clock(MAX_SESSION_S)}    prompt {number} of {len(prompts)}{who}")
        body = [head, Text(""), *prompt_lines(prompts, t_s), Text(""), seen_line(seen)]
        body += [Text(n, style="yellow") for n in notes[-4:]]
        body += [Text(status, style="bold")] if status else []
        return Panel(Group(*body), title="enrol: teach the driver your gel and your hand", title_align="left")

    def publish(self, record: WindowRecord) -> None:
        """Draw the script at the record's window end."""
        t_us = int(record.estimate.t_us)
        prompts, notes = self.script.prompts(), self.script.notes()
        t_s = (t_us - int(self.script.start_us or t_us)) * 1e-6
        if self._live is not None:
            if self._drawn_us is not None and t_us - self._drawn_us < DRAW_EVERY_US:
                return
            self._drawn_us = t_us
            self._last = (t_s, seen_in(record))
            self._live.update(self.panel(prompts, t_s, *self._last[1:], notes), refresh=True)
            return
        while self._said_cues < len(prompts) and prompts[self._said_cues].cue_s <= t_s:
            p = prompts[self._said_cues]
            self._said_cues += 1
            self._plain(f"{clock(p.cue_s)} prompt {self._said_cues} of {len(prompts)}: {p.instruction()}")
        while self._said_notes < len(notes):
            self._plain(notes[self._said_notes])
            self._said_notes += 1

    def labelling(self, done_us: int, total_us: int) -> None:
        """After the session: how far the labelling of its recording is (us of recording done, of
        ``total_us``), an ``on_progress`` of :func:`~neurotouch_hid.pipeline.track.pipeline_over`."""
        if self._live is None:
            if not self._said_labelling:
                self._plain("labelling the recording")
            self._said_labelling = True
            return
        status = f"labelling the recording: {done_us * 1e-6:.0f} of {max(done_us, total_us) * 1e-6:.0f} s"
        prompts, notes = self.script.prompts(), self.script.notes()
        self._live.update(self.panel(prompts, *self._last, notes, status), refresh=True)

    def neutralise(self) -> None:
        """Nothing to release: a view drives no device."""

    def prepare(self, profile: object) -> None:
        """Nothing to prepare: the view shows no profile."""

    def _plain(self, line: str) -> None:
        self.console.print(line, highlight=False, soft_wrap=True, markup=False)


def seen_in(record: WindowRecord) -> Seen:
    """What the pipeline sees in ``record``: the gel's motion from its markers (0 with none, or
    no geometry), the gesture read and its intensity."""
    m, sensor = record.markers, record.sensor
    moved = 0.0 if m is None or sensor is None else motion_mm(m.now_px, m.rest_px, sensor.px_per_mm)
    return Seen(moved, record.estimate.gesture, float(record.estimate.intensity_mm))
