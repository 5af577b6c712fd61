"""Guest check of two gels on one board over USB, in a real kernel: ``gadget setup --protocol hid
--serial LEFT1 --serial RIGHT1`` makes one gadget with a pad per camera on dummy_hcd's UDC, and
two drivers (``run --output usb --serial LEFT1``, ``--serial RIGHT1``) at once each find their own
pad by their serial. The same kernel's host side sees two joysticks, told apart by their
interface (phys ``.../input0``, ``.../input1``; one USB device: the same name and serial), each
driven by its own gel: LEFT1's holds a push (stick right, button 1 down), RIGHT1's pushes and
rests again and again, and LEFT1's pad never lets go meanwhile. SIGTERM to LEFT1's driver: its pad
is left centred, nothing pressed; RIGHT1's pad keeps moving meanwhile, and its driver still runs
once LEFT1's has exited (0).

Run by tests/kernel/guest.py inside qemu after checks_gadget.py (whose kernel set-up it uses);
asserted on by tests/test_gadget_kernel.py. Each driver is ``run_driver`` (what `neurotouch-hid
run` calls) in a process forked from this one (a Python start costs tens of seconds here), on a
predictions file replayed in real time as ``run --source PRED.jsonl`` does (the emulated guest
cannot run the gesture pipeline in real time, let alone twice).
"""

from __future__ import annotations

import json
import os
import select
import signal
import tempfile
import time
from pathlib import Path

import guestlib
import numpy as np
from checks_gadget import _kernel
from checks_runtime import timeline
from outputlib import PROFILE

from neurotouch_hid.core.estimate import GestureType
from neurotouch_hid.targets.gadget import configfs
from neurotouch_hid.targets.protocols import PROTOCOLS

LEFT, RIGHT = "LEFT1", "RIGHT1"
HID_IDS = (PROTOCOLS["hid"].vendor, PROTOCOLS["hid"].product)
#: ABS_X of the push held at 6 mm, the profile's saturation: the joystick's signed 16-bit maximum.
FULL_RIGHT = 32767
#: How long each gel's predictions last (s): a minute, several times what the check needs once
#: both drivers run; no more, since each run reads its whole file before it starts, which costs
#: guest time in proportion (tests/kernel/README.md, checks_gadget_ffs.py's DualSense).
GEL_S = 60.0
#: How long the two joysticks' first reports may take after the drivers are forked (s).
WAIT_S = 120.0


def _preds(folder: Path, pushes: int, push_s: float, rest_s: float) -> Path:
    """A gel pushing to the right (the user frame's +x) ``pushes`` times, each ramped to 6 mm in
    0.3 s, held ``push_s``, then ``rest_s`` at rest: the predictions file a run replays."""
    from neurotouch_hid.core.dataset import write_predictions
    from neurotouch_hid.core.estimate import GestureEstimate

    segments = [(1.0, GestureType.NONE, lambda f: 0.0)]
    for _ in range(pushes):
        segments += [(0.3, GestureType.PUSH, lambda f: 6.0 * f), (push_s, GestureType.PUSH, lambda f: 6.0)]
        segments += [(rest_s, GestureType.NONE, lambda f: 0.0)]
    estimates = [
        GestureEstimate(
            t_us=e.t_us,
            gesture=e.gesture,
            resting=False,
            intensity_mm=e.intensity_mm,
            translation_mm=np.array([e.intensity_mm, 0.0]),
        )
        if e.gesture is GestureType.PUSH
        else e
        for e in timeline(segments)
    ]
    path = folder / "gestures.jsonl"
    write_predictions(path, estimates)
    return path


