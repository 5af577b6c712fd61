"""Guest checks of the gadget's FunctionFS functions that answer their host's control requests:
the HID interface (``ffs.HidInterfaceTarget``) and the Xbox 360 pad's vendor requests, on
dummy_hcd, read on the same kernel's host side. Run by tests/kernel/guest.py in the same guest as
checks_gadget.py; asserted on by tests/test_gadget_ffs_kernel.py.

* :func:`check_usb_dualsense`: ``run --output usb --protocol dualsense`` read by hid-playstation
  (its docstring); :func:`check_usb_dualsense_killed`: the same killed by SIGKILL mid-press;
* :func:`check_usb_hid_interface_answers_feature_reports`: a HID interface with a small report
  format of this check's own (an input report 0x01, a feature report 0x05 of 41 bytes, an output
  report 0x02: the shape of a protocol whose host reads feature reports), made with configfs and
  FunctionFS here: hid-generic binds; the report descriptor the host read is the format's;
  ``HIDIOCGFEATURE`` (hidapi's ``get_feature_report``) returns the feature report's 41 bytes, and
  an unknown id fails; the input report arrives; an output report written on hidraw (the OUT
  endpoint) and one sent as SET_REPORT come back as Feedback; closing sends the neutral report.
"""

from __future__ import annotations

import struct
import tempfile
import time
from pathlib import Path

import guestlib
from checks_gadget import UDC, _kernel
from outputlib import HidrawReader

from neurotouch_hid.core.controller import ControllerState
from neurotouch_hid.core.stages import Feedback
from neurotouch_hid.targets.gadget import configfs

TIMEOUT_S = 600
#: Ids of the check's own HID interface (the Linux Foundation's, as the ``hid`` joystick, another product).
IDS = (0x1D6B, 0x0105)


class FeatureFormat:
    """A report format with a feature report (the check's own): input 0x01 (the X axis's high byte
    + 128, 6 zero bytes), feature 0x05 (40 bytes: 0..39), output 0x02 (7 bytes: rumble strong,
    weak)."""

    name = "feature-check"
    descriptor = bytes.fromhex(
        "05010905a101"  # Generic Desktop, Game Pad, Application
        "8501" "0930" "1500" "26ff00" "7508" "9501" "8102"  # report 1: X, 8 bits
        "7508" "9506" "8103"  # 6 constant bytes
        "0600ff" "8505" "0921" "9528" "b102"  # report 5: 40 vendor bytes, feature
        "8502" "0922" "9507" "9102"  # report 2: 7 vendor bytes, output
        "c0"
    )  # fmt: skip
    report_length = 8
    feature_ids = (0x05,)

    def pack(self, state: ControllerState) -> bytes:
        return struct.pack("<BB6x", 0x01, (state.axes.get("ABS_X", 0) >> 8) + 128)

    def neutral(self) -> bytes:
        return self.pack(ControllerState.neutral())

    def feature(self, report_id: int, identity: object) -> bytes:
        if report_id != 0x05:
            raise KeyError(report_id)
        return bytes([0x05, *range(40)])

    def parse_output(self, data: bytes) -> list[Feedback]:
        if len(data) >= 3 and data[0] == 0x02:
            return [Feedback("rumble", strong=data[1] / 255, weak=data[2] / 255)]
        return []


def _plan() -> configfs.GadgetPlan:
    return configfs.GadgetPlan("feature-check", *IDS, 0x0100, "neurotouch-hid", "Feature check", (), "pad")


def _dmesg() -> list[str]:
    return guestlib.sh(["dmesg"]).stdout.splitlines()


