"""Guest check of the copilot (a profile's ``copilot:``) in a real kernel.

Run by tests/kernel/guest.py inside qemu; asserted on by tests/test_copilot_kernel.py. Two
python-evdev UInput devices stand in for the devices beside the gel: a helper's Xbox pad
("Helper Pad", 045e:02ea, xpad's buttons and axes, FF_RUMBLE: this check answers its effect
uploads as the pad's driver would) and a switch box (a keyboard sending KEY_SPACE). As in
checks_runtime.py the gel is the pipeline's own output (a predictions file: the emulated guest
cannot run the pipeline in real time); everything after it is real: ``neurotouch-hid run`` in its
own process, its control socket, the uinput pad, the grab, inotify, SDL.

One driver start and one SDL start serve every step (a Python start costs tens of seconds here):
the run starts on the ``mouse`` profile (no joystick node), ``profile use default`` makes the pad,
``profile use`` of the copilot profile merges the two devices into it.
"""

from __future__ import annotations

import json
import math
import os
import queue
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import guestlib
from checks_runtime import NO_DROP_LAG_MS, timeline
from checks_runtime_remap import Watcher, _devices, _write_preds
from evdev import AbsInfo, UInput, ecodes

from neurotouch_hid.core.controller import BUTTONS
from neurotouch_hid.core.estimate import GestureType
from neurotouch_hid.inputs.hide import HIDDEN_DIR
from neurotouch_hid.targets.uinput.desktop import MOUSE_PHYS
from neurotouch_hid.targets.uinput.gamepad import PHYS

HERE = Path(__file__).resolve().parent
TIMEOUT_S = 420
#: Estimates 200 ms apart: the gel holds one push for minutes; few windows leave the emulated
#: guest's CPU to the driver's start, SDL and the devices.
STEP_US = 200_000
#: The gel's push (checks_runtime._gesture: 6 mm, to the right and a little up) through COPILOT's
#: stick at full deflection: ABS_X = cos(0.3) * 32767, ABS_Y = -sin(0.3) * 32768.
GEL_X, GEL_Y = round(math.cos(0.3) * 32767), round(-math.sin(0.3) * 32768)

COPILOT = """\
description: guest check of the copilot
mappings:
  stick: {input: push, output: left_stick, deadzone_mm: 0.5, saturation_mm: 6.0}
copilot:
  - device: "Helper Pad"
    policy: {ABS_X: further, ABS_Y: sum}
  - device: "Switch Box"
    map: {KEY_SPACE: BTN_WEST}
"""


def helper_pad() -> UInput:
    """A stand-in for a helper's Xbox pad: xpad's buttons and axes, FF_RUMBLE, 045e:02ea."""
    stick = AbsInfo(value=0, min=-32768, max=32767, fuzz=16, flat=128, resolution=0)
    trigger = AbsInfo(value=0, min=0, max=255, fuzz=0, flat=0, resolution=0)
    hat = AbsInfo(value=0, min=-1, max=1, fuzz=0, flat=0, resolution=0)
    buttons = ("BTN_SOUTH", "BTN_EAST", "BTN_NORTH", "BTN_WEST", "BTN_TL", "BTN_TR", "BTN_SELECT", "BTN_START")
    caps = {
        ecodes.EV_KEY: [ecodes.ecodes[b] for b in buttons + ("BTN_MODE", "BTN_THUMBL", "BTN_THUMBR")],
        ecodes.EV_ABS: [
            (ecodes.ABS_X, stick),
            (ecodes.ABS_Y, stick),
            (ecodes.ABS_RX, stick),
            (ecodes.ABS_RY, stick),
            (ecodes.ABS_Z, trigger),
            (ecodes.ABS_RZ, trigger),
            (ecodes.ABS_HAT0X, hat),
            (ecodes.ABS_HAT0Y, hat),
        ],
        ecodes.EV_FF: [ecodes.FF_RUMBLE],
    }
    return UInput(
        caps, name="Helper Pad", vendor=0x045E, product=0x02EA, version=0x0408, bustype=0x03,
        phys="usb-helper/input0", max_effects=16,
    )  # fmt: skip


