"""GestureEstimate -> ControllerState through a profile (the mapping stage of docs/architecture.md).

:class:`Mapper` is a pure function of the estimate and its own state (the 1-euro filters, the
buttons' hysteresis and toggle states, the last time): the same estimates in give the same
states out, whatever the clock. The input quantities are those of
:mod:`neurotouch_hid.mapping.profile` (mm, user frame).
"""

from __future__ import annotations

import math

import numpy as np

from neurotouch_hid.controller import AXES, BUTTONS, ControllerState
from neurotouch_hid.estimate import GestureEstimate, GestureType
from neurotouch_hid.mapping.filters import OneEuroFilter, response
from neurotouch_hid.mapping.profile import (
    ANALOG_AXES, DPAD, STICKS, AxisMapping, ButtonMapping, OneEuroSmoothing, Profile, StickMapping,
)

_ZERO2 = np.zeros(2)


def gesture_inputs(estimate: GestureEstimate) -> dict[str, np.ndarray | float]:
    """Every input quantity of the profile schema for one estimate (mm, user frame).

    Returns:
        name -> float, or (2,) float64 for ``push`` and ``contact``. All zero when the gel rests
        or the gesture is ``none``; non-finite estimate values count as 0.
    """
    gesture = estimate.gesture
    active = not estimate.resting and gesture != GestureType.NONE
    intensity = float(estimate.intensity_mm) if active and math.isfinite(estimate.intensity_mm) else 0.0
    push = _ZERO2
    if gesture == GestureType.PUSH and intensity > 0:
        direction = np.asarray(estimate.translation_mm, dtype=np.float64)
        norm = float(np.hypot(*direction)) if np.all(np.isfinite(direction)) else 0.0
        if norm > 0:
            push = direction / norm * intensity
    contact = _ZERO2
    if active and estimate.n_contacts > 0 and len(estimate.contacts_mm) > 0:
        first = np.asarray(estimate.contacts_mm[0], dtype=np.float64)
        contact = first if np.all(np.isfinite(first)) else _ZERO2
    twist = {GestureType.TWIST_CCW: intensity, GestureType.TWIST_CW: -intensity}.get(gesture, 0.0)
    pinch = intensity if gesture == GestureType.PINCH else 0.0
    zoom = intensity if gesture == GestureType.ZOOM else 0.0
    return {
        "push": push, "contact": contact,
        "intensity": intensity,
        "push_intensity": intensity if gesture == GestureType.PUSH else 0.0,
        "push_x": float(push[0]), "push_y": float(push[1]),
        "push_up": max(float(push[1]), 0.0), "push_down": max(-float(push[1]), 0.0),
        "push_left": max(-float(push[0]), 0.0), "push_right": max(float(push[0]), 0.0),
        "twist": twist, "twist_ccw": max(twist, 0.0), "twist_cw": max(-twist, 0.0),
        "pinch": pinch, "zoom": zoom, "pinch_zoom": zoom - pinch,
        "contact_x": float(contact[0]), "contact_y": float(contact[1]),
    }


def _filter_for(smoothing: OneEuroSmoothing | None) -> OneEuroFilter | None:
    if smoothing is None:
        return None
    return OneEuroFilter(smoothing.min_cutoff_hz, smoothing.beta, smoothing.d_cutoff_hz)


def _to_axis(name: str, value: float) -> int:
    """A normalised value (-1..1 for sticks, 0..1 for triggers) -> the axis' integer range."""
    low, high, neutral = AXES[name]
    value = min(max(value, -1.0), 1.0)
    if low == neutral:  # a trigger: only the positive side
        return int(round(max(value, 0.0) * high))
    return int(round(value * (high if value >= 0 else -low)))


class _Digital:
    """A button's hysteresis (press at >= press_mm, release at < release_mm) and toggle state."""

    def __init__(self, mapping: ButtonMapping) -> None:
        self.mapping = mapping
        self.pressed = False
        self.toggled = False

    def update(self, value: float) -> bool:
        was = self.pressed
        if not self.pressed and value >= self.mapping.press_mm:
            self.pressed = True
        elif self.pressed and value < self.mapping.release_mm:
            self.pressed = False
        if self.mapping.mode == "toggle":
            if self.pressed and not was:
                self.toggled = not self.toggled
            return self.toggled
        return self.pressed


class Mapper:
    """Applies a profile to a stream of estimates.

    ``update(estimate)`` returns the :class:`ControllerState` at ``estimate.t_us``: each mapping's
    input (see :func:`gesture_inputs`) is smoothed (1-euro filter, if the mapping has one), then
    shaped (dead zone, saturation, curve, gain, invert; :func:`~neurotouch_hid.mapping.filters.response`)
    for sticks and axes, or passed through hysteresis and hold/toggle for buttons and d-pad
    directions. Contributions to one axis add up and clamp; buttons are OR-ed; a stick's user
    +y (up) becomes a negative evdev y.
    """

    def __init__(self, profile: Profile) -> None:
        self.profile = profile
        self._filters = {name: _filter_for(m.smoothing) for name, m in profile.mappings.items()}
        self._digital = {name: _Digital(m) for name, m in profile.mappings.items() if isinstance(m, ButtonMapping)}

    def reset(self) -> None:
        """Forget filters, hysteresis and toggles (the next update starts from scratch)."""
        for f in self._filters.values():
            if f is not None:
                f.reset()
        for name, d in self._digital.items():
            self._digital[name] = _Digital(d.mapping)

    def update(self, estimate: GestureEstimate) -> ControllerState:
        """The controller state for one estimate (axes clamped to their ranges)."""
        inputs = gesture_inputs(estimate)
        analog = {name: 0.0 for name in ANALOG_AXES}
        hats = {"ABS_HAT0X": 0, "ABS_HAT0Y": 0}
        buttons = {name: False for name in BUTTONS}
        for name, mapping in self.profile.mappings.items():
            value = inputs[mapping.input]
            smoother = self._filters[name]
            if smoother is not None:
                value = smoother(value, estimate.t_us)
            if isinstance(mapping, StickMapping):
                vector = np.asarray(value, dtype=np.float64)
                magnitude = float(np.hypot(*vector))
                shaped = _shape(mapping, magnitude)
                x, y = (vector / magnitude * shaped) if shaped > 0 else (0.0, 0.0)
                axis_x, axis_y = STICKS[mapping.output]
                analog[axis_x] += -x if mapping.invert_x else x
                analog[axis_y] += y if mapping.invert_y else -y  # user +y (up) -> evdev -y
            elif isinstance(mapping, AxisMapping):
                scalar = float(value)
                shaped = math.copysign(_shape(mapping, abs(scalar)), scalar)
                analog[mapping.output] += -shaped if mapping.invert else shaped
            else:
                if self._digital[name].update(float(value)):
                    if mapping.output in DPAD:
                        hat, direction = DPAD[mapping.output]
                        hats[hat] += direction
                    else:
                        buttons[mapping.output] = True
        axes = {name: _to_axis(name, v) for name, v in analog.items()}
        axes.update({name: max(-1, min(1, v)) for name, v in hats.items()})
        return ControllerState(t_us=int(estimate.t_us), axes=axes, buttons=buttons)


def _shape(mapping: StickMapping | AxisMapping, magnitude_mm: float) -> float:
    return response(magnitude_mm, mapping.deadzone_mm, mapping.saturation, mapping.exponent, mapping.expo, mapping.gain)
