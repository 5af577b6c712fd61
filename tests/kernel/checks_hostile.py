"""Guest probes of two hostile inputs, each in the real kernel (asserted on by
tests/test_hostile_kernel.py; run by tests/kernel/guest.py inside qemu):

* **a hidraw reader flooding the UHID joystick** (``run --output hid``, the driver in this
  process as in checks_uhid.py, the gel held pushed): another process writes output reports to
  the device's hidraw node as fast as it can. What the flood costs the driver is the CPU time of
  the main thread, where the run's loop reads the device's events (``/proc/self/task/PID/stat``'s
  utime and stime), over a span of it, beside the same span without a flood; the whole process's
  is reported too (the other threads' varies with the host's load: the flood takes a CPU from
  them). The events the device read a second are counted, the windows dropped are the run's own
  count. The kernel's console prints errors only, as a distribution's quiet boot sets it
  (:data:`QUIET_PRINTK`). The same flood is then sent once
  more with the driver's bounds lifted (``uhid.HOST_EVENTS_PER_S`` and ``uhid.HOST_CPU_SHARE``
  set far out of reach: every event handled as it comes, as before the bounds), so that the
  probe shows what it measures without them. (A HIDIOCGINPUT flood was tried too: in this guest
  the reader's requests mostly failed or waited out a span whatever the bounds, 1 answered of
  274 without them, so it measured nothing; left out);
* **hiding a merged interface of a two-interface USB device**: a USB gadget on dummy_hcd with a
  joystick and a boot keyboard (the product's own ``hid`` gadget with its keyboard function),
  which the same kernel's host side enumerates as one USB device, two HID devices, two hidraw
  nodes; the copilot's :class:`~neurotouch_hid.inputs.hide.Hider` hides the joystick's event
  node. Hidden: that node, its joystick node, its HID device's hidraw; the keyboard's hidraw and
  event node stay. What hiding took before (every interface's hidraw of the USB device) is
  computed on the same sysfs, so that the probe shows that it tells the two apart.
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import guestlib
from checks_runtime import _write
from outputlib import PROFILE, InProcessRun, push_right

TIMEOUT_S = 300
#: How long each span of :func:`check_a_flooding_hidraw_reader_costs_the_driver_a_bounded_share`
#: lasts (s of wall time).
SPAN_S = 2.5
GADGET = "nt-hostile"

#: The flooding reader, a Python of its own (``-S``: no site, a fast start in the emulated guest):
#: argv is the hidraw node and how long to write output reports to it (s). Prints ``go`` when it
#: starts, then how many writes succeeded and how many were tried.
FLOOD = r"""
import os, sys, time
node, seconds = sys.argv[1], float(sys.argv[2])
fd = os.open(node, os.O_RDWR)
report, done, tries = bytes([0, 0xFF, 0x55, 0xAA]), 0, 0
print("go", flush=True)
end = time.monotonic() + seconds
while time.monotonic() < end:
    tries += 1
    try:
        os.write(fd, report)
        done += 1
    except OSError:
        time.sleep(0.001)
print(done, tries, flush=True)
"""


def _cpu_s(stat: str = "/proc/self/stat") -> tuple[float, float]:
    """CPU time (s) of this process, every thread's, or of one thread (``/proc/self/task/TID/stat``):
    (utime, stime) of its stat file (proc(5))."""
    fields = Path(stat).read_text().rsplit(")", 1)[1].split()
    tick = os.sysconf("SC_CLK_TCK")
    return int(fields[11]) / tick, int(fields[12]) / tick


def _main_thread_cpu_s() -> float:
    """The main thread's CPU time (s): where the run's loop reads the UHID device's events."""
    return sum(_cpu_s(f"/proc/self/task/{os.getpid()}/stat"))


#: /proc/sys/kernel/printk during the check: a console that prints errors, not warnings, as a
#: distribution's ``quiet`` boot sets it. The test kernel's serial console prints every kernel
#: line; uhid.c logs each event a full queue drops while holding the queue's spinlock, so under
#: emulation the driver's reads spun on that lock for as long as the console printed (a system
#: time that grew with the bounds: the slower the driver reads, the fuller the queue).
QUIET_PRINTK = "4 4 1 7"