def switch_box() -> UInput:
    """A stand-in for a switch interface: a keyboard with Space and Enter."""
    return UInput(
        {ecodes.EV_KEY: [ecodes.KEY_SPACE, ecodes.KEY_ENTER]},
        name="Switch Box", vendor=0x1234, product=0x5678, version=1, bustype=0x03, phys="usb-switch/input0",
    )  # fmt: skip


class RumbleAnswerer:
    """Answers the helper pad's force-feedback uploads and erases (as its driver would) and keeps
    what arrived: (``"upload"``, type, strong, weak) and (``"play"``, id, value)."""

    def __init__(self, ui: UInput):
        from neurotouch_hid.targets.uinput.gamepad import _begin_ff_request

        self._begin = _begin_ff_request
        self.ui = ui
        self.seen: list[tuple] = []
        self._stop = threading.Event()
        self.thread = threading.Thread(target=self._loop, daemon=True)
        self.thread.start()

    def _loop(self) -> None:
        import select

        while not self._stop.is_set():
            try:
                if not select.select([self.ui.fd], [], [], 0.2)[0]:
                    continue
                events = list(self.ui.read())
            except (OSError, ValueError):
                return
            for ev in events:
                if ev.type == ecodes.EV_UINPUT and ev.code == ecodes.UI_FF_UPLOAD:
                    upload = self._begin(self.ui, "upload", ev.value)
                    rumble = upload.effect.u.ff_rumble_effect
                    self.seen.append(("upload", upload.effect.type, rumble.strong_magnitude, rumble.weak_magnitude))
                    upload.retval = 0
                    self.ui.end_upload(upload)
                elif ev.type == ecodes.EV_UINPUT and ev.code == ecodes.UI_FF_ERASE:
                    erase = self._begin(self.ui, "erase", ev.value)
                    erase.retval = 0
                    self.ui.end_erase(erase)
                elif ev.type == ecodes.EV_FF:
                    self.seen.append(("play", ev.code, ev.value))

    def stop(self) -> None:
        self._stop.set()
        self.thread.join(5)


def press(ui: UInput, *events: tuple[int, int, int]) -> None:
    """Write ``events`` (type, code, value) on ``ui`` as one report."""
    for etype, code, value in events:
        ui.write(etype, code, value)
    ui.syn()


class Sdl:
    """tests/kernel/sdl_probe.py ``--serve``: one SDL start, commands on stdin."""

    def __init__(self, product: str):
        self.proc = subprocess.Popen(
            [sys.executable, str(HERE / "sdl_probe.py"), "--serve", "300", product],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            env=guestlib.sdl_env(),
        )
        self.replies: queue.Queue = queue.Queue()
        self.started = time.monotonic()
        self.said: list[tuple[float, list[str]]] = []  # each reply's seconds after the start and keys
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self) -> None:
        for line in iter(self.proc.stdout.readline, ""):
            if line.startswith("{"):
                reply = json.loads(line)
                self.said.append((round(time.monotonic() - self.started, 1), sorted(reply)[:4]))
                self.replies.put(reply)

    def next_with(self, key: str, timeout_s: float) -> dict:
        end = time.monotonic() + timeout_s
        while time.monotonic() < end:
            try:
                reply = self.replies.get(timeout=max(0.1, end - time.monotonic()))
            except queue.Empty:
                break
            if key in reply or reply.get("done"):
                return reply
        return {"error": f"no {key!r} reply within {timeout_s} s"}

    def ask(self, command: str, key: str, timeout_s: float = 30.0) -> dict:
        self.proc.stdin.write(command + "\n")
        self.proc.stdin.flush()
        return self.next_with(key, timeout_s)

    def until(self, predicate, timeout_s: float = 30.0) -> dict:
        """Ask ``state`` until ``predicate(values)`` holds; the last values."""
        end, values = time.monotonic() + timeout_s, {}
        while time.monotonic() < end:
            values = self.ask("state", "v").get("v", {})
            if predicate(values):
                break
            time.sleep(0.05)
        return values

    def close(self) -> str:
        if self.proc.poll() is None:
            try:
                self.proc.stdin.write("quit\n")
                self.proc.stdin.close()
                self.proc.wait(30)
            except (OSError, subprocess.TimeoutExpired):
                self.proc.kill()
        return self.proc.stderr.read()[-2000:]


