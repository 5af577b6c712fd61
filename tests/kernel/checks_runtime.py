"""Guest checks of ``neurotouch-hid run --output gamepad`` (the runtime) in a real kernel.

Run by tests/kernel/guest.py inside qemu; asserted on by tests/test_runtime_kernel.py.

The guest is software-emulated (no KVM), roughly a hundred times slower than the host: the gesture
pipeline (numba tracker, OpenCV) cannot process even a second of events within a check's time
there. These checks therefore feed the runtime a gesture sequence as the pipeline's own output, a
predictions file (DATASET.md "Predictions", ``--source FILE.jsonl``): everything after the
pipeline is real -- the runtime's threads, pacing and shutdown, the profile and Mapper, the uinput
device -- and the host tests (tests/test_runtime.py) run the same runtime with the pipeline on
simulated recordings. Expected states come from the same estimates through ``--output jsonl``
side by side.
"""

from __future__ import annotations

import json
import math
import os
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import guestlib
import numpy as np
from evdev import ecodes

from neurotouch_hid.controller import AXES, BUTTONS
from neurotouch_hid.estimate import GestureEstimate, GestureType
from neurotouch_hid.output.gamepad import PHYS

REPO = Path(__file__).resolve().parent.parent.parent
TIMEOUT_S = 300
STEP_US = 10_000

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


def gesture_sequence(hold_s: float = 0.4, lead_in_s: float = 0.5) -> list[GestureEstimate]:
    """Rest, then each gesture: ramp up to 6 mm in 0.3 s, hold, ramp down in 0.2 s, rest 0.3 s."""
    out: list[GestureEstimate] = []
    t = 1_000_000

    def add(seconds: float, gesture: GestureType, level) -> None:
        nonlocal t
        n = max(1, int(round(seconds * 1e6 / STEP_US)))
        for k in range(n):
            out.append(_gesture(t, gesture, level((k + 1) / n)))
            t += STEP_US

    add(lead_in_s, GestureType.NONE, lambda f: 0.0)
    for gesture in (GestureType.PUSH, GestureType.TWIST_CCW, GestureType.ZOOM, GestureType.PINCH, GestureType.TWIST_CW):
        add(0.3, gesture, lambda f: 6.0 * f)
        add(hold_s, gesture, lambda f: 6.0)
        add(0.2, gesture, lambda f: 6.0 * (1 - f))
        add(0.3, GestureType.NONE, lambda f: 0.0)
    return out


def _write(folder: Path, estimates: list[GestureEstimate]) -> tuple[Path, Path]:
    from neurotouch_hid.output.jsonl import write_predictions

    preds = folder / "gestures.jsonl"
    write_predictions(preds, estimates)
    profile = folder / "guestcheck.yaml"
    profile.write_text(PROFILE)
    return preds, profile


def _cli(*args: str) -> list[str]:
    return [sys.executable, "-m", "neurotouch_hid.cli", *args]


def _env() -> dict:
    return dict(os.environ, PYTHONPATH=str(REPO), PYTHONUNBUFFERED="1")


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


def _expected_states(preds: Path, profile: Path, folder: Path) -> list[tuple]:
    """The same estimates through ``neurotouch-hid run --output jsonl --fast``."""
    out = folder / "expected.jsonl"
    proc = guestlib.sh(_cli("run", "--source", str(preds), "--profile", str(profile), "--output", "jsonl",
                            "--fast", "--out", str(out)), timeout=TIMEOUT_S, env=_env(), cwd=str(REPO))
    assert proc.returncode == 0, f"run --output jsonl failed: {proc.stderr[-2000:]}"
    lines = [json.loads(line) for line in out.read_text().splitlines() if line.strip()]
    return [_state_key(d["axes"], d["buttons"]) for d in lines]


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
            self.reader.pump(timeout_s=0.2, until=lambda r: len(r.reports) > seen or self._stop.is_set())
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
    from neurotouch_hid.mapping.profile import load_profile
    from neurotouch_hid.output.gamepad import GamepadIdentity, VirtualGamepad
    from neurotouch_hid.runtime import run_driver

    folder = Path(tempfile.mkdtemp(prefix="runtime-check-"))
    preds, profile_path = _write(folder, gesture_sequence())
    expected = _changes(_expected_states(preds, profile_path, folder))
    assert len(expected) > 20, f"the sequence moves the pad too little: {len(expected)} states"
    dev = load_profile(profile_path).device
    with VirtualGamepad(GamepadIdentity(name=dev.name, vendor=dev.vendor, product=dev.product, version=dev.version)) as pad:
        guestlib.settle()
        props = guestlib.udev_properties(pad.device_path)
        watcher = PadWatcher(pad.device_path)
        stats = run_driver(str(preds), profile_path, "gamepad", output_obj=pad)
        guestlib.wait_for(lambda: watcher.states[-1] == NEUTRAL, 5.0)
        watcher.stop()
    got = _changes(watcher.states)
    assert props.get("ID_INPUT_JOYSTICK") == "1", f"udev does not class the pad as a joystick: {props}"
    assert stats.dropped_items == 0, f"the runtime dropped {stats.dropped_items} items: the guest is too slow"
    first_diff = next((i for i, (a, b) in enumerate(zip(got, expected)) if a != b), None)
    assert got == expected, (f"read back {len(got)} states, expected {len(expected)}; first difference at "
                             f"{first_diff}: {got[first_diff] if first_diff is not None else None} vs "
                             f"{expected[first_diff] if first_diff is not None else None}")
    assert watcher.states[-1] == NEUTRAL
    pressed = sum(1 for s in got if any(s[len(AXES):]))
    return {"states": len(got), "with_button": pressed, "windows": stats.windows,
            "latency_p99_us": round(stats.latency.percentile_us(99)), "ID_INPUT_JOYSTICK": props.get("ID_INPUT_JOYSTICK")}