def check_usb_hid_interface_answers_feature_reports() -> dict:
    """See the module docstring."""
    import hidraw
    from outputlib import hid_driver

    from neurotouch_hid.targets.gadget.ffs import HidInterfaceTarget

    t0 = time.monotonic()
    _kernel()
    before = len(_dmesg())
    fmt = FeatureFormat()
    configfs.create(_plan())
    target = reader = None
    seen: dict = {}
    try:
        target = HidInterfaceTarget(configfs.FFS_ROOT / "pad", fmt, max_packet=64, interval_ms=4)
        configfs.bind(udc=UDC)
        found = guestlib.wait_for(lambda: hidraw.enumerate(*IDS), 60.0, 0.1)
        assert found, "the host side never enumerated the HID interface"
        guestlib.settle()
        seen["sysfs_name"], seen["driver"] = hid_driver(IDS)
        device = hidraw.device()
        device.open(*IDS)
        seen["descriptor"] = bytes(device.get_report_descriptor())
        seen["feature"] = bytes(device.get_feature_report(0x05, 64))
        try:
            seen["unknown_feature"] = bytes(device.get_feature_report(0x07, 64))
        except (OSError, ValueError) as exc:
            seen["unknown_feature"] = f"refused: {exc}"
        reader = HidrawReader(device)
        pushed = ControllerState.neutral()
        pushed.axes["ABS_X"] = 32767
        target.write(pushed)
        seen["got_push"] = guestlib.wait_for(lambda: fmt.pack(pushed) in reader.reports, 20.0)
        device.write(bytes([0x02, 0xFF, 0x80, 0, 0, 0, 0, 0]))  # the OUT endpoint
        device.send_feature_report(bytes([0x05, *([0] * 40)]))  # a feature set: logged, no feedback
        got: list = []
        seen["feedback"] = guestlib.wait_for(lambda: got.extend(target.feedback()) or got, 20.0, 0.05)
        target.close()
        seen["neutral"] = guestlib.wait_for(lambda: reader.reports[-1:] == [fmt.neutral()], 10.0)
        seen["last"] = reader.reports[-1] if reader.reports else b""
    finally:
        if reader is not None:
            reader.stop()
        if target is not None:
            target.close()
        configfs.remove()
    log = _dmesg()[before:]
    assert seen["driver"] == "hid-generic", f"the HID driver: {seen['driver']}; kernel: {log[-10:]}"
    assert seen["descriptor"] == fmt.descriptor, f"descriptor read back: {seen['descriptor'].hex()}"
    assert seen["feature"] == fmt.feature(0x05, None), f"feature 0x05: {seen['feature'].hex()}"
    assert isinstance(seen["unknown_feature"], str), f"feature 0x07 answered: {seen['unknown_feature']}"
    assert seen["got_push"], "the input report never arrived"
    assert seen["feedback"] and seen["feedback"][0].kind == "rumble", f"feedback: {seen['feedback']}"
    assert seen["neutral"], f"last report after close: {seen['last'].hex()}"
    return {
        "hid_device": seen["sysfs_name"],
        "driver": seen["driver"],
        "feature": seen["feature"].hex(),
        "unknown_feature": seen["unknown_feature"],
        "feedback": [(f.kind, round(f.strong, 3), round(f.weak, 3), f.source) for f in seen["feedback"]],
        "kernel_log": [line for line in log if "hid" in line.lower() or "usb" in line.lower()][-12:],
        "seconds": round(time.monotonic() - t0, 1),
    }