def _pad(watcher: Watcher) -> dict:
    """The pad's sticks' x and y and the buttons held (the Xbox layout's names)."""
    axes, names = watcher.reader.axes, {ecodes.ecodes[n]: n for n in BUTTONS}
    return {
        "ABS_X": axes.get(ecodes.ABS_X, 0),
        "ABS_Y": axes.get(ecodes.ABS_Y, 0),
        "buttons": sorted(names.get(c, str(c)) for c in watcher.pressed),
    }


def check_copilot_merges_grabs_rejoins_and_rumbles() -> dict:
    """``run`` on ``mouse`` makes no joystick node; ``profile use default`` makes the pad;
    ``profile use`` of a copilot profile grabs the helper's pad and the switch box (a reader of the
    helper's own node then receives nothing) and merges them: the helper's buttons arrive on the
    pad (evdev and SDL), its stick follows the policies against the gel's push (``further`` on
    ABS_X, ``sum`` on ABS_Y), Space on the switch box presses the mapped button; an SDL rumble on
    the pad is played on the helper's device; the helper destroyed mid-press leaves its controls
    neutral at once and the run goes on; a new device of that name rejoins; merged by root, the
    devices' nodes leave /dev/input (a udev "change" event makes none again), so an SDL started
    then lists one GameController, the gel's pad; ``profile use default``
    (no copilot) lets go of it and releases the grab, the copilot profile again grabs it and shows
    the button it holds; SIGTERM: the run ends cleanly, the pad's last state neutral, the helper's
    node is back in /dev/input and delivers to other readers again, a new one included (the switch
    box's node as it was before: number, mode, owner, ACL), nothing left hidden.

    The driver runs in this process (``run_driver``, what ``neurotouch-hid run`` calls, in the main
    thread, where SIGTERM's handler runs): a second Python start would cost minutes here. The steps
    run in a thread beside it, and end it with a real SIGTERM to this process."""
    from neurotouch_hid.engine.driver import DriverOptions, run_driver
    from neurotouch_hid.service.control import SOCKET_NAME

    started = time.monotonic()
    folder = Path(tempfile.mkdtemp(prefix="copilot-"))
    runtime_dir = folder / "xdg"
    runtime_dir.mkdir(mode=0o700)
    profile = folder / "copilot.yaml"
    profile.write_text(COPILOT)
    G = GestureType
    gel = timeline(
        [(0.4, G.NONE, lambda f: 0.0), (0.4, G.PUSH, lambda f: 6.0 * f), (400.0, G.PUSH, lambda f: 6.0)], STEP_US
    )
    preds = _write_preds(folder, gel)
    scenario = Scenario(runtime_dir / SOCKET_NAME, profile)
    env = {"XDG_RUNTIME_DIR": str(runtime_dir), "XDG_CONFIG_HOME": str(folder / "config")}
    saved = {name: os.environ.get(name) for name in env}
    os.environ.update(env)
    thread = threading.Thread(target=scenario.run, daemon=True)
    try:
        thread.start()
        stats = run_driver(
            str(preds),
            "mouse",
            "gamepad",
            DriverOptions(max_lag_us=int(NO_DROP_LAG_MS) * 1000, say=scenario.said.append),
        )
        scenario.details["windows"] = stats.windows
    finally:
        scenario.driver_done.set()
        thread.join(120)
        for name, value in saved.items():
            if value is None:
                os.environ.pop(name, None)
            else:
                os.environ[name] = value
        scenario.close()
    if scenario.error is not None:
        raise scenario.error
    details = scenario.details
    assert details["pad_last"] == {"ABS_X": 0, "ABS_Y": 0, "buttons": []}, details["pad_last"]
    assert details["helper_reader_after_stop"], "the helper's node delivers nothing after the run"
    assert details["helper_reader_while_grabbed"] == 0 and details["helper_reader_while_grabbed_again"] == 0, details
    assert details["hidden_after_stop"] == [] and details["helper_node_readable_after_stop"], details
    assert details["box_node_as_before"] and not details["helper_node_in_dev_after_udev_change"], details
    details["said"] = [line for line in scenario.said if "merged" in line or "went away" in line]
    details["seconds"] = round(time.monotonic() - started, 1)
    return details


def _hidden() -> list[str]:
    """The nodes this process's driver has hidden now (relative to /dev)."""
    folder = HIDDEN_DIR / str(os.getpid())
    return sorted(str(p.relative_to(folder)) for p in folder.rglob("*") if not p.is_dir()) if folder.is_dir() else []


