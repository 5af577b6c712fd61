"""Guest check of ``neurotouch-hid run --output hid --protocol dualsense``: the DualSense on UHID,
read by the kernel's hid-playstation, hidraw, evdev and SDL as a host reads a real one.

Run by tests/kernel/guest.py inside qemu; asserted on by tests/test_dualsense_kernel.py. As in
checks_uhid.py, the run is fed a predictions file (the emulated guest cannot run the gesture
pipeline in real time) with the shipped ``touchpad`` profile: the gel at rest, one finger
pressing and moving to the right and up, a second finger, the second lifting, both lifting, then
two fingers pushing hard (the stick, the touchpad's click) held until SIGTERM. Everything after
the pipeline is real: the runtime, the profile's touchpad mapping, the UHID device, the kernel's
hid-playstation. The driver runs in this process (``outputlib.InProcessRun``, ended by a real
SIGTERM); one SDL start serves SDL's assertions:

* hid-playstation binds (sysfs ``driver``) with no "Failed to retrieve" and no "Duplicate
  device" in the kernel's log; the pad, its Touchpad and its Motion Sensors are evdev devices;
* HIDIOCGFEATURE (hidapi's ``get_feature_report`` on hidraw) of 0x05, 0x09, 0x20 gives 41, 20
  and 64 bytes, each starting with its id; HID_UNIQ is the MAC of the pairing report;
* the Touchpad's slot 0 follows the first finger (ABS_MT_POSITION_X/Y as the profile maps the
  contact), the second finger appears in slot 1, each lift ends its slot (tracking id -1);
* SDL (pygame, ``sdl_probe.py --serve``) opens it as a game controller, and a rumble it plays
  comes back to the driver as Feedback (its line for the user) and reaches the pad the profile
  merges (``copilot:``, checks_copilot.py's "Helper Pad"): an FF_RUMBLE upload and play on it;
* SIGTERM: the last report hidraw reads is the neutral one, every touch point inactive;
* a second run (a restart) has the same HID_UNIQ.

:func:`check_killed_dualsense_leaves_the_host_neutral`: the run killed by SIGKILL with two
touches active, the stick pushed and the touchpad clicked (:func:`killed`, which
checks_gadget_ffs.py runs on the gadget too): what the host's readers (evdev's of the pad and of
its Touchpad, hidapi's) read until the device is gone ends on the neutral state.
"""

from __future__ import annotations

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
from checks_copilot import RumbleAnswerer, helper_pad
from checks_runtime import ProbeLines, _write
from outputlib import HidrawReader, InProcessRun, hid_driver

from neurotouch_hid.core.estimate import GestureEstimate, GestureType
from neurotouch_hid.mapping.profile import load_profile
from neurotouch_hid.mapping.touchpad import pad_position
from neurotouch_hid.targets.identity import identity_for
from neurotouch_hid.targets.protocols import PROTOCOLS
from neurotouch_hid.targets.reports.dualsense import DUALSENSE

TIMEOUT_S = 420
ROW = PROTOCOLS["dualsense"]
IDS = (ROW.vendor, ROW.product)
#: Seconds of gel at rest before the first touch: hidapi's reader and the Touchpad's evdev reader
#: must be open before it (UHID delivers a report on a change only, evdev a change only); the run
#: replays from when its device exists, and under emulation at load 12-17 the readers took more
#: than 13 s to open.
REST_S = 45.0
#: The fingers (user frame, mm): the first moves from A0 to A1, the second rests at B.
A0, A1, B = (-10.0, 0.0), (10.0, 5.0), (-12.0, -6.0)
#: The two fingers held until SIGTERM, pushed hard (the shipped profile clicks from 4 mm).
HELD = ((0.0, 0.0), (15.0, -8.0))
#: Windows while the fingers change (us), and while nothing does.
STEP_US, STILL_US = 40_000, 250_000
# linux/input-event-codes.h
ABS_MT_SLOT, ABS_MT_POSITION_X, ABS_MT_POSITION_Y, ABS_MT_TRACKING_ID = 0x2F, 0x35, 0x36, 0x39