def check_usb_xinput_answers_the_vendor_requests() -> dict:
    """The Xbox 360 pad (``ffs.XInputTarget``, no run) bound on dummy_hcd: xpad binds; the host
    asks the vendor requests a wired pad answers (``C1 01``, wValue 0x0100, 20 bytes, and 0x0000,
    8 bytes) through usbfs (pyusb; usbfs lets a vendor request reach an interface another driver
    holds) and reads the pad's answers; the kernel log has no "unable to receive magic message"
    (xpad asks 0x0100 on open from Linux 6.4 on; this 6.1's does not ask); the configuration has
    one interface; a run of the ``switch-access`` profile (keys) on it is refused, naming ``hid``,
    before any gadget is made."""
    import usb.core

    from neurotouch_hid.core.errors import DeviceError
    from neurotouch_hid.mapping.profile import load_profile
    from neurotouch_hid.targets.gadget import UsbGadget
    from neurotouch_hid.targets.gadget.ffs import XINPUT_CAPABILITIES, XInputTarget
    from neurotouch_hid.targets.reports.xinput import XINPUT

    t0 = time.monotonic()
    _kernel()
    before = len(_dmesg())
    seen: dict = {}
    try:  # a profile with keys on an xinput gadget: refused before any gadget is made
        UsbGadget("xinput", load_profile("switch-access")).__enter__()
        seen["switch_access"] = "accepted"
    except DeviceError as exc:
        seen["switch_access"] = str(exc)
    seen["made_for_switch_access"] = configfs.gadget_dir().exists()
    configfs.create(configfs.plan("xinput"))
    target = None
    try:
        target = XInputTarget(configfs.FFS_ROOT / configfs.FFS_INSTANCE, XINPUT)
        configfs.bind(udc=UDC)
        bound = guestlib.wait_for(lambda: sorted(Path("/sys/bus/usb/drivers/xpad").glob("*:*")), 60.0, 0.1)
        assert bound, "xpad did not bind"
        guestlib.settle()
        device = usb.core.find(idVendor=XINPUT.vendor, idProduct=XINPUT.product)
        assert device is not None, "pyusb does not find the pad"
        seen["interfaces"] = device.get_active_configuration().bNumInterfaces
        for value, length in ((0x0100, 20), (0x0000, 8)):
            seen[f"{value:04x}"] = bytes(device.ctrl_transfer(0xC1, 0x01, value, 0, length, timeout=5000))
        try:
            seen["other"] = bytes(device.ctrl_transfer(0xC1, 0x01, 0x0200, 0, 20, timeout=5000))
        except usb.core.USBError as exc:
            seen["other"] = f"stalled: {exc}"
    finally:
        if target is not None:
            target.close()
        configfs.remove()
    log = _dmesg()[before:]
    magic = [line for line in log if "magic message" in line]
    assert not magic, f"xpad: {magic}"
    assert seen["0100"] == XINPUT_CAPABILITIES[0x0100], f"C1 01 0100: {seen['0100'].hex()}"
    assert seen["0000"] == XINPUT_CAPABILITIES[0x0000], f"C1 01 0000: {seen['0000'].hex()}"
    assert isinstance(seen["other"], str), f"C1 01 0200 answered: {seen['other']}"
    assert seen["interfaces"] == 1, f"bNumInterfaces {seen['interfaces']}"
    assert "use --protocol hid" in seen["switch_access"] and not seen["made_for_switch_access"], seen
    return {
        "switch_access": seen["switch_access"],
        "interfaces": seen["interfaces"],
        "answers": {key: seen[key].hex() for key in ("0100", "0000")},
        "other": seen["other"],
        "kernel_log": [line for line in log if "xpad" in line.lower() or "x-box" in line.lower()][-6:],
        "seconds": round(time.monotonic() - t0, 1),
    }


def strokes(seconds: float = 200.0) -> list:
    """Predictions (40 ms windows, as a DualSense's touches change in :func:`checks_dualsense.touches`):
    the gel at rest 2 s, then one finger pressing 2 mm and moving from (-10, 0) to (10, 5) mm in
    the user frame over 1.5 s, lifting for 0.5 s, again and again for ``seconds``: a reader that
    opens late (a loaded emulated host enumerates the gadget in 10 to 100 s) or falls behind still
    sees whole strokes. (The run reads the whole file before it starts: 20,000 windows of 10 ms
    took tens of seconds of the emulated CPU; 5,000 of 40 ms take a quarter of that.)"""
    import numpy as np

    from neurotouch_hid.core.estimate import GestureEstimate, GestureType

    window_us, out = 40_000, []
    rest, cycle, stroke = 50, 50, 38  # windows: 2 s at rest; a 2 s cycle; its first 1.52 s pressed
    for i in range(int(seconds * 1e6 / window_us)):
        t_us = (i + 1) * window_us
        phase = (i - rest) % cycle
        if i < rest or phase >= stroke:
            out.append(GestureEstimate(t_us=t_us))
            continue
        f = phase / (stroke - 1)
        mm = np.array([[-10.0 + 20.0 * f, 5.0 * f]])
        out.append(
            GestureEstimate(
                t_us=t_us, gesture=GestureType.PUSH, resting=False, intensity_mm=2.0,
                contacts_px=mm.copy(), contacts_mm=mm, translation_mm=np.array([2.0, 0.0]),
            )
        )  # fmt: skip
    return out


