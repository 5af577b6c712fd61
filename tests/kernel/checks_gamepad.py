"""Guest checks of the virtual gamepad (neurotouch_hid.targets.uinput.gamepad) in a real kernel.

Run by tests/kernel/guest.py inside qemu; asserted on by tests/test_kernel.py.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
from pathlib import Path

import guestlib
from evdev import ecodes

from neurotouch_hid.core.controller import AXES, BUTTONS, ControllerState
from neurotouch_hid.targets.uinput.gamepad import PHYS, GamepadIdentity, VirtualGamepad, changed_events

HERE = Path(__file__).resolve().parent
TIMEOUT_S = 300  # generous: a loaded host under software emulation is slow

#: A state with every kind of value away from neutral.
PRESSED = ControllerState(
    t_us=1,
    axes={
        "ABS_X": 32767,
        "ABS_Y": -32768,
        "ABS_RX": 12345,
        "ABS_RY": -20000,
        "ABS_Z": 255,
        "ABS_RZ": 128,
        "ABS_HAT0X": -1,
        "ABS_HAT0Y": 1,
    },
    buttons={**{b: False for b in BUTTONS}, "BTN_SOUTH": True, "BTN_START": True, "BTN_THUMBR": True},
)


def _codes(state: ControllerState) -> tuple[dict[int, int], set[int]]:
    axes = {ecodes.ecodes[n]: v for n, v in state.axes.items()}
    keys = {ecodes.ecodes[n] for n, v in state.buttons.items() if v}
    return axes, keys


def check_device_appears() -> dict:
    """The uinput device exists with the Xbox 360 identity and exactly the gamepad capabilities."""
    with VirtualGamepad() as pad:
        path = pad.device_path
        assert path and os.path.exists(path), f"no event node for the gamepad: {path!r}"
        dev = pad._ui.device
        caps = dev.capabilities()
        keys = sorted(caps.get(ecodes.EV_KEY, []))
        absinfo = {code: info for code, info in caps.get(ecodes.EV_ABS, [])}
        want_keys = sorted(ecodes.ecodes[b] for b in BUTTONS)
        assert keys == want_keys, f"buttons {keys} != {want_keys}"
        for name, (lo, hi, _) in AXES.items():
            info = absinfo.get(ecodes.ecodes[name])
            assert info is not None, f"{name} missing"
            assert (info.min, info.max) == (lo, hi), f"{name} range {info.min}..{info.max}"
        assert set(absinfo) == {ecodes.ecodes[n] for n in AXES}, f"extra axes: {sorted(absinfo)}"
        types = sorted(caps)
        assert ecodes.EV_REL not in caps, "a gamepad must not have relative (mouse) axes"
        assert not dev.input_props(), f"input properties set: {dev.input_props()}"
        ident = GamepadIdentity()
        assert (dev.info.bustype, dev.info.vendor, dev.info.product, dev.info.version) == (
            ident.bustype,
            ident.vendor,
            ident.product,
            ident.version,
        ), str(dev.info)
        assert dev.name == ident.name and dev.phys == PHYS, (dev.name, dev.phys)
        custom = GamepadIdentity(name="NeuroTouch test pad", vendor=0x1234, product=0x5678, version=0x0042)
        with VirtualGamepad(custom) as other:
            info = other._ui.device.info
            assert (other._ui.device.name, info.vendor, info.product, info.version) == (
                custom.name,
                custom.vendor,
                custom.product,
                custom.version,
            ), str(info)
        return {
            "path": path,
            "name": dev.name,
            "phys": dev.phys,
            "event_types": types,
            "info": f"{dev.info.bustype:04x}:{dev.info.vendor:04x}:{dev.info.product:04x}:{dev.info.version:04x}",
            "stick_absinfo": str(absinfo[ecodes.ABS_X]),
        }


def check_udev_classifies_joystick() -> dict:
    """udev (input_id + our rules) says joystick, marks our pad, tags /dev/uinput uaccess."""
    with VirtualGamepad() as pad:
        guestlib.settle()
        props = guestlib.udev_properties(pad.device_path)
        assert props.get("ID_INPUT_JOYSTICK") == "1", f"not a joystick to udev: {props}"
        for other in ("ID_INPUT_MOUSE", "ID_INPUT_TOUCHPAD", "ID_INPUT_TOUCHSCREEN", "ID_INPUT_TABLET"):
            assert other not in props, f"udev also says {other}: {props}"
        assert props.get("ID_NEUROTOUCH_VIRTUAL") == "1", f"our rule did not tag the pad: {props}"
        uinput = guestlib.udev_properties("/dev/uinput")
        tags = uinput.get("CURRENT_TAGS", uinput.get("TAGS", "")).strip(":").split(":")
        assert "uaccess" in tags, f"/dev/uinput not tagged uaccess: {uinput}"
        mode = os.stat("/dev/uinput").st_mode
        assert not mode & 0o002, f"/dev/uinput is world-writable: {oct(mode)}"
        js = sorted(p.name for p in Path("/sys/class/input").glob("js*"))
        return {
            "ID_INPUT_JOYSTICK": props["ID_INPUT_JOYSTICK"],
            "ID_NEUROTOUCH_VIRTUAL": props["ID_NEUROTOUCH_VIRTUAL"],
            "uinput_tags": tags,
            "uinput_mode": oct(mode & 0o777),
            "joydev_nodes": js,
        }


def check_evdev_roundtrip() -> dict:
    """A reader sees exactly the changed axes/buttons per report, and the values written."""
    with VirtualGamepad() as pad:
        reader = guestlib.EventReader(pad.device_path)
        pad.write(PRESSED)
        reader.pump(until=lambda r: len(r.reports) >= 1)
        want_axes, want_keys = _codes(PRESSED)
        assert reader.axes == want_axes, f"axes {reader.axes} != {want_axes}"
        assert reader.keys == want_keys, f"keys {reader.keys} != {want_keys}"
        first = len(reader.reports[0])
        assert first == len(changed_events(ControllerState.neutral(), PRESSED)), reader.reports

        moved = ControllerState(
            t_us=2, axes={**PRESSED.axes, "ABS_X": -1000}, buttons={**PRESSED.buttons, "BTN_SOUTH": False}
        )
        pad.write(moved)
        reader.pump(until=lambda r: len(r.reports) >= 2)
        assert sorted(reader.reports[1]) == sorted(
            [(ecodes.EV_ABS, ecodes.ABS_X, -1000), (ecodes.EV_KEY, ecodes.BTN_SOUTH, 0)]
        ), reader.reports[1]

        pad.write(moved)  # nothing changed: no report at all
        reader.pump(timeout_s=0.3)
        assert len(reader.reports) == 2, f"a repeated state produced reports: {reader.reports[2:]}"

        pad.write(ControllerState(axes={"ABS_Z": 999, "ABS_X": -99999}))  # out of range: clamped
        reader.pump(until=lambda r: len(r.reports) >= 3)
        assert reader.axes[ecodes.ABS_Z] == 255 and reader.axes[ecodes.ABS_X] == -32768, reader.axes

        pad.neutralise()
        reader.pump(until=lambda r: len(r.reports) >= 4)
        assert not reader.keys and not any(reader.axes.values()), (reader.keys, reader.axes)
        kernel_state = {c: pad._ui.device.absinfo(c).value for c in reader.axes}
        assert not any(kernel_state.values()) and not pad._ui.device.active_keys(), kernel_state
        reader.close()
        return {"reports": len(reader.reports), "first_report_events": first, "second_report": reader.reports[1]}


def check_close_releases() -> dict:
    """close() with a button held: a reader polling in its own thread (like a game) sees the
    release and the centring before the device disappears."""
    pad = VirtualGamepad()
    reader = guestlib.EventReader(pad.device_path)
    pad.write(PRESSED)
    reader.pump(until=lambda r: r.keys)
    held = sorted(reader.keys)
    thread = threading.Thread(target=reader.pump, kwargs={"timeout_s": 5.0, "until": lambda r: r.gone})
    thread.start()
    pad.close()
    pad.close()  # idempotent
    thread.join(10)
    released = not reader.keys and not any(reader.axes.values())
    reader.close()
    assert held, "the button press was not seen"
    assert released, f"after close(): keys {reader.keys}, axes {reader.axes}"
    pad.write(PRESSED)  # a late write from another thread during shutdown: ignored
    assert not os.path.exists(reader.device.path), "write() after close() brought the device back"
    return {"held_before_close": held, "device_gone": reader.gone}


def check_sigterm_releases() -> dict:
    """A process holding the pad with a button pressed is SIGTERMed: its handler calls close(),
    no button stays pressed."""
    holder = subprocess.Popen(
        [sys.executable, str(HERE / "holder.py")],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=dict(os.environ, PYTHONUNBUFFERED="1"),
    )
    try:
        line = holder.stdout.readline()
        assert line.startswith("ready "), (
            f"holder said {line!r}; stderr: {holder.stderr.read() if holder.poll() is not None else ''}"
        )
        path = line.split()[1]
        reader = guestlib.EventReader(path)
        held = sorted(reader.keys)
        assert ecodes.BTN_SOUTH in held, f"holder's press not visible: {held}"
        holder.send_signal(signal.SIGTERM)
        reader.pump(timeout_s=60.0, until=lambda r: r.gone)
        code = holder.wait(timeout=120)
        keys, axes, gone = set(reader.keys), dict(reader.axes), reader.gone
        reader.close()
    finally:
        if holder.poll() is None:
            holder.kill()
    assert not keys, f"buttons still pressed after SIGTERM: {keys}"
    assert not any(axes.values()), f"axes not centred after SIGTERM: {axes}"
    assert code == 0, f"holder exit code {code}: {holder.stderr.read()}"
    return {"held_before_sigterm": held, "device_gone": gone, "holder_exit": code}


def check_sdl_gamecontroller() -> dict:
    """SDL2 (pygame) sees a GameController and reads the button, stick and trigger written."""
    env = guestlib.sdl_env()
    proc = subprocess.run(
        [sys.executable, str(HERE / "sdl_probe.py")], capture_output=True, text=True, env=env, timeout=280
    )
    lines = [ln for ln in proc.stdout.splitlines() if ln.startswith("{")]
    assert lines, f"sdl_probe gave no result (exit {proc.returncode}): {proc.stderr[-2000:]}"
    result = json.loads(lines[-1])
    assert result.get("error") is None, result
    assert result["is_controller"], f"SDL does not see a GameController: {result}"
    assert result["pressed"]["a"] == 1 and result["pressed"]["start"] == 1, result
    assert result["pressed"]["leftx"] > 30000 and result["pressed"]["triggerright"] > 30000, result
    assert result["released"]["a"] == 0 and abs(result["released"]["leftx"]) < 2, result
    return result
