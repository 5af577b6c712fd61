"""Guest checks of the keyboard and mouse outputs, layers, ``profile use`` and rumble in a real kernel.

Run by tests/kernel/guest.py inside qemu (after checks_runtime.py: the name sorts after it, so
the older checks get the boot's time first); asserted on by tests/test_remap_kernel.py. As in
checks_runtime.py, the runtime is fed the pipeline's output (a predictions file) because the
software-emulated guest cannot run the pipeline in real time; everything after it is real: the
runtime's threads and pacing, the shipped profiles and the Mapper, the uinput keyboard, mouse and
pad, the control socket, SIGTERM. Expected values come from the same estimates through the
Mapper (``mapping.replay``) in the check's own process. The driver runs in the check's process
too (``run_driver``, what ``run`` calls; ``outputlib.InProcessRun``, ended by a real SIGTERM): a
Python start of ``run`` costs 20 to 60 s under emulation, and checks_runtime.py's SDL check
starts ``run`` as its own process, as a user does.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import guestlib
from checks_runtime import NO_DROP_LAG_MS, timeline
from evdev import InputDevice, ecodes, list_devices
from outputlib import InProcessRun

from neurotouch_hid.core.estimate import GestureEstimate, GestureType
from neurotouch_hid.targets.uinput.desktop import KEYBOARD_PHYS, MOUSE_PHYS
from neurotouch_hid.targets.uinput.gamepad import PHYS

HERE = Path(__file__).resolve().parent
TIMEOUT_S = 300
G = GestureType
#: Window length of the replayed estimates (us). 40 ms rather than the pipeline's 10: under
#: software emulation, with other guests on the same two cores, the runtime's thread cannot map
#: and write 100 windows a second and would drop data; the Mapper's timing (dwell, motion) is
#: on the estimates' clock, so longer windows test the same behaviour.
STEP_US = 40_000
#: The names these checks use for the key codes they read (evdev gives several names per code).
NAMES = {
    ecodes.ecodes[n]: n
    for n in (
        "KEY_SPACE",
        "KEY_TAB",
        "KEY_LEFTSHIFT",
        "KEY_ENTER",
        "KEY_ESC",
        "KEY_A",
        "KEY_B",
        "KEY_LEFTCTRL",
        "KEY_F9",
        "BTN_LEFT",
        "BTN_RIGHT",
        "BTN_SOUTH",
    )
}


def sequence(*steps: tuple[GestureType, float, float], lead_in_s: float = 1.0) -> list[GestureEstimate]:
    """Rest ``lead_in_s``, then per step (gesture, level mm, hold s): ramp up 0.1 s, hold, ramp
    down 0.1 s, rest 0.4 s; :data:`STEP_US` windows."""
    segments = [(lead_in_s, G.NONE, lambda f: 0.0)]
    for gesture, mm, hold_s in steps:
        segments += [
            (0.1, gesture, lambda f, mm=mm: mm * f),
            (hold_s, gesture, lambda f, mm=mm: mm),
            (0.1, gesture, lambda f, mm=mm: mm * (1 - f)),
            (0.4, G.NONE, lambda f: 0.0),
        ]
    return timeline(segments, STEP_US)


def _write_preds(folder: Path, estimates: list[GestureEstimate]) -> Path:
    from neurotouch_hid.core.dataset import write_predictions

    path = folder / "gestures.jsonl"
    write_predictions(path, estimates)
    return path


class Watcher:
    """Reads one of our devices in a thread: every (type, code, value) and its pressed keys."""

    def __init__(self, path: str):
        self.reader = guestlib.EventReader(path)
        self.events: list[tuple[int, int, int]] = []
        self.error: str | None = None
        self._stop = threading.Event()
        self.thread = threading.Thread(target=self._loop, daemon=True)
        self.thread.start()

    def _loop(self) -> None:
        seen = 0
        while not self._stop.is_set() and not self.reader.gone:
            self.reader.pump(timeout_s=0.2, until=lambda r, seen=seen: len(r.reports) > seen or self._stop.is_set())
            for report in self.reader.reports[seen:]:
                for event in report:
                    if event[0] == ecodes.EV_SYN and event[1] == ecodes.SYN_DROPPED:
                        self.error = "the reader lost events (SYN_DROPPED)"
                    self.events.append(event)
            seen = len(self.reader.reports)

    def total(self, code: int) -> int:
        return sum(v for t, c, v in self.events if t == ecodes.EV_REL and c == code)

    def keys_log(self) -> list[tuple[str, int]]:
        """Every key event as (evdev name, value), in order."""
        return [(NAMES.get(c, str(c)), v) for t, c, v in self.events if t == ecodes.EV_KEY]

    @property
    def pressed(self) -> set[int]:
        return set(self.reader.keys)

    def stop(self) -> None:
        self._stop.set()
        self.thread.join(10)
        self.reader.close()
        assert self.error is None, self.error


def _devices(phys: str) -> list[str]:
    found = []
    for path in list_devices():
        try:
            if InputDevice(path).phys == phys:
                found.append(path)
        except OSError:
            pass
    return found


def _expected(profile: str, estimates: list[GestureEstimate]):
    from neurotouch_hid.mapping.profile import load_profile
    from neurotouch_hid.mapping.replay import replay

    return replay(load_profile(profile), estimates)


def _run_in_process(
    profile: str, estimates: list[GestureEstimate], folder: Path
) -> tuple[dict[str, Watcher], object, dict]:
    """The runtime (paced, its threads) with the devices ``open_output`` makes for ``profile``;
    a watcher on each device before the run starts."""
    import contextlib

    from neurotouch_hid.engine.driver import DriverOptions, open_output, run_driver
    from neurotouch_hid.mapping.profile import load_profile

    preds = _write_preds(folder, estimates)
    with contextlib.ExitStack() as stack:
        outputs = open_output("gamepad", load_profile(profile), stack)
        (devices,) = outputs.targets  # the uinput pad, keyboard and mouse: one target
        guestlib.settle()
        props = {
            d.what: dict(
                guestlib.udev_properties(d.device_path),
                KEY_CODES=set(InputDevice(d.device_path).capabilities().get(ecodes.EV_KEY, [])),
            )
            for d in devices.devices
            if hasattr(d, "what")
        }
        watchers = {}
        for device in (devices.pad, devices.keyboard, devices.mouse):
            if device is not None:
                watchers["pad" if device is devices.pad else device.what] = Watcher(device.device_path)
        stats = run_driver(
            str(preds), profile, "gamepad", DriverOptions(outputs=[outputs], max_lag_us=int(NO_DROP_LAG_MS) * 1000)
        )
    time.sleep(0.3)
    for w in watchers.values():
        w.stop()
    return watchers, stats, props


def check_mouse_profile_moves_the_pointer() -> dict:
    """``run --profile mouse`` on a push up and to the right: the uinput mouse reports REL_X and
    REL_Y motion, exactly the counts the Mapper gives for the same estimates; a pinch clicks
    BTN_LEFT and releases it; a twist scrolls with hi-res and legacy wheel events; udev calls it a
    mouse; no pad and no keyboard (the profile uses neither)."""
    folder = Path(tempfile.mkdtemp(prefix="remap-mouse-"))
    estimates = sequence((G.PUSH, 6.0, 0.8), (G.PINCH, 4.0, 0.2), (G.TWIST_CCW, 6.0, 0.8))
    watchers, stats, props = _run_in_process("mouse", estimates, folder)
    assert set(watchers) == {"mouse"}, f"devices made: {sorted(watchers)}"
    mouse = watchers["mouse"]
    states = _expected("mouse", estimates)
    want = {
        name: sum(s.rel.get(name, 0) for s in states) for name in ("REL_X", "REL_Y", "REL_WHEEL", "REL_WHEEL_HI_RES")
    }
    got = {name: mouse.total(ecodes.ecodes[name]) for name in want}
    assert stats.dropped_items == 0, f"the runtime dropped {stats.dropped_items} items"
    assert got == want, f"read back {got}, the Mapper gives {want}"
    assert got["REL_X"] > 50 and got["REL_Y"] < -10, got  # right and up (screen y grows downwards)
    assert got["REL_WHEEL"] >= 1 and got["REL_WHEEL_HI_RES"] >= 120, got
    clicks = mouse.keys_log()
    assert clicks == [("BTN_LEFT", 1), ("BTN_LEFT", 0)], clicks
    assert not mouse.pressed
    assert props["mouse"].get("ID_INPUT_MOUSE") == "1", props["mouse"]
    assert props["mouse"]["KEY_CODES"] == {ecodes.BTN_LEFT, ecodes.BTN_RIGHT}, props["mouse"]["KEY_CODES"]
    return {
        "rel": got,
        "clicks": clicks,
        "ID_INPUT_MOUSE": props["mouse"].get("ID_INPUT_MOUSE"),
        "windows": stats.windows,
    }


def check_switch_access_presses_and_releases_keys() -> dict:
    """``run --profile switch-access``: each held gesture presses its key after the dwell and
    releases it (push Space, twist_cw Tab, twist_ccw Shift+Tab, pinch Enter, zoom Escape); a short
    brush fires nothing; the key log is the Mapper's; udev calls the device a keyboard."""
    folder = Path(tempfile.mkdtemp(prefix="remap-switch-"))
    estimates = sequence(
        (G.PUSH, 4.0, 0.1),  # shorter than the dwell: nothing
        (G.PUSH, 4.0, 0.6),
        (G.TWIST_CW, 4.0, 0.6),
        (G.TWIST_CCW, 4.0, 0.6),
        (G.PINCH, 4.0, 0.6),
        (G.ZOOM, 4.0, 0.6),
    )
    watchers, stats, props = _run_in_process("switch-access", estimates, folder)
    assert set(watchers) == {"keyboard"}, f"devices made: {sorted(watchers)}"
    keyboard = watchers["keyboard"]
    log = keyboard.keys_log()
    want = [
        ("KEY_SPACE", 1),
        ("KEY_SPACE", 0),
        ("KEY_TAB", 1),
        ("KEY_TAB", 0),
        ("KEY_LEFTSHIFT", 1),
        ("KEY_TAB", 1),
        ("KEY_TAB", 0),
        ("KEY_LEFTSHIFT", 0),
        ("KEY_ENTER", 1),
        ("KEY_ENTER", 0),
        ("KEY_ESC", 1),
        ("KEY_ESC", 0),
    ]
    assert stats.dropped_items == 0, f"the runtime dropped {stats.dropped_items} items"
    assert log == want, f"key log {log}"
    assert not keyboard.pressed
    assert props["keyboard"].get("ID_INPUT_KEYBOARD") == "1", props["keyboard"]
    # the keys of the shipped profiles and udev's keyboard block (1..31), nothing else, no SysRq
    shipped = {ecodes.ecodes[k] for k in ("KEY_SPACE", "KEY_TAB", "KEY_LEFTSHIFT", "KEY_ENTER", "KEY_ESC")}
    assert props["keyboard"]["KEY_CODES"] == shipped | set(range(1, 32)), sorted(props["keyboard"]["KEY_CODES"])
    return {"keys": log, "ID_INPUT_KEYBOARD": props["keyboard"].get("ID_INPUT_KEYBOARD"), "windows": stats.windows}