def _node_stat(path: str) -> tuple[int, int, int, int, bytes]:
    """A node's device number, mode, owner, group and POSIX ACL (b"" without one)."""
    st = os.stat(path)
    try:
        acl = os.getxattr(path, "system.posix_acl_access")
    except OSError:
        acl = b""
    return st.st_rdev, st.st_mode, st.st_uid, st.st_gid, acl


def _node(path: str) -> str:
    """``path`` (/dev/input/eventN), or where this process's driver hid it."""
    hidden = HIDDEN_DIR / str(os.getpid()) / "input" / Path(path).name
    return path if os.path.exists(path) else str(hidden)


class Scenario:
    """The steps beside the running driver (a thread): the devices, the readers, SDL, the
    control socket; ends the run with SIGTERM, then checks what is left once it returned."""

    def __init__(self, socket: Path, profile: Path):
        self.socket, self.profile = socket, profile
        self.said: list[str] = []
        self.details: dict = {}
        self.error: BaseException | None = None
        self.driver_done = threading.Event()
        self.helper, self.box = helper_pad(), switch_box()
        self.answerer = RumbleAnswerer(self.helper)
        guestlib.settle()
        self.helper_reader = Watcher(self.helper.device.path)
        self.pad: Watcher | None = None
        self.grabbed_from = 0  # the helper's reader's events when it was grabbed the last time
        self.sdl = Sdl("028e")  # SDL's ~12 s start overlaps the driver's
        self.before = {phys: set(_devices(phys)) for phys in (PHYS, MOUSE_PHYS)}
        self.started = time.monotonic()

    def new(self, phys: str) -> list[str]:
        return sorted(set(_devices(phys)) - self.before[phys])

    def count(self, text: str) -> int:
        return sum(text in line for line in list(self.said))

    def run(self) -> None:
        try:
            self.during()
        except BaseException as exc:
            self.error = exc
        finally:
            # the run's SIGTERM handler is in place once its control socket is (a failure before
            # that leaves the run to end with its source: SIGTERM's default would end the guest)
            if not self.driver_done.is_set() and self.socket.exists():
                os.kill(os.getpid(), signal.SIGTERM)
        try:
            if self.error is None:
                self.after()
        except BaseException as exc:
            self.error = exc

    def during(self) -> None:
        from neurotouch_hid.service.control import request_use

        details, helper, box = self.details, self.helper, self.box
        mouse_up = guestlib.wait_for(lambda: self.new(MOUSE_PHYS) or self.driver_done.is_set(), 200.0, 0.1)
        assert mouse_up and not self.driver_done.is_set(), f"the run did not start: {self.said[-20:]}"
        guestlib.wait_for(lambda: self.socket.exists(), 60.0)
        details["run_started_s"] = round(time.monotonic() - self.started, 1)
        details["pads_with_mouse_profile"] = self.new(PHYS)
        assert not self.new(PHYS), f"the mouse profile made a pad: {self.new(PHYS)}"
        press(helper, (ecodes.EV_KEY, ecodes.BTN_EAST, 1))
        press(helper, (ecodes.EV_KEY, ecodes.BTN_EAST, 0))
        # a press and a release (the reader keeps events, not SYN_REPORTs): not grabbed yet
        reads = guestlib.wait_for(lambda: len(self.helper_reader.events) >= 2, 10.0)
        assert reads, "the helper's reader reads nothing"

        details["use_default"] = request_use("default", path=self.socket)
        assert guestlib.wait_for(lambda: self.new(PHYS), 30.0), "profile use default made no pad"
        pad = self.pad = Watcher(self.new(PHYS)[0])
        details["pads"] = len(self.new(PHYS))
        details["ID_INPUT_JOYSTICK"] = guestlib.udev_properties(self.new(PHYS)[0]).get("ID_INPUT_JOYSTICK")

        self.box_node = _node_stat(box.device.path)  # merged from here to the end (hidden, back, hidden, back)
        details["use_copilot"] = request_use(str(self.profile), path=self.socket)
        merged = guestlib.wait_for(lambda: self.count("merged Helper Pad") and self.count("merged Switch Box"), 30.0)
        assert merged, f"the devices were not merged: {self.said[-10:]}"
        details["merged_s"] = round(time.monotonic() - self.started, 1)
        # merged as root: the helper's nodes left /dev/input
        details["hidden"] = _hidden()
        details["helper_node_in_dev_while_merged"] = os.path.exists(helper.device.path)
        # a udev "change" event of the hidden device (udevadm trigger's default action) makes no node again
        changed_at = time.monotonic()
        guestlib.sh(["udevadm", "trigger", "--action=change", f"/sys/class/input/{Path(helper.device.path).name}"])
        guestlib.settle()
        details["udev_change_s"] = round(time.monotonic() - changed_at, 1)
        details["helper_node_in_dev_after_udev_change"] = os.path.exists(helper.device.path)
        grabbed_at = len(self.helper_reader.events)
        gel_held = guestlib.wait_for(lambda: pad.reader.axes.get(ecodes.ABS_X, 0) > 30000, 60.0)
        assert gel_held, f"the gel's push does not show on the pad: {_pad(pad)}"
        details["gel_alone"] = _pad(pad)
        gel_x, gel_y = details["gel_alone"]["ABS_X"], details["gel_alone"]["ABS_Y"]
        assert abs(gel_x - GEL_X) <= 2 and abs(gel_y - GEL_Y) <= 2, details["gel_alone"]

        # the helper's stick: ABS_X nearer centre than the gel's (further: the gel's stays), ABS_Y summed
        press(helper, (ecodes.EV_ABS, ecodes.ABS_X, -20000), (ecodes.EV_ABS, ecodes.ABS_Y, 8000))
        summed = guestlib.wait_for(lambda: pad.reader.axes.get(ecodes.ABS_Y) == gel_y + 8000, 10.0)
        details["helper_small"] = _pad(pad)
        assert summed and details["helper_small"]["ABS_X"] == gel_x, details
        press(helper, (ecodes.EV_ABS, ecodes.ABS_X, -32768), (ecodes.EV_KEY, ecodes.BTN_SOUTH, 1))
        further = guestlib.wait_for(
            lambda: pad.reader.axes.get(ecodes.ABS_X) == -32768 and ecodes.BTN_SOUTH in pad.pressed, 10.0
        )
        details["helper_full"] = _pad(pad)
        assert further, details
        opened = self.sdl.next_with("opened", 200.0)
        if not opened.get("opened"):
            alive = self.sdl.proc.poll() is None
            raise AssertionError(
                f"SDL did not open the pad: {opened}; the probe said {self.sdl.said[-8:]} (s after its start, "
                f"keys), running {alive}, its stderr {self.sdl.close()[-600:]!r}; the pad: {_pad(pad)}"
            )
        details["sdl_controllers"] = opened["count"]
        sdl_held = self.sdl.until(lambda v: v.get("a") and v.get("leftx", 0) <= -32767)
        details["sdl_held"] = {k: sdl_held.get(k) for k in ("a", "x", "leftx", "lefty")}
        assert sdl_held.get("a") and sdl_held.get("leftx") <= -32767, sdl_held

        press(box, (ecodes.EV_KEY, ecodes.KEY_SPACE, 1))
        boxed = guestlib.wait_for(lambda: ecodes.BTN_WEST in pad.pressed, 10.0)
        press(box, (ecodes.EV_KEY, ecodes.KEY_SPACE, 0))
        unboxed = guestlib.wait_for(lambda: ecodes.BTN_WEST not in pad.pressed, 10.0)
        assert boxed and unboxed, f"Space on the switch box: {pad.keys_log()}"

        rumble = self.sdl.ask("rumble", "rumble")
        details["sdl_rumble"] = rumble
        answerer = self.answerer
        played = guestlib.wait_for(lambda: any(s[0] == "play" and s[2] > 0 for s in answerer.seen), 15.0)
        details["helper_ff"] = answerer.seen[:6]
        assert rumble.get("rumble") and played, f"the rumble did not reach the helper: {rumble} {answerer.seen}"
        # SDL enumerating afresh now (its joystick subsystems started again: a game started now)
        details["sdl_before_merge"] = {"count": opened["count"], "guids": opened["guids"]}
        relisted_at = time.monotonic()
        late = self.sdl.ask("relist", "relisted").get("relisted", {})
        details["relist_s"] = round(time.monotonic() - relisted_at, 1)
        details["late_sdl"] = late
        assert late.get("found") and late["count"] == 1, f"an SDL started while merged lists: {late}"
        details["helper_reader_while_grabbed"] = len(self.helper_reader.events) - grabbed_at

        # unplugged mid-press: the pad lets go at once, the run goes on
        helper.close()
        released = guestlib.wait_for(
            lambda: ecodes.BTN_SOUTH not in pad.pressed and pad.reader.axes.get(ecodes.ABS_X) == gel_x, 10.0
        )
        details["after_unplug"] = _pad(pad)
        assert released and details["after_unplug"]["ABS_Y"] == gel_y, details["after_unplug"]
        assert not self.driver_done.is_set(), "the run ended when the helper went away"
        assert guestlib.wait_for(lambda: self.count("Helper Pad went away"), 10.0), self.said[-5:]

        self.helper = helper = helper_pad()  # the same name: rejoins
        answerer.stop()
        self.answerer = RumbleAnswerer(helper)
        rejoined = guestlib.wait_for(lambda: self.count("merged Helper Pad") >= 2, 30.0)
        assert rejoined, f"the new Helper Pad was not merged: {self.said[-5:]}"
        self.helper_reader.stop()
        self.helper_reader = Watcher(_node(helper.device.path))  # hidden by now: read from where it is
        press(helper, (ecodes.EV_KEY, ecodes.BTN_NORTH, 1))
        assert guestlib.wait_for(lambda: ecodes.BTN_NORTH in pad.pressed, 10.0), _pad(pad)
        details["rejoined"] = _pad(pad)

        # a profile without copilot: the pad lets go of the helper's button, the grab is released
        details["use_plain"] = request_use("default", path=self.socket)
        let_go = guestlib.wait_for(lambda: ecodes.BTN_NORTH not in pad.pressed, 10.0)
        free_from = len(self.helper_reader.events)
        press(helper, (ecodes.EV_KEY, ecodes.BTN_EAST, 1))
        press(helper, (ecodes.EV_KEY, ecodes.BTN_EAST, 0))
        guestlib.wait_for(lambda: len(self.helper_reader.events) >= free_from + 2, 10.0)
        details["helper_reader_after_switch"] = len(self.helper_reader.events) - free_from
        details["helper_node_in_dev_after_switch"] = os.path.exists(helper.device.path)
        assert let_go and details["helper_reader_after_switch"] >= 2, details
        # back: grabbed again, and the button it holds shows on the pad
        request_use(str(self.profile), path=self.socket)
        regrabbed = guestlib.wait_for(lambda: self.count("merged Helper Pad") >= 3, 30.0)
        self.grabbed_from = len(self.helper_reader.events)
        held = guestlib.wait_for(lambda: ecodes.BTN_NORTH in pad.pressed, 10.0)
        details["merged_again"] = _pad(pad)
        assert regrabbed and held, details["merged_again"]
        # the copilot has no thread of its own: its devices wait on the run's one loop, which the
        # main thread serves (no polling: only the games watcher's documented timer wakes it)
        details["threads"] = sorted(t.name for t in threading.enumerate())
        assert "nt-copilot" not in details["threads"] and "nt-feedback" not in details["threads"], details["threads"]
        details["steps_s"] = round(time.monotonic() - self.started, 1)

    def after(self) -> None:
        """Once SIGTERM ended the run: the pad's last state, the helper's node free again."""
        details, pad = self.details, self.pad
        assert self.driver_done.wait(60), "SIGTERM did not end the run"
        guestlib.wait_for(lambda: pad.reader.gone, 10.0)
        time.sleep(0.2)
        details["pad_last"] = _pad(pad)
        grabbed_events = len(self.helper_reader.events)
        press(self.helper, (ecodes.EV_KEY, ecodes.BTN_NORTH, 0))
        details["helper_reader_after_stop"] = bool(
            guestlib.wait_for(lambda: len(self.helper_reader.events) > grabbed_events, 10.0)
        )
        details["helper_reader_while_grabbed_again"] = grabbed_events - self.grabbed_from
        # its node back in /dev/input (nothing left hidden), and a new reader of it receives its events
        details["hidden_after_stop"] = _hidden()
        details["box_node_as_before"] = _node_stat(self.box.device.path) == self.box_node
        back = Watcher(self.helper.device.path)
        try:
            press(self.helper, (ecodes.EV_KEY, ecodes.BTN_EAST, 1))
            details["helper_node_readable_after_stop"] = bool(guestlib.wait_for(lambda: back.events, 10.0))
        finally:
            back.stop()

    def close(self) -> None:
        self.details["sdl_stderr"] = self.sdl.close()[-300:]
        self.answerer.stop()
        for watcher in (self.helper_reader, self.pad):
            if watcher is not None:
                watcher.reader.close()
        for device in (self.helper, self.box):
            try:
                device.close()
            except OSError:
                pass


