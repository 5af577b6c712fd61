"""Guest checks of the one output path (docs/architecture.md, "Targets and inputs") in a real kernel.

Run by tests/kernel/guest.py inside qemu; asserted on by tests/test_road_kernel.py. The driver
runs in the check's own process (``outputlib.InProcessRun``: ``run_driver`` in the main thread,
ended by a real SIGTERM), beside a stand-in for a helper's pad (checks_copilot.py's "Helper Pad",
045e:02ea, FF_RUMBLE, its uploads answered as its driver would).

* :func:`check_sigterm_before_the_run_and_merged_first`: for ``--output gamepad``, ``hid`` and
  ``usb`` (dummy_hcd), a first run with a ``copilot:`` profile: the simulated gel with ``--fast``
  and ``NUMBA_CACHE_DIR`` a new empty folder, so the engine waits for a real cold compile of the
  pipeline's numba code (child processes; minutes under emulation), as a camera's first run
  does. The helper's pad is merged before the gel's device appears, seen by polling evdev every
  10 ms: at that moment the check's own EVIOCGRAB of it fails with EBUSY and its node is hidden
  (the guest runs as root); once the run says it compiles, it is still grabbed. A SIGTERM then
  stops the driver before the compile ends: run_driver returns (``run``'s exit 0), the device
  goes with nothing held, the helper's node comes back.
* :func:`check_copilot_merges_into_hid_and_usb_and_gets_the_hosts_rumble`: the same profile on
  ``--output hid`` (UHID, hid-generic) and ``--output usb --protocol xinput`` (dummy_hcd, xpad):
  a press on the helper's pad reaches the host's device; on the xpad side, a rumble the host
  plays (EVIOCSFF, then EV_FF) comes back from the gadget's OUT endpoint as Feedback and is
  played on the helper's pad.
"""

from __future__ import annotations

import errno
import os
import sys
import tempfile
import threading
import time
from pathlib import Path

import guestlib
from checks_copilot import RumbleAnswerer, helper_pad, press
from checks_runtime_remap import _write_preds
from evdev import InputDevice, ecodes, ff, list_devices
from outputlib import InProcessRun, push_right

from neurotouch_hid.service.warmup import COMPILING
from neurotouch_hid.targets.gadget import configfs
from neurotouch_hid.targets.protocols import PROTOCOLS
from neurotouch_hid.targets.uhid import HID_DEFAULT
from neurotouch_hid.targets.uinput.gamepad import PHYS

TIMEOUT_S = 900
MODULES = ("dummy_hcd", "libcomposite", "usb_f_hid", "usb_f_fs", "usbhid", "hid-generic", "xpad", "uhid")
#: The helper's pad merged: its own controls pass through to the gel's controller.
COPILOT = """\
description: guest check of the copilot on every output
mappings:
  push: {input: push, output: left_stick, deadzone_mm: 0.5, saturation_mm: 6.0}
copilot:
  - device: "Helper Pad"
"""
#: The gel's device as each output makes it: (vendor, product) on the host side, or the pad's phys.
GEL_IDS = {
    "hid": (HID_DEFAULT.vendor, HID_DEFAULT.product),
    "usb": (PROTOCOLS["hid"].vendor, PROTOCOLS["hid"].product),
    "xinput": (PROTOCOLS["xinput"].vendor, PROTOCOLS["xinput"].product),
}


def _kernel() -> dict:
    loaded = {m: guestlib.sh(["modprobe", m]).returncode == 0 for m in MODULES}
    configfs.mount_configfs()
    configfs.remove()  # a gadget a check before left
    guestlib.settle()
    return loaded


def _gel_device(output: str) -> str | None:
    """The event node of the gel's device of ``output`` (its joystick side: ABS_X), or None."""
    for path in list_devices():
        try:
            dev = InputDevice(path)
            if ecodes.ABS_X not in [c for c, _ in dev.capabilities().get(ecodes.EV_ABS, [])]:
                continue
            if output == "gamepad" and dev.phys == PHYS:
                return path
            if output != "gamepad" and (dev.info.vendor, dev.info.product) == GEL_IDS[output]:
                return path
        except OSError:
            pass
    return None


def _profile() -> Path:
    folder = Path(tempfile.mkdtemp(prefix="road-check-"))
    (folder / "copilot.yaml").write_text(COPILOT)
    return folder / "copilot.yaml"


def _grabbed_by_another(device: InputDevice) -> str:
    """EVIOCGRAB of ``device`` from here: "EBUSY" when another holder grabbed it (the driver),
    "grabbed" when this check could (then let go at once)."""
    try:
        device.grab()
    except OSError as exc:
        return errno.errorcode.get(exc.errno, str(exc.errno))
    device.ungrab()
    return "grabbed"


