"""The pad, and keyboard and mouse beside it: one uinput device each, made only when a profile uses it.

Each device offers only what the profiles use (docs/limits.md, Devices): a profile that a
crafted file or a bug made press something else cannot type it.

:class:`VirtualKeyboard` offers the keys it is given plus keys 1..31 (Esc, digits, Q..P, A, S, D,
Tab, Enter, Backspace, Left Ctrl: without all of them udev does not call a device a keyboard
and desktops do not apply the keyboard layout to it), never KEY_SYSRQ, and writes the
:attr:`ControllerState.keys` it offers; :class:`VirtualMouse` has BTN_LEFT and REL_X/REL_Y (what
makes a mouse for udev) plus the buttons and wheels given (a wheel with its hi-res code, 120 per
detent, kernel 5.0+), and writes its buttons in :attr:`ControllerState.keys` and the motion in
:attr:`ControllerState.rel`. Each is a :class:`~neurotouch_hid.core.stages.Target` (the keyboard and
mouse get nothing back: no ``fileno``). :class:`UinputOutputs` puts the pad and these together as
one :class:`~neurotouch_hid.core.stages.Target` (written to through
:class:`~neurotouch_hid.targets.TargetOutputs`, the run's one output path), so that a chord is
written in order across them. :class:`UinputDesktop` is the keyboard and mouse alone beside a HID
output (``run --output hid``: the joystick goes to UHID), or a plain "not sent" where uinput
cannot be used (no /dev/uinput, no permission, python-evdev not installed), said once per
profile that uses them. The pad too is made only when a profile
uses it (:attr:`~neurotouch_hid.mapping.profile.Profile.uses_pad`: a mapping or a merged device
drives a pad control), released and centred, so that a mouse or keyboard profile does not take
a player slot from a real pad; once made it stays for the run (games keep their handle).
The keyboard and mouse offer the union of the profiles known at start (shipped and the user's:
``profile use NAME`` keeps the same devices);
:meth:`UinputOutputs.prepare`, called after everything is released, makes a missing keyboard or
mouse, or replaces one that lacks what a new profile needs (a profile file given by path, or
edited since) by one offering both. Neutral = every key and button released (motion is an
impulse and stops by itself); every device is neutral before it goes.

Library: python-evdev's :class:`evdev.UInput` (kernel uinput, Documentation/input/uinput.rst);
the hi-res wheel convention is the kernel's (Documentation/input/event-codes.rst, EV_REL).
"""

from __future__ import annotations

import functools
import logging
import threading
from typing import TYPE_CHECKING, Callable, Iterable, TypeVar

from neurotouch_hid.core.controller import MOUSE_BUTTONS, MOUSE_REL, ControllerState, Feedback
from neurotouch_hid.core.errors import DeviceError
from neurotouch_hid.service.extras import MissingExtraError, require
from neurotouch_hid.targets.closing import NeutralOnClose
from neurotouch_hid.targets.uinput.gamepad import VirtualGamepad, create_uinput

if TYPE_CHECKING:
    from neurotouch_hid.mapping.profile import Profile

log = logging.getLogger(__name__)

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


#: Key codes 1..31 (KEY_ESC .. KEY_D): udev's input_id sets ID_INPUT_KEYBOARD only for a device
#: that has all of them (systemd, src/udev/udev-builtin-input_id.c, test_key).
UDEV_KEYBOARD_CODES = tuple(range(1, 32))
#: The wheels' hi-res codes, offered and written with them.
_HI_RES = {"REL_WHEEL": "REL_WHEEL_HI_RES", "REL_HWHEEL": "REL_HWHEEL_HI_RES"}