LAYERED = """\
description: guest check of layers and profile use
layers:
  alt: {input: pinch, mode: toggle, press_mm: 2.0, release_mm: 1.0}
mappings:
  latch: {input: zoom, output: KEY_A, mode: toggle, press_mm: 2.0, release_mm: 1.0}
  click: {input: zoom, output: BTN_RIGHT, mode: toggle, press_mm: 2.0, release_mm: 1.0}
  enter: {input: push_intensity, output: KEY_ENTER, layer: alt, press_mm: 2.0, release_mm: 1.0}
  fire: {input: push_intensity, output: BTN_SOUTH, layer: alt, press_mm: 2.0, release_mm: 1.0}
"""

#: The profile switched to mid-push: the same push then holds something on every device.
EVERYTHING = """\
description: guest check - one push holds something on every device
mappings:
  key: {input: push_intensity, output: KEY_LEFTCTRL+KEY_B, mode: long_press, dwell_ms: 200}
  button: {input: push_intensity, output: BTN_LEFT}
  pad: {input: push_intensity, output: A}
  stick: {input: push, output: left_stick}
  pointer: {input: push, output: pointer}
"""


def watch_run(run: InProcessRun) -> dict[str, Watcher]:
    """A watcher on each device a gamepad run (pad, keyboard, mouse) makes, once all three are
    there (in ``run``'s steps thread); AssertionError when the run ended first."""
    before = {phys: set(_devices(phys)) for phys in (PHYS, KEYBOARD_PHYS, MOUSE_PHYS)}
    new = lambda phys: sorted(set(_devices(phys)) - before[phys])  # noqa: E731
    found = guestlib.wait_for(
        lambda: (new(PHYS) and new(KEYBOARD_PHYS) and new(MOUSE_PHYS)) or not run.alive(), 150.0, 0.05
    )
    assert found and run.alive(), f"the devices did not appear: {run.said[-5:] if not run.alive() else 'timeout'}"
    return {
        "pad": Watcher(new(PHYS)[0]),
        "keyboard": Watcher(new(KEYBOARD_PHYS)[0]),
        "mouse": Watcher(new(MOUSE_PHYS)[0]),
    }