def pressed(gesture: GestureType, points, level: float, t_us: int) -> GestureEstimate:
    """A window of ``gesture`` at ``level`` mm with a contact at each of ``points`` (mm)."""
    mm = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    return GestureEstimate(
        t_us=t_us,
        gesture=gesture,
        resting=False,
        intensity_mm=level,
        contacts_px=mm.copy(),
        contacts_mm=mm,
        translation_mm=np.array([level, 0.0]),
    )


def touches(rest_s: float = REST_S, hold_s: float = 240.0) -> list[GestureEstimate]:
    """The predictions: rest; one finger moving A0 -> A1 (1 s); a second finger at B (1 s); the
    second lifts (0.6 s); both lift (rest 0.6 s); two fingers pushing 5 mm held ``hold_s``. Windows
    of :data:`STEP_US` while the fingers change, :data:`STILL_US` while nothing does: a window
    costs ~45 ms of the emulated CPU (checks_runtime.STEP_US), and more at a high host load."""
    out: list[GestureEstimate] = []
    t = 0

    def add(seconds: float, make, step_us: int = STEP_US) -> None:
        nonlocal t
        n = max(1, int(round(seconds * 1e6 / step_us)))
        for i in range(n):
            t += step_us
            out.append(make((i + 1) / n, t))

    def moving(f: float) -> tuple[float, float]:
        return A0[0] + (A1[0] - A0[0]) * f, A0[1] + (A1[1] - A0[1]) * f

    add(rest_s, lambda f, t: GestureEstimate(t_us=t), STILL_US)
    add(1.0, lambda f, t: pressed(GestureType.PUSH, [moving(f)], 2.0, t))
    add(1.0, lambda f, t: pressed(GestureType.PINCH, [A1, B], 2.0, t))
    add(0.6, lambda f, t: pressed(GestureType.PUSH, [A1], 2.0, t))
    add(0.6, lambda f, t: GestureEstimate(t_us=t))
    add(hold_s, lambda f, t: pressed(GestureType.PUSH, list(HELD), 5.0, t), STILL_US)
    return out


#: A pause of the Touchpad's reports this long (s) is marked ("stalled"): shorter than the lift
#: between two strokes of checks_gadget_ffs.strokes (0.48 s), so a host that missed a whole lift
#: shows it. Reports come every 40 ms while a finger moves; between strokes the pause is marked too,
#: outside any stroke.
STALL_S = 0.4


class TouchWatcher:
    """Reads the Touchpad's event node in a thread: per slot, its events in order, each
    ``(code name, value)`` with ``id`` for ABS_MT_TRACKING_ID, ``x``/``y`` for the positions and
    ``("dropped", 0)`` in every slot where the kernel dropped events because this reader fell behind
    (:class:`guestlib.EventReader`), ``("stalled", ms)`` in every slot where the kernel's reports
    stopped for :data:`STALL_S` or longer (a starved emulated host: what was meant meanwhile, a lift
    among it, may never have reached the host); ``clicks``: BTN_LEFT's values."""

    def __init__(self, path: str) -> None:
        self.reader = guestlib.EventReader(path)
        self.slot = self.reader.axes.get(ABS_MT_SLOT, 0)  # the pad has none
        self.slots: dict[int, list[tuple[str, int]]] = {0: [], 1: []}
        self.clicks: list[int] = []
        self.times: list[float] = []  # when each report was read (monotonic s)
        self._stop = threading.Event()
        self._seen = 0
        self._last_t: float | None = None  # the last report's kernel time (s)
        self.thread = threading.Thread(target=self._loop, daemon=True)
        self.thread.start()

    def _loop(self) -> None:
        names = {ABS_MT_TRACKING_ID: "id", ABS_MT_POSITION_X: "x", ABS_MT_POSITION_Y: "y"}
        while not self._stop.is_set() and not self.reader.gone:
            self.reader.pump(timeout_s=0.2, until=lambda r: len(r.reports) > self._seen or self._stop.is_set())
            now = time.monotonic()
            for k, report in enumerate(self.reader.reports[self._seen :], start=self._seen):
                self.times.append(now)
                t_kernel = self.reader.report_times[k]
                if self._last_t is not None and t_kernel - self._last_t >= STALL_S:
                    for events in self.slots.values():
                        events.append(("stalled", round((t_kernel - self._last_t) * 1000)))
                self._last_t = t_kernel
                for etype, code, value in report:
                    if etype == 0 and code == guestlib.SYN_DROPPED:
                        for events in self.slots.values():
                            events.append(("dropped", 0))
                        self.slot = self.reader.axes.get(ABS_MT_SLOT, self.slot)
                    elif etype == 3 and code == ABS_MT_SLOT:
                        self.slot = value
                    elif etype == 3 and code in names:
                        self.slots.setdefault(self.slot, []).append((names[code], value))
                    elif etype == 1 and code == 0x110:  # BTN_LEFT: the touchpad's click
                        self.clicks.append(value)
            self._seen = len(self.reader.reports)

    def ids(self, slot: int) -> list[int]:
        return [v for name, v in list(self.slots.get(slot, [])) if name == "id"]

    def stop(self) -> None:
        self._stop.set()
        self.thread.join(10)
        self.reader.close()


