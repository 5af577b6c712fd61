"""One merged input device: opened, grabbed, read within bounds, its controls as the pad's.

The device is opened read-write when allowed (a rumble is written to it) and grabbed
(EVIOCGRAB: while grabbed, no other reader of its node, a game included, receives its events;
Documentation/input/input.rst). It is read after each ``select``: one ``read`` takes at most
:data:`MAX_EVENTS_PER_READ` events (python-evdev's read buffer), key values are 0/1 and axis values
are clamped to the device's own ``absinfo`` range; its levels change only at a SYN_REPORT (the end
of the device's frame), and a SYN_DROPPED (the kernel's buffer overflowed) is followed by a fresh
read of the keys held and axes' values (EVIOCGKEY, EVIOCGABS), as Documentation/input/
event-codes.rst asks.

Rumble: a game's rumble on the gel's pad (:class:`~neurotouch_hid.stages.Feedback`) is uploaded
to a device that has FF_RUMBLE as one effect (EVIOCSFF) and played (an EV_FF write), or stopped
(EVIOCRMFF erases it when the device is let go). The two ioctls go through :func:`fcntl.ioctl`,
which releases the interpreter's lock while the kernel waits for the device's driver to accept
the effect (python-evdev's ``upload_effect`` holds it): the runtime's threads go on meanwhile,
even when that driver is a program (a uinput device) in this very process.

Library: python-evdev's :class:`evdev.InputDevice` and ``evdev.ff`` (the ``struct ff_effect``
layout); the ioctls are linux/input.h's.
"""

from __future__ import annotations

import ctypes
import errno
import fcntl
import logging
from typing import TYPE_CHECKING

from neurotouch_hid.mapping.merge import NEUTRAL, AxisRange, DeviceMap, Levels

if TYPE_CHECKING:
    from neurotouch_hid.inputs.match import InputInfo
    from neurotouch_hid.mapping.profile import CopilotDevice
    from neurotouch_hid.stages import Feedback

log = logging.getLogger(__name__)

#: Events one read takes at most (python-evdev's ``device_read_many`` reads 64 input_event structs).
MAX_EVENTS_PER_READ = 64
#: A rumble without a duration lasts this long (ms): the game renews or stops it.
DEFAULT_RUMBLE_MS = 1000
#: Errors that mean the device went away (unplugged) or its node was closed.
GONE_ERRNOS = (errno.ENODEV, errno.EBADF, errno.EIO)
#: linux/input.h: EVIOCSFF = _IOW('E', 0x80, struct ff_effect), EVIOCRMFF = _IOW('E', 0x81, int).
_IOC_WRITE, _IOC_SIZESHIFT, _IOC_DIRSHIFT = 1, 16, 30


def _iow(number: int, size: int) -> int:
    return (_IOC_WRITE << _IOC_DIRSHIFT) | (size << _IOC_SIZESHIFT) | (ord("E") << 8) | number


EVIOCRMFF = _iow(0x81, 4)


def _names(table: dict, code: int) -> list[str]:
    names = table.get(code, [])
    return [names] if isinstance(names, str) else list(names)


