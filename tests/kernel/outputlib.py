"""Helpers of the output checks (checks_uhid.py, checks_gadget.py; run inside the qemu guest):
the pushed gel's predictions, the profile's state for it, hidapi's reader, and the driver run in
the check's own process (a second Python start costs 30 to 120 s under emulation)."""

from __future__ import annotations

import json
import logging
import os
import signal
import threading
import time
from pathlib import Path

import guestlib
import numpy as np
from checks_runtime import NO_DROP_LAG_MS, timeline

from neurotouch_hid.core.estimate import GestureType

#: The push to the right: the left stick and button A (2 mm of push presses it).
PROFILE = """\
description: guest check of neurotouch-hid run --output hid
mappings:
  push: {input: push, output: left_stick, deadzone_mm: 0.5, saturation_mm: 6.0}
  fire: {input: push_intensity, output: BTN_SOUTH, press_mm: 2.0, release_mm: 1.0}
"""


def push_right(hold_s: float, rest_s: float = 1.0) -> list:
    """Rest ``rest_s``, then a push straight to the right (the user frame's +x only) ramped to 6 mm in
    0.3 s and held ``hold_s``: a list of GestureEstimate."""
    from neurotouch_hid.core.estimate import GestureEstimate

    estimates = timeline(
        [(rest_s, GestureType.NONE, lambda f: 0.0), (0.3, GestureType.PUSH, lambda f: 6.0 * f)]
        + [(hold_s, GestureType.PUSH, lambda f: 6.0)]
    )
    return [
        GestureEstimate(
            t_us=e.t_us,
            gesture=e.gesture,
            resting=False,
            intensity_mm=e.intensity_mm,
            translation_mm=np.array([e.intensity_mm, 0.0]),
        )
        if e.gesture is GestureType.PUSH
        else e
        for e in estimates
    ]


def held_state(folder: Path, profile: Path):
    """The profile's ControllerState for the held push: the last push line of ``run --output
    jsonl --fast`` over the push held 0.4 s (the driver's own run_driver, in this process; the
    run's very last line is the neutral state written at its end)."""
    from neurotouch_hid.core.controller import ControllerState
    from neurotouch_hid.core.dataset import write_predictions
    from neurotouch_hid.engine.driver import DriverOptions, run_driver

    preds = folder / "held.jsonl"
    write_predictions(preds, push_right(0.4))
    out = folder / "expected.jsonl"
    run_driver(str(preds), profile, "jsonl", DriverOptions(fast=True, out=out))
    last = [d for d in map(json.loads, out.read_text().splitlines()) if d["gesture"] == "push"][-1]
    return ControllerState(axes=last["axes"], buttons=last["buttons"])


class HidrawReader:
    """Reads a device's input reports through hidapi (hidraw backend) in a thread: ``reports``,
    bytes each; ``error``: why reading ended (the device went away), else None."""

    def __init__(self, device) -> None:
        self.device = device
        self.reports: list[bytes] = []
        self.error: str | None = None
        self._stop = threading.Event()
        self.thread = threading.Thread(target=self._loop, daemon=True)
        self.thread.start()

    def _loop(self) -> None:
        while not self._stop.is_set():
            try:
                data = self.device.read(64, 200)
            except (OSError, ValueError) as exc:  # the device went away
                self.error = str(exc)
                return
            if data:
                self.reports.append(bytes(data))

    def stop(self) -> None:
        self._stop.set()
        self.thread.join(5)


def hid_driver(ids: tuple[int, int]) -> tuple[str | None, str | None]:
    """(sysfs name, bound driver) of the HID device with ``ids``: /sys/bus/hid/devices/0003:VID:PID.N."""
    for dev in sorted(Path("/sys/bus/hid/devices").glob(f"0003:{ids[0]:04X}:{ids[1]:04X}.*")):
        driver = dev / "driver"
        return dev.name, (driver.resolve().name if driver.exists() else None)
    return None, None


def _ignore(*_) -> None:
    """SIGTERM outside the run's own handler (before it installed it, after it restored ours)."""


def _installed(early: bool) -> bool:
    """The driver's SIGTERM handler is in place: the runtime's (``early``: or the one run_driver
    installs before its first device, :class:`~neurotouch_hid.engine.stopping.EarlyStop`)."""
    from neurotouch_hid.engine.stopping import EarlyStop

    handler = signal.getsignal(signal.SIGTERM)
    before_the_run = isinstance(getattr(handler, "__self__", None), EarlyStop)
    return handler is not _ignore and (early or not before_the_run)


