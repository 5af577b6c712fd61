"""Keyboard and mouse beside the pad: one uinput device each, made only when a profile uses it.

:class:`VirtualKeyboard` offers every evdev ``KEY_*`` key (so a later profile switch can press any
of them on the same device) and writes :attr:`ControllerState.keys` that are keyboard keys;
:class:`VirtualMouse` has the five mouse buttons, REL_X/REL_Y, and both wheels with their hi-res
codes (REL_WHEEL_HI_RES/REL_HWHEEL_HI_RES, 120 per detent, kernel 5.0+), and writes the mouse
buttons in :attr:`ControllerState.keys` and the motion in :attr:`ControllerState.rel`.
:class:`UinputOutputs` puts the pad and these together behind the one ``write`` /
``neutralise`` / ``close`` an output has; :meth:`UinputOutputs.prepare` makes a missing keyboard
or mouse when a profile switch needs one. Neutral = every key and button released (motion is an
impulse and stops by itself); every device is neutral before it goes.

Library: python-evdev's :class:`evdev.UInput` (kernel uinput, Documentation/input/uinput.rst);
the hi-res wheel convention is the kernel's (Documentation/input/event-codes.rst, EV_REL).
"""

from __future__ import annotations

import functools
import threading
from typing import Any

from neurotouch_hid.controller import MOUSE_BUTTONS, MOUSE_REL, ControllerState
from neurotouch_hid.errors import DeviceError
from neurotouch_hid.output.gamepad import NeutralOnClose, VirtualGamepad, create_uinput

#: ``phys`` of the keyboard and the mouse (the udev rule's ``neurotouch-hid/*`` tags them
#: ID_NEUROTOUCH_VIRTUAL=1 like the pad).
KEYBOARD_PHYS = "neurotouch-hid/keyboard"
MOUSE_PHYS = "neurotouch-hid/mouse"
KEYBOARD_NAME = "NeuroTouch keyboard"
MOUSE_NAME = "NeuroTouch mouse"
#: Modifiers go down before, and up after, the other keys of a chord written in one report.
MODIFIERS = frozenset(
    {
        "KEY_LEFTSHIFT",
        "KEY_RIGHTSHIFT",
        "KEY_LEFTCTRL",
        "KEY_RIGHTCTRL",
        "KEY_LEFTALT",
        "KEY_RIGHTALT",
        "KEY_LEFTMETA",
        "KEY_RIGHTMETA",
    }
)


@functools.cache
def keyboard_codes() -> tuple[int, ...]:
    """Every ``KEY_*`` code (sorted, no duplicates, none of the BTN_* range 0x100..0x15f)."""
    from evdev import ecodes

    from neurotouch_hid.mapping.profile import keyboard_keys

    codes = {ecodes.ecodes[name] for name in keyboard_keys()}
    return tuple(sorted(c for c in codes if 0 < c and not ecodes.BTN_MISC <= c < ecodes.KEY_OK))


class _UinputDevice(NeutralOnClose):
    """A uinput device whose keys are tracked, so that it can always be released."""

    def __init__(self, what: str, capabilities: dict, name: str, phys: str, devnode: str) -> None:
        from evdev import ecodes

        self._ecodes = ecodes.ecodes
        self._ui = create_uinput(
            what,
            capabilities,
            devnode,
            name=name,
            vendor=0,
            product=0,
            version=1,
            bustype=ecodes.BUS_VIRTUAL,
            phys=phys,
        )
        self.what = what
        self._down: frozenset[str] = frozenset()
        self._lock = threading.RLock()
        self._closed = False

    @property
    def device_path(self) -> str | None:
        """The event node, e.g. ``/dev/input/event6`` (None if it could not be opened)."""
        device = self._ui.device
        return device.path if device is not None else None

    def _emit(self, keys: frozenset[str], rel: dict[str, int]) -> None:
        """Press/release what changed (modifiers first down, last up), then the motion, one report."""
        with self._lock:
            if self._closed:
                return
            up = sorted(self._down - keys, key=lambda k: k in MODIFIERS)
            down = sorted(keys - self._down, key=lambda k: k not in MODIFIERS)
            moves = [(name, rel[name]) for name in MOUSE_REL if rel.get(name)]
            if not (up or down or moves):
                return
            ev_key, ev_rel, codes = self._ecodes["EV_KEY"], self._ecodes["EV_REL"], self._ecodes
            try:
                for name in up:
                    self._ui.write(ev_key, codes[name], 0)
                for name in down:
                    self._ui.write(ev_key, codes[name], 1)
                for name, value in moves:
                    self._ui.write(ev_rel, codes[name], int(value))
                self._ui.syn()
            except OSError as exc:
                raise DeviceError(f"writing to the virtual {self.what} failed: {exc}") from None
            self._down = keys

    def neutralise(self) -> None:
        """Release every key and button."""
        self._emit(frozenset(), {})

    def _destroy(self) -> None:
        self._ui.close()


