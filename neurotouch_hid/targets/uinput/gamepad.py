"""The virtual gamepad: a uinput device with the Xbox 360 layout that SDL, Steam and browsers know.

Layout (docs/architecture.md, :mod:`neurotouch_hid.core.controller`): sticks ABS_X/Y/RX/RY in
-32768..32767 (flat 128 like the kernel's xpad driver, but fuzz 0, see :data:`STICK_FUZZ`), triggers ABS_Z/RZ in 0..255,
d-pad ABS_HAT0X/Y in -1..1, and the 11 buttons BTN_SOUTH .. BTN_THUMBR. Nothing mouse- or
touch-like, so udev classes it as a joystick (ID_INPUT_JOYSTICK=1) and SDL as a GameController.
Like xpad it advertises force feedback ``FF_RUMBLE`` (Wine and SDL offer rumble only then). The
pad is a :class:`~neurotouch_hid.core.stages.Target`: its uinput descriptor (:meth:`VirtualGamepad.fileno`)
is readable when a game uploads, erases or plays an effect, and :meth:`VirtualGamepad.feedback`,
called then by the run's one feedback path (:class:`~neurotouch_hid.targets.TargetOutputs`),
answers every upload and erase at once (the kernel blocks the game's EVIOCSFF until uinput
answers) and returns each rumble played or stopped as a :class:`~neurotouch_hid.core.stages.Feedback`
(said to the user -- the gel has no motor -- and played on the merged pads that can rumble).
By default it presents itself as "Microsoft X-Box 360 pad", USB 045e:028e version 0x0114: the ids
SDL's controller database maps without configuration.

The device is made when a profile first drives it (``targets/uinput/desktop.py``) and kept for the rest
of the run (a profile switch calls :meth:`VirtualGamepad.neutralise`, not a new device: games
keep their handle). The runtime owns
signal handling; on SIGTERM/SIGINT it must call :meth:`VirtualGamepad.close`, which centres every
axis and releases every button before the device disappears, so no button stays pressed.

Library: python-evdev's :class:`evdev.UInput` (kernel uinput, Documentation/input/uinput.rst).
"""

from __future__ import annotations

import logging
import os
import threading
import time
from dataclasses import dataclass
from typing import TYPE_CHECKING, Callable

from neurotouch_hid.core.controller import AXES, BUTTONS, ControllerState, Feedback
from neurotouch_hid.core.errors import DeviceError
from neurotouch_hid.service.udev import uinput_help, uinput_problem
from neurotouch_hid.targets.closing import NeutralOnClose

if TYPE_CHECKING:
    from evdev import UInput

    from neurotouch_hid.mapping.profile import Profile

#: ``phys`` of every device we create; the udev rule tags devices with it ID_NEUROTOUCH_VIRTUAL=1.
PHYS = "neurotouch-hid/gamepad"
#: Stick noise filter: 0, unlike xpad's 16. The input core "defuzzes" every value closer than
#: ``fuzz`` to the last one (input_defuzz_abs_event: within fuzz/2 it is dropped), so with 16 a
#: stick at 5 could never be centred to 0. Our values are computed, not noisy: the profile's dead
#: zone and hysteresis do the filtering.
STICK_FUZZ = 0
#: Stick dead band hint for games (what xpad reports).
STICK_FLAT = 128
#: The same force-feedback line (e.g. "play effect 0") is passed to ``on_effect`` at most this often (s).
EFFECT_REPEAT_S = 1.0
#: Most events read from the pad in one :meth:`VirtualGamepad.feedback` call (the rest wait for
#: the next: the descriptor stays readable).
MAX_FF_EVENTS = 64
#: Force-feedback effects the pad keeps at once (xpad's memless force feedback: FF_MEMLESS_EFFECTS).
MAX_EFFECTS = 16
_STICKS = ("ABS_X", "ABS_Y", "ABS_RX", "ABS_RY")
log = logging.getLogger(__name__)
_NAME_MAX = 79  # UINPUT_MAX_NAME_SIZE (80) minus the terminating NUL


@dataclass(frozen=True)
class GamepadIdentity:
    """What the device tells the system it is (uinput_setup): name, USB ids, version, bus, phys.

    Defaults are the wired Xbox 360 pad's, which SDL's controller database knows as
    ``030000005e0400008e02000014010000``."""

    name: str = "Microsoft X-Box 360 pad"
    vendor: int = 0x045E
    product: int = 0x028E
    version: int = 0x0114
    bustype: int = 0x03  # BUS_USB
    #: the camera's (``targets.identity.Identity.phys``): SDL and Steam tell two pads apart by it
    phys: str = PHYS


