"""Guest check of ``neurotouch-hid run --output hid``: the generic HID joystick on UHID, read the
ways a host reads it.

Run by tests/kernel/guest.py inside qemu; asserted on by tests/test_uhid_kernel.py. As in
checks_runtime.py, the run is fed the pipeline's output (a predictions file: the emulated guest
cannot run the gesture pipeline in real time): the simulated gel at rest, then pushed to the
right and held until SIGTERM. Everything after the pipeline is real: the runtime, the profile,
the UHID device, the kernel's hid-generic and hid-input, hidraw. The driver runs in this
process (``run_driver``, what ``run`` calls, ended by a real SIGTERM to this process: a second
Python start costs 30 to 120 s under emulation); one SDL start serves every assertion:

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
* SIGTERM: the run returns normally, the last report hidraw reads is the neutral one, evdev reads X centred.
"""

from __future__ import annotations

import subprocess
import sys
import tempfile
import time
from pathlib import Path

import guestlib
from checks_runtime import PadWatcher, ProbeLines, _write
from outputlib import PROFILE, HidrawReader, InProcessRun, held_state, hid_driver, push_right

from neurotouch_hid.targets.reports.hid import HID_JOYSTICK
from neurotouch_hid.targets.uhid import HID_DEFAULT
from neurotouch_hid.targets.uhid_events import PHYS

TIMEOUT_S = 300
IDS = (HID_DEFAULT.vendor, HID_DEFAULT.product)
#: Seconds of gel at rest before the push: the driver starts its source as soon as the device
#: exists, and UHID (unlike a USB host, which polls) delivers a report on a change only, so
#: hidapi's reader must be open before the push to read it (it opens within a second or two).
REST_S = 3.0


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
    # the rest: hidapi's reader is open before the push (the run's first report after its start)
    preds, profile = _write(folder, push_right(120.0, rest_s=REST_S), PROFILE)
    t0 = time.monotonic()  # SDL's start (a Python start) overlaps the expected state's and the run's
    probe = subprocess.Popen(
        [sys.executable, str(Path(__file__).resolve().parent / "sdl_probe.py"), "--joystick", "240"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=guestlib.sdl_env(),
    )
    lines = ProbeLines(probe)
    held = held_state(folder, profile)
    assert held.axes["ABS_X"] > 0 and held.buttons["BTN_SOUTH"], f"the profile's held push: {held}"
    held_report = HID_JOYSTICK.pack(held)
    run = InProcessRun(preds, profile, "hid")
    seen: dict = {}

    def steps(run: InProcessRun) -> None:
        t_run = time.monotonic()
        found = guestlib.wait_for(lambda: hidraw.enumerate(*IDS) or not run.alive(), 150.0, 0.1)
        assert found and run.alive(), f"no hidraw device: {run.said[-5:]}"
        seen["device_s"] = time.monotonic() - t_run
        seen["info"] = found[0]
        device = hidraw.device()
        device.open(*IDS)
        seen["reader"] = reader = HidrawReader(device)  # UHID sends a report on a change only
        guestlib.settle()
        seen["sysfs_name"], seen["driver"] = hid_driver(IDS)
        seen["descriptor"] = bytes(device.get_report_descriptor())
        node = guestlib.wait_for(_our_input_device, 10.0)
        assert node, "no input device with our phys"
        seen["props"] = guestlib.udev_properties(node)
        seen["watcher"] = watcher = PadWatcher(node)  # reads in a thread, like a game: a gone device's queue is lost
        seen["x_max"] = watcher.reader.device.absinfo(ecodes.ABS_X).max
        guestlib.wait_for(lambda: watcher.reader.axes.get(ecodes.ABS_X) == held.axes["ABS_X"], 120.0)
        seen["evdev_held"] = dict(watcher.reader.axes)
        seen["evdev_south"] = ecodes.BTN_TRIGGER in watcher.reader.keys  # button 1 of a Joystick: BTN_TRIGGER
        seen["got_held"] = guestlib.wait_for(lambda: held_report in reader.reports, 30.0)
        seen["held_s"] = time.monotonic() - t_run
        seen["asked"] = bytes(device.get_input_report(0, 64))
        ready = guestlib.wait_for(
            lambda: lines.first("ready") or lines.first("done") or probe.poll() is not None, 150.0
        )
        seen["sdl_ready_s"] = time.monotonic() - t0
        assert isinstance(ready, dict) and ready.get("ready"), f"SDL did not start: {lines.lines} {probe.poll()}"
        seen["sdl_held"] = guestlib.wait_for(
            lambda: next((d for d in lines.samples_raw() if d["axes"] and d["axes"][0] > 0.99), None), 60.0
        )
        run.stop()
        guestlib.wait_for(lambda: watcher.reader.gone, 10.0)
        time.sleep(0.5)
        reader.stop()

    try:
        run(steps)
        opened = lines.first("opened")
    finally:
        if probe.poll() is None:
            probe.kill()
        if "watcher" in seen:
            seen["watcher"].stop()
    reader, watcher, props, descriptor = seen["reader"], seen["watcher"], seen["props"], seen["descriptor"]
    sdl_held, evdev_held = seen["sdl_held"], seen["evdev_held"]
    assert run.returned, f"the run did not return after SIGTERM: {run.said[-5:]}"
    assert seen["driver"] == "hid-generic", f"the HID driver of {seen['sysfs_name']}: {seen['driver']}"
    assert descriptor == HID_JOYSTICK.descriptor, f"descriptor read back: {descriptor.hex()}"
    assert seen["got_held"], (
        f"the held push never arrived as {held_report.hex()}: {[r.hex() for r in reader.reports[-5:]]}"
    )
    assert seen["asked"] == held_report, f"GET_REPORT while held: {seen['asked'].hex()}, expected {held_report.hex()}"
    assert reader.reports[-1] == HID_JOYSTICK.neutral(), f"last report after SIGTERM: {reader.reports[-1].hex()}"
    assert evdev_held.get(ecodes.ABS_X) == held.axes["ABS_X"] > 0, f"evdev ABS_X {evdev_held.get(ecodes.ABS_X)}"
    assert seen["evdev_south"], "button A (HID button 1) is not BTN_TRIGGER on evdev"
    assert watcher.states[-1][0] == 0, f"evdev after SIGTERM: ABS_X {watcher.states[-1][0]}"  # ABS_X first
    assert props.get("ID_INPUT_JOYSTICK") == "1", f"udev: {props}"
    assert sdl_held, f"SDL never read axis 0 at full right: {lines.lines[-5:]}"
    info = seen["info"]
    return {
        "modprobe": modprobe,
        "hid_device": seen["sysfs_name"],
        "driver": seen["driver"],
        "hidapi": {"path": info["path"].decode(), "product": info["product_string"], "usage_page": info["usage_page"],
                   "usage": info["usage"]},
        "descriptor_bytes": len(descriptor),
        "reports": len(reader.reports),
        "held_report": held_report.hex(),
        "evdev_abs_x_max": seen["x_max"],
        "ID_INPUT_JOYSTICK": props.get("ID_INPUT_JOYSTICK"),
        "sdl_opened": opened,
        "sdl_held_axes": sdl_held["axes"],
        "sdl_ready_s": round(seen["sdl_ready_s"], 1),
        "device_after_start_s": round(seen["device_s"], 1),
        "held_after_start_s": round(seen["held_s"], 1),
        "check_s": round(time.monotonic() - t0, 1),
        "said_tail": run.said[-2:],
    }  # fmt: skip