def _uhid_hidraw() -> str | None:
    """The hidraw node of the run's UHID joystick (its HID device's uevent names the phys)."""
    from neurotouch_hid.targets.uhid_events import PHYS

    for hid in Path("/sys/bus/hid/devices").glob("*"):
        try:
            if f"HID_PHYS={PHYS}" in (hid / "uevent").read_text().splitlines():
                return next((f"/dev/{p.name}" for p in (hid / "hidraw").glob("hidraw*")), None)
        except OSError:
            continue
    return None


def check_a_flooding_hidraw_reader_costs_the_driver_a_bounded_share() -> dict:
    """See the module docstring: spans of :data:`SPAN_S` of one ``run --output hid``: quiet, the
    flood, the flood with the bounds lifted."""
    from neurotouch_hid.core.stats import RunStats
    from neurotouch_hid.targets import uhid

    guestlib.sh(["modprobe", "uhid"])
    guestlib.sh(["modprobe", "hid-generic"])
    folder = Path(tempfile.mkdtemp(prefix="hostile-flood-"))
    preds, profile = _write(folder, push_right(600.0, rest_s=0.5), PROFILE)
    stats = RunStats()
    run = InProcessRun(preds, profile, "hid", options={"stats": stats}, max_lag_ms="1000")
    bounds = {"HOST_EVENTS_PER_S": uhid.HOST_EVENTS_PER_S, "HOST_CPU_SHARE": uhid.HOST_CPU_SHARE}
    spans: dict = {}
    read = {"events": 0}
    read_event = uhid.read_event

    def counted(fd: int):  # the device's reads, counted (``feedback`` calls the module's read_event)
        event = read_event(fd)
        read["events"] += 1
        return event

    uhid.read_event = counted

    def span(name: str, node: str, flooded: bool) -> None:
        flood = None
        if flooded:
            command = [sys.executable, "-S", "-c", FLOOD, node, str(SPAN_S + 1.0)]
            flood = subprocess.Popen(command, stdout=subprocess.PIPE, text=True)
            assert flood.stdout.readline().strip() == "go", "the flood did not start"
            time.sleep(0.5)  # flooding before the span is measured
        (user, system), main, events = _cpu_s(), _main_thread_cpu_s(), read["events"]
        wall, windows, dropped = time.monotonic(), stats.windows, stats.dropped_items
        time.sleep(SPAN_S)
        (user_after, system_after), main_after = _cpu_s(), _main_thread_cpu_s()
        wall = time.monotonic() - wall
        spans[name] = {
            "share": round((user_after - user + system_after - system) / wall, 3),
            "system_share": round((system_after - system) / wall, 3),
            "main_thread_share": round((main_after - main) / wall, 3),
            "events_per_s": round((read["events"] - events) / wall),
            "windows": stats.windows - windows,
            "dropped_items": stats.dropped_items - dropped,
        }
        if flood is not None:
            out, _ = flood.communicate(timeout=60)
            spans[name]["writes"], spans[name]["tries"] = (int(n) for n in out.split()[-2:])

    def steps(run: InProcessRun) -> None:
        node = guestlib.wait_for(lambda: _uhid_hidraw() or not run.alive(), 150.0, 0.1)
        assert node and run.alive(), f"no hidraw node of the UHID joystick: {run.said[-5:]}"
        guestlib.wait_for(lambda: stats.windows > 20, 60.0)  # the held push under way
        span("quiet", node, False)
        span("flood", node, True)
        for name in bounds:  # the bounds lifted: every event as soon as it comes, whatever it costs
            setattr(uhid, name, 10**9)
        try:
            span("flood_unbounded", node, True)
        finally:
            for name, value in bounds.items():
                setattr(uhid, name, value)
        run.stop()

    t0 = time.monotonic()
    printk = Path("/proc/sys/kernel/printk")
    console = printk.read_text().split()
    printk.write_text(QUIET_PRINTK)
    try:
        run(steps)
    finally:
        printk.write_text(" ".join(console))
        uhid.read_event = read_event
    assert run.returned, f"the run did not return after SIGTERM: {run.said[-5:]}"
    return {**bounds, "span_s": SPAN_S, **spans, "check_s": round(time.monotonic() - t0, 1), "printk_before": console}