def create_uinput(what: str, capabilities: dict, devnode: str = "/dev/uinput", **setup: object) -> UInput:
    """A python-evdev :class:`evdev.UInput` device (the virtual ``what``: gamepad, keyboard, mouse)
    with ``capabilities`` and ``setup`` (name, ids, bus, phys, ... of ``UInput``).

    Raises:
        DeviceError: ``devnode`` cannot be used (:func:`uinput_problem`) or the kernel refuses the
            device; the message's first line says why, the next ones the fix
            (:func:`neurotouch_hid.service.udev.uinput_help`).
    """
    problem = uinput_problem(devnode)
    if problem:
        raise DeviceError(f"{problem}\n{uinput_help()}")
    from evdev import UInput, UInputError

    try:
        return UInput(capabilities, devnode=devnode, **setup)
    except (OSError, UInputError) as exc:
        raise DeviceError(
            f"the kernel refused to create the virtual {what} on {devnode}: {exc}\n" + uinput_help()
        ) from None


def capabilities() -> dict[int, list]:
    """python-evdev capability dict of the gamepad: EV_KEY with the 11 buttons, EV_ABS with the 8
    axes and their AbsInfo (range, fuzz, flat), EV_FF with FF_RUMBLE (as xpad). No EV_REL, no
    BTN_TOUCH/BTN_LEFT, no properties."""
    from evdev import AbsInfo, ecodes

    absinfo = []
    for name, (lo, hi, _neutral) in AXES.items():
        fuzz, flat = (STICK_FUZZ, STICK_FLAT) if name in _STICKS else (0, 0)
        absinfo.append((ecodes.ecodes[name], AbsInfo(value=0, min=lo, max=hi, fuzz=fuzz, flat=flat, resolution=0)))
    return {
        ecodes.EV_KEY: [ecodes.ecodes[name] for name in BUTTONS],
        ecodes.EV_ABS: absinfo,
        ecodes.EV_FF: [ecodes.FF_RUMBLE],
    }


def describe_effect(effect) -> str:
    """One line for an uploaded force-feedback effect (python-evdev ``ff.Effect``): its id, type
    and, for a rumble, the strong and weak motors' magnitudes (0..65535) and length (ms)."""
    from evdev import ecodes

    names = ecodes.FF.get(effect.type, f"type {effect.type}")
    names = [names] if isinstance(names, str) else list(names)  # FF_RUMBLE is also FF_EFFECT_MIN
    line = f"effect {effect.id}: {next((n for n in names if not n.startswith('FF_EFFECT_')), names[0])}"
    if effect.type == ecodes.FF_RUMBLE:
        rumble = effect.u.ff_rumble_effect
        line += f" strong {rumble.strong_magnitude} weak {rumble.weak_magnitude}"
    return line + f" for {effect.ff_replay.length} ms"


def normalised(state: ControllerState) -> ControllerState:
    """A full copy of ``state``: every axis of AXES clamped to its range (missing = neutral), every
    button of BUTTONS as a bool (missing = released); names outside the layout are dropped."""
    axes = {name: min(max(int(state.axes.get(name, neutral)), lo), hi) for name, (lo, hi, neutral) in AXES.items()}
    buttons = {name: bool(state.buttons.get(name, False)) for name in BUTTONS}
    return ControllerState(t_us=state.t_us, axes=axes, buttons=buttons)


def changed_events(previous: ControllerState | None, state: ControllerState) -> list[tuple[str, int]]:
    """The (evdev name, value) pairs to write to go from ``previous`` to ``state``.

    Both are taken :func:`normalised`. With ``previous=None`` every axis and button is listed (the
    first write). Axes come first, in AXES order, then buttons in BUTTONS order, as 0/1."""
    new = normalised(state)
    old = normalised(previous) if previous is not None else None
    out = [(n, v) for n, v in new.axes.items() if old is None or old.axes[n] != v]
    out += [(n, int(v)) for n, v in new.buttons.items() if old is None or old.buttons[n] != v]
    return out