def _compile_children() -> list[int]:
    """The pids of the first run's compile children still alive (``python -P -m
    neurotouch_hid.service.warmup GROUP``, /proc/PID/cmdline)."""
    found = []
    for cmdline in Path("/proc").glob("[0-9]*/cmdline"):
        try:
            if b"neurotouch_hid.service.warmup" in cmdline.read_bytes():
                found.append(int(cmdline.parent.name))
        except OSError:
            continue
    return found


def _early_stop(output: str, cold_cache: Path) -> dict:
    helper = helper_pad()
    answerer = RumbleAnswerer(helper)
    node = helper.device.path
    guestlib.settle()
    # the simulated gel, --fast: as the camera's first run, the engine starts once the pipeline's
    # numba code is compiled, here into an empty cache (warmup.Warmup, interpreted=False)
    env = {"NUMBA_CACHE_DIR": str(cold_cache), "PYTHONPATH": os.pathsep.join(sys.path)}  # the compiling children's
    run = InProcessRun("sim", _profile(), output, env=env, options={"fast": True})
    seen: dict = {}

    def steps(run: InProcessRun) -> None:
        t0 = time.monotonic()
        while time.monotonic() - t0 < 600 and run.alive():
            gel = _gel_device("usb" if output == "usb" else output)
            if gel is not None:  # the moment it is first seen: what was merged, grabbed, hidden
                seen.update(gel=gel, said_then=list(run.said), helper_there=os.path.exists(node))
                seen["grab_then"] = _grabbed_by_another(helper.device)
                seen["appeared_s"] = round(time.monotonic() - t0, 2)
                break
            time.sleep(0.01)
        assert "gel" in seen, f"the {output} device never appeared: {run.said[-5:]}"
        seen["reader"] = reader = guestlib.EventReader(seen["gel"])
        seen["compiling"] = guestlib.wait_for(
            lambda: next((line for line in list(run.said) if line.startswith(COMPILING)), None) or not run.alive(),
            300.0,
            0.05,
        )
        seen["compiling_s"] = round(time.monotonic() - t0, 2)
        seen["grab_compiling"] = _grabbed_by_another(helper.device)
        reader.pump(timeout_s=0.5, max_s=2.0)
        run.stop(reader, early=True)

    try:
        run(steps)
    finally:
        answerer.stop()
        back = guestlib.wait_for(lambda: os.path.exists(node), 10.0)
        helper.close()
        if "reader" in seen:
            seen["reader"].close()
    reader = seen["reader"]
    merged_first = any(line.startswith("merged Helper Pad") for line in seen["said_then"])
    assert merged_first, f"the helper's pad was not merged before the {output} device appeared: {seen['said_then']}"
    assert seen["grab_then"] == "EBUSY", (
        f"EVIOCGRAB of the helper's pad as the {output} device appeared: {seen['grab_then']}"
    )
    assert not seen["helper_there"], f"the helper's node {node} was still there when the {output} device appeared"
    assert isinstance(seen["compiling"], str), f"no cold compile (numba cache {cold_cache}): {run.said[-6:]}"
    assert not [line for line in run.said if "compile failed" in line], run.said[-6:]
    assert seen["grab_compiling"] == "EBUSY", f"EVIOCGRAB during the compile: {seen['grab_compiling']}"
    assert run.returned, f"run_driver did not return after SIGTERM: {run.said[-5:]}"
    assert any("stopped (SIGTERM) before the run started" in line for line in run.said), run.said[-5:]
    children_gone = guestlib.wait_for(lambda: not _compile_children(), 20.0)
    assert children_gone, f"the compile's children outlived the stopped run: {_compile_children()}"
    gone = guestlib.wait_for(lambda: _gel_device("usb" if output == "usb" else output) is None, 20.0)
    assert gone, f"the {output} device stayed after the SIGTERM"
    assert not reader.keys, f"{output}: keys held at the end: {reader.keys}"
    assert back, f"the helper's node {node} did not come back"
    return {
        "appeared_s": seen["appeared_s"],
        "compiling_s": seen["compiling_s"],
        "grab_then": seen["grab_then"],
        "said": run.said[-4:],
        "axes": dict(reader.axes),
    }


def check_sigterm_before_the_run_and_merged_first() -> dict:
    """See the module docstring."""
    loaded = _kernel()
    done = {"modprobe": loaded, "numba_imported_before": "numba" in sys.modules}
    cold_cache = Path(tempfile.mkdtemp(prefix="road-cold-numba-"))  # empty: every kernel group cold
    if "numba" in sys.modules:  # numba read NUMBA_CACHE_DIR when imported: the pipeline's kernels, made later, use this
        from numba.core import config

        config.CACHE_DIR = str(cold_cache)
    for output in ("gamepad", "hid", "usb"):
        t0 = time.monotonic()
        done[output] = _early_stop(output, cold_cache)
        done[output]["check_s"] = round(time.monotonic() - t0, 1)
    done["cached_after"] = sorted(path.name for path in cold_cache.rglob("*.nbi"))[:8]
    return done