#: The end of hid-playstation's name of the pad (its Touchpad and Motion Sensors add a word; usbhid
#: puts the manufacturer's string first).
PAD_NAME = "DualSense Wireless Controller"
#: The sizes of the feature reports hid-playstation reads (each with its id first).
FEATURE_SIZES = {0x05: 41, 0x09: 20, 0x20: 64}


def open_hidraw(alive, seen: dict, timeout_s: float):
    """The DualSense's hidraw node through hidapi once the host has it (AssertionError if
    ``alive()`` turns false or ``timeout_s`` passes first): how long that took into
    ``seen["device_s"]`` and a :class:`~outputlib.HidrawReader` of it into ``seen["reader"]``."""
    import hidraw

    t0 = time.monotonic()
    found = guestlib.wait_for(lambda: hidraw.enumerate(*IDS) or not alive(), timeout_s, 0.1)
    assert found and alive(), "no hidraw device, or the run ended"
    seen["device_s"] = time.monotonic() - t0
    device = hidraw.device()
    device.open(*IDS)
    seen["reader"] = HidrawReader(device)
    return device


def watch_touchpad(seen: dict, timeout_s: float = 20.0) -> TouchWatcher:
    """Once the DualSense's three evdev devices are there (or ``timeout_s`` passed): their names
    into ``seen["evdev"]``, name -> node into ``seen["nodes"]``, and a :class:`TouchWatcher` on the
    Touchpad, also ``seen["touch"]`` (for the caller's cleanup). AssertionError without a Touchpad."""
    nodes = guestlib.wait_for(lambda: (d := _devices()) and len(d) >= 3 and d, timeout_s) or _devices()
    seen["evdev"], seen["nodes"] = sorted(nodes), nodes
    pad = next((node for name, node in nodes.items() if name.endswith("Touchpad")), None)
    assert pad, f"no Touchpad among the DualSense's evdev devices: {seen['evdev']}"
    seen["touch"] = TouchWatcher(pad)
    return seen["touch"]


def stop_and_read_the_end(run, seen: dict) -> None:
    """SIGTERM to ``run`` (``InProcessRun.stop``), then the Touchpad's reader (``seen["touch"]``)
    until the device is gone and hidraw's (``seen["reader"]``) half a second more: the last
    reports each read."""
    run.stop()
    guestlib.wait_for(lambda: seen["touch"].reader.gone, 10.0)
    time.sleep(0.5)
    seen["reader"].stop()


