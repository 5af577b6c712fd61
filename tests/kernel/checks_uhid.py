"""Guest check of ``neurotouch-hid run --output hid``: the generic HID joystick on UHID, read the
ways a host reads it.

Run by tests/kernel/guest.py inside qemu; asserted on by tests/test_uhid_kernel.py. As in
checks_runtime.py, the run is fed the pipeline's output (a predictions file: the emulated guest
cannot run the gesture pipeline in real time): the simulated gel at rest, then pushed to the
right and held until SIGTERM. Everything after the pipeline is real: the runtime, the profile,
the UHID device, the kernel's hid-generic and hid-input, hidraw. One driver start and one SDL
start serve every assertion:

* ``/dev/uhid`` after ``modprobe uhid``; the device's HID driver (sysfs ``driver`` link) is
  hid-generic;
* hidapi (cython-hidapi's ``hidraw`` module: the hidraw backend, which sees UHID devices; its
  ``hid`` module is libusb's and sees only USB ones) opens it by vendor and product id, reads the
  report descriptor (equal to docs/reports.md's) and input reports: the held push arrives as the
  report ``pack`` makes of the profile's state, also when asked for (GET_REPORT, answered by the
  driver);
* evdev: ABS_X positive (the push is to the right) on the input device with phys
  ``neurotouch-hid/uhid``, which udev classes as a joystick;
* SDL (pygame, ``sdl_probe.py --joystick``): a joystick whose axis 0 goes to full right;
* SIGTERM: exit 0, the last report hidraw reads is the neutral one, evdev reads X centred.
"""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import guestlib
import numpy as np
from checks_runtime import NO_DROP_LAG_MS, PadWatcher, ProbeLines, _cli, _env, _write, timeline

from neurotouch_hid.estimate import GestureType
from neurotouch_hid.targets.reports.hid import HID_JOYSTICK
from neurotouch_hid.targets.uhid import HID_DEFAULT, PHYS

TIMEOUT_S = 300

#: The push to the right: the left stick and button A (2 mm of push presses it).
PROFILE = """\
description: guest check of neurotouch-hid run --output hid
mappings:
  push: {input: push, output: left_stick, deadzone_mm: 0.5, saturation_mm: 6.0}
  fire: {input: push_intensity, output: BTN_SOUTH, press_mm: 2.0, release_mm: 1.0}
"""