def holds_everything(w: dict[str, Watcher]) -> bool:
    """What EVERYTHING holds during a push: the Ctrl+B chord, BTN_LEFT, the pad's A, the stick right."""
    codes = ecodes.ecodes
    return (
        {codes["KEY_LEFTCTRL"], codes["KEY_B"]} <= w["keyboard"].pressed
        and codes["BTN_LEFT"] in w["mouse"].pressed
        and codes["BTN_SOUTH"] in w["pad"].pressed
        and w["pad"].reader.axes.get(ecodes.ABS_X, 0) > 0
    )


def stop_run(run: InProcessRun, w: dict[str, Watcher]) -> str:
    """SIGTERM the run, wait for it and for its devices to go, stop the watchers; what it said
    (the lines ``run`` prints on stderr)."""
    run.stop()
    guestlib.wait_for(lambda: all(x.reader.gone for x in w.values()), 10.0)
    time.sleep(0.2)
    for watcher in w.values():
        watcher.stop()
    return "\n".join(run.said)


def check_layer_switch_profile_use_and_sigterm_leave_nothing_pressed() -> dict:
    """``neurotouch-hid run``: a zoom latches KEY_A and BTN_RIGHT (toggles) in the base layer; a
    pinch switches to layer ``alt``: both are released before anything of ``alt`` is pressed. In
    ``alt`` a held push presses KEY_ENTER and the pad's A; ``profile use`` (the control socket,
    as the CLI sends it) switches to a profile file mid-push: both are released at once, then the
    new profile (in the user's folder at start, so the keyboard offers its keys: the same device)
    holds a Ctrl+B chord, BTN_LEFT, A and the stick with the same push. SIGTERM:
    exit 0, nothing pressed on any device, the stick centred, every device gone."""
    from neurotouch_hid.service.control import SOCKET_NAME, request_use

    folder = Path(tempfile.mkdtemp(prefix="remap-layers-"))
    runtime_dir = folder / "xdg"
    runtime_dir.mkdir(mode=0o700)
    env = {"XDG_RUNTIME_DIR": str(runtime_dir), "XDG_CONFIG_HOME": str(folder / "config")}
    profile, everything = folder / "layered.yaml", folder / "config" / "neurotouch-hid" / "profiles" / "everything.yaml"
    everything.parent.mkdir(parents=True)
    profile.write_text(LAYERED)
    everything.write_text(EVERYTHING)
    preds = _write_preds(folder, sequence((G.ZOOM, 4.0, 0.3), (G.PINCH, 4.0, 0.3), (G.PUSH, 4.0, 120.0), lead_in_s=2.0))
    run = InProcessRun(preds, profile, "gamepad", env=env)
    codes = ecodes.ecodes

    def steps(run: InProcessRun) -> tuple:
        w = watch_run(run)
        # the latch lasts well under a second of a slow guest: judged from the event logs, not polled
        held = guestlib.wait_for(
            lambda: codes["KEY_ENTER"] in w["keyboard"].pressed and codes["BTN_SOUTH"] in w["pad"].pressed, 90.0
        )
        assert held, f"the push in layer alt pressed nothing: {w['keyboard'].keys_log()} {w['pad'].keys_log()}"
        before_use = {"keyboard": w["keyboard"].keys_log(), "mouse": w["mouse"].keys_log()}
        answer = request_use(str(everything), path=runtime_dir / SOCKET_NAME)  # what `profile use FILE` sends
        all_held = guestlib.wait_for(lambda: holds_everything(w), 30.0)
        return w, before_use, answer, all_held, stop_run(run, w)

    w, before_use, answer, all_held, err = run(steps)
    kb_log, pad_log = w["keyboard"].keys_log(), w["pad"].keys_log()
    # the zoom latched KEY_A and BTN_RIGHT; the layer switch released both before alt pressed KEY_ENTER
    assert before_use == {
        "keyboard": [("KEY_A", 1), ("KEY_A", 0), ("KEY_ENTER", 1)],
        "mouse": [("BTN_RIGHT", 1), ("BTN_RIGHT", 0)],
    }, before_use
    # profile use released KEY_ENTER and A before the new profile pressed anything (A again, the chord)
    assert kb_log[3:6] == [("KEY_ENTER", 0), ("KEY_LEFTCTRL", 1), ("KEY_B", 1)], kb_log
    assert pad_log[:3] == [("BTN_SOUTH", 1), ("BTN_SOUTH", 0), ("BTN_SOUTH", 1)], pad_log
    assert all_held, (
        f"the new profile did not hold something on every device: {kb_log} {w['mouse'].keys_log()} {pad_log}"
    )
    assert run.returned, f"the run did not return after SIGTERM: {err[-2000:]}"
    leftover = {name: sorted(watcher.pressed) for name, watcher in w.items() if watcher.pressed}
    assert not leftover, f"after SIGTERM still pressed: {leftover}"
    assert w["pad"].reader.axes.get(ecodes.ABS_X) == 0, w["pad"].reader.axes
    assert kb_log[-2:] == [("KEY_B", 0), ("KEY_LEFTCTRL", 0)], kb_log  # the chord's modifier goes up last
    gone = [p for phys in (PHYS, KEYBOARD_PHYS, MOUSE_PHYS) for p in _devices(phys)]
    assert not gone, f"devices outlived the process: {gone}"
    return {
        "keyboard": kb_log,
        "mouse": w["mouse"].keys_log(),
        "pad": pad_log,
        "profile_use": answer,
        "returned": run.returned,
        "pointer_x": w["mouse"].total(ecodes.REL_X),
    }