def read_features(device, seen: dict, tries: int = 3) -> None:
    """HIDIOCGFEATURE (hidapi's ``get_feature_report``) of each feature report into
    ``seen["features"]`` (id -> bytes), each tried ``tries`` times a second apart (a UHID request
    gives up after 5 s): the errors, with how long each took, into ``seen["feature_errors"]``."""
    seen["features"], seen["feature_errors"] = {}, []
    for rid in DUALSENSE.feature_ids:
        for _ in range(tries):
            t_ask = time.monotonic()
            try:
                seen["features"][rid] = bytes(device.get_feature_report(rid, 256))
                break
            except OSError as exc:
                seen["feature_errors"].append((rid, str(exc), round(time.monotonic() - t_ask, 2)))
                time.sleep(1.0)


def assert_bound(seen: dict, log: list[str]) -> None:
    """hid-playstation bound (``seen["driver"]``) without "Failed to retrieve" or "Duplicate
    device" in the kernel's ``log``, and ``seen["features"]`` each of its size with its id first."""
    assert seen["driver"] == "playstation", f"the HID driver of {seen['sysfs_name']}: {seen['driver']}; {log[-8:]}"
    bad = [line for line in log if "Failed to retrieve" in line or "Duplicate device" in line]
    assert not bad, f"the kernel's log: {bad}"
    assert set(seen["features"]) == set(FEATURE_SIZES), f"HIDIOCGFEATURE: {seen.get('feature_errors')}"
    for rid, data in seen["features"].items():
        assert data[0] == rid and len(data) == FEATURE_SIZES[rid], (rid, data.hex())


#: The merged pad of the copilot's checks (checks_copilot.helper_pad), as a profile names it.
COPILOT = """
copilot:
  - device: "Helper Pad"
"""


def merged_touchpad(folder: Path) -> Path:
    """The shipped ``touchpad`` profile with checks_copilot.py's "Helper Pad" merged, in ``folder``."""
    from neurotouch_hid.mapping.profile import find_profile

    path = folder / "touchpad-merged.yaml"
    path.write_text(Path(find_profile("touchpad")).read_text() + COPILOT)
    return path


def merged_rumble(answerer: RumbleAnswerer, timeout_s: float = 30.0) -> dict:
    """What the merged pad received once the host's rumble came back as Feedback: its uploads
    (type, strong, weak) and its plays (id, value), waited for until one plays."""
    played = guestlib.wait_for(lambda: [s for s in list(answerer.seen) if s[0] == "play" and s[2]], timeout_s)
    return {
        "uploads": [s[1:] for s in list(answerer.seen) if s[0] == "upload"][:3],
        "plays": [s[1:] for s in played or []][:3],
    }


def assert_merged_rumble(got: dict, answerer: RumbleAnswerer, run) -> None:
    """An FF_RUMBLE effect with a strength was uploaded to the merged pad and played."""
    from evdev import ecodes

    assert got["plays"], f"the host's rumble never reached the merged pad: {answerer.seen} {run.said[-8:]}"
    rumbles = [upload for upload in got["uploads"] if upload[0] == ecodes.FF_RUMBLE]
    assert rumbles and max(max(u[1], u[2]) for u in rumbles) > 0, got["uploads"]


def _devices() -> dict[str, str]:
    """The DualSense's evdev devices: name -> node."""
    from evdev import InputDevice, list_devices

    found = {}
    for path in list_devices():
        try:
            device = InputDevice(path)
        except OSError:
            continue
        if (device.info.vendor, device.info.product) == IDS:
            found[device.name] = path
    return found


def _uniq(sysfs_name: str) -> str | None:
    for line in (Path("/sys/bus/hid/devices") / sysfs_name / "uevent").read_text().splitlines():
        if line.startswith("HID_UNIQ="):
            return line.split("=", 1)[1]
    return None


def _kernel_log() -> list[str]:
    return guestlib.sh(["dmesg"]).stdout.splitlines()


