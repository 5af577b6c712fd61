"""Guest checks of ``neurotouch-hid run --output gamepad`` (the runtime) in a real kernel.

Run by tests/kernel/guest.py inside qemu; asserted on by tests/test_runtime_kernel.py.

The guest is software-emulated (no KVM), roughly a hundred times slower than the host: the gesture
pipeline (numba tracker, OpenCV) cannot process even a second of events within a check's time
there. These checks therefore feed the runtime a gesture sequence as the pipeline's own output, a
predictions file (docs/dataset.md "Predictions", ``--source FILE.jsonl``): everything after the
pipeline is real -- the runtime's threads, pacing and shutdown, the profile and Mapper, the uinput
device -- and the host tests (tests/test_runtime.py) run the same runtime with the pipeline on
simulated recordings. Expected states come from the same estimates through the driver's
``jsonl`` output (``run --output jsonl --fast``), in the check's own process.
"""

from __future__ import annotations

import json
import math
import signal
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from pathlib import Path

import guestlib
import numpy as np
from evdev import ecodes

from neurotouch_hid.core.controller import AXES, BUTTONS
from neurotouch_hid.core.estimate import GestureEstimate, GestureType
from neurotouch_hid.targets.uinput.gamepad import PHYS

REPO = Path(__file__).resolve().parent.parent.parent
TIMEOUT_S = 300
#: The estimates' spacing (us): 40 ms, not the paper's 10 ms windows; the runtime maps a window in
#: ~45 ms here (~0.5 ms on the host), so a 10 ms sequence ran 4-5 times slower than its own time.
STEP_US = 40_000

#: A profile using every kind of output: a stick, an axis, both triggers and a button.
PROFILE = """\
description: guest check of neurotouch-hid run
mappings:
  push: {input: push, output: left_stick, deadzone_mm: 0.5, saturation_mm: 6.0}
  twist: {input: twist, output: ABS_RX, deadzone_mm: 0.5, saturation_mm: 5.0}
  zoom: {input: zoom, output: ABS_RZ, deadzone_mm: 0.3, saturation_mm: 4.0}
  pinch: {input: pinch, output: ABS_Z, deadzone_mm: 0.3, saturation_mm: 4.0}
  fire: {input: push_intensity, output: BTN_SOUTH, press_mm: 2.0, release_mm: 1.0}
"""


def _gesture(t_us: int, gesture: GestureType, level_mm: float) -> GestureEstimate:
    if level_mm <= 0:
        return GestureEstimate(t_us=t_us)
    kw = {}
    if gesture is GestureType.PUSH:  # to the right and a little up (user frame)
        kw["translation_mm"] = level_mm * np.array([math.cos(0.3), math.sin(0.3)])
    elif gesture in (GestureType.TWIST_CW, GestureType.TWIST_CCW):
        kw["rotation_rad"] = (0.1 if gesture is GestureType.TWIST_CCW else -0.1) * level_mm
    return GestureEstimate(t_us=t_us, gesture=gesture, resting=False, intensity_mm=level_mm, **kw)


ALL_GESTURES = (GestureType.PUSH, GestureType.TWIST_CCW, GestureType.ZOOM, GestureType.PINCH, GestureType.TWIST_CW)


def gesture_sequence(
    hold_s: float = 0.4,
    lead_in_s: float = 0.5,
    gestures: tuple[GestureType, ...] = ALL_GESTURES,
    last_hold_s: float | None = None,
) -> list[GestureEstimate]:
    """Rest, then each gesture: ramp up to 6 mm in 0.3 s, hold (the last one ``last_hold_s`` if
    given), ramp down in 0.2 s, rest 0.3 s."""
    segments: list[tuple[float, GestureType, Callable[[float], float]]] = [(lead_in_s, GestureType.NONE, lambda f: 0.0)]
    for i, gesture in enumerate(gestures):
        hold = last_hold_s if last_hold_s is not None and i == len(gestures) - 1 else hold_s
        segments += [
            (0.3, gesture, lambda f: 6.0 * f),
            (hold, gesture, lambda f: 6.0),
            (0.2, gesture, lambda f: 6.0 * (1 - f)),
            (0.3, GestureType.NONE, lambda f: 0.0),
        ]
    return timeline(segments)


