"""One merged input device: opened, grabbed, read within bounds, its controls as the pad's.

The device is opened read-write when allowed (a rumble is written to it) and grabbed
(EVIOCGRAB: while grabbed, no other reader of its node, a game included, receives its events;
Documentation/input/input.rst). It is read after each ``select``: one ``read`` takes at most
:data:`MAX_EVENTS_PER_READ` events (python-evdev's read buffer), key values are 0/1 and axis values
are clamped to the device's own ``absinfo`` range; its levels change only at a SYN_REPORT (the end
of the device's frame). After a SYN_DROPPED (the kernel's buffer overflowed) every event up to and
including the next SYN_REPORT is ignored, across reads, and the levels are then the keys held and
axes' values queried from the device (EVIOCGKEY, EVIOCGABS), as Documentation/input/event-codes.rst
asks.

Rumble: a game's rumble on the gel's pad (:class:`~neurotouch_hid.core.stages.Feedback`) is uploaded
to a device that has FF_RUMBLE as one effect (EVIOCSFF) and played (an EV_FF write), or stopped
(EVIOCRMFF erases it when the device is let go); a rumble without a duration plays until it is
stopped (replay length 0, as drivers/input/ff-memless.c plays it). A node python-evdev could open
read-only only (it falls back to O_RDONLY when the node is not writable by the user) cannot play an
effect: its rumble is off, said once in the log. The two ioctls go through :func:`fcntl.ioctl`,
which releases the interpreter's lock while the kernel waits for the device's driver to accept
the effect (python-evdev's ``upload_effect`` holds it): the runtime's threads go on meanwhile,
even when that driver is a program (a uinput device) in this very process.

Library: python-evdev's :class:`evdev.InputDevice` and ``evdev.ff`` (the ``struct ff_effect``
layout); the ioctls are linux/input.h's.
"""

from __future__ import annotations

import contextlib
import ctypes
import errno
import fcntl
import logging
from typing import TYPE_CHECKING

from neurotouch_hid.mapping.merge import NEUTRAL, AxisRange, DeviceMap, Levels

if TYPE_CHECKING:
    from neurotouch_hid.core.stages import Feedback
    from neurotouch_hid.inputs.match import InputInfo
    from neurotouch_hid.mapping.profile import CopilotDevice

log = logging.getLogger(__name__)