def _push_right(hold_s: float) -> list:
    """Rest 1 s, then a push straight to the right (the user frame's +x only) ramped to 6 mm in
    0.3 s and held ``hold_s``."""
    from neurotouch_hid.estimate import GestureEstimate

    estimates = timeline(
        [(1.0, GestureType.NONE, lambda f: 0.0), (0.3, GestureType.PUSH, lambda f: 6.0 * f)]
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


def _held_state(folder: Path, profile: Path):
    """The profile's state for the held push: the last push line of ``run --output jsonl --fast``
    over the push held 0.4 s (the driver's own run_driver, in this process)."""
    from neurotouch_hid.controller import ControllerState
    from neurotouch_hid.dataset import write_predictions
    from neurotouch_hid.driver import run_driver

    preds = folder / "held.jsonl"
    write_predictions(preds, _push_right(0.4))
    out = folder / "expected.jsonl"
    run_driver(str(preds), profile, "jsonl", fast=True, out=out)
    # the last line of the push (the run's neutral line at its end follows it)
    last = [d for d in map(json.loads, out.read_text().splitlines()) if d["gesture"] == "push"][-1]
    return ControllerState(axes=last["axes"], buttons=last["buttons"])


class HidrawReader:
    """Reads the device's input reports through hidapi (hidraw backend) in a thread."""

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


def _hid_driver() -> tuple[str | None, str | None]:
    """(sysfs device name, bound driver) of our UHID device: /sys/bus/hid/devices/0003:VID:PID.N."""
    pattern = f"0003:{HID_DEFAULT.vendor:04X}:{HID_DEFAULT.product:04X}.*"
    for dev in sorted(Path("/sys/bus/hid/devices").glob(pattern)):
        driver = dev / "driver"
        return dev.name, (driver.resolve().name if driver.exists() else None)
    return None, None


def _our_input_device() -> str | None:
    from evdev import InputDevice, list_devices

    for path in list_devices():
        try:
            if InputDevice(path).phys == PHYS:
                return path
        except OSError:
            pass
    return None


def check_run_output_hid() -> dict:
    """See the module docstring: one run of ``--output hid``, read through sysfs, hidapi, evdev and SDL."""
    import hidraw
    from evdev import ecodes

    modprobe = {m: guestlib.sh(["modprobe", m]).returncode == 0 for m in ("uhid", "hid-generic")}
    guestlib.settle()
    assert Path("/dev/uhid").exists(), f"no /dev/uhid after modprobe: {modprobe}"
    folder = Path(tempfile.mkdtemp(prefix="uhid-check-"))
    preds, profile = _write(folder, _push_right(120.0), PROFILE)
    t0 = time.monotonic()  # SDL, the run and the expected state start together (each a Python start here)
    probe = subprocess.Popen(
        [sys.executable, str(Path(__file__).resolve().parent / "sdl_probe.py"), "--joystick", "240"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=guestlib.sdl_env(),
    )
    lines = ProbeLines(probe)
    run = None
    reader = watcher = None
    try:
        run = subprocess.Popen(
            _cli("run", "--source", str(preds), "--profile", str(profile), "--output", "hid",
                 "--max-lag-ms", NO_DROP_LAG_MS),
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=_env(),
        )  # fmt: skip
        t_run = time.monotonic()
        held = _held_state(folder, profile)
        assert held.axes["ABS_X"] > 0 and held.buttons["BTN_SOUTH"], f"the profile's held push: {held}"
        held_report = HID_JOYSTICK.pack(held)
        ready = guestlib.wait_for(
            lambda: lines.first("ready") or lines.first("done") or probe.poll() is not None, 150.0
        )
        assert isinstance(ready, dict) and ready.get("ready"), f"SDL did not start: {lines.lines} {probe.poll()}"
        sdl_ready_s = time.monotonic() - t0
        found = guestlib.wait_for(
            lambda: hidraw.enumerate(HID_DEFAULT.vendor, HID_DEFAULT.product) or run.poll() is not None, 150.0, 0.1
        )
        assert found and run.poll() is None, f"no hidraw device: {run.stderr.read()[-2000:] if run.poll() else found}"
        device_s = time.monotonic() - t_run
        info = found[0]
        guestlib.settle()
        sysfs_name, driver = _hid_driver()
        device = hidraw.device()
        device.open(HID_DEFAULT.vendor, HID_DEFAULT.product)
        descriptor = bytes(device.get_report_descriptor())
        reader = HidrawReader(device)
        node = guestlib.wait_for(_our_input_device, 10.0)
        assert node, "no input device with our phys"
        props = guestlib.udev_properties(node)
        watcher = PadWatcher(node)  # reads in a thread, like a game: a gone device's queue is lost
        x_max = watcher.reader.device.absinfo(ecodes.ABS_X).max
        guestlib.wait_for(lambda: watcher.reader.axes.get(ecodes.ABS_X) == held.axes["ABS_X"], 120.0)
        evdev_held = dict(watcher.reader.axes)
        evdev_south = ecodes.BTN_TRIGGER in watcher.reader.keys  # button 1 of a Joystick: BTN_TRIGGER
        got_held = guestlib.wait_for(lambda: held_report in reader.reports, 30.0)
        held_s = time.monotonic() - t_run
        asked = bytes(device.get_input_report(0, 64))
        sdl_held = guestlib.wait_for(
            lambda: next((d for d in lines.samples_raw() if d["axes"] and d["axes"][0] > 0.99), None), 60.0
        )
        run.send_signal(signal.SIGTERM)
        _, err = run.communicate(timeout=60)
        guestlib.wait_for(lambda: watcher.reader.gone, 10.0)
        time.sleep(0.5)
        reader.stop()
        opened = lines.first("opened")
    finally:
        for proc in (run, probe):
            if proc is not None and proc.poll() is None:
                proc.kill()
        if watcher is not None:
            watcher.stop()
    assert run.returncode == 0, f"run exit code {run.returncode}: {err[-2000:]}"
    assert driver == "hid-generic", f"the HID driver of {sysfs_name}: {driver}"
    assert descriptor == HID_JOYSTICK.descriptor, f"descriptor read back: {descriptor.hex()}"
    assert got_held, f"the held push never arrived as {held_report.hex()}: {[r.hex() for r in reader.reports[-5:]]}"
    assert asked == held_report, f"GET_REPORT while held: {asked.hex()}, expected {held_report.hex()}"
    assert reader.reports[-1] == HID_JOYSTICK.neutral(), f"last report after SIGTERM: {reader.reports[-1].hex()}"
    assert evdev_held.get(ecodes.ABS_X) == held.axes["ABS_X"] > 0, f"evdev ABS_X {evdev_held.get(ecodes.ABS_X)}"
    assert evdev_south, "button A (HID button 1) is not BTN_TRIGGER on evdev"
    assert watcher.states[-1][0] == 0, f"evdev after SIGTERM: ABS_X {watcher.states[-1][0]}"  # ABS_X first
    assert props.get("ID_INPUT_JOYSTICK") == "1", f"udev: {props}"
    assert sdl_held, f"SDL never read axis 0 at full right: {lines.lines[-5:]}"
    return {
        "modprobe": modprobe,
        "hid_device": sysfs_name,
        "driver": driver,
        "hidapi": {"path": info["path"].decode(), "product": info["product_string"], "usage_page": info["usage_page"],
                   "usage": info["usage"]},
        "descriptor_bytes": len(descriptor),
        "reports": len(reader.reports),
        "held_report": held_report.hex(),
        "evdev_abs_x_max": x_max,
        "ID_INPUT_JOYSTICK": props.get("ID_INPUT_JOYSTICK"),
        "sdl_opened": opened,
        "sdl_held_axes": sdl_held["axes"],
        "sdl_ready_s": round(sdl_ready_s, 1),
        "device_after_start_s": round(device_s, 1),
        "held_after_start_s": round(held_s, 1),
        "check_s": round(time.monotonic() - t0, 1),
        "stderr_tail": err.strip().splitlines()[-2:],
    }  # fmt: skip