def keyboard_codes(keys: Iterable[str]) -> tuple[int, ...]:
    """The codes a keyboard offering ``keys`` (``KEY_*`` names) has: theirs and
    :data:`UDEV_KEYBOARD_CODES`, sorted, without the keys the machine acts on (SysRq, power,
    reboot, sleep, radios: profiles may not press them,
    :data:`~neurotouch_hid.mapping.profile.KERNEL_COMMAND_KEYS`)."""
    from evdev import ecodes

    from neurotouch_hid.mapping.profile import KERNEL_COMMAND_KEYS

    codes = set(UDEV_KEYBOARD_CODES) | {ecodes.ecodes[name] for name in keys if name not in KERNEL_COMMAND_KEYS}
    return tuple(sorted(codes - {ecodes.ecodes[name] for name in KERNEL_COMMAND_KEYS}))


def mouse_capabilities(outputs: Iterable[str]) -> dict[int, list[int]]:
    """EV_KEY and EV_REL codes of a mouse driving ``outputs`` (mouse button and REL_* names):
    theirs (a wheel with its hi-res code) plus BTN_LEFT, REL_X and REL_Y."""
    from evdev import ecodes

    wanted = set(outputs) | {"BTN_LEFT", "REL_X", "REL_Y"}
    buttons = [b for b in MOUSE_BUTTONS if b in wanted]
    rels = [r for r in MOUSE_REL if r in wanted or any(_HI_RES.get(w) == r for w in wanted)]
    return {ecodes.EV_KEY: [ecodes.ecodes[b] for b in buttons], ecodes.EV_REL: [ecodes.ecodes[r] for r in rels]}


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

    def prepare(self, profile: Profile) -> None:
        """Nothing: what the device offers is fixed when it is made (:class:`UinputOutputs`
        replaces one that lacks what a profile needs)."""

    def fileno(self) -> int | None:
        """None: a keyboard and a mouse get nothing back from games."""
        return None

    def feedback(self) -> list[Feedback]:
        """Nothing (never called: :meth:`fileno` is None)."""
        return []

    def _destroy(self) -> None:
        self._ui.close()


class VirtualKeyboard(_UinputDevice):
    """A uinput keyboard offering ``keys`` (``KEY_*`` names; :func:`keyboard_codes`);
    :meth:`write` presses those of ``state.keys`` it offers (``self.offers``); ``phys``: the
    camera's (``neurotouch-hid/SERIAL/keyboard``) or :data:`KEYBOARD_PHYS`. Raises DeviceError
    like :class:`VirtualGamepad`."""

    def __init__(self, keys: Iterable[str] = (), devnode: str = "/dev/uinput", phys: str = KEYBOARD_PHYS) -> None:
        from evdev import ecodes

        codes = keyboard_codes(keys)
        super().__init__("keyboard", {ecodes.EV_KEY: list(codes)}, KEYBOARD_NAME, phys, devnode)
        offered = set(codes)
        self.offers = frozenset(n for n, c in ecodes.ecodes.items() if n.startswith("KEY_") and c in offered)

    def write(self, state: ControllerState) -> None:
        self._emit(state.keys & self.offers, {})

    def lets_go(self, state: ControllerState) -> bool:
        """Whether writing ``state`` releases a key it holds now."""
        return bool(self._down - (state.keys & self.offers))


class VirtualMouse(_UinputDevice):
    """A uinput mouse driving ``outputs`` (mouse buttons, REL_* names; :func:`mouse_capabilities`);
    :meth:`write` presses the buttons of ``state.keys`` it offers and moves by ``state.rel``'s
    codes it offers (``self.offers``); ``phys``: the camera's (``neurotouch-hid/SERIAL/mouse``)
    or :data:`MOUSE_PHYS`. Raises DeviceError like :class:`VirtualGamepad`."""

    def __init__(self, outputs: Iterable[str] = (), devnode: str = "/dev/uinput", phys: str = MOUSE_PHYS) -> None:
        from evdev import ecodes

        caps = mouse_capabilities(outputs)
        super().__init__("mouse", caps, MOUSE_NAME, phys, devnode)
        offered = {c for codes in caps.values() for c in codes}
        self.offers = frozenset(n for n in (*MOUSE_BUTTONS, *MOUSE_REL) if ecodes.ecodes[n] in offered)

    def write(self, state: ControllerState) -> None:
        rel = {name: v for name, v in state.rel.items() if name in self.offers}
        self._emit(state.keys & self.offers, rel)