#: Events one read takes at most (python-evdev's ``device_read_many`` reads 64 input_event structs).
MAX_EVENTS_PER_READ = 64
#: The longest replay length an effect can have (ms; struct ff_replay's ``length`` is a __u16).
MAX_RUMBLE_MS = 0xFFFF
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
            self._dropping = False  # after a SYN_DROPPED, until the SYN_REPORT that ends its frame
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

    def _commit(self) -> bool:
        """The pending keys and axes become the device's (at a SYN_REPORT); whether its levels changed."""
        self._keys, self._abs = set(self._pending_keys), dict(self._pending_abs)
        levels = self._levels()
        if levels == self.levels:
            return False
        self.levels = levels
        return True

    def read(self) -> bool:
        """Read what is there (at most :data:`MAX_EVENTS_PER_READ` events); returns whether the
        device's levels changed at a SYN_REPORT.

        After a SYN_DROPPED, the events up to and including the next SYN_REPORT (in this read or a
        later one) are ignored: they are the rest of a frame whose start was lost. At that
        SYN_REPORT the keys held and the axes' values are queried (EVIOCGKEY, EVIOCGABS) and are the
        levels; the events after it in the same read are ignored too, since the queries, made after
        those events were read, already hold them (and EVIOCGKEY flushed the key events still
        queued). Documentation/input/event-codes.rst, SYN_DROPPED.

        Raises:
            OSError: with an errno of :data:`GONE_ERRNOS` when the device is gone.
        """
        ec = self._ecodes
        try:
            events = list(self.device.read())
        except BlockingIOError:
            return False
        changed = False
        for ev in events[:MAX_EVENTS_PER_READ]:
            if ev.type == ec.EV_SYN and ev.code == ec.SYN_DROPPED:
                self._dropping = True
            elif self._dropping:
                if ev.type == ec.EV_SYN and ev.code == ec.SYN_REPORT:
                    self._dropping = False
                    self._resync()
                    return self._commit() or changed
            elif ev.type == ec.EV_KEY and ev.code in self.map.keys:
                (self._pending_keys.add if ev.value else self._pending_keys.discard)(ev.code)
            elif ev.type == ec.EV_ABS and ev.code in self.map.axes:
                self._pending_abs[ev.code] = self._clamp(ev.code, int(ev.value))
            elif ev.type == ec.EV_SYN and ev.code == ec.SYN_REPORT:
                changed |= self._commit()
        return changed

    def rumble(self, request: Feedback) -> None:
        """Play ``request`` (a ``"rumble"``: magnitudes 0..1, ``duration_ms`` in ms) on the device.

        One FF_RUMBLE effect is uploaded (EVIOCSFF; again, with the new magnitudes, for each
        request) and played (an EV_FF write); magnitudes 0 stop it. ``duration_ms`` None or 0
        plays it until it is stopped (replay length 0: drivers/input/ff-memless.c plays such an
        effect until it is stopped), longer than :data:`MAX_RUMBLE_MS` is cut to it. Nothing for a
        device without FF_RUMBLE, nor for one python-evdev opened read-only: the first rumble
        there erases the effect it uploaded, turns rumble off for the device (``can_rumble``) and
        says once in the log that the node must be writable (Documentation/input/ff.rst: effects
        are played by writing to the device).

        Raises:
            OSError: the kernel refuses the effect (EVIOCSFF) or the write.
        """
        if not self.can_rumble or request.kind != "rumble":
            return
        from evdev import ff

        ec = self._ecodes
        if request.strong <= 0 and request.weak <= 0:
            if self._effect is not None:
                self._play(0)
            return
        length = min(max(int(request.duration_ms or 0), 0), MAX_RUMBLE_MS)
        rumble = ff.Rumble(
            strong_magnitude=round(min(max(request.strong, 0.0), 1.0) * 0xFFFF),
            weak_magnitude=round(min(max(request.weak, 0.0), 1.0) * 0xFFFF),
        )
        effect = ff.Effect(
            ec.FF_RUMBLE,
            -1 if self._effect is None else self._effect,
            0,
            ff.Trigger(0, 0),
            ff.Replay(length, 0),
            ff.EffectType(ff_rumble_effect=rumble),
        )
        fcntl.ioctl(self.device.fd, _iow(0x80, ctypes.sizeof(effect)), effect, True)  # the kernel writes its id
        self._effect = int(effect.id)
        self._play(1)

    def _play(self, value: int) -> None:
        """Play (1) or stop (0) the uploaded effect; a node opened read-only turns rumble off."""
        from evdev import EvdevError

        try:
            self.device.write(self._ecodes.EV_FF, self._effect, value)
        except EvdevError as exc:  # python-evdev's need_write: the node was opened O_RDONLY (no OSError)
            self.can_rumble = False
            effect, self._effect = self._effect, None
            with contextlib.suppress(OSError):
                fcntl.ioctl(self.device.fd, EVIOCRMFF, effect)  # EVIOCRMFF needs no write access
            log.warning(
                "cannot rumble %s (%s): %s; the game's rumble is not played on it. Rumble needs the "
                "device node writable by this user: add the user to the group that owns it (usually "
                "'sudo usermod -aG input $USER', then log in again) or give it a udev rule; "
                "'neurotouch-hid doctor' checks it",
                self.spec.device,
                self.info.path,
                exc,
            )

    def close(self) -> None:
        """Stop a rumble, release the grab, close the node; the device's levels are neutral.

        Never raises: each step is done whatever the one before raised (the device may be gone
        already, or opened read-only: python-evdev's EvdevError, which is no OSError)."""
        self.levels = NEUTRAL
        device = getattr(self, "device", None)
        if device is None:
            return
        for step in (self._stop_rumble, device.ungrab, device.close):
            try:
                step()
            except Exception as exc:  # the grab must be released and the node closed whatever happened
                log.debug("closing %s: %s", getattr(device, "path", "?"), exc)

    def _stop_rumble(self) -> None:
        """Stop the uploaded effect and erase it (EVIOCRMFF, which stops it as well)."""
        effect = getattr(self, "_effect", None)
        if effect is not None:
            self._effect = None
            try:
                self.device.write(self._ecodes.EV_FF, effect, 0)
            finally:
                fcntl.ioctl(self.device.fd, EVIOCRMFF, effect)