def check_run_sigterm_releases_everything() -> dict:
    """``neurotouch-hid run --output gamepad`` held in a push with the button pressed: SIGTERM
    ends it with exit code 0 and a reader sees every button released and every axis centred."""
    folder = Path(tempfile.mkdtemp(prefix="runtime-sigterm-"))
    preds, profile_path = _write(folder, gesture_sequence(hold_s=30.0, lead_in_s=0.2))
    before = set(_our_devices())
    proc = subprocess.Popen(_cli("run", "--source", str(preds), "--profile", str(profile_path), "--output", "gamepad"),
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=_env(), cwd=str(REPO))
    watcher = None
    try:
        path = guestlib.wait_for(lambda: (set(_our_devices()) - before) or proc.poll() is not None, 150.0, 0.1)
        assert path and proc.poll() is None, f"no gamepad appeared: {proc.stderr.read()[-2000:] if proc.poll() is not None else 'timeout'}"
        node = sorted(set(_our_devices()) - before)[0]
        guestlib.settle()
        props = guestlib.udev_properties(node)
        watcher = PadWatcher(node)
        btn = ecodes.ecodes["BTN_SOUTH"]
        held = guestlib.wait_for(lambda: btn in watcher.reader.keys and watcher.reader.axes.get(ecodes.ABS_X, 0) > 0, 30.0)
        assert held, f"the push never pressed the button: {watcher.states[-3:]}"
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=60)
        guestlib.wait_for(lambda: watcher.reader.gone or watcher.states[-1] == NEUTRAL, 10.0)
        time.sleep(0.3)
        watcher.stop()
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0, f"exit code {proc.returncode}: {err[-2000:]}"
    assert watcher.states[-1] == NEUTRAL, f"after SIGTERM the pad reads {watcher.states[-1]}"
    assert not set(_our_devices()) - before, "the device outlived the process"
    return {"exit_code": proc.returncode, "ID_INPUT_JOYSTICK": props.get("ID_INPUT_JOYSTICK"),
            "states_seen": len(watcher.states), "stderr_tail": err.strip().splitlines()[-1:] if err.strip() else []}


def check_bad_profile_starts_no_device() -> dict:
    """A profile with an error: exit code 2, one error naming the file, and no input device."""
    folder = Path(tempfile.mkdtemp(prefix="runtime-badprofile-"))
    preds, _ = _write(folder, gesture_sequence())
    bad = folder / "broken.yaml"
    bad.write_text("mappings:\n  push: {input: push, output: left_stik}\n")
    inputs_before = sorted(p.name for p in Path("/sys/class/input").iterdir())
    proc = guestlib.sh(_cli("run", "--source", str(preds), "--profile", str(bad), "--output", "gamepad"),
                       timeout=TIMEOUT_S, env=_env(), cwd=str(REPO))
    guestlib.settle()
    inputs_after = sorted(p.name for p in Path("/sys/class/input").iterdir())
    assert proc.returncode == 2, f"exit code {proc.returncode}: {proc.stderr[-2000:]}"
    assert "broken.yaml" in proc.stderr and "Traceback" not in proc.stderr, proc.stderr[-2000:]
    assert inputs_after == inputs_before, f"input devices changed: {sorted(set(inputs_after) ^ set(inputs_before))}"
    return {"exit_code": proc.returncode, "error": proc.stderr.strip().splitlines()[0][:300]}