def _input_nodes(ids: tuple[int, int]) -> dict[str, str]:
    """The event nodes of the USB device with ``ids``: ``joystick`` (has ABS_X), ``keyboard`` (has
    KEY_A)."""
    from evdev import InputDevice, ecodes, list_devices

    found = {}
    for path in list_devices():
        try:
            device = InputDevice(path)
        except OSError:
            continue
        if (device.info.vendor, device.info.product) != ids:
            continue
        caps = device.capabilities()
        if ecodes.ABS_X in [code for code, _ in caps.get(ecodes.EV_ABS, [])]:
            found["joystick"] = path
        elif ecodes.KEY_A in caps.get(ecodes.EV_KEY, []):
            found["keyboard"] = path
        device.close()
    return found


def _hid_device(event_node: str) -> Path:
    """The HID device (sysfs) an event node's input device belongs to."""
    device = (Path("/sys/class/input") / Path(event_node).name / "device").resolve()
    return next(parent for parent in device.parents if (parent / "hidraw").is_dir())


def _every_interfaces_hidraw(event_node: str) -> list[str]:
    """What hiding took before: every hidraw of the USB device the input device is on, all its
    interfaces' (the search up to the USB device, ``idVendor``, then ``*/*/hidraw/hidraw*``)."""
    device = (Path("/sys/class/input") / Path(event_node).name / "device").resolve()
    usb = next(parent for parent in device.parents if (parent / "idVendor").is_file())
    return sorted({p.name for p in usb.glob("*/*/hidraw/hidraw*")})


def check_hiding_a_merged_interface_leaves_the_same_usb_devices_keyboard() -> dict:
    """See the module docstring: the joystick interface hidden, the keyboard interface left."""
    from neurotouch_hid.inputs.hide import Hider
    from neurotouch_hid.targets.gadget import configfs

    for module in ("dummy_hcd", "libcomposite", "usb_f_hid", "usbhid", "hid-generic"):
        guestlib.sh(["modprobe", module])
    plan = configfs.plan("hid", keyboard=True)
    ids = (plan.vendor, plan.product)
    configfs.remove(GADGET)
    configfs.create(plan, name=GADGET)
    hider = Hider()
    details: dict = {}
    try:
        configfs.bind(GADGET)
        nodes = guestlib.wait_for(lambda: len(found := _input_nodes(ids)) == 2 and found, 60.0, 0.2)
        assert nodes, f"the gadget's joystick and keyboard as input devices: {_input_nodes(ids)}"
        guestlib.settle()
        joystick_hidraw = sorted(p.name for p in (_hid_device(nodes["joystick"]) / "hidraw").glob("hidraw*"))
        keyboard_hidraw = sorted(p.name for p in (_hid_device(nodes["keyboard"]) / "hidraw").glob("hidraw*"))
        details.update(
            nodes=nodes,
            joystick_hidraw=joystick_hidraw,
            keyboard_hidraw=keyboard_hidraw,
            every_interfaces_hidraw=_every_interfaces_hidraw(nodes["joystick"]),
        )
        details["hidden"] = hider.hide(nodes["joystick"])
        details["in_dev_while_hidden"] = {
            name: os.path.exists(f"/dev/{name}")
            for name in [*joystick_hidraw, *keyboard_hidraw, f"input/{Path(nodes['keyboard']).name}"]
        }
        details["put_back"] = hider.restore_all()
        details["in_dev_after"] = {name: os.path.exists(f"/dev/{name}") for name in details["hidden"]}
    finally:
        hider.restore_all()
        configfs.remove(GADGET)
    return details