def _merged_press(output: str, protocol: str | None = None) -> dict:
    """A press of the helper's A reaches the host's device of ``output``; with xinput, a rumble the
    host plays reaches the helper's pad."""
    helper = helper_pad()
    answerer = RumbleAnswerer(helper)
    guestlib.settle()
    folder = Path(tempfile.mkdtemp(prefix="road-merge-"))
    preds = _write_preds(folder, push_right(hold_s=120.0))  # as checks_gadget.py: parsed in seconds
    run = InProcessRun(preds, _profile(), output, protocol=protocol)
    side = protocol or output
    button = ecodes.BTN_SOUTH if side == "xinput" else ecodes.BTN_TRIGGER  # hid-input: a joystick's button 1
    seen: dict = {}

    def steps(run: InProcessRun) -> None:
        gel = guestlib.wait_for(lambda: _gel_device(side) or not run.alive(), 600.0, 0.1)
        assert isinstance(gel, str), f"no {side} device: {run.said[-5:]}"
        seen["reader"] = reader = guestlib.EventReader(gel)
        guestlib.wait_for(lambda: any(line.startswith("merged Helper Pad") for line in run.said), 60.0)
        # the run has started once the gel's push moves the host's stick
        reader.pump(timeout_s=60.0, until=lambda r: r.axes.get(ecodes.ABS_X, 0) > 0, max_s=400.0)
        seen["gel_x"] = reader.axes.get(ecodes.ABS_X, 0)
        press(helper, (ecodes.EV_KEY, ecodes.BTN_SOUTH, 1))
        reader.pump(timeout_s=60.0, until=lambda r: button in r.keys, max_s=120.0)
        seen["pressed"] = button in reader.keys
        press(helper, (ecodes.EV_KEY, ecodes.BTN_SOUTH, 0))
        reader.pump(timeout_s=60.0, until=lambda r: button not in r.keys, max_s=120.0)
        seen["released"] = button not in reader.keys
        # the run's own Python threads (those this check had before it aside), and the process's tasks
        seen["threads"] = sorted({t.name for t in threading.enumerate()} - before - {threading.current_thread().name})
        seen["tasks"] = len(os.listdir("/proc/self/task"))
        if side == "xinput":  # the host plays a rumble on the gel's pad (xpad: an OUT report to the gadget)
            rumble = ff.Rumble(strong_magnitude=0xC000, weak_magnitude=0x4000)
            effect = ff.Effect(
                ecodes.FF_RUMBLE, -1, 0, ff.Trigger(0, 0), ff.Replay(1000, 0), ff.EffectType(ff_rumble_effect=rumble)
            )
            writer = InputDevice(gel)
            effect_id = writer.upload_effect(effect)
            writer.write(ecodes.EV_FF, effect_id, 1)
            seen["played"] = guestlib.wait_for(lambda: [s for s in answerer.seen if s[0] == "play" and s[2]], 60.0)
            seen["uploads"] = [s for s in answerer.seen if s[0] == "upload"]
            writer.close()
        run.stop(reader)

    before = {t.name for t in threading.enumerate()}
    try:
        run(steps)
    finally:
        answerer.stop()
        helper.close()
        if "reader" in seen:
            seen["reader"].close()
    assert run.returned, f"the run did not return after SIGTERM: {run.said[-5:]}"
    assert seen["gel_x"] > 0, f"{side}: the gel's push never reached the host: {run.said[-5:]}"
    assert seen["pressed"], f"{side}: the helper's press never reached the host: {run.said[-5:]}"
    assert seen["released"], f"{side}: the helper's release never reached the host"
    if side == "hid":  # the main thread (the loop), the source's, the pipeline's, at most the resting detector's
        assert set(seen["threads"]) <= {"nt-source", "nt-pipeline", "nt-resting"}, seen["threads"]
    result = {"said": run.said[-6:], "threads": seen["threads"], "tasks": seen["tasks"]}
    if side == "xinput":
        assert seen["played"], f"the host's rumble never reached the helper's pad: {answerer.seen} {run.said[-8:]}"
        strong = [s[2] for s in seen["uploads"] if s[1] == ecodes.FF_RUMBLE]
        assert strong and max(strong) > 0, seen["uploads"]
        assert any("rumble (the gel has no motor)" in line for line in run.said), run.said[-8:]
        result.update(helper_uploads=seen["uploads"][:3], helper_plays=seen["played"][:3])
    return result


def check_copilot_merges_into_hid_and_usb_and_gets_the_hosts_rumble() -> dict:
    """See the module docstring."""
    loaded = _kernel()
    done = {"modprobe": loaded}
    for output, protocol in (("hid", None), ("usb", "xinput")):
        t0 = time.monotonic()
        done[protocol or output] = _merged_press(output, protocol)
        done[protocol or output]["check_s"] = round(time.monotonic() - t0, 1)
    return done
