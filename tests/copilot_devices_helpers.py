"""Fake evdev nodes for the copilot's device tests (tests/test_copilot_devices.py,
tests/test_copilot_rumble.py).

:class:`FakeNode` is a device as the kernel holds it (its keys held and axes' values, which
EVIOCGKEY/EVIOCGABS return; the reads its client gets, one list of events a read; a pipe whose read
end is its descriptor, so ``select`` wakes on it); :class:`FakeInputDevice` stands in for
python-evdev's ``InputDevice`` (a node opened read-only writes through python-evdev's own ``write``,
which raises ``EvdevError`` on such a descriptor); the ioctls of device.py (EVIOCSFF, EVIOCRMFF) are
recorded. /dev/input and /sys/class/input are folders of plain files, as in
tests/test_copilot_controls.py."""

from __future__ import annotations

import errno
import os
import types
from collections import deque
from pathlib import Path

import evdev
import evdev.eventio
import pytest
from evdev import AbsInfo, InputEvent, ecodes, ff

import neurotouch_hid.inputs.device as device_module
from neurotouch_hid.engine.loop import Loop
from neurotouch_hid.inputs.copilot import Copilot
from neurotouch_hid.inputs.device import EVIOCRMFF
from neurotouch_hid.mapping.profile import parse_profile

#: A wait that ends a hang only (helpers.wait_until): what is waited for is asserted, never a delay.
HANG_S = 15.0


HELPER = 'copilot:\n  - {device: "Helper Pad"}\n'


def _event(etype: int, code: int, value: int) -> InputEvent:
    return InputEvent(0, 0, etype, code, value)


REPORT = (ecodes.EV_SYN, ecodes.SYN_REPORT, 0)


