"""The copilot's arithmetic: the gel's controller state and the merged devices' controls -> one state.

A profile's ``copilot:`` (:class:`~neurotouch_hid.mapping.profile.CopilotDevice`) names devices
merged into the gel's pad: a helper's gamepad, a switch box, a foot pedal. Each device's evdev
controls become pad controls through a :class:`DeviceMap` (its ``map:``, and for a pad its own
buttons, sticks, triggers and d-pad passed through to the same controls of the Xbox 360 layout of
:mod:`neurotouch_hid.core.controller`); its :class:`Levels` are then combined with the gel's state by
:func:`merge_state`, per control, by the entry's policy:

- a button is pressed while either presses (``either``);
- an axis takes the value further from centre (``further``, the default), the gel's while it is
  off centre, else the device's (``gel``), the device's while it is off centre, else the gel's
  (``helper``), or the sum of both deflections, clipped to the axis' range (``sum``);
- keyboard keys a ``map:`` presses are down while the device holds them (beside the gel's keys).

Devices are combined in the order listed: each with what the gel and the devices above it give.
Everything here is pure (no device, no thread): ``inputs/`` reads the devices and calls it.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Iterable, Mapping

from neurotouch_hid.core.controller import AXES, BUTTONS, TRIGGERS, ControllerState

if TYPE_CHECKING:
    from neurotouch_hid.mapping.profile import CopilotDevice

#: A pad's d-pad reported as buttons (xpad's ``dpad_to_buttons``: BTN_TRIGGER_HAPPY1..4) -> the
#: d-pad direction of the Xbox 360 layout.
DPAD_BUTTONS: dict[str, str] = {
    "BTN_TRIGGER_HAPPY1": "dpad_left",
    "BTN_TRIGGER_HAPPY2": "dpad_right",
    "BTN_TRIGGER_HAPPY3": "dpad_up",
    "BTN_TRIGGER_HAPPY4": "dpad_down",
}
#: Source axes that rest at their minimum (triggers, pedals): read as 0..1 of their range; every
#: other axis rests at its centre and is read as -1..1.
ONE_SIDED_AXES = frozenset({"ABS_Z", "ABS_RZ", "ABS_GAS", "ABS_BRAKE", "ABS_THROTTLE", "ABS_RUDDER"})
#: Of those, the two that are a trigger on one pad (xpad) and the right stick on another (a
#: DirectInput pad through hid-generic, resting at its middle): one-sided only when they drive a
#: trigger; mapped to a stick axis (``map: {ABS_Z: ABS_RX, ABS_RZ: ABS_RY}``) they are a stick.
TRIGGER_OR_STICK_AXES = frozenset({"ABS_Z", "ABS_RZ"})
_DPAD_HAT = {
    "dpad_left": ("ABS_HAT0X", -1),
    "dpad_right": ("ABS_HAT0X", 1),
    "dpad_up": ("ABS_HAT0Y", -1),
    "dpad_down": ("ABS_HAT0Y", 1),
}


@dataclass(frozen=True)
class Levels:
    """A merged device's controls now, in the pad's terms.

    Attributes:
        axes: pad axis (``AXES`` name) -> value in that axis' range, for every axis the device
            drives (its neutral value when it rests).
        buttons: the pad buttons (``BUTTONS`` names) it holds.
        keys: the keyboard keys (``KEY_*``) its ``map:`` presses.
    """

    axes: Mapping[str, int] = field(default_factory=dict)
    buttons: frozenset[str] = frozenset()
    keys: frozenset[str] = frozenset()


#: A device that is missing, unplugged or released: it drives nothing.
NEUTRAL = Levels()


@dataclass(frozen=True)
class AxisRange:
    """An input device's absolute axis as the kernel describes it (``struct input_absinfo``):
    minimum, maximum and flat (the dead band around the centre, in the axis' units)."""

    minimum: int
    maximum: int
    flat: int = 0


def one_sided(source: str, target: str) -> bool:
    """Whether source axis ``source`` driving pad axis ``target`` rests at its minimum (a pedal,
    or a trigger driving a trigger: :data:`ONE_SIDED_AXES`, :data:`TRIGGER_OR_STICK_AXES`)."""
    if source in TRIGGER_OR_STICK_AXES:
        return target in TRIGGERS
    return source in ONE_SIDED_AXES


def _fraction(one_side: bool, value: int, info: AxisRange) -> float:
    """``value`` of a source axis as a fraction of its travel: 0..1 for a one-sided axis
    (:func:`one_sided`), -1..1 around the centre otherwise (0 within ``flat``, and at both
    middle values of a range with an even count of them: 0..255 rests at 127 or 128)."""
    lo, hi = info.minimum, info.maximum
    if hi <= lo:
        return 0.0
    value = min(max(value, lo), hi)
    if one_side:
        return (value - lo) / (hi - lo)
    centre = (lo + hi) / 2
    offset = value - centre
    if abs(offset) <= max(info.flat, 0.5):
        return 0.0
    return offset / (hi - centre) if offset > 0 else offset / (centre - lo)


def _pad_value(axis: str, fraction: float) -> int:
    """A fraction of travel (-1..1, or 0..1) as a value of pad axis ``axis``: a stick -32768..32767,
    a trigger 0..255 (negative fractions count as 0), a hat -1, 0 or 1 (from half travel on)."""
    lo, hi, neutral = AXES[axis]
    if neutral == lo:  # a trigger
        return round(max(fraction, 0.0) * hi)
    if hi == 1:  # a hat
        return 0 if abs(fraction) < 0.5 else (1 if fraction > 0 else -1)
    return round(fraction * hi) if fraction >= 0 else round(fraction * -lo)


class DeviceMap:
    """How one merged device's evdev controls drive the pad.

    Args:
        spec: the profile's entry (its ``map:`` and ``passthrough``).
        key_names: the device's EV_KEY codes -> every evdev name of each (python-evdev's
            ``ecodes.KEY``/``BTN`` values: one code often has several names, BTN_A = BTN_SOUTH).
        axes: the device's EV_ABS codes -> (their names, :class:`AxisRange`).

    A control named in ``map:`` drives its target; else, with ``passthrough``, a pad control
    (a button of :data:`~neurotouch_hid.core.controller.BUTTONS`, an axis of
    :data:`~neurotouch_hid.core.controller.AXES`, a d-pad button of :data:`DPAD_BUTTONS`) drives the
    same control of the pad; anything else is ignored.
    """

    def __init__(
        self,
        spec: CopilotDevice,
        key_names: Mapping[int, Iterable[str]],
        axes: Mapping[int, tuple[Iterable[str], AxisRange]],
    ) -> None:
        self.keys: dict[int, str] = {}  # code -> target (a pad button, dpad_*, KEY_*)
        self.axes: dict[int, tuple[str, str, AxisRange]] = {}  # code -> (source name, pad axis, range)
        for code, names in key_names.items():
            target = self._target(spec, list(names), BUTTONS + tuple(DPAD_BUTTONS))
            if target is not None:
                self.keys[code] = DPAD_BUTTONS.get(target, target)
        for code, (names, info) in axes.items():
            names = list(names)
            target = self._target(spec, names, tuple(AXES))
            if target is not None:
                source = next((n for n in names if n in spec.map), names[0] if names else "")
                self.axes[code] = (source, target, info)

    @staticmethod
    def _target(spec: CopilotDevice, names: list[str], passed: tuple[str, ...]) -> str | None:
        for name in names:
            if name in spec.map:
                return spec.map[name]
        if spec.passthrough:
            return next((n for n in names if n in passed), None)
        return None

    @property
    def drives(self) -> frozenset[str]:
        """The pad controls and keys this device can drive (its targets)."""
        return frozenset(self.keys.values()) | {axis for _, axis, _ in self.axes.values()}

    def levels(self, keys_down: Iterable[int], abs_values: Mapping[int, int]) -> Levels:
        """The device's :class:`Levels` from the key codes it holds and its axes' values (codes ->
        raw values, clamped to each axis' range here); codes it does not map are ignored. A pad
        axis driven by several of its controls takes the one further from centre; a d-pad
        direction sets its hat axis (opposite directions together: centred)."""
        buttons: set[str] = set()
        keys: set[str] = set()
        hats: dict[str, int] = {}
        for code in keys_down:
            target = self.keys.get(code)
            if target is None:
                continue
            if target in _DPAD_HAT:
                hat, sign = _DPAD_HAT[target]
                hats[hat] = hats.get(hat, 0) + sign
            elif target.startswith("KEY_"):
                keys.add(target)
            else:
                buttons.add(target)
        axes: dict[str, int] = {axis: AXES[axis][2] for _, axis, _ in self.axes.values()}
        for code, (source, axis, info) in self.axes.items():
            value = _pad_value(axis, _fraction(one_sided(source, axis), int(abs_values.get(code, info.minimum)), info))
            neutral = AXES[axis][2]
            if abs(value - neutral) > abs(axes[axis] - neutral):
                axes[axis] = value
        for hat, total in hats.items():
            if total and axes.get(hat, 0) == 0:
                axes[hat] = max(-1, min(1, total))
            else:
                axes.setdefault(hat, 0)
        return Levels(axes=axes, buttons=frozenset(buttons), keys=frozenset(keys))


def combine_axis(policy: str, gel: int, device: int, axis: str) -> int:
    """One axis' value when the gel (and the devices before) give ``gel`` and a device ``device``,
    by ``policy`` (``further``, ``gel``, ``helper``, ``sum``; see the module doc); clipped to the
    axis' range."""
    lo, hi, neutral = AXES[axis]
    if policy == "sum":
        value = gel + device - neutral
    elif policy == "gel":
        value = gel if gel != neutral else device
    elif policy == "helper":
        value = device if device != neutral else gel
    else:
        value = device if abs(device - neutral) > abs(gel - neutral) else gel
    return min(max(value, lo), hi)


def merge_state(gel: ControllerState, devices: Iterable[tuple[Levels, Mapping[str, str]]]) -> ControllerState:
    """The pad's state: ``gel`` combined with each device's (:class:`Levels`, policies) in order
    (policies: pad control -> ``either``/``further``/``gel``/``helper``/``sum``, ``further`` for an
    axis not named). Buttons and keys: pressed while either presses. The gel's relative motion,
    touch points, touchpad click and time are kept; ``gel`` itself is not changed."""
    axes = dict(gel.axes)
    buttons = dict(gel.buttons)
    keys = gel.keys
    for levels, policies in devices:
        for axis, value in levels.axes.items():
            axes[axis] = combine_axis(policies.get(axis, "further"), axes.get(axis, AXES[axis][2]), value, axis)
        for button in levels.buttons:
            buttons[button] = True
        keys = keys | levels.keys
    return ControllerState(
        t_us=gel.t_us,
        axes=axes,
        buttons=buttons,
        keys=keys,
        rel=dict(gel.rel),
        touches=gel.touches,
        touch_click=gel.touch_click,
    )
