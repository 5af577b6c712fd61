"""What a new user meets in the first minutes: the piped terminal view keeps every output change,
the profile commands undo what they did, doctor's fixes can be copied, the help is readable, and
the README's commands are the ones that work."""

from __future__ import annotations

import io

from rich.console import Console

from neurotouch_hid.controller import ControllerState
from neurotouch_hid.output.jsonl import StateJsonlWriter
from neurotouch_hid.output.term import TermView


def plain_console() -> Console:
    return Console(file=io.StringIO(), force_terminal=False, width=10_000, color_system=None)


# --- the piped view ------------------------------------------------------------------------------
def test_piped_view_prints_a_key_press_and_its_release_however_short():
    console = plain_console()
    view = TermView(console, line_period_s=3600)  # no line is ever due by time
    view.write(ControllerState.neutral(0))  # the first line
    down = ControllerState.neutral(10_000)
    down.keys = frozenset({"KEY_SPACE"})
    view.write(down)
    view.write(ControllerState.neutral(20_000))
    view.close()
    lines = console.file.getvalue().splitlines()
    assert [("KEY_SPACE" in line) for line in lines] == [False, True, False]


def test_piped_view_prints_the_last_analogue_state_and_the_whole_mouse_motion():
    console = plain_console()
    view = TermView(console, line_period_s=3600)
    view.write(ControllerState.neutral(0))
    for i in range(1, 4):  # three steps within one period: not printed when written
        moved = ControllerState.neutral(i * 10_000)
        moved.axes["ABS_X"] = 32767
        moved.rel = {"REL_X": 5}
        view.write(moved)
    assert len(console.file.getvalue().splitlines()) == 1
    view.close()  # the stretch's last state is printed, with the motion of all three steps
    last = console.file.getvalue().splitlines()[-1]
    assert "L(+1.00,+0.00)" in last and "REL_X +15" in last


class Both:
    """The piped terminal view and the JSON lines of one and the same run."""

    accepts_estimate = True

    def __init__(self, term: TermView, jsonl: StateJsonlWriter):
        self.term, self.jsonl = term, jsonl

    def write(self, state, estimate=None):
        self.term.write(state, estimate)
        self.jsonl.write(state, estimate)

    def prepare(self, profile):
        pass

    def neutralise(self):
        self.term.neutralise()
        self.jsonl.neutralise()


def key_changes(keys_per_line: list[frozenset]) -> list[frozenset]:
    changes = [keys_per_line[0]]
    for keys in keys_per_line[1:]:
        if keys != changes[-1]:
            changes.append(keys)
    return changes


def test_piped_switch_access_run_shows_every_key_press_the_json_lines_show():
    import json

    from neurotouch_hid.driver import run_driver

    console, stream = plain_console(), io.StringIO()
    term = TermView(console)
    jsonl = StateJsonlWriter(stream)
    run_driver("sim", "switch-access", "term", seconds=8, fast=True, output_obj=Both(term, jsonl))
    term.close()
    from_json = [frozenset(json.loads(line)["keys"]) for line in stream.getvalue().splitlines()]
    from_term = []
    for line in console.file.getvalue().splitlines():
        keys = line.split(" keys ")[1].split()[0] if " keys " in line else "-"
        from_term.append(frozenset() if keys == "-" else frozenset(keys.split(",")))
    presses = [k for k in key_changes(from_json) if k]
    assert len(presses) >= 2  # the simulated hand's first gestures press keys within 8 s
    assert key_changes(from_term) == key_changes(from_json)