#: A driver process that hides a merged device as the copilot does (its ``Hider(guarded=True)``),
#: says what it hid, then waits to be killed: not ``neurotouch-hid run`` itself, whose start costs
#: minutes here (check_copilot_merges_grabs_rejoins_and_rumbles runs that one in this process).
HIDING_DRIVER = """\
import sys
from neurotouch_hid.inputs.hide import Hider
hider = Hider(guarded=True)
print(hider.hide(sys.argv[1]), flush=True)
print(hider._guard.pid, flush=True)
sys.stdin.read()
"""


def _guard_ready(pid: int) -> bool:
    """Whether guard ``pid`` waits on its pipe with its put-back prepared (its main thread asleep
    in the pipe's read, its preparing thread ended: neurotouch_hid/service/guard.py)."""
    try:
        return "pipe_read" in Path(f"/proc/{pid}/wchan").read_text() and len(os.listdir(f"/proc/{pid}/task")) == 1
    except OSError:
        return False


def check_a_killed_driver_leaves_no_device_hidden() -> dict:
    """A driver SIGKILLed while it hides the helper's pad (the OOM killer, a crash in native code:
    nothing in it runs): its guard puts the pad's nodes back on devtmpfs at once, the same node
    (number, mode, owner, ACL), nothing left in the hidden folder, and a reader of the node gets
    the pad's events again; the guard's line on the driver's standard error names them. The kill
    comes once the guard is ready (``guard_ready_s`` after the hiding: its Python's start and its
    prepared imports), as a driver's death comes long after its merge; ``back_after_s`` is from the
    kill to the node back in /dev."""
    helper = helper_pad()
    guestlib.settle()
    path = helper.device.path
    before = _node_stat(path)
    driver = subprocess.Popen(
        [sys.executable, "-c", HIDING_DRIVER, path],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    details: dict = {}
    try:
        details["hid"] = driver.stdout.readline().strip()
        details["in_dev_while_hidden"] = os.path.exists(path)
        hidden, guard = time.monotonic(), int(driver.stdout.readline())
        details["guard_ready"] = guestlib.wait_for(lambda: _guard_ready(guard), 120.0, 0.05)
        details["guard_ready_s"] = round(time.monotonic() - hidden, 2)
        killed = time.monotonic()
        driver.kill()
        driver.wait()
        deadline = killed + 30
        while not os.path.exists(path) and time.monotonic() < deadline:
            time.sleep(0.02)
        details["back_after_s"] = round(time.monotonic() - killed, 2)
        details["in_dev_after_kill"] = os.path.exists(path)
        details["node_as_before"] = details["in_dev_after_kill"] and _node_stat(path) == before
        deadline = time.monotonic() + 30  # the guard's own line comes once its folder is empty
        while (HIDDEN_DIR / str(driver.pid)).exists() and time.monotonic() < deadline:
            time.sleep(0.02)
        details["left_hidden"] = (HIDDEN_DIR / str(driver.pid)).exists()
        watcher = Watcher(path)
        try:
            press(helper, (ecodes.EV_KEY, ecodes.BTN_SOUTH, 1))
            press(helper, (ecodes.EV_KEY, ecodes.BTN_SOUTH, 0))
            deadline = time.monotonic() + 10
            while len(watcher.keys_log()) < 2 and time.monotonic() < deadline:
                time.sleep(0.02)
            details["reader_after_kill"] = watcher.keys_log()
        finally:
            watcher.stop()
    finally:
        driver.kill()
        driver.wait()
        details["said"] = driver.stderr.read().strip().splitlines()[-1:]
        helper.close()
    return details