def timeline(
    segments: list[tuple[float, GestureType, Callable[[float], float]]], step_us: int = STEP_US
) -> list[GestureEstimate]:
    """One estimate per ``step_us`` window from t = 1 s through ``segments`` (seconds, gesture,
    level(f) mm with f the fraction of the segment done, in (0, 1])."""
    out: list[GestureEstimate] = []
    t = 1_000_000
    for seconds, gesture, level in segments:
        n = max(1, int(round(seconds * 1e6 / step_us)))
        for k in range(n):
            out.append(_gesture(t, gesture, level((k + 1) / n)))
            t += step_us
    return out


def _write(folder: Path, estimates: list[GestureEstimate], profile_text: str = PROFILE) -> tuple[Path, Path]:
    from neurotouch_hid.core.dataset import write_predictions

    preds = folder / "gestures.jsonl"
    write_predictions(preds, estimates)
    profile = folder / "guestcheck.yaml"
    profile.write_text(profile_text)
    return preds, profile


#: ``run``'s allowed lag in these checks (ms): they compare every state the pad shows with the
#: profile's, so the run must not drop estimates when the emulated guest is starved (with the
#: default 200 ms, on a loaded host, the pad showed 77 of 101 states).
NO_DROP_LAG_MS = "600000"


def _start_run_on_pad(preds: Path, profile: Path) -> guestlib.ForkedCli:
    """``neurotouch-hid run --source PREDS --profile PROFILE --output gamepad`` in a process of its
    own (the CLI's ``main`` in a forked child: no Python start), lagging rather than dropping
    (NO_DROP_LAG_MS)."""
    args = ("run", "--source", str(preds), "--profile", str(profile), "--output", "gamepad")
    return guestlib.ForkedCli(*args, "--max-lag-ms", NO_DROP_LAG_MS)


def _state_key(axes: dict[str, int], buttons: dict[str, bool]) -> tuple:
    return tuple(int(axes[n]) for n in AXES) + tuple(bool(buttons[n]) for n in BUTTONS)


NEUTRAL = tuple(AXES[n][2] for n in AXES) + (False,) * len(BUTTONS)


def _changes(keys: list[tuple]) -> list[tuple]:
    """Consecutive duplicates removed, leading neutral states dropped."""
    out: list[tuple] = []
    for k in keys:
        if (out and out[-1] == k) or (not out and k == NEUTRAL):
            continue
        out.append(k)
    return out


def _expected_lines(preds: Path, profile: Path, folder: Path) -> list[dict]:
    """The state lines the same estimates give through ``run --output jsonl --fast`` (into
    ``folder/expected.jsonl``): the driver's own :func:`run_driver`, in this process (a second
    Python start costs tens of seconds here)."""
    from neurotouch_hid.engine.driver import DriverOptions, run_driver

    out = folder / "expected.jsonl"
    run_driver(str(preds), profile, "jsonl", DriverOptions(fast=True, out=out))
    return [json.loads(line) for line in out.read_text().splitlines() if line.strip()]


def _expected_states(preds: Path, profile: Path, folder: Path) -> list[tuple]:
    """:func:`_expected_lines` as state keys."""
    return [_state_key(d["axes"], d["buttons"]) for d in _expected_lines(preds, profile, folder)]