def check_run_output_hid_dualsense() -> dict:
    """See the module docstring: a run as a DualSense on UHID, read by hid-playstation, hidraw,
    evdev and SDL, then a restart."""

    modprobe = {m: guestlib.sh(["modprobe", m]).returncode == 0 for m in ("uhid", "hid-playstation")}
    guestlib.settle()
    log_before = len(_kernel_log())
    folder = Path(tempfile.mkdtemp(prefix="dualsense-check-"))
    preds, _ = _write(folder, touches())
    profile = merged_touchpad(folder)
    spec = load_profile(profile).touchpad
    helper = helper_pad()  # the user's own pad, merged (``copilot:``): the DualSense's rumble reaches it
    answerer = RumbleAnswerer(helper)
    guestlib.settle()
    t0 = time.monotonic()
    run = InProcessRun(preds, profile, "hid", protocol="dualsense")
    seen: dict = {}
    sdl: dict = {}

    def start_sdl() -> tuple[subprocess.Popen, ProbeLines]:
        """SDL once the touches are in: its start (tens of seconds of the emulated CPU) would
        compete with the run's windows."""
        sdl["probe"] = subprocess.Popen(
            [sys.executable, str(Path(__file__).resolve().parent / "sdl_probe.py"), "--serve", "240", f"{IDS[1]:04x}"],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            env=guestlib.sdl_env(),
        )
        sdl["lines"] = ProbeLines(sdl["probe"])
        return sdl["probe"], sdl["lines"]

    def steps(run: InProcessRun) -> None:
        t_run = time.monotonic()
        device = open_hidraw(run.alive, seen, 150.0)
        # the Touchpad's reader first: evdev sends changes only, a touch already held says nothing
        watcher = watch_touchpad(seen)
        seen["watching_s"] = time.monotonic() - t_run
        assert seen["watching_s"] < REST_S - 5, (
            f"the Touchpad's reader came {seen['watching_s']:.1f} s after the device"
        )
        guestlib.settle()
        seen["sysfs_name"], seen["driver"] = hid_driver(IDS)
        seen["uniq"] = _uniq(seen["sysfs_name"])
        read_features(device, seen)
        assert len(seen["features"]) == 3, f"HIDIOCGFEATURE: {seen['feature_errors']}; said {run.said[-6:]}"
        seen["descriptor"] = bytes(device.get_report_descriptor())
        # the first finger, its move, the second finger, the lifts, the two held fingers
        held = guestlib.wait_for(
            lambda: len([i for i in watcher.ids(0) if i >= 0]) >= 2 and len([i for i in watcher.ids(1) if i >= 0]) >= 2,
            150.0,
        )
        seen["touches_s"] = time.monotonic() - t_run
        reports = seen["reader"].reports
        assert held, (
            f"the touches did not all arrive: {watcher.slots}; run alive {run.alive()}, said {run.said[-6:]}; "
            f"{len(reports)} reports on hidraw, the last {reports[-1].hex() if reports else None}; touchpad "
            f"reports {len(watcher.times)} over {(watcher.times[-1] - watcher.times[0]) if watcher.times else 0:.1f} s"
        )
        seen["clicked"] = guestlib.wait_for(lambda: 1 in watcher.clicks, 10.0)
        t_sdl = time.monotonic()
        probe, lines = start_sdl()
        ready = guestlib.wait_for(
            lambda: lines.first("opened") or lines.first("done") or probe.poll() is not None, 180.0
        )
        seen["sdl_s"] = time.monotonic() - t_sdl
        if not (isinstance(ready, dict) and ready.get("opened")):
            error = probe.stderr.read()[-1500:] if probe.poll() is not None else "(still running)"
            raise AssertionError(f"SDL did not open it: {lines.lines}, exit {probe.poll()}, stderr {error}")
        probe.stdin.write("rumble\n")
        probe.stdin.flush()
        seen["sdl_rumble"] = guestlib.wait_for(lambda: lines.first("rumble"), 30.0)
        seen["rumble_said"] = guestlib.wait_for(
            lambda: next((line for line in list(run.said) if line.startswith("rumble (the gel has no motor)")), None),
            30.0,
        )
        seen["merged_rumble"] = merged_rumble(answerer)
        probe.stdin.write("quit\n")
        probe.stdin.flush()
        stop_and_read_the_end(run, seen)

    try:
        run(steps)
    finally:
        if "probe" in sdl and sdl["probe"].poll() is None:
            sdl["probe"].kill()
        if "touch" in seen:
            seen["touch"].stop()
        answerer.stop()
        helper.close()
    log = _kernel_log()[log_before:]
    reader, watcher = seen["reader"], seen["touch"]

    # a restart: the same camera (here the default identity) gives the same MAC
    (folder / "again").mkdir()
    rest = [GestureEstimate(t_us=(i + 1) * STILL_US) for i in range(1200)]
    again_preds, again_profile = _write(folder / "again", rest)
    again = InProcessRun(again_preds, again_profile, "hid", protocol="dualsense")

    def restart(run: InProcessRun) -> None:
        found = guestlib.wait_for(lambda: hid_driver(IDS)[1] == "playstation" or not run.alive(), 150.0, 0.1)
        assert found and run.alive(), f"no DualSense on the restart: {run.said[-5:]}"
        seen["uniq_again"] = _uniq(hid_driver(IDS)[0])
        run.stop()

    again(restart)
    log_all = _kernel_log()[log_before:]

    slot0, slot1 = watcher.slots[0], watcher.slots[1]
    first_lift = slot0.index(("id", -1)) if ("id", -1) in slot0 else len(slot0)
    moved = [v for name, v in slot0[:first_lift] if name == "x"]  # the first finger's x while it lasts
    assert run.returned, f"the run did not return after SIGTERM: {run.said[-5:]}"
    assert_bound(seen, log_all)
    assert any(name.endswith("Touchpad") for name in seen["evdev"]) and any(
        name.endswith("Motion Sensors") for name in seen["evdev"]
    ), seen["evdev"]
    mac = seen["features"][0x09][1:7]
    assert seen["uniq"] == ":".join(f"{b:02x}" for b in reversed(mac)) == identity_for(None).uniq, seen["uniq"]
    assert seen["uniq_again"] == seen["uniq"], f"HID_UNIQ after a restart: {seen['uniq_again']} != {seen['uniq']}"
    # slot 0: the first finger appears at A0, moves to A1, lifts; slot 1: the second finger at B, lifts
    start, end, second = pad_position(spec, *A0), pad_position(spec, *A1), pad_position(spec, *B)
    assert moved and abs(moved[0] - start[0]) <= 40 and moved[-1] == end[0], slot0[:40]
    assert moved == sorted(moved) and len(moved) >= 3, f"slot 0's x as the finger moved right: {moved}"
    assert ("y", end[1]) in slot0[:first_lift], slot0[:first_lift]
    assert ("x", second[0]) in slot1 and ("y", second[1]) in slot1, slot1
    ids0, ids1 = watcher.ids(0), watcher.ids(1)
    # each slot: a touch, its lift (-1), the held touch, its lift at SIGTERM
    assert len(ids0) == len(ids1) == 4 and ids0[1] == ids1[1] == -1 and min(ids0[::2] + ids1[::2]) >= 0, (
        ids0,
        ids1,
        f"events the kernel dropped for the reader falling behind: {watcher.reader.dropped} times",
    )
    assert watcher.ids(0)[-1] == -1 and watcher.ids(1)[-1] == -1, "a touch was left down after SIGTERM"
    assert reader.reports and reader.reports[-1] == DUALSENSE.neutral(), (
        f"last report after SIGTERM: {reader.reports[-1].hex() if reader.reports else None}"
    )
    assert seen["sdl_rumble"] and seen["sdl_rumble"].get("rumble"), f"SDL's rumble: {seen['sdl_rumble']}"
    assert seen["rumble_said"], f"no rumble feedback from the DualSense: {run.said[-8:]}"
    assert_merged_rumble(seen["merged_rumble"], answerer, run)
    return {
        "modprobe": modprobe,
        "hid_device": seen["sysfs_name"],
        "driver": seen["driver"],
        "kernel_log": [line for line in log_all if "playstation" in line or "DualSense" in line][-6:],
        "evdev": seen["evdev"],
        "features": {f"{rid:#04x}": data.hex() for rid, data in seen["features"].items()},
        "feature_errors": seen["feature_errors"],
        "uniq": seen["uniq"],
        "uniq_again": seen["uniq_again"],
        "descriptor_bytes": len(seen["descriptor"]),
        "slot0": slot0[:60],
        "slot1": slot1[:60],
        "ids": [watcher.ids(0), watcher.ids(1)],
        "clicked": bool(seen["clicked"]),
        "reports": len(reader.reports),
        "touchpad_reports": len(watcher.times),
        "touchpad_reports_s": round(watcher.times[-1] - watcher.times[0], 1) if watcher.times else None,
        "last_report": reader.reports[-1].hex(),
        "sdl_opened": sdl["lines"].first("opened"),
        "sdl_rumble": seen["sdl_rumble"],
        "rumble_said": seen["rumble_said"],
        "merged_rumble": seen["merged_rumble"],
        "device_after_start_s": round(seen["device_s"], 1),
        "watching_after_start_s": round(seen["watching_s"], 1),
        "touches_after_start_s": round(seen["touches_s"], 1),
        "sdl_opened_s": round(seen["sdl_s"], 1),
        "check_s": round(time.monotonic() - t0, 1),
        "said_tail": run.said[-4:],
        "kernel_log_new": log[-12:],
    }


