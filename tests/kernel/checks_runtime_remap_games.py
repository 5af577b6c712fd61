"""Guest check of the profile per game in a real kernel: a game starting and exiting switches the
running driver's profile mid-push, and nothing stays held on any virtual device.

Run by tests/kernel/guest.py inside qemu (after checks_runtime_remap.py, whose helpers it uses);
asserted on by tests/test_game_profiles_kernel.py. As there, the runtime is fed estimates (a
predictions file: a push held two minutes); everything else is real: the driver (``run_driver``,
what `neurotouch-hid run` calls, in the check's process, ended by a real SIGTERM:
``outputlib.InProcessRun``) with the user's games.yaml, a real process with SteamAppId in its environment,
psutil reading /proc, the switch through `profile use`'s path, the uinput keyboard, mouse and pad
read back with evdev.
"""

from __future__ import annotations

import os
import subprocess
import tempfile
from pathlib import Path

import guestlib
from checks_runtime_remap import EVERYTHING, G, _write_preds, holds_everything, sequence, stop_run, watch_run
from evdev import ecodes
from outputlib import InProcessRun

TIMEOUT_S = 300

#: The profile the driver starts with: the held push holds a key, a mouse button and the pad's B.
BASE = """\
description: guest check - a push holds Enter, the right mouse button and B
mappings:
  enter: {input: push_intensity, output: KEY_ENTER, press_mm: 2.0, release_mm: 1.0}
  click: {input: push_intensity, output: BTN_RIGHT, press_mm: 2.0, release_mm: 1.0}
  pad: {input: push_intensity, output: B, press_mm: 2.0, release_mm: 1.0}
"""


def check_a_game_switches_profiles_leaving_nothing_held() -> dict:
    """`run` on BASE with a push held: Enter, BTN_RIGHT and B are down. A process with
    SteamAppId=4242 starts (games.yaml maps 4242 to EVERYTHING): each device releases what BASE
    held before EVERYTHING presses its own (the Ctrl+B chord, BTN_LEFT, A, the stick off centre).
    The game exits: all of that is released and the stick centred before BASE presses again.
    SIGTERM: nothing pressed anywhere. Both switches are said on the driver's log."""
    folder = Path(tempfile.mkdtemp(prefix="games-"))
    runtime_dir, config = folder / "xdg-runtime", folder / "config"
    runtime_dir.mkdir(mode=0o700)
    # the game's profile is one of the user's (known when the driver starts, so the keyboard and
    # mouse offer its keys and buttons from the start: docs/limits.md)
    (config / "neurotouch-hid" / "profiles").mkdir(parents=True)
    base = folder / "base.yaml"
    base.write_text(BASE)
    (config / "neurotouch-hid" / "profiles" / "everything.yaml").write_text(EVERYTHING)
    (config / "neurotouch-hid" / "games.yaml").write_text("steam:\n  4242: everything\n")
    env = {"XDG_RUNTIME_DIR": str(runtime_dir), "XDG_CONFIG_HOME": str(config)}
    preds = _write_preds(folder, sequence((G.PUSH, 4.0, 120.0), lead_in_s=2.0))
    run = InProcessRun(preds, base, "gamepad", env=env)
    codes = ecodes.ecodes
    chord = {codes["KEY_LEFTCTRL"], codes["KEY_B"]}

    def steps(run: InProcessRun) -> tuple:
        w = watch_run(run)
        base_held = guestlib.wait_for(
            lambda: (
                codes["KEY_ENTER"] in w["keyboard"].pressed
                and codes["BTN_RIGHT"] in w["mouse"].pressed
                and codes["BTN_EAST"] in w["pad"].pressed
            ),
            90.0,
        )
        assert base_held, f"the push held nothing: {w['keyboard'].keys_log()} {w['pad'].keys_log()}"
        game = subprocess.Popen(["sleep", "600"], env=dict(os.environ, SteamAppId="4242"))
        try:
            game_held = guestlib.wait_for(lambda: holds_everything(w), 60.0)
            during = {name: sorted(watcher.pressed) for name, watcher in w.items()}
        finally:
            game.kill()
            game.wait(10)
        back = guestlib.wait_for(
            lambda: (
                codes["KEY_ENTER"] in w["keyboard"].pressed
                and codes["BTN_RIGHT"] in w["mouse"].pressed
                and codes["BTN_EAST"] in w["pad"].pressed
                and not chord & w["keyboard"].pressed
            ),
            60.0,
        )
        stick_after = w["pad"].reader.axes.get(ecodes.ABS_X)
        return w, game, game_held, during, back, stick_after, stop_run(run, w)

    w, game, game_held, during, back, stick_after, err = run(steps)
    kb, mouse, pad = w["keyboard"].keys_log(), w["mouse"].keys_log(), w["pad"].keys_log()
    assert game_held, f"the game's profile held nothing: {kb} {mouse} {pad}\n{err[-2000:]}"
    assert back, f"not back on the base profile: {kb} {mouse} {pad}\n{err[-2000:]}"
    # each device: what the old profile held is released before the new one presses anything
    assert kb == [
        ("KEY_ENTER", 1),
        ("KEY_ENTER", 0),
        ("KEY_LEFTCTRL", 1),
        ("KEY_B", 1),
        ("KEY_B", 0),
        ("KEY_LEFTCTRL", 0),
        ("KEY_ENTER", 1),
        ("KEY_ENTER", 0),
    ], kb
    assert mouse == [("BTN_RIGHT", 1), ("BTN_RIGHT", 0), ("BTN_LEFT", 1), ("BTN_LEFT", 0)] + [
        ("BTN_RIGHT", 1),
        ("BTN_RIGHT", 0),
    ], mouse
    east = str(ecodes.BTN_EAST)  # the watcher logs a code with several names (B, EAST) by number
    assert pad == [(east, 1), (east, 0), ("BTN_SOUTH", 1), ("BTN_SOUTH", 0), (east, 1), (east, 0)], pad
    assert stick_after == 0, f"the stick stayed off centre after the game exited: ABS_X {stick_after}"
    assert run.returned, f"the run did not return after SIGTERM: {err[-2000:]}"
    leftover = {name: sorted(watcher.pressed) for name, watcher in w.items() if watcher.pressed}
    assert not leftover, f"after SIGTERM still pressed: {leftover}"
    said = [line for line in err.splitlines() if line.startswith("switched to profile")]
    label = f"Steam app 4242 (pid {game.pid}, sleep)"
    assert said == [
        f"switched to profile everything ({label} is running)",
        f"switched to profile {base} ({label} exited)",
    ], err[-2000:]
    return {"keyboard": kb, "mouse": mouse, "pad": pad, "during_game": during, "said": said}