class PadWatcher:
    """Reads a gamepad's event node in a thread like a game; the full state after every report."""

    def __init__(self, path: str):
        self.reader = guestlib.EventReader(path)
        self._codes_axes = [(n, ecodes.ecodes[n]) for n in AXES]
        self._codes_keys = [(n, ecodes.ecodes[n]) for n in BUTTONS]
        self.states: list[tuple] = [self._snapshot(self.reader.axes, self.reader.keys)]
        self.error: str | None = None
        self._stop = threading.Event()
        self.thread = threading.Thread(target=self._loop, daemon=True)
        self.thread.start()

    def _snapshot(self, axes: dict[int, int], keys: set[int]) -> tuple:
        return _state_key({n: axes.get(c, 0) for n, c in self._codes_axes}, {n: c in keys for n, c in self._codes_keys})

    def _loop(self) -> None:
        seen = 0
        axes, keys = dict(self.reader.axes), set(self.reader.keys)
        while not self._stop.is_set() and not self.reader.gone:
            self.reader.pump(timeout_s=0.2, until=lambda r, seen=seen: len(r.reports) > seen or self._stop.is_set())
            for report in self.reader.reports[seen:]:
                for etype, code, value in report:
                    if etype == ecodes.EV_ABS:
                        axes[code] = value
                    elif etype == ecodes.EV_KEY:
                        (keys.add if value else keys.discard)(code)
                    elif etype == ecodes.EV_SYN and code == ecodes.SYN_DROPPED:
                        self.error = "the reader lost events (SYN_DROPPED)"
                self.states.append(self._snapshot(axes, keys))
            seen = len(self.reader.reports)

    def stop(self) -> None:
        self._stop.set()
        self.thread.join(10)
        self.reader.close()
        assert self.error is None, self.error


def _our_devices() -> list[str]:
    from evdev import InputDevice, list_devices

    found = []
    for path in list_devices():
        try:
            if InputDevice(path).phys == PHYS:
                found.append(path)
        except OSError:
            pass
    return found


def check_run_gamepad_matches_the_profile() -> dict:
    """The runtime (paced, real threads) drives the uinput pad; what evdev reads back, state by
    state, is what the same estimates give through ``--output jsonl``; the pad ends neutral."""
    from neurotouch_hid.engine.driver import DriverOptions, run_driver
    from neurotouch_hid.mapping.profile import load_profile
    from neurotouch_hid.targets import TargetOutputs
    from neurotouch_hid.targets.uinput.gamepad import GamepadIdentity, VirtualGamepad

    folder = Path(tempfile.mkdtemp(prefix="runtime-check-"))
    preds, profile_path = _write(folder, gesture_sequence())
    expected = _changes(_expected_states(preds, profile_path, folder))
    assert len(expected) > 20, f"the sequence moves the pad too little: {len(expected)} states"
    dev = load_profile(profile_path).device
    with VirtualGamepad(
        GamepadIdentity(name=dev.name, vendor=dev.vendor, product=dev.product, version=dev.version)
    ) as pad:
        guestlib.settle()
        props = guestlib.udev_properties(pad.device_path)
        watcher = PadWatcher(pad.device_path)
        with TargetOutputs([pad]) as outputs:  # the run's one output path, as run_driver's own
            stats = run_driver(
                str(preds),
                profile_path,
                "gamepad",
                DriverOptions(outputs=[outputs], max_lag_us=int(NO_DROP_LAG_MS) * 1000),
            )
        guestlib.wait_for(lambda: watcher.states[-1] == NEUTRAL, 5.0)
        watcher.stop()
    got = _changes(watcher.states)
    assert props.get("ID_INPUT_JOYSTICK") == "1", f"udev does not class the pad as a joystick: {props}"
    assert stats.dropped_items == 0, f"the runtime dropped {stats.dropped_items} items: the guest is too slow"
    first_diff = next((i for i, (a, b) in enumerate(zip(got, expected)) if a != b), None)
    assert got == expected, (
        f"read back {len(got)} states, expected {len(expected)}; first difference at "
        f"{first_diff}: {got[first_diff] if first_diff is not None else None} vs "
        f"{expected[first_diff] if first_diff is not None else None}"
    )
    assert watcher.states[-1] == NEUTRAL
    pressed = sum(1 for s in got if any(s[len(AXES) :]))
    return {
        "states": len(got),
        "with_button": pressed,
        "windows": stats.windows,
        "latency_p99_us": round(stats.latency.percentile_us(99)),
        "ID_INPUT_JOYSTICK": props.get("ID_INPUT_JOYSTICK"),
    }