#: The killed runs' press: two fingers at :data:`HELD` pushing 5 mm (a touch in each slot, the
#: left stick pushed, the touchpad clicked) for PRESS_S, the gel at rest for LIFT_S, again and
#: again: readers that open late still see whole touches begin.
PRESS_S, LIFT_S = 3.0, 1.0
#: hid-playstation's pad at rest: the sticks at 128 (0..255), the triggers at 0.
PAD_AT_REST = {0x00: 128, 0x01: 128, 0x03: 128, 0x04: 128, 0x02: 0, 0x05: 0}
# linux/input-event-codes.h
BTN_TOUCH, BTN_LEFT = 0x14A, 0x110


def pressing(seconds: float = 300.0) -> list[GestureEstimate]:
    """The killed runs' predictions (:data:`PRESS_S`, :data:`LIFT_S`), in :data:`STILL_US` windows."""
    out, t = [], 0
    per_press, per_lift = int(PRESS_S * 1e6 / STILL_US), int(LIFT_S * 1e6 / STILL_US)
    while t < seconds * 1e6:
        for _ in range(per_lift):
            t += STILL_US
            out.append(GestureEstimate(t_us=t))
        for _ in range(per_press):
            t += STILL_US
            out.append(pressed(GestureType.PUSH, list(HELD), 5.0, t))
    return out


