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
  comes back to the driver as Feedback (its line for the user);
* SIGTERM: the last report hidraw reads is the neutral one, every touch point inactive;
* a second run (a restart) has the same HID_UNIQ.
"""

from __future__ import annotations

import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import guestlib
import numpy as np
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

    def pressed(gesture: GestureType, points, level: float, t_us: int) -> GestureEstimate:
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

    def moving(f: float) -> tuple[float, float]:
        return A0[0] + (A1[0] - A0[0]) * f, A0[1] + (A1[1] - A0[1]) * f

    add(rest_s, lambda f, t: GestureEstimate(t_us=t), STILL_US)
    add(1.0, lambda f, t: pressed(GestureType.PUSH, [moving(f)], 2.0, t))
    add(1.0, lambda f, t: pressed(GestureType.PINCH, [A1, B], 2.0, t))
    add(0.6, lambda f, t: pressed(GestureType.PUSH, [A1], 2.0, t))
    add(0.6, lambda f, t: GestureEstimate(t_us=t))
    add(hold_s, lambda f, t: pressed(GestureType.PUSH, list(HELD), 5.0, t), STILL_US)
    return out


class TouchWatcher:
    """Reads the Touchpad's event node in a thread: per slot, its events in order, each
    ``(code name, value)`` with ``id`` for ABS_MT_TRACKING_ID, ``x``/``y`` for the positions;
    ``clicks``: BTN_LEFT's values."""

    def __init__(self, path: str) -> None:
        self.reader = guestlib.EventReader(path)
        self.slot = self.reader.device.absinfo(ABS_MT_SLOT).value
        self.slots: dict[int, list[tuple[str, int]]] = {0: [], 1: []}
        self.clicks: list[int] = []
        self.times: list[float] = []  # when each report was read (monotonic s)
        self._stop = threading.Event()
        self._seen = 0
        self.thread = threading.Thread(target=self._loop, daemon=True)
        self.thread.start()

    def _loop(self) -> None:
        names = {ABS_MT_TRACKING_ID: "id", ABS_MT_POSITION_X: "x", ABS_MT_POSITION_Y: "y"}
        while not self._stop.is_set() and not self.reader.gone:
            self.reader.pump(timeout_s=0.2, until=lambda r: len(r.reports) > self._seen or self._stop.is_set())
            now = time.monotonic()
            for report in self.reader.reports[self._seen :]:
                self.times.append(now)
                for etype, code, value in report:
                    if etype == 3 and code == ABS_MT_SLOT:
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
    import hidraw

    modprobe = {m: guestlib.sh(["modprobe", m]).returncode == 0 for m in ("uhid", "hid-playstation")}
    guestlib.settle()
    log_before = len(_kernel_log())
    folder = Path(tempfile.mkdtemp(prefix="dualsense-check-"))
    preds, _ = _write(folder, touches())
    profile = "touchpad"
    spec = load_profile(profile).touchpad
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
        found = guestlib.wait_for(lambda: hidraw.enumerate(*IDS) or not run.alive(), 150.0, 0.1)
        assert found and run.alive(), f"no hidraw device: {run.said[-5:]}"
        seen["device_s"] = time.monotonic() - t_run
        device = hidraw.device()
        device.open(*IDS)
        seen["reader"] = HidrawReader(device)
        # the Touchpad's reader first: evdev sends changes only, a touch already held says nothing
        nodes = guestlib.wait_for(lambda: (d := _devices()) and len(d) >= 3 and d, 20.0)
        seen["evdev"] = sorted(nodes or _devices())
        pad = next((node for name, node in (nodes or {}).items() if name.endswith("Touchpad")), None)
        assert pad, f"no Touchpad among the DualSense's evdev devices: {seen['evdev']}"
        seen["touch"] = watcher = TouchWatcher(pad)
        seen["watching_s"] = time.monotonic() - t_run
        assert seen["watching_s"] < REST_S - 5, (
            f"the Touchpad's reader came {seen['watching_s']:.1f} s after the device"
        )
        guestlib.settle()
        seen["sysfs_name"], seen["driver"] = hid_driver(IDS)
        seen["uniq"] = _uniq(seen["sysfs_name"])
        seen["features"], seen["feature_errors"] = {}, []
        for rid in DUALSENSE.feature_ids:
            for _ in range(3):  # an error is kept with how long it took (a UHID request gives up after 5 s)
                t_ask = time.monotonic()
                try:
                    seen["features"][rid] = bytes(device.get_feature_report(rid, 256))
                    break
                except OSError as exc:
                    seen["feature_errors"].append((rid, str(exc), round(time.monotonic() - t_ask, 2)))
                    time.sleep(1.0)
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
        assert isinstance(ready, dict) and ready.get("opened"), f"SDL did not open it: {lines.lines} {probe.poll()}"
        probe.stdin.write("rumble\n")
        probe.stdin.flush()
        seen["sdl_rumble"] = guestlib.wait_for(lambda: lines.first("rumble"), 30.0)
        seen["rumble_said"] = guestlib.wait_for(
            lambda: next((line for line in list(run.said) if line.startswith("rumble (the gel has no motor)")), None),
            30.0,
        )
        probe.stdin.write("quit\n")
        probe.stdin.flush()
        run.stop()
        guestlib.wait_for(lambda: watcher.reader.gone, 10.0)
        time.sleep(0.5)
        seen["reader"].stop()

    try:
        run(steps)
    finally:
        if "probe" in sdl and sdl["probe"].poll() is None:
            sdl["probe"].kill()
        if "touch" in seen:
            seen["touch"].stop()
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
    assert seen["driver"] == "playstation", f"the HID driver of {seen['sysfs_name']}: {seen['driver']}"
    bad = [line for line in log_all if "Failed to retrieve" in line or "Duplicate device" in line]
    assert not bad, f"the kernel's log: {bad}"
    assert any(name.endswith("Touchpad") for name in seen["evdev"]) and any(
        name.endswith("Motion Sensors") for name in seen["evdev"]
    ), seen["evdev"]
    for rid, data in seen["features"].items():
        assert data[0] == rid and len(data) == {0x05: 41, 0x09: 20, 0x20: 64}[rid], (rid, data.hex())
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
    assert len(ids0) == len(ids1) == 4 and ids0[1] == ids1[1] == -1 and min(ids0[::2] + ids1[::2]) >= 0, (ids0, ids1)
    assert watcher.ids(0)[-1] == -1 and watcher.ids(1)[-1] == -1, "a touch was left down after SIGTERM"
    assert reader.reports and reader.reports[-1] == DUALSENSE.neutral(), (
        f"last report after SIGTERM: {reader.reports[-1].hex() if reader.reports else None}"
    )
    assert seen["sdl_rumble"] and seen["sdl_rumble"].get("rumble"), f"SDL's rumble: {seen['sdl_rumble']}"
    assert seen["rumble_said"], f"no rumble feedback from the DualSense: {run.said[-8:]}"
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
        "device_after_start_s": round(seen["device_s"], 1),
        "watching_after_start_s": round(seen["watching_s"], 1),
        "touches_after_start_s": round(seen["touches_s"], 1),
        "sdl_opened_s": round(seen["sdl_s"], 1),
        "check_s": round(time.monotonic() - t0, 1),
        "said_tail": run.said[-4:],
        "kernel_log_new": log[-12:],
    }