#: PROFILE plus push mappings onto the other axes and a second button, so that one held push shows
#: a value on every output SDL reads (sticks, both triggers at part deflection, A and START), and a
#: device name of the profile's own with the Xbox 360 ids.
SDL_PROFILE = (
    PROFILE
    + """\
  push_rx: {input: push_x, output: ABS_RX, deadzone_mm: 0.3, saturation_mm: 8.0}
  push_ry: {input: push_y, output: ABS_RY, deadzone_mm: 0.3, saturation_mm: 4.0}
  push_lt: {input: push_intensity, output: ABS_Z, deadzone_mm: 0.3, saturation_mm: 9.0}
  push_rt: {input: push_intensity, output: ABS_RZ, deadzone_mm: 0.3, saturation_mm: 12.0}
  start: {input: push_intensity, output: BTN_START, press_mm: 4.0, release_mm: 3.0}
device: {name: NeuroTouch guest check pad, vendor: 0x045e, product: 0x028e, version: 0x0114}
"""
)
#: SDL GameController axis (sdl_probe.py --watch names) of each evdev axis, Xbox 360 layout.
SDL_AXES = {
    "ABS_X": "leftx",
    "ABS_Y": "lefty",
    "ABS_RX": "rightx",
    "ABS_RY": "righty",
    "ABS_Z": "triggerleft",
    "ABS_RZ": "triggerright",
}
#: SDL GameController button of each evdev button the SDL check's profile drives.
SDL_BUTTONS = {"BTN_SOUTH": "a", "BTN_START": "start"}
_AXIS_INDEX = {name: i for i, name in enumerate(AXES)}
_BUTTON_INDEX = {name: len(AXES) + i for i, name in enumerate(BUTTONS)}


def _sdl_view(key: tuple) -> tuple:
    """What SDL should read for an evdev state key: the six analogue axes, A, START, and whether
    any other button or d-pad direction is pressed (the check's profile drives none)."""
    others = (
        any(key[i] for n, i in _BUTTON_INDEX.items() if n not in SDL_BUTTONS)
        or key[_AXIS_INDEX["ABS_HAT0X"]] != 0
        or key[_AXIS_INDEX["ABS_HAT0Y"]] != 0
    )
    return (
        tuple(key[_AXIS_INDEX[n]] for n in SDL_AXES)
        + tuple(bool(key[_BUTTON_INDEX[n]]) for n in SDL_BUTTONS)
        + (bool(others),)
    )


#: SDL ignores an axis until its first move of more than this (SDL_joystick.c, SDL_PrivateJoystickAxis:
#: "don't send motion until there's real activity on this axis"), in SDL's raw -32768..32767 units.
SDL_MAX_ALLOWED_JITTER = 32767 // 80


def _sdl_raw(name: str, value: int) -> int:
    """An evdev axis value in SDL's joystick units: a -32768..32767 stick as it is, a 0..255
    trigger scaled onto -32768..32767 (SDL_sysjoystick.c AxisCorrect: 65535 / 255 = 257 per step)."""
    return 257 * value - 32768 if name in ("ABS_Z", "ABS_RZ") else value


def _sdl_expected(keys: list[tuple]) -> list[tuple]:
    """What SDL reads (:func:`_sdl_view` layout) after each of ``keys`` (one evdev report each,
    starting from a neutral pad SDL has opened): the state, except that an axis stays at its
    neutral value until its first move of more than SDL_MAX_ALLOWED_JITTER. (SDL's other rule for
    an axis at rest at its minimum, a trigger, whose first new value is within a quarter of the
    centre, is not modelled: an AssertionError says when a sequence reaches it.)"""
    neutral = _sdl_view(NEUTRAL)
    moved: set[str] = set()
    seen: set[str] = set()
    out = [neutral]
    for key in keys:
        view = list(_sdl_view(key))
        for i, name in enumerate(SDL_AXES):
            raw = _sdl_raw(name, view[i])
            if name not in seen and view[i] != neutral[i]:
                seen.add(name)
                assert not (
                    raw != _sdl_raw(name, neutral[i])
                    and neutral[i] == 0
                    and name in ("ABS_Z", "ABS_RZ")
                    and abs(raw) < 32767 // 4
                ), f"{name} first moves to {view[i]}: SDL's initial-value rule"
            if abs(raw - _sdl_raw(name, neutral[i])) > SDL_MAX_ALLOWED_JITTER:
                moved.add(name)
            if name not in moved:
                view[i] = neutral[i]
        out.append(tuple(view))
    return out


