"""The live terminal view of run and demo (neurotouch_hid/output/live.py): the gel plot, the
gestures performed and recognised, the profile, drawn in a real terminal (tmux) at 80x24."""

from __future__ import annotations

import os
import re
import subprocess
import sys
import time
import uuid

import numpy as np
import pytest
from kernel.vm import installed

from neurotouch_hid.core.estimate import GestureType
from neurotouch_hid.mapping.profile import load_profile
from neurotouch_hid.views.live import gel_cells, mapping_lines


def _grid(columns=9, rows=9):
    k = np.linspace(-8.0, 8.0, 5)
    return np.stack(np.meshgrid(k, k), axis=-1).reshape(-1, 2)


def _find(cells, char):
    return [(r, c) for r, row in enumerate(cells) for c, (ch, _) in enumerate(row) if ch == char]


def test_a_marker_moved_right_is_an_arrow_right_where_it_is_now():
    rest = _grid()
    now = rest.copy()
    centre = int(np.argmin(np.linalg.norm(rest, axis=1)))
    now[centre] += (3.0, 0.0)  # 3 mm right, user frame
    cells = gel_cells(rest, now, np.zeros((0, 2)), radius_mm=15.0, columns=31, rows=13)
    assert _find(cells, "→") == [(6, 18)]  # centre (6, 15) plus 3 mm = 3 columns of 1 mm
    assert len(_find(cells, "·")) == len(rest) - 1  # every other marker at rest
    assert not _find(cells, "←") and not _find(cells, "↑")


def test_up_is_up_and_contacts_are_drawn_on_top():
    rest = _grid()
    now = rest + (0.0, 1.5)  # the whole gel pushed up (user frame: y up)
    contact = np.array([[0.0, 1.5]])
    cells = gel_cells(rest, now, contact, radius_mm=15.0, columns=31, rows=13)
    assert _find(cells, "●") == [(5, 15)]  # above the centre row 6
    assert len(_find(cells, "↑")) == len(rest) - 1  # the contact covers one marker
    assert not _find(cells, "↓")


def test_lost_markers_are_left_out():
    rest = _grid()
    now = rest.copy()
    now[:5] = np.nan
    cells = gel_cells(rest, now, np.zeros((0, 2)), radius_mm=15.0)
    assert len(_find(cells, "·")) == len(rest) - 5


def test_the_profile_says_what_each_gesture_drives_in_its_words_and_the_pads():
    lines = mapping_lines(load_profile("default"))
    assert ("push", "L stick") in lines and ("pinch", "LT") in lines and ("twist", "R stick X") in lines
    assert len(lines) == len(load_profile("default").mappings)
    spacecraft = mapping_lines(load_profile("spacecraft"))
    assert ("twist", "roll (R stick X)") in spacecraft and ("zoom", "accelerate (RT)") in spacecraft
    assert not any("ABS_" in what or "BTN_" in what for _, what in lines + spacecraft)
    accessibility = dict(mapping_lines(load_profile("accessibility")))
    assert accessibility["twist_ccw"] == "confirm (A)"


def _tmux() -> str:
    """tmux, apt-installed when missing (as root, like the kernel tests' qemu)."""
    found = installed("tmux", "tmux")
    if found is None:
        pytest.skip(reason="tmux is not installed and cannot be apt-installed here (needs root and apt-get)")
    return found


def test_the_demo_in_a_real_80x24_terminal_shows_the_gel_the_gestures_and_the_profile(tmp_path):
    """A cold numba cache, so the compile's progress shows too, before any gesture."""
    tmux = _tmux()
    session = f"nt-live-{uuid.uuid4().hex[:8]}"
    env = {
        "NUMBA_CACHE_DIR": str(tmp_path / "numba"),
        "PYTHONPATH": os.pathsep.join(sys.path),
        "XDG_CONFIG_HOME": os.environ.get("XDG_CONFIG_HOME", str(tmp_path / "config")),
        "TERM": "xterm-256color",
    }
    command = " ".join(f"{k}={v}" for k, v in env.items())
    command += f" {sys.executable} -m neurotouch_hid.cli demo --seconds 60; sleep 60"
    subprocess.run([tmux, "new-session", "-d", "-s", session, "-x", "80", "-y", "24", command], check=True)
    try:
        screen = ""
        for _ in range(600):
            time.sleep(0.5)
            screen = subprocess.run([tmux, "capture-pane", "-p", "-t", session], capture_output=True, text=True).stdout
            if "compiling the gesture pipeline" in screen and re.search(r"windows [1-9]", screen):
                break  # a first state, the compile still going
        lines = screen.splitlines()
        assert len(lines) <= 24 and all(len(line) <= 80 for line in lines)
        assert "the gel, seen from outside" in screen
        assert screen.count("·") > 100  # the markers at rest
        assert "performed" in screen and "recognised" in screen
        assert "profile default" in screen
        for gesture, output in mapping_lines(load_profile("default")):
            assert f"{gesture}" in screen and f"→ {output}" in screen
        assert "L stick" in screen and "R stick" in screen and "LT" in screen
        assert "compiling the gesture pipeline, first run only" in screen
        assert "Traceback" not in screen
    finally:  # Ctrl-C ends the run (and its compile children) as a user would; then the terminal
        subprocess.run([tmux, "send-keys", "-t", session, "C-c"], capture_output=True)
        time.sleep(2)
        subprocess.run([tmux, "kill-session", "-t", session], capture_output=True)