def _without_guard() -> None:
    """In a killed run's child: the UHID device and the FunctionFS function without their guard
    (what the check shows the guard for)."""
    from neurotouch_hid.targets.gadget.ffs import FfsTarget
    from neurotouch_hid.targets.uhid import UhidDevice

    UhidDevice._start_guard = lambda self: None
    del FfsTarget.guarded


def killed(output: str, guarded: bool = True) -> dict:
    """``run --output OUTPUT --protocol dualsense`` (the shipped ``touchpad`` profile, fed
    :func:`pressing`) in a forked child killed by SIGKILL while two touches are active, the left
    stick pushed and the touchpad clicked: what the host's readers (evdev: the pad and its
    Touchpad; hidapi) read from then until the devices are gone. ``guarded`` False: the UHID
    device or the FunctionFS function without its guard. The caller removes a gadget the killed
    run made."""
    from checks_gadget import _ForkedRun

    t0 = time.monotonic()
    folder = Path(tempfile.mkdtemp(prefix="dualsense-killed-"))
    preds, _ = _write(folder, pressing())
    run = _ForkedRun(preds, "touchpad", "dualsense", output=output, before=None if guarded else _without_guard)
    seen: dict = {}
    pad = None
    try:
        open_hidraw(run.alive, seen, 400.0)
        touch = watch_touchpad(seen, 30.0)
        node = next((node for name, node in seen["nodes"].items() if name.endswith(PAD_NAME)), None)
        assert node, f"no pad among the DualSense's evdev devices: {seen['evdev']}"
        pad = TouchWatcher(node)

        def held() -> bool:
            ids = [touch.ids(slot)[-1:] for slot in (0, 1)]
            return (
                all(i and i[0] >= 0 for i in ids)
                and {BTN_TOUCH, BTN_LEFT} <= touch.reader.keys
                and pad.reader.axes.get(0x00, 128) != 128
            )

        assert guestlib.wait_for(held, 200.0, 0.02), (
            f"no press seen: slots {touch.slots}, keys {touch.reader.keys}, pad {pad.reader.axes}"
        )
        seen["at_kill"] = {
            "touch_ids": [touch.ids(0)[-1], touch.ids(1)[-1]],
            "touch_keys": sorted(touch.reader.keys),
            "pad_axes": dict(pad.reader.axes),
        }
        marks = {"touch": len(touch.reader.reports), "pad": len(pad.reader.reports), "hid": len(seen["reader"].reports)}
        t_kill = time.monotonic()
        run.kill()
        seen["gone"] = bool(guestlib.wait_for(lambda: touch.reader.gone and pad.reader.gone, 30.0, 0.02))
        seen["gone_s"] = round(time.monotonic() - t_kill, 2)
        time.sleep(0.5)
        seen["reader"].stop()
    finally:
        run.kill()
        for watcher in (seen.get("touch"), pad):
            if watcher is not None:
                watcher.stop()
        if "reader" in seen:
            seen["reader"].stop()
    hid = seen["reader"]
    return {
        "output": output,
        "guarded": guarded,
        "killed": os.WIFSIGNALED(run.status) and os.WTERMSIG(run.status) == signal.SIGKILL,
        "at_kill": seen["at_kill"],
        "gone": seen["gone"],
        "gone_after_kill_s": seen["gone_s"],
        # what each reader read after the kill, in order (evdev: a report = its events up to SYN_REPORT)
        "touchpad_after": touch.reader.reports[marks["touch"] :][-6:],
        "pad_after": pad.reader.reports[marks["pad"] :][-6:],
        "hidraw_after": [r.hex() for r in hid.reports[marks["hid"] :]][-3:],
        "hidraw_error": hid.error,
        "touchpad_last": {"ids": [touch.ids(0)[-1], touch.ids(1)[-1]], "keys": sorted(touch.reader.keys)},
        "pad_last": {"axes": {c: pad.reader.axes.get(c) for c in PAD_AT_REST}, "keys": sorted(pad.reader.keys)},
        "seconds": round(time.monotonic() - t0, 1),
    }