def _from_sdl(values: dict) -> tuple:
    """An SDL GameController reading back in evdev units (the :func:`_sdl_view` layout).

    SDL maps a -32768..32767 stick 1:1 and a 0..255 trigger onto 0..32767 (SDL_joystick.c
    AxisCorrect, then SDL_gamecontroller.c's trigger range): rounding ``value * 255 / 32767``
    gives the evdev trigger value back exactly."""
    axes = tuple(round(values[s] * 255 / 32767) if n in ("ABS_Z", "ABS_RZ") else values[s] for n, s in SDL_AXES.items())
    others = any(v for name, v in values.items() if name not in SDL_AXES.values() and name not in SDL_BUTTONS.values())
    return axes + tuple(bool(values[s]) for s in SDL_BUTTONS.values()) + (others,)


def _first_not_in_order(samples: list[tuple], expected: list[tuple]) -> int | None:
    """Index of the first of ``samples`` that does not follow, in ``expected``, the ones before it
    (a sample may repeat the expected state the previous one matched), or None: the samples are
    a subsequence of the expected states, as a reader polling now and then sees them."""
    j = 0
    for i, sample in enumerate(samples):
        while j < len(expected) and expected[j] != sample:
            j += 1
        if j == len(expected):
            return i
    return None


class ProbeLines:
    """Reads ``sdl_probe.py --watch``'s JSON lines in a thread."""

    def __init__(self, proc: subprocess.Popen):
        self.proc = proc
        self.lines: list[dict] = []
        self.thread = threading.Thread(target=self._loop, daemon=True)
        self.thread.start()

    def _loop(self) -> None:
        for line in self.proc.stdout:
            if line.startswith("{"):
                self.lines.append(json.loads(line))

    def first(self, key: str) -> dict | None:
        return next((d for d in self.lines if key in d), None)

    def samples(self) -> list[dict]:
        return [d for d in list(self.lines) if "v" in d]

    def samples_raw(self) -> list[dict]:
        """``--joystick``'s samples (their ``axes``, ``buttons``, ``hats``)."""
        return [d for d in list(self.lines) if "axes" in d and "t" in d]