def test_the_gamepad_with_the_view_beside_it_both_get_every_record_and_are_neutralised():
    """Two subscribers of one run: the pad writes the states that changed, the view shows them
    with the gesture; both are neutral at the end."""
    import io

    from rich.console import Console
    from runtime_fakes import FakeMapper, FakePipeline, RecordingOutput, batch

    from neurotouch_hid.engine.engine import Engine, RunParts
    from neurotouch_hid.engine.mode import RunMode, RunOptions
    from neurotouch_hid.views.live import LiveView

    pad = RecordingOutput()
    view = LiveView(Console(file=io.StringIO(), force_terminal=False, width=200))
    stream = [batch(k * 1000) for k in range(8)]
    Engine(
        RunParts(stream, FakePipeline(push_batches=3)),
        {"sign": 1},
        [pad, view],
        RunOptions(mode=RunMode.FAST, mapper_factory=FakeMapper),
    ).run()
    view.close()
    written = [state for kind, state in pad.calls if kind == "write"]
    assert [s.axes["ABS_X"] for s in written] == [1000, 2000, 3000, 0]
    assert pad.calls[-1] == ("neutralise", None)
    shown = view.console.file.getvalue()
    assert "push 1.00 mm" in shown and view.wants_markers is False  # a pipe: no markers asked for
    assert shown.splitlines()[-1].startswith("t ") and "buttons -" in shown.splitlines()[-1]


@pytest.mark.parametrize(
    ("kind", "terminal", "beside"),
    [
        ("gamepad", True, True),
        ("hid", True, True),
        ("gamepad", False, False),
        ("jsonl", True, False),
        ("term", True, False),
    ],
)
def test_the_live_view_goes_beside_the_pad_only_on_a_terminal(kind, terminal, beside):
    """``open_outputs`` keeps the output it is given first and adds the live view only beside the
    virtual gamepad drawn on a terminal (a pipe gets the pad's plain output alone)."""
    import contextlib
    import io

    from rich.console import Console
    from runtime_fakes import RecordingOutput

    from neurotouch_hid.engine.driver import open_outputs
    from neurotouch_hid.views.live import LiveView

    made = RecordingOutput()
    console = Console(file=io.StringIO(), force_terminal=terminal, width=120)
    with contextlib.ExitStack() as stack:
        outputs = open_outputs(made, kind, stack, console)
        assert outputs[0] is made
        assert [type(o) for o in outputs[1:]] == ([LiveView] if beside else [])
    assert open_outputs(made, kind, contextlib.ExitStack(), None) == [made]  # no console: no view


def test_a_run_s_lines_go_above_the_view_drawn_on_a_terminal_else_where_they_went():
    """The first run's compile line went to stderr while the view was drawn on the terminal's
    stdout, and the next redraw drew over it: the user saw no sign of the compile."""
    import io

    from rich.console import Console

    from neurotouch_hid.engine.driver import said_above
    from neurotouch_hid.views.term import TermView

    screen = io.StringIO()
    view = TermView(Console(file=screen, force_terminal=True, width=100))
    elsewhere: list[str] = []
    try:
        said_above([view], elsewhere.append)("compiling the gesture pipeline, first run only")
    finally:
        view.close()
    assert "compiling the gesture pipeline, first run only" in screen.getvalue() and elsewhere == []
    piped = TermView(Console(file=io.StringIO(), width=100))
    try:
        assert said_above([piped], elsewhere.append) == elsewhere.append
    finally:
        piped.close()