def _begin_ff_request(ui, kind: str, request_id: int):
    """UI_BEGIN_FF_UPLOAD / UI_BEGIN_FF_ERASE for the kernel's request ``request_id`` (the value of
    its EV_UINPUT event); returns python-evdev's ``ff.UInputUpload`` / ``ff.UInputErase``, to be
    answered with ``ui.end_upload`` / ``ui.end_erase``.

    python-evdev 2.0's ``begin_upload(id)`` / ``begin_erase(id)`` store the id in ``effect_id``,
    not ``request_id``, so they only work while the kernel's request is number 0; this fills
    ``request_id`` and calls the same C helpers (``_uinput_begin_upload/erase``).
    Raises UInputError when the kernel refuses."""
    import ctypes

    from evdev import UInputError, ff

    request = ff.UInputUpload() if kind == "upload" else ff.UInputErase()
    request.request_id = request_id
    begin = ui.dll._uinput_begin_upload if kind == "upload" else ui.dll._uinput_begin_erase
    ret = begin(ui.fd, ctypes.byref(request))
    if ret:
        raise UInputError(f"cannot begin the force-feedback {kind}: {os.strerror(ret)}")
    return request


class VirtualGamepad(NeutralOnClose):
    """A uinput gamepad (Xbox 360 layout) that mirrors :class:`ControllerState` values, as a
    :class:`~neurotouch_hid.core.stages.Target`.

    Use as a context manager, or call :meth:`close`. Thread-safe: :meth:`close` may be called
    from a signal handler or another thread while :meth:`write` runs. ``on_effect`` is told each
    upload, erase and play, one line each (the same line at most once per
    :data:`EFFECT_REPEAT_S`; default: the debug log).

    Raises:
        DeviceError: ``devnode`` (default /dev/uinput) is missing, not a character device or not
            writable, or the kernel refuses the device; the message names the udev rule and the
            commands that fix it.
    """

    def __init__(
        self,
        identity: GamepadIdentity | None = None,
        devnode: str = "/dev/uinput",
        *,
        on_effect: Callable[[str], None] | None = None,
    ) -> None:
        self.identity = identity or GamepadIdentity()
        self.what = "uinput pad"
        self.on_effect = on_effect or (lambda line: log.debug("rumble (the gel has no motor): %s", line))
        self._said, self._said_at = "", 0.0  # a game replaying one effect every frame is told once a second
        self._rumbles: dict[int, tuple[int, int, int]] = {}  # effect id -> (strong, weak 0..65535, length ms)
        if not 0 < len(self.identity.name.encode()) <= _NAME_MAX:
            raise DeviceError(f"gamepad name {self.identity.name!r} must be 1..{_NAME_MAX} bytes long")
        from evdev import ecodes

        self._ecodes = ecodes.ecodes
        self._ui = create_uinput(
            "gamepad",
            capabilities(),
            devnode,
            name=self.identity.name,
            vendor=self.identity.vendor,
            product=self.identity.product,
            version=self.identity.version,
            bustype=self.identity.bustype,
            phys=self.identity.phys,
            max_effects=MAX_EFFECTS,
        )
        self._lock = threading.RLock()
        self._last: ControllerState | None = None
        self._closed = False
        self.effects = 0  # force-feedback requests answered (uploads, erases, plays)
        self.write(ControllerState.neutral())

    def fileno(self) -> int | None:
        """The uinput descriptor: readable when a game uploads, erases or plays an effect (None
        once closed)."""
        return None if self._closed else self._ui.fd

    def feedback(self) -> list[Feedback]:
        """Read the force-feedback requests waiting (at most :data:`MAX_FF_EVENTS`, non-blocking),
        answer every upload and erase at once (success: the kernel blocks the game's EVIOCSFF until
        then, Documentation/input/uinput.rst), and return each rumble played or stopped as a
        ``"rumble"`` :class:`~neurotouch_hid.core.stages.Feedback` (magnitudes 0..1, the game's effect id;
        a stop, or an erase, has both 0). An ``on_effect`` that fails is logged: the next request
        is answered all the same."""
        from evdev import UInputError, ecodes

        received: list[Feedback] = []
        with self._lock:
            if self._closed:
                return received
            try:
                events = [ev for ev, _ in zip(self._ui.read(), range(MAX_FF_EVENTS))]
            except BlockingIOError:
                return received
            except OSError as exc:
                raise DeviceError(f"reading the virtual gamepad's force-feedback requests failed: {exc}") from None
            for ev in events:
                try:
                    if ev.type == ecodes.EV_UINPUT and ev.code == ecodes.UI_FF_UPLOAD:
                        upload = _begin_ff_request(self._ui, "upload", ev.value)
                        upload.retval = 0
                        line = "uploaded " + describe_effect(upload.effect)
                        self._remember_rumble(upload.effect)
                        self._ui.end_upload(upload)
                        request = None
                    elif ev.type == ecodes.EV_UINPUT and ev.code == ecodes.UI_FF_ERASE:
                        erase = _begin_ff_request(self._ui, "erase", ev.value)
                        erase.retval = 0
                        line = f"erased effect {erase.effect_id}"
                        self._ui.end_erase(erase)
                        request = self._rumble_of(erase.effect_id, 0)  # an erased effect plays no more
                        self._rumbles.pop(erase.effect_id, None)
                    elif ev.type == ecodes.EV_FF and ev.code < MAX_EFFECTS:
                        line = f"{'play' if ev.value else 'stop'} effect {ev.code}"
                        request = self._rumble_of(ev.code, ev.value)
                    else:
                        continue
                except (OSError, UInputError) as exc:
                    log.warning("could not answer a force-feedback request: %s", exc)
                    continue
                self.effects += 1
                if request is not None:
                    received.append(request)
                self._tell(line)
        return received

    def _tell(self, line: str) -> None:
        now = time.monotonic()
        if line == self._said and now - self._said_at < EFFECT_REPEAT_S:
            return
        self._said, self._said_at = line, now
        try:  # the game's next request must still be answered
            self.on_effect(line)
        except Exception as exc:
            log.warning("could not report a force-feedback request (%s): %s", line, exc)

    def _remember_rumble(self, effect) -> None:
        """An uploaded effect (python-evdev ``ff.Effect``): a rumble's magnitudes and length kept
        for its play; any other type forgotten (the gel's pad forwards rumble only)."""
        from evdev import ecodes

        if effect.type == ecodes.FF_RUMBLE and 0 <= effect.id < MAX_EFFECTS:
            rumble = effect.u.ff_rumble_effect
            self._rumbles[effect.id] = (rumble.strong_magnitude, rumble.weak_magnitude, effect.ff_replay.length)
        else:
            self._rumbles.pop(effect.id, None)

    def _rumble_of(self, effect_id: int, value: int) -> Feedback | None:
        """A play (``value`` > 0, the repeat count) or stop (0) of effect ``effect_id`` as a
        ``"rumble"`` :class:`~neurotouch_hid.core.stages.Feedback` (magnitudes 0..1; a stop has both 0);
        None for an effect that is no rumble."""
        rumble = self._rumbles.get(effect_id)
        if rumble is None:
            return None
        strong, weak, length = rumble if value > 0 else (0, 0, 0)
        return Feedback("rumble", strong / 0xFFFF, weak / 0xFFFF, length or None, source=self.what, effect=effect_id)

    @property
    def device_path(self) -> str | None:
        """The event node games read, e.g. ``/dev/input/event5`` (None if it could not be opened)."""
        device = self._ui.device
        return device.path if device is not None else None

    @property
    def closed(self) -> bool:
        return self._closed

    def prepare(self, profile: Profile) -> None:
        """Nothing to get ready: the pad's layout is the same for every profile, and its name and ids
        stay those it was created with (games keep their handle)."""

    def write(self, state: ControllerState) -> None:
        """Write the axes and buttons that changed since the last write, then one SYN_REPORT.

        Values are clamped to each axis' range. Nothing is written when nothing changed (the kernel
        would drop an empty report anyway). After :meth:`close` a write does nothing: during
        shutdown another thread may still deliver one last state, and the device must stay gone.
        Raises DeviceError when the kernel rejects the write."""
        with self._lock:
            if self._closed:
                return
            events = changed_events(self._last, state)
            if not events:
                return
            ev_abs, ev_key = self._ecodes["EV_ABS"], self._ecodes["EV_KEY"]
            try:
                for name, value in events:
                    self._ui.write(ev_abs if name.startswith("ABS_") else ev_key, self._ecodes[name], value)
                self._ui.syn()
            except OSError as exc:
                raise DeviceError(f"writing to the virtual gamepad failed: {exc}") from None
            self._last = normalised(state)

    def neutralise(self) -> None:
        """Centre every axis (triggers to 0) and release every button, then SYN_REPORT."""
        self.write(ControllerState.neutral())

    def _destroy(self) -> None:
        """Destroy the uinput device (a game's request still waiting is answered by the kernel:
        the device is gone)."""
        self._ui.close()

    def __enter__(self) -> "VirtualGamepad":
        return self

    def __exit__(self, *exc_info) -> None:
        self.close()