def check_sdl_reads_run_like_the_profile() -> dict:
    """A game's view of ``neurotouch-hid run --output gamepad``: SDL2 (pygame), started beside the
    run, sees the device the run creates appear as a GameController with the profile's USB ids,
    and what it reads while the run replays a sequence (zoom, twist, then a push held with A and
    START pressed and every axis deflected, until SIGTERM) is, sample by sample and in order, one
    of the states the same sequence gives through ``--output jsonl``; evdev at the same time
    reads exactly those states. The run is a process of its own (the CLI's main, forked): SIGTERM
    in the held push (A and START down, every axis off centre) ends it with exit code 0, evdev
    reads everything released and centred, and the device goes with the process."""
    from neurotouch_hid.core.dataset import write_predictions
    from neurotouch_hid.mapping.profile import load_profile

    folder = Path(tempfile.mkdtemp(prefix="runtime-sdl-"))
    estimates = gesture_sequence(
        hold_s=0.4,
        lead_in_s=3.0,
        last_hold_s=90.0,  # SIGTERM ends it as soon as both readers see it: long only when starved
        gestures=(GestureType.ZOOM, GestureType.TWIST_CCW, GestureType.PUSH),
    )
    preds, profile_path = _write(folder, estimates, SDL_PROFILE)
    hold_t = next(e.t_us for e in estimates if e.gesture is GestureType.PUSH and e.intensity_mm == 6.0)
    env = guestlib.sdl_env()
    probe = subprocess.Popen(
        [sys.executable, str(Path(__file__).resolve().parent / "sdl_probe.py"), "--watch", "200"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
    )
    probe_lines = ProbeLines(probe)
    dev = load_profile(profile_path).device
    before = set(_our_devices())
    run = watcher = None
    timings: dict = {}
    try:
        ready = guestlib.wait_for(
            lambda: probe_lines.first("ready") or probe_lines.first("done") or probe.poll() is not None, 150.0
        )
        assert isinstance(ready, dict) and ready.get("ready"), (
            f"SDL did not start: {probe_lines.lines} {probe.stderr.read()[-2000:] if probe.poll() is not None else ''}"
        )
        # the run once SDL waits for pads (a forked run has its pad in seconds, SDL took ~5 s to
        # start): its 3 s of rest at first leave SDL and evdev time to open the pad before it moves
        t_run = time.monotonic()
        run = _start_run_on_pad(preds, profile_path)
        found = guestlib.wait_for(lambda: (set(_our_devices()) - before) or run.poll() is not None, 150.0, 0.05)
        assert found and run.poll() is None, (
            f"no gamepad appeared: {run.stderr.read()[-2000:] if run.poll() is not None else 'timeout'}"
        )
        node = sorted(set(_our_devices()) - before)[0]
        watcher = PadWatcher(node)
        t_device = time.monotonic()
        evdev_name = watcher.reader.device.name
        opened = guestlib.wait_for(lambda: probe_lines.first("opened") or probe_lines.first("done"), 60.0)
        assert opened and "opened" in opened, f"SDL saw no GameController: {probe_lines.lines[-3:]}"
        timings = {
            "sdl_init_s": ready["init_seconds"],
            "run_to_device_s": round(t_device - t_run, 2),
            "device_to_sdl_open_s": round(opened["opened"] - t_device, 2),
        }
        # the states up to the hold (the mapping's state depends on the past only), from the
        # sequence cut 1 s into the hold: not the 90 s of hold, which take minutes to map here;
        # the cut sequence's last line is the end of its run (everything centred and released)
        until_hold = folder / "until-hold.jsonl"
        write_predictions(until_hold, [e for e in estimates if e.t_us <= hold_t + 1_000_000])
        *lines, end = _expected_lines(until_hold, profile_path, folder)
        assert _state_key(end["axes"], end["buttons"]) == NEUTRAL, f"the run did not end neutral: {end}"
        expected_keys = [_state_key(d["axes"], d["buttons"]) for d in lines if d["t_us"] <= hold_t]
        held = expected_keys[-1]
        expected = _changes(expected_keys) + [NEUTRAL]  # SIGTERM in the held push: neutral
        sdl_expected = _sdl_expected(expected_keys + [NEUTRAL])
        assert all(v != n for v, n in zip(_sdl_view(held)[:-1], _sdl_view(NEUTRAL))), (
            f"the held push does not move every output SDL reads: {_sdl_view(held)}"
        )
        guestlib.settle()
        props = guestlib.udev_properties(node)
        sdl_held = sdl_expected[-2]
        reached = guestlib.wait_for(
            lambda: (
                watcher.states[-1] == held
                and probe_lines.samples()
                and _from_sdl(probe_lines.samples()[-1]["v"]) == sdl_held
            ),
            80.0,
        )
        sdl_last = probe_lines.samples()[-1]["v"] if probe_lines.samples() else None
        assert reached, (
            f"the held push was not read back: evdev {watcher.states[-1]}, SDL {sdl_last} "
            f"(in evdev units {_from_sdl(sdl_last) if sdl_last else None}), expected {held} / {sdl_held}"
        )
        run.send_signal(signal.SIGTERM)
        _, err = run.communicate(timeout=60)
        probe.wait(timeout=60)
        probe_lines.thread.join(10)
        guestlib.wait_for(lambda: watcher.reader.gone or watcher.states[-1] == NEUTRAL, 10.0)
        watcher.stop()
    finally:
        for proc in (run, probe):
            if proc is not None and proc.poll() is None:
                proc.kill()
    done = probe_lines.first("done") or {}
    assert done.get("error") is None, f"sdl_probe: {done}"
    assert run.returncode == 0, f"run exit code {run.returncode}: {err[-2000:]}"
    assert done.get("removed"), f"SDL did not see the pad unplugged after the run ended: {done}"
    assert not set(_our_devices()) - before, "the device outlived the process"
    assert props.get("ID_INPUT_JOYSTICK") == "1", f"udev does not class the pad as a joystick: {props}"
    assert evdev_name == dev.name, f"the device is called {evdev_name!r}, the profile says {dev.name!r}"

    guid = bytes.fromhex(opened["guid"])
    bus, vendor, product, version = (int.from_bytes(guid[i : i + 2], "little") for i in (0, 4, 8, 12))
    assert (bus, vendor, product, version) == (0x03, dev.vendor, dev.product, dev.version), (
        f"SDL's GUID {opened['guid']} says bus {bus:04x} {vendor:04x}:{product:04x} v{version:04x}, the profile {dev}"
    )

    got = _changes(watcher.states)
    first_diff = next((i for i, (a, b) in enumerate(zip(got, expected)) if a != b), None)
    assert got == expected, (
        f"evdev read back {len(got)} states, expected {len(expected)}; first difference at "
        f"{first_diff}: {got[first_diff] if first_diff is not None else None} vs "
        f"{expected[first_diff] if first_diff is not None else None}"
    )

    sdl_states = [_from_sdl(d["v"]) for d in probe_lines.samples()]  # one per change SDL saw
    assert sdl_states[0] == _sdl_view(NEUTRAL), (
        f"SDL opened the pad after the sequence had started moving it (lead-in too short?): {sdl_states[0]}, {timings}"
    )
    bad = _first_not_in_order(sdl_states, sdl_expected)
    assert bad is None, (
        f"SDL read {sdl_states[bad]} (evdev units) at its change {bad}: not a state the profile "
        f"gives there; SDL so far: {sdl_states[max(0, bad - 3) : bad]}; {timings}"
    )
    moving = [s for s in sdl_states if s != _sdl_view(NEUTRAL)]
    return {
        "sdl_controller_name": opened["controller_name"],
        "sdl_joystick_name": opened["joystick_name"],
        "profile_device_name": dev.name,
        "evdev_name": evdev_name,
        "guid": opened["guid"],
        "mapping": opened["mapping"],
        "sdl": ready.get("sdl"),
        "sdl_states": len(sdl_states),
        "sdl_moving_states": len(moving),
        "sdl_held_raw": sdl_last,
        "held_evdev": dict(zip([*AXES, *BUTTONS], held)),
        "evdev_states": len(got),
        "expected_states": len(expected),
        "sdl_saw_unplug": done.get("removed"),
        "ID_INPUT_JOYSTICK": props.get("ID_INPUT_JOYSTICK"),
        "exit_code": run.returncode,
        "evdev_last_neutral": watcher.states[-1] == NEUTRAL,
        "device_outlived_run": sorted(set(_our_devices()) - before),
        **timings,
    }


def check_bad_profile_starts_no_device() -> dict:
    """A profile with an error: exit code 2, one error naming the file, and no input device. The
    CLI's ``main`` runs in this process (a Python start costs tens of seconds here, and the
    command ends before it would open anything)."""
    folder = Path(tempfile.mkdtemp(prefix="runtime-badprofile-"))
    preds, _ = _write(folder, gesture_sequence())
    bad = folder / "broken.yaml"
    bad.write_text("mappings:\n  push: {input: push, output: left_stik}\n")
    inputs_before = sorted(p.name for p in Path("/sys/class/input").iterdir())
    code, out, err = guestlib.cli_in_process(
        "run", "--source", str(preds), "--profile", str(bad), "--output", "gamepad"
    )
    guestlib.settle()
    inputs_after = sorted(p.name for p in Path("/sys/class/input").iterdir())
    assert code == 2, f"exit code {code}: {err[-2000:]}"
    assert "broken.yaml" in err and "Traceback" not in out + err, err[-2000:]
    assert inputs_after == inputs_before, f"input devices changed: {sorted(set(inputs_after) ^ set(inputs_before))}"
    return {"exit_code": code, "error": err.strip().splitlines()[0][:300]}