def test_the_live_view_answers_q_h_and_space_in_a_real_terminal(tmp_path):
    """``demo`` drawn in tmux: ``h`` shows the keys, Space holds the picture, ``q`` ends the run
    cleanly, with the run's summary (Ctrl-C printed none), and the terminal's mode is restored."""
    tmux = _tmux()
    session = f"nt-keys-{uuid.uuid4().hex[:8]}"
    env = {
        "PYTHONPATH": os.pathsep.join(sys.path),
        "XDG_CONFIG_HOME": os.environ.get("XDG_CONFIG_HOME", str(tmp_path / "config")),
        "TERM": "xterm-256color",
    }
    done = tmp_path / "exit"
    command = " ".join(f"{k}={v}" for k, v in env.items())
    command += f" {sys.executable} -m neurotouch_hid.cli demo --seconds 300; echo $? > {done}; stty -a; sleep 60"

    def screen() -> str:
        return subprocess.run([tmux, "capture-pane", "-p", "-J", "-t", session], capture_output=True, text=True).stdout

    def wait_for(pattern: str, seconds: float = 300) -> str:
        shown = ""
        for _ in range(int(seconds * 4)):
            shown = screen()
            if re.search(pattern, shown):
                return shown
            time.sleep(0.25)
        raise AssertionError(f"{pattern!r} never shown:\n{shown}")

    subprocess.run([tmux, "new-session", "-d", "-s", session, "-x", "80", "-y", "24", command], check=True)
    try:
        shown = wait_for(r"windows [1-9]")
        assert "q quit  h help" in shown
        subprocess.run([tmux, "send-keys", "-t", session, "h"], check=True)
        assert "Space hold the picture (the pad goes on)" in wait_for(r"Ctrl-C quit \(with the run's summary\)", 10)
        subprocess.run([tmux, "send-keys", "-t", session, "Space"], check=True)
        held = wait_for(r"held: picture only \(Space\)", 10)
        time.sleep(1.0)
        assert re.search(r"t [0-9.]+ s", screen()).group() == re.search(r"t [0-9.]+ s", held).group()
        subprocess.run([tmux, "send-keys", "-t", session, "q"], check=True)
        for _ in range(120):
            if done.exists():
                break
            time.sleep(0.25)
        assert done.read_text().strip() == "0"
        shown = wait_for(r"icanon", 10)  # stty: the terminal back in canonical mode, not -icanon
        assert re.search(r"\d+ windows, \d+ events", shown), shown  # the run's summary
        assert "-icanon" not in shown and "Traceback" not in shown
    finally:
        subprocess.run([tmux, "send-keys", "-t", session, "C-c"], capture_output=True)
        time.sleep(1)
        subprocess.run([tmux, "kill-session", "-t", session], capture_output=True)


def record_for(profile, game: str = ""):
    from neurotouch_hid.core.controller import ControllerState
    from neurotouch_hid.core.estimate import GestureEstimate
    from neurotouch_hid.core.stages import WindowRecord
    from neurotouch_hid.core.stats import RunStats

    stats = RunStats()
    stats.game = game
    estimate = GestureEstimate(1_000_000, GestureType.NONE, True, 0.0)
    return WindowRecord(
        estimate=estimate,
        state=ControllerState.neutral(1_000_000),
        state_changed=False,
        gesture_changed=False,
        profile=profile,
        profile_name="many",
        sensor=None,
        markers=None,
        performed=None,
        labelled=False,
        stats=stats,
        compile=None,
    )


def rendered(panel, width: int = 80) -> str:
    import io

    from rich.console import Console

    console = Console(file=io.StringIO(), width=width, force_terminal=False)
    console.print(panel)
    return console.file.getvalue()


def test_a_profile_with_more_mappings_than_lines_says_how_many_more_and_the_game_it_follows():
    from neurotouch_hid.core.controller import ControllerState
    from neurotouch_hid.mapping.profile import Profile
    from neurotouch_hid.views.live import MAPPINGS_SHOWN, live_layout

    keys = [f"KEY_F{n}" for n in range(1, 11)]
    profile = Profile.model_validate(
        {"mappings": {f"m{n}": {"input": "pinch", "output": k} for n, k in enumerate(keys)}}
    )
    shown = rendered(live_layout(ControllerState.neutral(), None, record_for(profile, "Portal 2 (620)")))
    assert f"+{10 - (MAPPINGS_SHOWN - 1)} more" in shown
    assert "F7 key" in shown and "F8 key" not in shown
    assert "profile many  for Portal 2 (620)" in shown
    few = rendered(live_layout(ControllerState.neutral(), None, record_for(load_profile("default"))))
    assert "more" not in few and "for " not in few.split("profile many")[1].splitlines()[0]