class MergedInput:
    """An input device merged into the pad (a profile's ``copilot:`` entry matched to it).

    Args:
        spec: the profile's entry. info: the device (:func:`~neurotouch_hid.inputs.match.input_devices`).

    Raises:
        OSError: the node cannot be opened or grabbed (EBUSY: another program grabbed it).
    """

    def __init__(self, spec: CopilotDevice, info: InputInfo) -> None:
        from evdev import InputDevice, ecodes

        self.spec = spec
        self.info = info
        self._ecodes = ecodes
        self.device = InputDevice(info.path)
        try:
            self.device.grab()
            caps = self.device.capabilities(absinfo=True)
            key_codes = caps.get(ecodes.EV_KEY, [])
            keys = {code: _names(ecodes.KEY, code) + _names(ecodes.BTN, code) for code in key_codes}
            self._ranges = {
                code: AxisRange(absinfo.min, absinfo.max, max(absinfo.flat, 0))
                for code, absinfo in caps.get(ecodes.EV_ABS, [])
            }
            axes = {code: (_names(ecodes.ABS, code), r) for code, r in self._ranges.items()}
            self.map = DeviceMap(spec, keys, axes)
            self.can_rumble = ecodes.FF_RUMBLE in caps.get(ecodes.EV_FF, [])
            self._keys: set[int] = set()
            self._abs: dict[int, int] = {}
            self._pending_keys: set[int] = set()
            self._pending_abs: dict[int, int] = {}
            self._effect: int | None = None
            self._resync()
        except BaseException:
            self.close()
            raise
        self.levels: Levels = self._levels()

    @property
    def fd(self) -> int:
        return self.device.fd

    def _clamp(self, code: int, value: int) -> int:
        r = self._ranges.get(code)
        return value if r is None else min(max(value, r.minimum), r.maximum)

    def _resync(self) -> None:
        """The keys held and axes' values now (EVIOCGKEY, EVIOCGABS), after opening or a SYN_DROPPED."""
        self._keys = {c for c in self.device.active_keys() if c in self.map.keys}
        self._abs = {c: self._clamp(c, self.device.absinfo(c).value) for c in self.map.axes}
        self._pending_keys, self._pending_abs = set(self._keys), dict(self._abs)

    def _levels(self) -> Levels:
        return self.map.levels(self._keys, self._abs)

    def read(self) -> bool:
        """Read what is there (at most :data:`MAX_EVENTS_PER_READ` events); returns whether the
        device's levels changed at a SYN_REPORT. Raises OSError with an errno of
        :data:`GONE_ERRNOS` when the device is gone."""
        ec = self._ecodes
        try:
            events = list(self.device.read())
        except BlockingIOError:
            return False
        changed = False
        for ev in events[:MAX_EVENTS_PER_READ]:
            if ev.type == ec.EV_KEY and ev.code in self.map.keys:
                (self._pending_keys.add if ev.value else self._pending_keys.discard)(ev.code)
            elif ev.type == ec.EV_ABS and ev.code in self.map.axes:
                self._pending_abs[ev.code] = self._clamp(ev.code, int(ev.value))
            elif ev.type == ec.EV_SYN and ev.code == ec.SYN_DROPPED:
                self._resync()
            elif ev.type == ec.EV_SYN and ev.code == ec.SYN_REPORT:
                self._keys, self._abs = set(self._pending_keys), dict(self._pending_abs)
                levels = self._levels()
                if levels != self.levels:
                    self.levels, changed = levels, True
        return changed

    def rumble(self, request: Feedback) -> None:
        """Play ``request`` (a ``"rumble"``) on the device: one FF_RUMBLE effect uploaded (again,
        with the new magnitudes) and played; magnitudes 0 stop it. Nothing for a device without
        FF_RUMBLE. Raises OSError when the kernel refuses."""
        if not self.can_rumble or request.kind != "rumble":
            return
        from evdev import ff

        ec = self._ecodes
        if request.strong <= 0 and request.weak <= 0:
            if self._effect is not None:
                self.device.write(ec.EV_FF, self._effect, 0)
            return
        length = request.duration_ms if request.duration_ms is not None else DEFAULT_RUMBLE_MS
        rumble = ff.Rumble(
            strong_magnitude=round(min(max(request.strong, 0.0), 1.0) * 0xFFFF),
            weak_magnitude=round(min(max(request.weak, 0.0), 1.0) * 0xFFFF),
        )
        effect = ff.Effect(
            ec.FF_RUMBLE,
            -1 if self._effect is None else self._effect,
            0,
            ff.Trigger(0, 0),
            ff.Replay(min(max(int(length), 0), 0xFFFF), 0),
            ff.EffectType(ff_rumble_effect=rumble),
        )
        fcntl.ioctl(self.device.fd, _iow(0x80, ctypes.sizeof(effect)), effect, True)  # the kernel writes its id
        self._effect = int(effect.id)
        self.device.write(ec.EV_FF, self._effect, 1)

    def close(self) -> None:
        """Stop a rumble, release the grab, close the node; the device's levels are neutral.
        Never raises (the device may be gone already)."""
        self.levels = NEUTRAL
        device = getattr(self, "device", None)
        if device is None:
            return
        for step in (self._stop_rumble, device.ungrab, device.close):
            try:
                step()
            except (OSError, ValueError, AttributeError):
                pass

    def _stop_rumble(self) -> None:
        effect = getattr(self, "_effect", None)
        if effect is not None:
            self._effect = None
            self.device.write(self._ecodes.EV_FF, effect, 0)
            fcntl.ioctl(self.device.fd, EVIOCRMFF, effect)
