"""The terminal view of the gamepad: stick grids, triggers, d-pad, buttons, plain lines without a TTY."""

from __future__ import annotations

import io

import pytest
from rich.console import Console

from neurotouch_hid.core.controller import AXES, BUTTONS, ControllerState
from neurotouch_hid.core.estimate import GestureEstimate, GestureType
from neurotouch_hid.core.stats import RunStats
from neurotouch_hid.views.term import (
    BUTTON_LABELS,
    STICK_COLUMNS,
    STICK_ROWS,
    TermView,
    axis_fraction,
    buttons_text,
    dpad_text,
    stick_cell,
    stick_grid,
)

LO, HI, _ = AXES["ABS_X"]


def plain_console(width: int = 200) -> Console:
    return Console(file=io.StringIO(), force_terminal=False, width=width, color_system=None)


def test_stick_cells_put_the_corners_and_the_centre_where_a_player_expects_them():
    assert stick_cell(0, 0) == (STICK_COLUMNS // 2, STICK_ROWS // 2)
    assert stick_cell(LO, LO) == (0, 0)  # evdev: -y is up, so top-left
    assert stick_cell(HI, HI) == (STICK_COLUMNS - 1, STICK_ROWS - 1)
    assert stick_cell(HI, LO) == (STICK_COLUMNS - 1, 0)
    assert stick_cell(10 * HI, 10 * LO) == stick_cell(HI, LO)  # out of range is clamped


def test_stick_grid_draws_one_dot_at_the_stick_position():
    rows = stick_grid(HI, LO).plain.splitlines()
    assert len(rows) == STICK_ROWS and all(len(r) == STICK_COLUMNS for r in rows)
    assert rows[0][-1] == "●" and sum(r.count("●") for r in rows) == 1


def test_axis_fractions_of_sticks_triggers_and_dpad():
    assert axis_fraction("ABS_X", HI) == pytest.approx(1.0, abs=1e-4)
    assert axis_fraction("ABS_X", LO) == -1.0
    assert axis_fraction("ABS_X", 0) == 0.0
    assert axis_fraction("ABS_Z", 0) == 0.0 and axis_fraction("ABS_Z", 255) == 1.0
    assert axis_fraction("ABS_HAT0Y", -1) == -1.0


def lit(text) -> set[str]:
    """The labels of the spans drawn reversed (lit)."""
    return {text.plain[s.start : s.end].strip() for s in text.spans if "reverse" in str(s.style)}


def test_pressed_buttons_and_dpad_directions_are_lit():
    buttons = {name: name in ("BTN_SOUTH", "BTN_TR") for name in BUTTONS}
    assert lit(buttons_text(buttons)) == {"A", "RB"}
    assert lit(dpad_text(-1, 0)) == {"←"}
    assert lit(dpad_text(1, 1)) == {"→", "↓"}
    assert lit(dpad_text(0, 0)) == set()
    assert set(BUTTON_LABELS) == set(BUTTONS)


def test_without_a_terminal_it_prints_plain_lines_at_most_once_a_period_and_a_last_neutral_one():
    console = plain_console()
    stats = RunStats(windows=7, dropped_items=3)
    view = TermView(console, stats=stats, line_period_s=3600)
    state = ControllerState.neutral(2_500_000)
    state.axes["ABS_X"] = HI
    state.axes["ABS_RZ"] = 200
    state.buttons["BTN_EAST"] = True
    view.write(state, GestureEstimate(t_us=2_500_000, gesture=GestureType.PUSH, resting=False, intensity_mm=4.25))
    view.write(state)  # within the period: no new line
    view.neutralise()
    view.close()
    lines = console.file.getvalue().splitlines()
    assert len(lines) == 2
    first, last = lines
    assert "push 4.25 mm" in first and "L(+1.00,+0.00)" in first and "RT 200" in first and "buttons B" in first
    assert "windows 7 dropped 3" in first
    assert "none" in last and "L(+0.00,+0.00)" in last and "RT   0" in last and "buttons -" in last
    assert "\x1b[" not in console.file.getvalue()


def test_on_a_terminal_it_draws_the_pad_live():
    console = Console(file=io.StringIO(), force_terminal=True, width=120)
    stats = RunStats(windows=12, dropped_items=2, dropped_events=500)
    with TermView(console, stats=stats, refresh_per_second=50) as view:
        state = ControllerState.neutral(1_000_000)
        state.axes["ABS_Z"] = 255
        state.buttons["BTN_SOUTH"] = True
        view.write(state, GestureEstimate(t_us=1_000_000, gesture=GestureType.PINCH, resting=False, intensity_mm=3.0))
    text = console.file.getvalue()
    assert "NeuroTouch gamepad" in text and "left stick" in text and "right stick" in text
    assert "pinch" in text and "3.00 mm" in text
    assert "dropped 2 items (500 events, 0 frames)" in text
    assert " 255" in text  # the left trigger's value beside its bar


def test_the_view_keeps_the_last_estimate_for_states_written_without_one():
    console = plain_console()
    view = TermView(console, line_period_s=0)
    view.write(
        ControllerState.neutral(1), GestureEstimate(t_us=1, gesture=GestureType.ZOOM, resting=False, intensity_mm=1.5)
    )
    view.write(ControllerState.neutral(2))
    lines = console.file.getvalue().splitlines()
    assert all("zoom 1.50 mm" in line for line in lines) and len(lines) == 2


@pytest.mark.parametrize("encoding", ["latin-1", "ascii"])
def test_on_a_terminal_that_is_not_utf8_the_pad_is_drawn_in_characters_it_has(encoding):
    """A latin-1 or ASCII terminal (LANG=de_DE.ISO-8859-1, PYTHONIOENCODING): the view's dots,
    arrows and bars raised UnicodeEncodeError, and ``run --output term`` and ``demo`` ended in a
    traceback with nothing drawn."""
    out = io.BytesIO()
    console = Console(file=io.TextIOWrapper(out, encoding=encoding), force_terminal=True, width=120)
    with TermView(console, stats=RunStats(windows=3, profile="jeu-ß-ゲーム"), refresh_per_second=50) as view:
        state = ControllerState.neutral(1_000_000)
        state.axes["ABS_X"], state.axes["ABS_HAT0Y"], state.axes["ABS_Z"] = HI, -1, 255
        view.write(state, GestureEstimate(t_us=1_000_000, gesture=GestureType.PUSH, resting=False, intensity_mm=2.0))
        view.say("switched to profile ゲーム → mouse")
    console.file.flush()
    text = out.getvalue().decode(encoding)
    assert "left stick" in text and "push" in text and "2.00 mm" in text
    assert "o" in text and "^" in text  # the stick's position and the d-pad's up, in ASCII
    assert "switched to profile ?????? > mouse" in text and "profile jeu-" in text