def test_log_lines_go_above_the_view_while_it_draws_and_back_after():
    """A profile switch is said by ``logging``, whose handler writes to the terminal's stderr:
    around rich's Live that line was drawn over, leaving stale frames. While the view draws it
    goes through the view (above it); after, to the terminal again."""
    import io
    import logging

    from rich.console import Console

    from neurotouch_hid.views.term import TermView

    class Tty(io.StringIO):
        def isatty(self) -> bool:
            return True

    terminal_stderr = Tty()
    handler = logging.StreamHandler(terminal_stderr)
    root = logging.getLogger()
    root.addHandler(handler)
    screen = io.StringIO()
    try:
        view = TermView(Console(file=screen, force_terminal=True, width=100))
        try:
            logging.getLogger("neurotouch_hid.engine.engine").warning("switched to profile mouse (Portal 2 is running)")
        finally:
            view.close()
        assert terminal_stderr.getvalue() == ""
        assert "switched to profile mouse (Portal 2 is running)" in screen.getvalue()
        logging.getLogger("neurotouch_hid.engine.engine").warning("after")
        assert terminal_stderr.getvalue() == "after\n"
    finally:
        root.removeHandler(handler)


def test_the_compile_line_ticks_while_no_window_comes():
    """The first run waits for the simulator's and tracker's kernels: no window comes for seconds
    (~12 s under load), and the panel stood still at ``t 0.000 s``. The compile's line now ends
    with a spinner and the seconds since the start, which move at every redraw."""
    from neurotouch_hid.core.controller import ControllerState
    from neurotouch_hid.core.stages import CompileProgress
    from neurotouch_hid.views.live import live_layout

    record = record_for(load_profile("default"))._replace(
        compile=CompileProgress("compiling the gesture pipeline, first run only: 10%, 0 s (interpreted meanwhile)", 0.1)
    )
    early = rendered(live_layout(ControllerState.neutral(), None, record, 1_000_000, wall_s=3.2))
    later = rendered(live_layout(ControllerState.neutral(), None, record, 1_000_000, wall_s=12.6))
    assert "3 s since the start" in early and "13 s since the start" in later
    assert "⠴ 3 s" in early and "⠋ 13 s" in later  # the spinner moves an eighth of a second a step


def test_keys_are_read_from_a_terminal_only_in_the_foreground():
    """A run started in the background (``run &``) that put the terminal in cbreak mode would be
    stopped by SIGTTOU: the view reads keys only as the terminal's foreground job."""
    import io
    import os

    from rich.console import Console

    from neurotouch_hid.views.live import LiveView, in_foreground

    primary, secondary = os.openpty()
    try:
        terminal = os.fdopen(secondary, "r", closefd=False)
        assert terminal.isatty() and not in_foreground(terminal)  # a new pty: no foreground job of ours
        view = LiveView(Console(file=io.StringIO(), force_terminal=True, width=100), keys=terminal)
        try:
            assert view._keys is None
        finally:
            view.close()
    finally:
        os.close(primary)
        os.close(secondary)


def test_the_drawn_gesture_and_contacts_are_the_latest_windows_while_the_pad_holds_still():
    """A push held with its stick at the end of its travel (or a button held, or a gesture the
    profile does not map) leaves the pad's state unchanged: the view kept drawing the intensity
    and the contacts of the window the state last changed in, beside the markers of now."""
    import io

    from rich.console import Console

    from neurotouch_hid.core.controller import ControllerState
    from neurotouch_hid.core.estimate import GestureEstimate
    from neurotouch_hid.views.live import LiveView

    def push(t_us: int, mm: float, x_mm: float) -> GestureEstimate:
        at = np.array([[x_mm, 0.0]])
        return GestureEstimate(t_us, GestureType.PUSH, False, mm, contacts_px=at, contacts_mm=at)

    view = LiveView(Console(file=io.StringIO(), force_terminal=True, width=100), refresh_per_second=50)
    try:
        state = ControllerState.neutral(10_000)
        state.axes["ABS_X"] = 32767
        first = record_for(load_profile("default"))
        view.publish(first._replace(estimate=push(10_000, 2.0, -20.0), state=state, state_changed=True))
        view.publish(first._replace(estimate=push(20_000, 6.0, 20.0), state=state, gesture_changed=False))
        shown = rendered(view.__rich__(), 100)
    finally:
        view.close()
    gesture = next(line for line in shown.splitlines() if "gesture" in line and "push" in line)
    assert "6.00 mm" in gesture, shown
    gel = [line[:34] for line in shown.splitlines() if "●" in line[:34]]  # the gel's column
    assert len(gel) == 1 and gel[0].index("●") > 17, shown  # the contact at +20 mm: right of the centre