class FakeNode:
    """One evdev device: its capabilities (``keys``: key codes; ``axes``: code -> (min, max);
    ``ff``: EV_FF codes), its state now (``held``, ``values``), the reads its client will get."""

    def __init__(self, keys=(), axes=None, ff_codes=(), *, read_only: bool = False) -> None:
        self.keys, self.axes, self.ff = list(keys), dict(axes or {}), list(ff_codes)
        self.held: set[int] = set()
        self.values = {code: (lo + hi) // 2 for code, (lo, hi) in self.axes.items()}
        self.reads: deque[list[InputEvent]] = deque()
        self.r, self.w = os.pipe()
        os.set_blocking(self.r, False)
        self.read_only = read_only  # python-evdev fell back to O_RDONLY (the node is not writable)
        self.gone = False
        self.grabbed = False
        self.held_by_other = False  # another program grabbed it: EVIOCGRAB fails with EBUSY
        self.closed = 0
        self.written: list[tuple[int, int, int]] = []

    def queue(self, *events: tuple[int, int, int]) -> None:
        """One read of these events as they are (the device's state is the test's to set)."""
        self.reads.append([_event(*e) for e in events])
        os.write(self.w, b"x")

    def frame(self, *events: tuple[int, int, int]) -> None:
        """The device sends ``events`` and a SYN_REPORT, read at once; its state follows them."""
        for etype, code, value in events:
            if etype == ecodes.EV_KEY:
                (self.held.add if value else self.held.discard)(code)
            elif etype == ecodes.EV_ABS:
                self.values[code] = value
        self.queue(*events, REPORT)

    def unplug(self) -> None:
        self.gone = True
        os.write(self.w, b"x")


class FakeInputDevice:
    """python-evdev's ``InputDevice`` on a :class:`FakeNode` (the registry is set by the fixture)."""

    nodes: dict[str, FakeNode] = {}

    def __init__(self, path: str) -> None:
        self.path = path
        self.node = self.nodes[path]
        if self.node.gone:
            raise OSError(errno.ENODEV, "No such device")
        self.fd = self.node.r

    def grab(self) -> None:
        if self.node.held_by_other:
            raise OSError(errno.EBUSY, "Device or resource busy")
        self.node.grabbed = True

    def ungrab(self) -> None:
        if not self.node.grabbed:
            raise OSError(errno.EINVAL, "Invalid argument")
        self.node.grabbed = False

    def close(self) -> None:
        if self.fd > -1:
            self.fd = -1
            self.node.closed += 1

    def capabilities(self, absinfo: bool = True) -> dict:
        caps: dict = {}
        if self.node.keys:
            caps[ecodes.EV_KEY] = list(self.node.keys)
        if self.node.axes:
            caps[ecodes.EV_ABS] = [(code, self.absinfo(code)) for code in self.node.axes]
        if self.node.ff:
            caps[ecodes.EV_FF] = list(self.node.ff)
        return caps

    def active_keys(self) -> list[int]:  # EVIOCGKEY
        return sorted(self.node.held)

    def absinfo(self, code: int) -> AbsInfo:  # EVIOCGABS
        lo, hi = self.node.axes[code]
        return AbsInfo(self.node.values[code], lo, hi, 0, 0, 0)

    def read(self):
        if self.node.gone:
            raise OSError(errno.ENODEV, "No such device")
        try:
            os.read(self.node.r, 4096)
        except BlockingIOError:
            pass
        if not self.node.reads:
            raise BlockingIOError(errno.EAGAIN, "Resource temporarily unavailable")
        events = self.node.reads.popleft()
        if self.node.reads:
            os.write(self.node.w, b"x")
        return iter(events)

    def write(self, etype: int, code: int, value: int) -> None:
        if self.node.read_only:  # python-evdev's own write: its need_write check raises EvdevError
            evdev.eventio.EventIO.write(self, etype, code, value)
        self.node.written.append((etype, code, value))


class Rig:
    """A fake /dev/input and /sys/class/input, the nodes in them, and the ioctls device.py made."""

    def __init__(self, root: Path) -> None:
        self.dev, self.sys = root / "dev" / "input", root / "sys" / "class" / "input"
        (self.dev / "by-id").mkdir(parents=True)
        self.sys.mkdir(parents=True)
        self.nodes: dict[str, FakeNode] = {}
        self.ioctls: list[tuple] = []
        self._next_id = 0

    def add(self, name: str, node: str, device: FakeNode, phys: str = "usb-1/input0") -> FakeNode:
        folder = self.sys / node / "device"
        (folder / "id").mkdir(parents=True)
        (folder / "name").write_text(name + "\n")
        (folder / "phys").write_text(phys + "\n")
        (folder / "id" / "vendor").write_text("045e\n")
        (folder / "id" / "product").write_text("02ea\n")
        self.nodes[str(self.dev / node)] = device
        (self.dev / node).write_text("")  # last: the inotify event comes when the device is described
        return device

    def ioctl(self, fd: int, request: int, arg, mutate: bool = False) -> int:
        """EVIOCSFF (the kernel gives a new effect its id) and EVIOCRMFF, recorded."""
        if request == EVIOCRMFF:
            self.ioctls.append(("erase", arg))
        elif isinstance(arg, ff.Effect):
            if arg.id == -1:
                arg.id, self._next_id = self._next_id, self._next_id + 1
            rumble = arg.u.ff_rumble_effect
            self.ioctls.append(("upload", arg.id, rumble.strong_magnitude, rumble.weak_magnitude, arg.ff_replay.length))
        else:
            raise AssertionError(f"unexpected ioctl {request:#x}")
        return 0

    def uploads(self) -> list[tuple]:
        return [call[1:] for call in self.ioctls if call[0] == "upload"]

    def copilot(self, text: str = HELPER, said: list[str] | None = None, loop: Loop | None = None) -> Copilot:
        said = [] if said is None else said
        copilot = parse_profile(text, "p.yaml").copilot
        return Copilot(copilot, input_dir=self.dev, sysfs=self.sys, say=said.append, loop=loop)

    def close(self) -> None:
        for node in self.nodes.values():
            for fd in (node.r, node.w):
                os.close(fd)


@pytest.fixture
def rig(tmp_path, monkeypatch):
    made = Rig(tmp_path)
    monkeypatch.setattr(FakeInputDevice, "nodes", made.nodes)
    monkeypatch.setattr(evdev, "InputDevice", FakeInputDevice)
    monkeypatch.setattr(device_module, "fcntl", types.SimpleNamespace(ioctl=made.ioctl))
    yield made
    made.close()


def _rumbler(read_only: bool = False) -> FakeNode:
    """A helper's pad with button A and FF_RUMBLE."""
    return FakeNode(keys=[ecodes.BTN_SOUTH], ff_codes=[ecodes.FF_RUMBLE], read_only=read_only)


class _PadRumble:
    """The gel's pad's force-feedback side (neurotouch_hid/targets/uinput/gamepad.py) without uinput:
    effects remembered as the pad remembers an upload, each play or stop handed to
    ``on_feedback`` as the run's feedback path forwards what the pad returns."""

    def __init__(self, on_feedback) -> None:
        from neurotouch_hid.targets.uinput.gamepad import VirtualGamepad

        self.pad = object.__new__(VirtualGamepad)
        self.pad._rumbles, self.pad.what = {}, "uinput pad"
        self.on_feedback = on_feedback

    def _remember_rumble(self, effect) -> None:
        self.pad._remember_rumble(effect)

    def _forward_rumble(self, effect_id: int, value: int) -> None:
        request = self.pad._rumble_of(effect_id, value)
        if request is not None:
            self.on_feedback(request)


def _pad_rumble(on_feedback) -> _PadRumble:
    return _PadRumble(on_feedback)


def _effect(effect_id: int, strong: int, weak: int, length_ms: int) -> ff.Effect:
    rumble = ff.Rumble(strong_magnitude=strong, weak_magnitude=weak)
    replay, union = ff.Replay(length_ms, 0), ff.EffectType(ff_rumble_effect=rumble)
    return ff.Effect(ecodes.FF_RUMBLE, effect_id, 0, ff.Trigger(0, 0), replay, union)