def _start(preds: Path, profile: Path, serial: str) -> tuple[int, int]:
    """``run --source PREDS --profile PROFILE --output usb --protocol hid --serial SERIAL`` in a
    forked child: (its pid, the read end of the pipe its answer comes on: JSON, what it said)."""
    # what a run imports as it goes, imported here once: each child has it then (an import costs
    # seconds under emulation, and each child would pay it)
    import neurotouch_hid.engine.engine  # noqa: F401
    import neurotouch_hid.mapping.mapper  # noqa: F401
    import neurotouch_hid.targets.gadget.targets  # noqa: F401
    from neurotouch_hid.engine.driver import DriverOptions, run_driver

    read_fd, write_fd = os.pipe()
    child = os.fork()
    if child == 0:
        said: list[str] = []
        answer: dict = {"ok": False}
        try:
            os.close(read_fd)
            signal.signal(signal.SIGTERM, signal.SIG_DFL)
            run_driver(str(preds), str(profile), "usb", DriverOptions(protocol="hid", serial=serial, say=said.append))
            answer = {"ok": True}
        except BaseException as exc:  # noqa: BLE001 - handed to the parent
            answer = {"ok": False, "error": f"{type(exc).__name__}: {exc}"}
        finally:
            answer["said"] = said[-10:]
            data = json.dumps(answer, default=str).encode()
            while data:
                data = data[os.write(write_fd, data) :]
            os._exit(0)
    os.close(write_fd)
    return child, read_fd


def _end(pid: int, fd: int, timeout_s: float = 60.0, term: bool = True) -> dict:
    """SIGTERM to the child (``term``: not when it was sent one already), then its answer and
    exit code (killed after ``timeout_s``)."""
    try:
        if term:
            os.kill(pid, signal.SIGTERM)
    except ProcessLookupError:
        pass
    chunks, end = [], time.monotonic() + timeout_s
    while time.monotonic() < end and select.select([fd], [], [], max(0.0, end - time.monotonic()))[0]:
        chunk = os.read(fd, 65536)
        if not chunk:
            break
        chunks.append(chunk)
    os.close(fd)
    done, status = os.waitpid(pid, os.WNOHANG)
    if done == 0:
        os.kill(pid, signal.SIGKILL)
        _, status = os.waitpid(pid, 0)
    answer = json.loads(b"".join(chunks) or b'{"ok": false, "error": "no answer"}')
    answer["exit"] = os.waitstatus_to_exitcode(status)
    return answer


def _pushes(reader: guestlib.EventReader) -> int:
    """How many times the pad's stick went from centre to the right (ABS_X 0, then above 0)."""
    x, count = 0, 0
    for report in reader.reports:
        for kind, code, value in report:
            if (kind, code) == (3, 0):  # EV_ABS, ABS_X
                count += x == 0 and value > 0
                x = value
    return count


def _joysticks() -> dict[str, str]:
    """The host's event nodes of the gadget's joysticks, by interface (phys's ``inputN``)."""
    from evdev import InputDevice, ecodes, list_devices

    found = {}
    for path in list_devices():
        device = InputDevice(path)
        if (device.info.vendor, device.info.product) == HID_IDS and ecodes.EV_ABS in device.capabilities():
            found[device.phys.rsplit("/", 1)[-1]] = path
        device.close()
    return found