class _Said(logging.Handler):
    """The driver's log lines of WARNING and above (what ``run`` prints on stderr), into a list."""

    def __init__(self, lines: list[str]) -> None:
        super().__init__(logging.WARNING)
        self.lines = lines

    def emit(self, record: logging.LogRecord) -> None:
        self.lines.append(record.getMessage())


class InProcessRun:
    """``neurotouch-hid run`` as the CLI runs it (``run_driver``), in this process's main thread,
    where the runtime installs its SIGTERM handler; ``steps(self)`` run in a thread beside it and
    end it with :meth:`stop`, a real SIGTERM to this process. ``said``: the lines the run told
    the user (``say``'s, and the driver's log lines of WARNING and above, as the CLI prints them
    on stderr); ``done``: set once ``run_driver`` returned. ``env``: environment variables set
    for the run (XDG_RUNTIME_DIR for its control socket, XDG_CONFIG_HOME for the user's
    profiles), restored after it. ``options``: more of the run's
    :class:`~neurotouch_hid.engine.driver.DriverOptions` fields (``wait``).
    ``max_lag_ms``: the lag the run allows (``--max-lag-ms``; these checks' default: none dropped)."""

    def __init__(
        self,
        preds: Path | str,
        profile: Path | str,
        output: str,
        protocol: str | None = None,
        env: dict | None = None,
        options: dict | None = None,
        max_lag_ms: str = NO_DROP_LAG_MS,
    ) -> None:
        self.args = (str(preds), profile, output)
        self.protocol = protocol
        self.env = env or {}
        self.options = options or {}
        self.max_lag_us = int(max_lag_ms) * 1000
        self.said: list[str] = []
        self.done = threading.Event()
        self.returned = False

    def alive(self) -> bool:
        return not self.done.is_set()

    def stop(self, watcher=None, timeout_s: float = 90.0, early: bool = False) -> None:
        """SIGTERM to this process once the runtime's handler replaced ours (``early``: once the
        driver's from before its first device did, :class:`~neurotouch_hid.engine.stopping.EarlyStop`:
        a stop before the run starts), reading ``watcher``'s
        events (a guestlib.EventReader) until the run returned: once the run removes its device,
        evdev drops what a reader had not read."""
        installed = guestlib.wait_for(lambda: _installed(early) or self.done.is_set(), 300)
        if installed and not self.done.is_set():
            os.kill(os.getpid(), signal.SIGTERM)
        if watcher is not None:
            # in short reads: a device that stays after the run (a gadget ``gadget setup`` made)
            # sends nothing more, and one long read would wait out its whole timeout
            deadline = time.monotonic() + timeout_s
            while not watcher.gone and not self.done.is_set() and time.monotonic() < deadline:
                watcher.pump(timeout_s=0.5, until=lambda r: self.done.is_set(), max_s=timeout_s)
            watcher.pump(timeout_s=0.2, max_s=2.0)  # what the run wrote as it ended
        self.done.wait(timeout_s)

    def __call__(self, steps):
        """Run the driver and ``steps``; return what ``steps`` returned, raise what it raised."""
        from neurotouch_hid.engine.driver import DriverOptions, run_driver

        box: dict = {}

        def beside() -> None:
            try:
                box["value"] = steps(self)
            except BaseException as exc:  # noqa: BLE001 - re-raised in the main thread
                box["error"] = exc
            finally:
                if not self.done.is_set():
                    self.stop()

        previous = signal.signal(signal.SIGTERM, _ignore)
        thread = threading.Thread(target=beside, daemon=True)
        environ = {name: os.environ.get(name) for name in self.env}
        os.environ.update(self.env)
        said = _Said(self.said)
        logging.getLogger("neurotouch_hid").addHandler(said)
        try:
            thread.start()
            run_driver(
                *self.args,
                DriverOptions(protocol=self.protocol, max_lag_us=self.max_lag_us, say=self.said.append, **self.options),
            )
            self.returned = True
        finally:
            self.done.set()
            thread.join(180)
            signal.signal(signal.SIGTERM, previous)
            logging.getLogger("neurotouch_hid").removeHandler(said)
            for name, value in environ.items():
                if value is None:
                    os.environ.pop(name, None)
                else:
                    os.environ[name] = value
        if "error" in box:
            raise box["error"]
        return box.get("value")