def _stroke(slot: list) -> list[int] | None:
    """The x positions of the last whole stroke in ``slot``'s events (``(name, value)``: a
    tracking id >= 0, its moves, the id -1), None before one was seen whole. A stroke with a
    ``("dropped", 0)`` inside (the kernel dropped events because the reader fell behind) or a
    ``("stalled", ms)`` (the host's reports stopped longer than a lift: a starved emulated guest, seen
    in CI at host load ~10 as two strokes read as one, the lift between them never read) is not
    whole: its lift or its next touch may be among the lost events."""
    start, last = None, None
    for i, (name, value) in enumerate(slot):
        if name in ("dropped", "stalled"):
            start = None
        elif name == "id" and value >= 0 and start is None:
            start = i
        elif name == "id" and value == -1:
            if start is not None:
                last = (start, i)
            start = None
    return None if last is None else [value for name, value in slot[last[0] : last[1]] if name == "x"]


#: A DualSense rumble as a host writes it: output report 0x02 (48 bytes), valid_flag0's compatible
#: vibration, motor_right 0x40, motor_left 0xC0 (hid-playstation.c, struct dualsense_output_report_common).
RUMBLE = bytes([0x02, 0x01, 0x00, 0x40, 0xC0]) + bytes(43)


def check_usb_dualsense() -> dict:
    """``run --output usb --protocol dualsense`` with the shipped ``touchpad`` profile, fed
    :func:`strokes`: the HID interface on FunctionFS answers the host's requests itself, so the
    host's hid-playstation binds with no "Failed to retrieve" (and no "Duplicate device") in the
    kernel's log; HIDIOCGFEATURE gives 0x05, 0x09 and 0x20 their 41, 20 and 64 bytes, each with
    its id first; the Touchpad's slot 0 follows a stroke to the right (a whole one, from its
    touch to its lift); a rumble the host writes on hidraw (output report 0x02, the OUT endpoint)
    comes back as Feedback and reaches the pad the profile merges (``copilot:``); SIGTERM in the
    middle of a stroke: the touch point goes inactive (tracking id -1) and hidraw's last report
    is the neutral one."""
    from checks_copilot import RumbleAnswerer, helper_pad
    from checks_dualsense import (
        _uniq,
        assert_bound,
        assert_merged_rumble,
        merged_rumble,
        merged_touchpad,
        open_hidraw,
        read_features,
        stop_and_read_the_end,
        watch_touchpad,
    )
    from checks_runtime import _write
    from outputlib import InProcessRun, hid_driver

    from neurotouch_hid.targets.protocols import PROTOCOLS
    from neurotouch_hid.targets.reports.dualsense import DUALSENSE

    ids = (PROTOCOLS["dualsense"].vendor, PROTOCOLS["dualsense"].product)
    t0 = time.monotonic()
    _kernel()
    modprobe = guestlib.sh(["modprobe", "hid-playstation"]).returncode == 0
    before = len(_dmesg())
    folder = Path(tempfile.mkdtemp(prefix="gadget-dualsense-"))
    preds, _ = _write(folder, strokes())
    helper = helper_pad()  # merged (``copilot:``): the host's rumble on the gadget reaches it
    answerer = RumbleAnswerer(helper)
    guestlib.settle()
    run = InProcessRun(preds, merged_touchpad(folder), "usb", protocol="dualsense")
    seen: dict = {}

    def steps(run: InProcessRun) -> None:
        t_run = time.monotonic()
        device = open_hidraw(run.alive, seen, 400.0)
        guestlib.settle()
        seen["sysfs_name"], seen["driver"] = hid_driver(ids)
        seen["uniq"] = _uniq(seen["sysfs_name"])
        read_features(device, seen, tries=1)
        watcher = watch_touchpad(seen, 30.0)
        seen["watching_s"] = time.monotonic() - t_run
        seen["stroke"] = guestlib.wait_for(lambda: _stroke(list(watcher.slots[0])), 180.0)
        reports = seen["reader"].reports
        assert seen["stroke"], (
            f"no whole stroke on the Touchpad: {watcher.slots[0][-20:]}; hidraw read {len(reports)} reports, the "
            f"last {reports[-1].hex() if reports else None}; the run said {run.said[-8:]}; "
            f"kernel: {_dmesg()[before:][-10:]}; the device {seen['device_s']:.0f} s, the watcher "
            f"{seen['watching_s']:.0f} s after the start"
        )
        device.write(RUMBLE)  # the host's rumble: the OUT endpoint, then Feedback, then the merged pad
        seen["merged_rumble"] = merged_rumble(answerer)
        down = guestlib.wait_for(lambda: watcher.ids(0)[-1:] not in ([], [-1]), 30.0, 0.02)
        seen["down_at_sigterm"] = bool(down)
        stop_and_read_the_end(run, seen)

    try:
        run(steps)
    finally:
        if "touch" in seen:
            seen["touch"].stop()
        answerer.stop()
        helper.close()
        configfs.remove()
    log = _dmesg()[before:]
    reader, watcher = seen["reader"], seen["touch"]
    moved = seen["stroke"]
    assert_merged_rumble(seen["merged_rumble"], answerer, run)
    assert run.returned, f"the run did not return after SIGTERM: {run.said[-5:]}"
    assert_bound(seen, log)
    assert len(moved) >= 3 and moved == sorted(moved) and moved[-1] > moved[0], f"slot 0's x in a stroke: {moved}"
    assert seen["down_at_sigterm"] and watcher.ids(0)[-1] == -1, f"a touch left down after SIGTERM: {watcher.ids(0)}"
    assert reader.reports and reader.reports[-1] == DUALSENSE.neutral(), (
        f"last report after SIGTERM: {reader.reports[-1].hex() if reader.reports else None}"
    )
    return {
        "modprobe": modprobe,
        "hid_device": seen["sysfs_name"],
        "driver": seen["driver"],
        "uniq": seen["uniq"],
        "features": {f"{rid:#04x}": len(data) for rid, data in seen["features"].items()},
        "evdev": seen["evdev"],
        "slot0_x": moved[:40],
        "ids": watcher.ids(0)[-6:],
        "events_dropped": watcher.reader.dropped,  # SYN_DROPPED: the reader fell behind
        "last_report": reader.reports[-1].hex(),
        "kernel_log": [line for line in log if "playstation" in line or "DualSense" in line][-6:],
        "merged_rumble": seen["merged_rumble"],
        "device_after_start_s": round(seen["device_s"], 1),
        "watching_after_start_s": round(seen["watching_s"], 1),
        "seconds": round(time.monotonic() - t0, 1),
    }


def check_usb_dualsense_killed() -> dict:
    """``run --output usb --protocol dualsense`` killed by SIGKILL mid-press (checks_dualsense's
    :func:`~checks_dualsense.killed`): the gadget's guard, whose copy of the IN endpoint keeps the
    function bound, hands the host the neutral report; then the gadget is unbound (FunctionFS,
    every file closed) and the host's devices go (:func:`~checks_dualsense.assert_killed_neutral`).
    The check removes the gadget the killed run made."""
    from checks_dualsense import assert_killed_neutral, killed

    _kernel()
    guestlib.sh(["modprobe", "hid-playstation"])
    try:
        done = killed("usb")
    finally:
        configfs.remove()
    assert_killed_neutral(done)
    return done