def assert_killed_neutral(done: dict) -> None:
    """What the host read last after the kill (``killed``'s details) is the neutral state: both
    touch points inactive (tracking id -1), nothing pressed on the Touchpad or the pad, the sticks
    and triggers at rest, hidraw's last report the neutral one; then the devices went."""
    at_kill = done["at_kill"]
    assert done["killed"], "the run was not killed by SIGKILL"
    assert min(at_kill["touch_ids"]) >= 0 and at_kill["pad_axes"].get(0x00) != 128, at_kill
    assert done["touchpad_last"]["ids"] == [-1, -1], f"touch points after the kill: {done['touchpad_after']}"
    assert done["touchpad_last"]["keys"] == [] and done["pad_last"]["keys"] == [], done
    assert done["pad_last"]["axes"] == PAD_AT_REST, f"the pad after the kill: {done['pad_after']}"
    assert done["hidraw_after"] and done["hidraw_after"][-1] == DUALSENSE.neutral().hex(), done["hidraw_after"]
    assert done["gone"], "the devices stayed after the kill"


def check_killed_dualsense_leaves_the_host_neutral() -> dict:
    """``run --output hid --protocol dualsense`` killed by SIGKILL mid-press (:func:`killed`): the
    UHID device's guard hands the host the neutral report before the device goes with it
    (:func:`assert_killed_neutral`)."""
    guestlib.sh(["modprobe", "uhid"])
    guestlib.sh(["modprobe", "hid-playstation"])
    done = killed("hid")
    assert_killed_neutral(done)
    return done