D = TypeVar("D", bound=_UinputDevice)


class UinputOutputs:
    """The pad, the keyboard and the mouse a profile uses, as one :class:`~neurotouch_hid.core.stages.Target`.

    ``write(state)`` writes each device's part; :meth:`neutralise` and :meth:`close` act on all
    (the pad last on close, so a game sees its release even if another device fails).
    :meth:`prepare` creates the pad (``make_pad(profile)``), keyboard or mouse a (new) profile
    needs, or replaces a keyboard or mouse that lacks some of its keys or buttons; the pad is never
    replaced (``pad``: one made already, kept whatever the profile), and the keyboard and mouse
    offer from the start what the ``known`` profiles use, so that switching between them keeps
    every device (programs keep their handles). Its readable side is the pad's (force feedback;
    :meth:`fileno` changes from None when :meth:`prepare` makes the pad).
    """

    what = "uinput pad, keyboard and mouse"

    def __init__(
        self,
        pad: VirtualGamepad | None,
        profile: Profile | None = None,
        devnode: str = "/dev/uinput",
        known: Iterable[Profile] = (),
        make_pad: Callable[[Profile], VirtualGamepad] | None = None,
        phys: str | None = None,
    ) -> None:
        self.pad = pad
        self._make_pad = make_pad
        self._phys = phys  # the camera's (``neurotouch-hid/SERIAL``): the keyboard's and mouse's prefix
        self.keyboard: VirtualKeyboard | None = None
        self.mouse: VirtualMouse | None = None
        self._devnode = devnode
        known = list(known)
        self._known_keys = frozenset().union(*(p.keyboard_keys for p in known))
        self._known_mouse = frozenset().union(*(p.mouse_outputs for p in known))
        if profile is not None:
            try:
                self.prepare(profile)
            except BaseException:
                self.close()
                raise

    @property
    def device_path(self) -> str | None:
        """The pad's event node (None while there is no pad)."""
        return self.pad.device_path if self.pad is not None else None

    @property
    def devices(self) -> list:
        """The devices in the order a press is written: the keyboard first (a modifier is down
        before the mouse button of a chord such as Ctrl+click), then the mouse, then the pad."""
        return [d for d in (self.keyboard, self.mouse, self.pad) if d is not None]

    @property
    def _releasing(self) -> list:
        """The devices in the order a release is written: the mouse before the keyboard (a
        chord's modifier up last), the pad last (a game sees its release even if another fails)."""
        return [d for d in (self.mouse, self.keyboard, self.pad) if d is not None]

    def prepare(self, profile: Profile) -> None:
        """Make the pad, keyboard and/or mouse ``profile`` uses: the pad once a profile drives it
        (neutral from its first report); a missing keyboard or mouse (offering what the known
        profiles use too), or one lacking some of its keys or buttons replaced by one offering
        both (the old one is released and removed first: call this only after :meth:`neutralise`).
        Raises DeviceError when the kernel refuses."""
        if self.pad is None and self._make_pad is not None and profile.uses_pad:
            self.pad = self._make_pad(profile)
        keyboard, mouse = VirtualKeyboard, VirtualMouse
        if self._phys is not None:  # the camera's: two gels' keyboards and mice told apart too
            keyboard = functools.partial(VirtualKeyboard, phys=f"{self._phys}/keyboard")
            mouse = functools.partial(VirtualMouse, phys=f"{self._phys}/mouse")
        self.keyboard = self._made(self.keyboard, profile.keyboard_keys, self._known_keys, keyboard)
        self.mouse = self._made(self.mouse, profile.mouse_outputs, self._known_mouse, mouse)

    def _made(
        self, device: D | None, needed: frozenset[str], known: frozenset[str], make: Callable[[frozenset[str], str], D]
    ) -> D | None:
        """``device`` if it offers ``needed`` (or nothing is needed), else a new one offering
        ``needed`` and what ``device`` offered (``known`` for a first one); the old one is closed."""
        if not needed or (device is not None and needed <= device.offers):
            return device
        offered = known if device is None else device.offers
        if device is not None:
            log.warning("the profile uses keys the virtual %s lacks: it is made again with them", device.what)
            device.close()
        return make(offered | needed, self._devnode)

    def fileno(self) -> int | None:
        """The pad's descriptor (force-feedback requests), None while there is no pad."""
        return self.pad.fileno() if self.pad is not None else None

    def feedback(self) -> list[Feedback]:
        """The pad's force-feedback requests answered, its rumble returned (:meth:`VirtualGamepad.feedback`)."""
        return self.pad.feedback() if self.pad is not None else []

    def write(self, state: ControllerState) -> None:
        releasing = self.keyboard is not None and self.keyboard.lets_go(state)
        for device in self._releasing if releasing else self.devices:
            device.write(state)

    def neutralise(self) -> None:
        for device in self._releasing:
            device.neutralise()

    def close(self) -> None:
        errors = []
        for device in self._releasing:
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