#: A profile switched to by path whose key (F9) no profile known at start uses.
NEW_KEY = """\
description: guest check - a key the keyboard does not offer yet
mappings:
  key: {input: push_intensity, output: KEY_F9, press_mm: 2.0, release_mm: 1.0}
"""


def _offers_key(path: str, code: int) -> bool:
    """Whether the input device at ``path`` offers key ``code`` (False while it cannot be opened)."""
    try:
        return code in InputDevice(path).capabilities().get(ecodes.EV_KEY, [])
    except OSError:
        return False


def check_profile_use_of_new_keys_makes_the_keyboard_again() -> dict:
    """``profile use`` of a profile file whose key the keyboard does not offer (KEY_F9): KEY_ENTER,
    held by the old profile, is released on the old keyboard, which goes; a new keyboard offering
    F9 (and not SysRq) comes, F9 is held on it; SIGTERM releases it. The pad stays the same device."""
    from neurotouch_hid.service.control import SOCKET_NAME, request_use

    folder = Path(tempfile.mkdtemp(prefix="remap-newkey-"))
    runtime_dir = folder / "xdg"
    runtime_dir.mkdir(mode=0o700)
    env = {"XDG_RUNTIME_DIR": str(runtime_dir), "XDG_CONFIG_HOME": str(folder / "config")}
    profile, new_key = folder / "layered.yaml", folder / "new-key.yaml"
    profile.write_text(LAYERED)
    new_key.write_text(NEW_KEY)
    preds = _write_preds(folder, sequence((G.PINCH, 4.0, 0.3), (G.PUSH, 4.0, 120.0), lead_in_s=2.0))
    run = InProcessRun(preds, profile, "gamepad", env=env)
    codes = ecodes.ecodes

    def steps(run: InProcessRun) -> tuple:
        w = watch_run(run)
        old_keyboard = _devices(KEYBOARD_PHYS)
        held = guestlib.wait_for(lambda: codes["KEY_ENTER"] in w["keyboard"].pressed, 90.0)
        assert held, f"the push in layer alt pressed nothing: {w['keyboard'].keys_log()}"
        answer = request_use(str(new_key), path=runtime_dir / SOCKET_NAME)
        # the new keyboard may get the old one's /dev/input/eventN: told apart by the old one's
        # reader seeing it go and by the new one offering F9
        remade = guestlib.wait_for(
            lambda: (
                w["keyboard"].reader.gone
                and _devices(KEYBOARD_PHYS)
                and _offers_key(_devices(KEYBOARD_PHYS)[0], codes["KEY_F9"])
            ),
            30.0,
        )
        assert remade, f"no new keyboard: {_devices(KEYBOARD_PHYS)} (was {old_keyboard}, answer {answer!r})"
        new_path = _devices(KEYBOARD_PHYS)[0]
        offered = set(InputDevice(new_path).capabilities().get(ecodes.EV_KEY, []))
        new = Watcher(new_path)
        f9_held = guestlib.wait_for(lambda: codes["KEY_F9"] in new.pressed, 30.0)
        return w, answer, offered, new, f9_held, stop_run(run, {**w, "new": new})

    w, answer, offered, new, f9_held, err = run(steps)
    old_log = w["keyboard"].keys_log()
    assert old_log[-1] == ("KEY_ENTER", 0) and w["keyboard"].reader.gone, old_log
    assert codes["KEY_F9"] in offered and codes["KEY_ENTER"] in offered and codes["KEY_SYSRQ"] not in offered
    assert f9_held, f"F9 not held on the new keyboard: {new.keys_log()}"
    assert run.returned, f"the run did not return after SIGTERM: {err[-2000:]}"
    assert not new.pressed and new.keys_log()[-1] == ("KEY_F9", 0), new.keys_log()
    return {
        "profile_use": answer,
        "old_keyboard": old_log,
        "new_keyboard": new.keys_log(),
        "returned": run.returned,
    }