def check_usb_two_cameras_two_pads() -> dict:
    """See the module docstring."""
    from evdev import ecodes

    t0 = time.monotonic()
    _kernel()
    folder = Path(tempfile.mkdtemp(prefix="gadget-pads-"))
    profile = folder / "guestcheck.yaml"
    profile.write_text(PROFILE)
    code, out, err = guestlib.cli_in_process(
        "gadget", "setup", "--protocol", "hid", "--serial", LEFT, "--serial", RIGHT
    )
    assert code == 0, f"gadget setup: {out}{err}"
    functions = sorted(p.name for p in (configfs.gadget_dir() / "functions").iterdir())
    runs: dict[str, tuple[int, int]] = {}
    readers: dict[str, guestlib.EventReader] = {}
    details: dict = {"setup": out.strip().splitlines(), "functions": functions}
    phases = details["phases_s"] = {"set_up": round(time.monotonic() - t0, 1)}  # where the guest's time goes

    def mark(name: str) -> None:
        phases[name] = round(time.monotonic() - t0, 1)

    try:
        for serial, (pushes, push_s, rest_s) in ((LEFT, (1, GEL_S, 1.0)), (RIGHT, (int(GEL_S / 0.8), 0.2, 0.3))):
            (folder / serial).mkdir()
            runs[serial] = _start(_preds(folder / serial, pushes, push_s, rest_s), profile, serial)
        mark("forked")
        nodes = guestlib.wait_for(lambda: _joysticks() if len(_joysticks()) == 2 else None, 30.0)
        assert nodes and sorted(nodes) == ["input0", "input1"], f"the host's joysticks: {nodes}"
        for serial, interface in ((LEFT, "input0"), (RIGHT, "input1")):  # the gadget's pads in the serials' order
            readers[serial] = guestlib.EventReader(nodes[interface])
            device = readers[serial].device
            details[serial] = {"interface": interface, "name": device.name, "phys": device.phys, "uniq": device.uniq}
        left, right = readers[LEFT], readers[RIGHT]
        t_fork = time.monotonic()
        held = lambda r: r.axes.get(ecodes.ABS_X, 0) == FULL_RIGHT and r.keys  # noqa: E731
        left.pump(timeout_s=WAIT_S, until=held, max_s=WAIT_S)
        assert held(left), f"LEFT1's held push: {left.axes}, {left.keys}"
        details["left_held_after_s"] = round(time.monotonic() - t_fork, 1)
        mark("left_held")
        held_from = len(left.reports)
        right.pump(timeout_s=WAIT_S, until=lambda r: _pushes(r) >= 3, max_s=WAIT_S)
        assert _pushes(right) >= 3, f"RIGHT1's pushes: {right.reports[-5:]}"
        left.pump(timeout_s=0.2, max_s=1.0)
        let_go = [r for r in left.reports[held_from:] if (ecodes.EV_ABS, ecodes.ABS_X, 0) in r]
        assert not let_go and left.keys, f"LEFT1's pad let go while RIGHT1 pushed: {let_go}"
        details["right_pushes_while_left_held"] = _pushes(right)

        mark("right_pushed")
        os.kill(runs[LEFT][0], signal.SIGTERM)  # its driver ends while RIGHT1's pushes on
        left.pump(timeout_s=2.0, until=lambda r: not r.keys and r.axes.get(ecodes.ABS_X) == 0, max_s=30.0)
        details["left_after_stop"] = {"x": left.axes.get(ecodes.ABS_X), "keys": sorted(left.keys)}
        before = _pushes(right)
        right.pump(timeout_s=5.0, until=lambda r: _pushes(r) >= before + 2, max_s=30.0)
        details["right_pushes_after_left_stopped"] = _pushes(right) - before
        mark("right_pushed_after_left_stop")
        details["left_result"] = _end(*runs.pop(LEFT), term=False)
        mark("left_exited")
        details["right_running_after_left_exited"] = os.waitpid(runs[RIGHT][0], os.WNOHANG)[0] == 0
        details["right_result"] = _end(*runs.pop(RIGHT))
        mark("right_exited")
        right.pump(timeout_s=2.0, until=lambda r: not r.keys and r.axes.get(ecodes.ABS_X) == 0, max_s=30.0)
        details["right_after_stop"] = {"x": right.axes.get(ecodes.ABS_X), "keys": sorted(right.keys)}
    finally:
        for pid, fd in runs.values():
            _end(pid, fd, 10.0)
        for reader in readers.values():
            reader.close()
        configfs.remove()
    for serial, result in ((LEFT, details["left_result"]), (RIGHT, details["right_result"])):
        assert result["ok"] and result["exit"] == 0, f"{serial}'s driver: {result}"
    assert details["left_after_stop"] == {"x": 0, "keys": []}, details["left_after_stop"]
    assert details["right_pushes_after_left_stopped"] >= 2, "RIGHT1's pad stopped moving when LEFT1's driver ended"
    assert details["right_running_after_left_exited"], "RIGHT1's driver ended with LEFT1's"
    assert details["right_after_stop"] == {"x": 0, "keys": []}, details["right_after_stop"]
    assert details[LEFT]["phys"] != details[RIGHT]["phys"]
    details["seconds"] = round(time.monotonic() - t0, 1)
    return details