class UinputDesktop:
    """The uinput keyboard and mouse the profiles use, or a plain "not sent" when uinput cannot be used.

    Args:
        profile: the profile mapping now (its keyboard and mouse are made at once).
        known: every profile the run may switch to (the devices offer what they use from the
            start, so a switch keeps them).
        say: one line for the user (what is not sent, and why).
        devnode: the uinput node.
        phys: the camera's (``neurotouch-hid/SERIAL``): the keyboard's and mouse's prefix
            (None: their own, ``neurotouch-hid/keyboard`` and ``/mouse``).
    """

    what = "uinput keyboard and mouse"

    def __init__(
        self,
        profile: Profile,
        known: Iterable[Profile] = (),
        say: Callable[[str], None] = log.warning,
        devnode: str = "/dev/uinput",
        phys: str | None = None,
    ) -> None:
        self.say = say
        self._phys = phys
        self.outputs: UinputOutputs | None = None
        self.unavailable: str | None = None  # why uinput cannot be used, once found
        self._known = list(known)
        self._devnode = devnode
        self._told: set[str] = set()
        self.prepare(profile)

    def prepare(self, profile: Profile) -> None:
        """Make the keyboard and mouse ``profile`` uses (on the first profile that uses one), or
        say once per such profile that they are not sent."""
        if not (profile.keyboard_keys or profile.mouse_outputs):
            return
        if self.outputs is None and self.unavailable is None:
            try:
                require("uinput", "the uinput keyboard and mouse")
            except MissingExtraError as exc:
                self.unavailable = str(exc)
            else:
                # no pad: the joystick is another target's (UinputOutputs skips a missing device)
                self.outputs = UinputOutputs(None, None, self._devnode, known=self._known, phys=self._phys)  # type: ignore[arg-type]
        if self.outputs is not None:
            try:
                self.outputs.prepare(profile)
                return
            except DeviceError as exc:
                self.unavailable = str(exc).splitlines()[0]
        what = " and ".join(
            n for n, used in (("keyboard", profile.keyboard_keys), ("mouse", profile.mouse_outputs)) if used
        )
        line = f"the profile's {what} outputs are not sent: {self.unavailable} (see `neurotouch-hid doctor`)"
        if line not in self._told:
            self._told.add(line)
            self.say(line)

    def write(self, state: ControllerState) -> None:
        """The keys and mouse motion of ``state`` to the devices there are."""
        if self.outputs is not None:
            self.outputs.write(state)

    def neutralise(self) -> None:
        """Release every key and button."""
        if self.outputs is not None:
            self.outputs.neutralise()

    def fileno(self) -> int | None:
        """None: a keyboard and a mouse get nothing back."""
        return None

    def feedback(self) -> list[Feedback]:
        """Nothing (never called: :meth:`fileno` is None)."""
        return []

    def close(self) -> None:
        """Release and remove the devices."""
        if self.outputs is not None:
            self.outputs.close()