def check_sdl_sees_a_gamecontroller_with_rumble() -> dict:
    """SDL2 opens the virtual pad (made as ``run --output gamepad`` makes it, in this process) as a
    GameController, says it has rumble and plays one: the pad, read by the run's one feedback path
    (TargetOutputs), answers the effect upload at once, reports the upload and the play
    (``on_effect``) and returns the play as a rumble the run says and forwards."""
    from neurotouch_hid.targets import TargetOutputs
    from neurotouch_hid.targets.uinput.gamepad import GamepadIdentity, VirtualGamepad

    said: list[str] = []
    sdl_env = dict(
        os.environ,
        SDL_VIDEODRIVER="dummy",
        SDL_AUDIODRIVER="dummy",
        PYGAME_HIDE_SUPPORT_PROMPT="1",
        PYTHONPATH=os.pathsep.join(sys.path),
    )
    told: list[str] = []
    forwarded: list = []
    pad = VirtualGamepad(GamepadIdentity(), on_effect=said.append)
    with TargetOutputs([pad], say=told.append, forward=forwarded.append):
        guestlib.settle()
        probe = subprocess.run(
            [sys.executable, str(HERE / "sdl_probe.py"), "--rumble", "120"],
            capture_output=True,
            text=True,
            env=sdl_env,
            timeout=250,
        )
        effects = pad.effects
    lines = [json.loads(line) for line in probe.stdout.splitlines() if line.startswith("{")]
    done = next((line for line in lines if line.get("done")), None)
    assert done is not None, f"sdl_probe gave no result: {probe.stdout[-1000:]} {probe.stderr[-2000:]}"
    assert done.get("error") is None, done
    assert done["is_controller"], done
    assert done["rumble"], f"SDL could not rumble: {done}"
    assert any(line.startswith("uploaded effect") and "FF_RUMBLE" in line for line in said), said
    assert any(line.startswith("play effect") for line in said), said
    assert any(f.kind == "rumble" and f.strong > 0 and f.source == "uinput pad" for f in forwarded), forwarded
    assert any(line.startswith("rumble (the gel has no motor): strong") for line in told), told
    return {**done, "pad_said": said[:6], "requests_answered": effects, "run_said": told[:4]}