class VirtualKeyboard(_UinputDevice):
    """A uinput keyboard with every ``KEY_*`` key; :meth:`write` presses ``state.keys``' keyboard
    keys. Raises DeviceError like :class:`VirtualGamepad`."""

    def __init__(self, devnode: str = "/dev/uinput") -> None:
        from evdev import ecodes

        super().__init__("keyboard", {ecodes.EV_KEY: list(keyboard_codes())}, KEYBOARD_NAME, KEYBOARD_PHYS, devnode)

    def write(self, state: ControllerState) -> None:
        self._emit(frozenset(k for k in state.keys if k.startswith("KEY_")), {})


class VirtualMouse(_UinputDevice):
    """A uinput mouse: BTN_LEFT .. BTN_EXTRA, REL_X/REL_Y, REL_WHEEL/REL_HWHEEL and their hi-res
    codes; :meth:`write` presses ``state.keys``' mouse buttons and moves by ``state.rel``.
    Raises DeviceError like :class:`VirtualGamepad`."""

    def __init__(self, devnode: str = "/dev/uinput") -> None:
        from evdev import ecodes

        caps = {
            ecodes.EV_KEY: [ecodes.ecodes[b] for b in MOUSE_BUTTONS],
            ecodes.EV_REL: [ecodes.ecodes[r] for r in MOUSE_REL],
        }
        super().__init__("mouse", caps, MOUSE_NAME, MOUSE_PHYS, devnode)

    def write(self, state: ControllerState) -> None:
        self._emit(frozenset(k for k in state.keys if k in MOUSE_BUTTONS), state.rel)


class UinputOutputs:
    """The pad, and the keyboard and mouse a profile uses, as one output.

    ``write(state)`` writes each device's part; :meth:`neutralise` and :meth:`close` act on all
    (the pad last on close, so a game sees its release even if another device fails).
    :meth:`prepare` creates the keyboard or mouse a (new) profile needs; devices are never
    removed while running, so programs keep their handles.
    """

    #: uinput devices show states only (:class:`~neurotouch_hid.stages.Output`).
    accepts_estimate = False

    def __init__(self, pad: VirtualGamepad, profile: Any = None, devnode: str = "/dev/uinput") -> None:
        self.pad = pad
        self.keyboard: VirtualKeyboard | None = None
        self.mouse: VirtualMouse | None = None
        self._devnode = devnode
        if profile is not None:
            try:
                self.prepare(profile)
            except BaseException:
                self.close()
                raise

    @property
    def device_path(self) -> str | None:
        return self.pad.device_path

    @property
    def devices(self) -> list:
        return [d for d in (self.keyboard, self.mouse, self.pad) if d is not None]

    def prepare(self, profile: Any) -> None:
        """Create the keyboard and/or mouse if ``profile`` uses them and they do not exist yet.
        Raises DeviceError when the kernel refuses."""
        if profile.uses_keyboard and self.keyboard is None:
            self.keyboard = VirtualKeyboard(self._devnode)
        if profile.uses_mouse and self.mouse is None:
            self.mouse = VirtualMouse(self._devnode)

    def write(self, state: ControllerState, estimate: Any = None) -> None:
        for device in self.devices:
            device.write(state)

    def neutralise(self) -> None:
        for device in self.devices:
            device.neutralise()

    def close(self) -> None:
        errors = []
        for device in self.devices:
            try:
                device.close()
            except Exception as exc:  # the next device must still be released
                errors.append(exc)
        if errors:
            raise errors[0]

    def __enter__(self) -> "UinputOutputs":
        return self

    def __exit__(self, *exc_info) -> None:
        self.close()
