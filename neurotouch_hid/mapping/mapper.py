"""GestureEstimate -> ControllerState through a profile (the mapping stage of docs/architecture.md).

:class:`Mapper` is a pure function of the estimate and its own state (the 1-euro filters, the
activators, the pointer's and wheels' sub-count remainders, the current layer): the same
estimates in give the same states out, whatever the wall clock. Every time it uses is the
estimates' camera clock (``t_us``, int64 us): a long press, a double press, turbo and the
pointer's motion are table-testable. The input quantities are those of
:mod:`neurotouch_hid.mapping.profile` (mm, user frame).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from neurotouch_hid.core.controller import AXES, BUTTONS, MOUSE_REL, TRIGGERS, ControllerState
from neurotouch_hid.core.estimate import GestureEstimate, GestureType
from neurotouch_hid.mapping.activator import Activator
from neurotouch_hid.mapping.filters import OneEuroFilter, response
from neurotouch_hid.mapping.inputs import TYPE_INPUTS, felt_level, gesture_inputs
from neurotouch_hid.mapping.profile import (
    ANALOG_AXES,
    BASE_LAYER,
    DPAD,
    STICKS,
    AxisMapping,
    ButtonMapping,
    OneEuroSmoothing,
    PointerMapping,
    Profile,
    RelMapping,
    StickMapping,
)
from neurotouch_hid.mapping.rel_motion import RelMotion, Wheel
from neurotouch_hid.mapping.touchpad import TouchTracker

#: The evdev axes whose up is negative (the kernel's gamepad.rst and REL_Y's convention): a
#: positive scalar mapped onto one of them (``push_y``, ``contact_y``, ``pinch_zoom``...) moves
#: it up, as a stick mapping's user +y does.
UP_IS_NEGATIVE = frozenset(("ABS_Y", "ABS_RY", "REL_Y"))


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


class Mapper:
    """Applies a profile to a stream of estimates.

    ``update(estimate)`` returns the :class:`ControllerState` at ``estimate.t_us``: each mapping
    of the current layer takes its input (see :func:`gesture_inputs`), smoothed (1-euro filter,
    if the mapping has one), then shaped (dead zone, saturation, curve, gain, anti-deadzone,
    invert; :func:`~neurotouch_hid.mapping.filters.response`) for sticks, axes, the pointer and
    the wheels, or passed through its :class:`Activator` for button-like outputs. Contributions
    to one axis add up and clamp (a trigger's each from its positive side only); buttons, keys and
    d-pad directions are OR-ed (opposite directions: the hat centred); a stick's user +y (up) becomes a
    negative evdev y, the pointer's a negative REL_Y, and so does a positive scalar on a y axis
    (:data:`UP_IS_NEGATIVE`). Pointer and wheel velocities become counts
    over the camera time since the last estimate (:class:`RelMotion`).

    Layers: the profile's layer switches are evaluated first; the current layer is the first
    (in file order) whose switch is on, else ``base``. When it changes, that update returns the
    neutral state (everything of the old layer released, no motion) and every mapping starts
    afresh; the new layer's mappings act from the next estimate on.

    A gesture whose type changes (the gel not resting in between, windows of ``none`` allowed):
    in the estimate of the new type, the mappings of :data:`TYPE_INPUTS` forget their smoothing,
    so the old type's outputs are released in the very state the new type's begin (never both
    held, as a decaying filter would leave them); a button the old type held that a mapping of
    the new type presses too stays held through the change (:meth:`Activator.carry`, while the
    new value is at or above its ``release_mm``), so neither a toggle nor a game sees a new press;
    and if the old type comes back within the gesture (the intensity, whatever the type, never
    below the mapping's ``release_mm`` in between), its holds go on without a new press
    (:meth:`Activator.suspend`): a toggle flips once per gesture, however the type flickers.
    Before all of this, within one press a new type is followed only from the second window in a
    row that reads it (:meth:`_confirmed`): one window of another type, at whatever intensity,
    presses none of its outputs.

    The touchpad (a profile's ``touchpad:``): the contact points become touch points
    (:class:`~neurotouch_hid.mapping.touchpad.TouchTracker`) and the click's input goes through
    its activator, in every layer; a layer change lifts every touch (its neutral state has none).
    """

    def __init__(self, profile: Profile) -> None:
        self.profile = profile
        self._switches = {name: Activator.of(s) for name, s in profile.layers.items()}
        self._switch_filters = {name: _filter_for(s.smoothing) for name, s in profile.layers.items()}
        self.layer = BASE_LAYER
        pad = profile.touchpad
        self._touch = TouchTracker(pad) if pad is not None else None
        click = pad.click if pad is not None else None
        self._click = Activator.of(click) if click is not None else None
        self._click_input = click.input if click is not None else ""
        self._click_filter = _filter_for(click.smoothing) if click is not None else None
        self._fresh_mappings()
        self._fresh_types()
        self._felt_mm = felt_level(profile)

    def _fresh_types(self) -> None:
        #: the type the outputs follow within the current press (None: none since the gel let go),
        #: the last estimate of that type, and another type read by the window before (unconfirmed)
        self._shown: GestureType | None = None
        self._shown_estimate: GestureEstimate | None = None
        self._unconfirmed: GestureType | None = None

    def _confirmed(self, estimate: GestureEstimate) -> GestureEstimate:
        """The estimate the outputs follow: within one press (the gel moving, its intensity above
        0, whatever ``none`` windows of an undecided type come between), a type other than the one
        the outputs follow reaches them only from the second window in a row that reads it; the
        first is mapped as the type before, with its push direction, at no more than its last
        intensity (so it moves no output further than the type before had; one window of another type
        is a misreading as often as a change, and 10 ms of another output is a tap a game takes
        for a press). This holds once the type followed has reached the profile's lowest level
        of a typed input (:func:`felt_level`): below it the type before moved nothing, and the
        new one is followed at once (an onset's provisional type, docs/method.md, "Episode
        vote"). A resting window or one without intensity ends the press: the next type is
        followed from its first window."""
        gesture = estimate.gesture
        if estimate.resting or not (estimate.intensity_mm > 0):  # NaN too: the gel let go
            self._fresh_types()
            return estimate
        if gesture is GestureType.NONE:
            return estimate
        before = self._shown_estimate
        felt = before is not None and before.intensity_mm >= self._felt_mm
        if not felt or gesture is self._shown or gesture is self._unconfirmed:
            self._shown, self._shown_estimate, self._unconfirmed = gesture, estimate, None
            return estimate
        self._unconfirmed = gesture
        return dataclasses.replace(
            estimate,
            gesture=self._shown,
            intensity_mm=min(float(estimate.intensity_mm), float(before.intensity_mm)),
            translation_mm=before.translation_mm,
            rotation_rad=before.rotation_rad,
            scale=before.scale,
        )

    def _fresh_mappings(self) -> None:
        mappings = self.profile.mappings
        #: the last state, while the mapper rests at its fixed point (:meth:`_quiet_after`): a
        #: resting estimate then gives that state again at its own time
        self._quiet: ControllerState | None = None
        self._quiet_us: int | None = None  # the last resting window's time at the fixed point
        self._filters = {name: _filter_for(m.smoothing) for name, m in mappings.items()}
        self._activators = {name: Activator.of(m) for name, m in mappings.items() if isinstance(m, ButtonMapping)}
        self._pointer = {"REL_X": RelMotion(), "REL_Y": RelMotion()}
        self._wheels = {"REL_WHEEL": Wheel(), "REL_HWHEEL": Wheel()}
        self._kind: GestureType | None = None  # the gesture's type (None at rest)

    def _hand_over(self, estimate: GestureEstimate, inputs: dict, layer: str) -> None:
        """A type change: the type's mappings restart their smoothing; a button held by a mapping
        whose input is gone now goes on under the new type's mapping of the same output; the old
        type's holds are suspended (its return within the gesture goes on with them)."""
        active = not estimate.resting and estimate.gesture is not GestureType.NONE
        kind = estimate.gesture if active else None
        changed = kind is not None and self._kind is not None and kind is not self._kind
        for name, activator in self._activators.items():
            if inputs["intensity"] < self.profile.mappings[name].release_mm:  # that gesture is over
                activator.settle()
        if estimate.resting:
            self._kind = None
        elif kind is not None:
            self._kind = kind
        if not changed:
            return
        mappings = self.profile.mappings
        typed = [n for n, m in mappings.items() if m.layer == layer and m.input in TYPE_INPUTS]
        gone = [n for n in typed if not np.any(inputs[mappings[n].input])]
        for name in typed:
            self._filters[name] = _filter_for(mappings[name].smoothing)
        for name in gone:
            if name in self._activators:
                self._activators[name].suspend()
        left: dict[str, Activator] = {}  # output -> the hold of a mapping whose input is gone
        for name in gone:
            if name in self._activators and self._activators[name].held:
                left.update(dict.fromkeys(mappings[name].presses, self._activators[name]))
        for name in typed:
            m = mappings[name]
            if name in gone or name not in self._activators or float(inputs[m.input]) < m.release_mm:
                continue
            source = next((left[out] for out in m.presses if out in left), None)
            if source is not None:
                self._activators[name].carry(source)

    def reset(self) -> None:
        """Forget filters, activators, motion remainders and layers (the next update starts from scratch)."""
        self._switches = {name: Activator.of(s) for name, s in self.profile.layers.items()}
        self._switch_filters = {name: _filter_for(s.smoothing) for name, s in self.profile.layers.items()}
        self.layer = BASE_LAYER
        if self._touch is not None:
            self._touch.lift()
        if self._click is not None:
            self._click = Activator.of(self.profile.touchpad.click)  # type: ignore[union-attr]
            self._click_filter = _filter_for(self.profile.touchpad.click.smoothing)  # type: ignore[union-attr]
        self._fresh_mappings()
        self._fresh_types()

    def _current_layer(self, inputs: dict, t_us: int) -> str:
        """The layer of this estimate. A switch held by a gesture of one type stays held while the
        gesture goes on under another (its input at 0, the gesture's intensity at or above the
        switch's ``release_mm``): a flicker of the type neither drops a held layer nor flips a
        toggled one twice (a layer change releases everything)."""
        layer = BASE_LAYER
        for name, switch in self._switches.items():
            spec = self.profile.layers[name]
            raw = value = inputs[spec.input]
            smoother = self._switch_filters[name]
            if smoother is not None:
                value = smoother(value, t_us)
            if switch.held and spec.input in TYPE_INPUTS and raw == 0 and inputs["intensity"] >= spec.release_mm:
                value = max(float(value), spec.release_mm)  # the gesture goes on under another type
            if switch.update(float(value), t_us) and layer == BASE_LAYER:
                layer = name
        return layer

    def update(self, estimate: GestureEstimate) -> ControllerState:
        """The controller state for one estimate (axes clamped to their ranges).

        A resting gel costs next to nothing: once a resting estimate left the mapper at its fixed
        point (nothing held, every filter at exactly zero, no motion), the next resting estimate
        gives the same state at its own time; the clocks (filters, pointer and wheels) move once,
        to the last resting window, when the rest ends. That is what the full computation would
        do (tests/test_mapper.py compares them).
        """
        t_us = int(estimate.t_us)
        if estimate.resting and self._quiet is not None:
            return self._rest_again(t_us)
        self._wake_clocks()
        self._quiet = None
        estimate = self._confirmed(estimate)
        inputs = gesture_inputs(estimate)
        layer = self._current_layer(inputs, t_us)
        if layer != self.layer:
            self.layer = layer
            self._fresh_mappings()
            if self._touch is not None:
                self._touch.lift()
            return ControllerState.neutral(t_us)
        self._hand_over(estimate, inputs, layer)
        analog = dict.fromkeys(ANALOG_AXES, 0.0)
        velocity = dict.fromkeys(("REL_X", "REL_Y", "REL_WHEEL", "REL_HWHEEL"), 0.0)
        directions: set[str] = set()  # the d-pad directions pressed (OR-ed, as buttons)
        buttons = dict.fromkeys(BUTTONS, False)
        keys: set[str] = set()
        for name, mapping in self.profile.mappings.items():
            if mapping.layer != layer:
                continue
            value = inputs[mapping.input]
            smoother = self._filters[name]
            if smoother is not None:
                value = smoother(value, t_us)
            if isinstance(mapping, (StickMapping, PointerMapping)):
                vx, vy = float(value[0]), float(value[1])
                magnitude = float(np.hypot(vx, vy))
                shaped = _shape(mapping, magnitude)
                x, y = (vx / magnitude * shaped, vy / magnitude * shaped) if shaped > 0 else (0.0, 0.0)
                x, y = (-x if mapping.invert_x else x), (-y if mapping.invert_y else y)
                if isinstance(mapping, StickMapping):
                    axis_x, axis_y = STICKS[mapping.output]
                    analog[axis_x] += x
                    analog[axis_y] += -y  # user +y (up) -> evdev -y
                else:
                    velocity["REL_X"] += x * mapping.speed
                    velocity["REL_Y"] += -y * mapping.speed  # user +y (up) -> pointer up
            elif isinstance(mapping, (AxisMapping, RelMapping)):
                scalar = float(value)
                shaped = math.copysign(_shape(mapping, abs(scalar)), scalar)
                shaped = -shaped if mapping.invert else shaped
                shaped = -shaped if mapping.output in UP_IS_NEGATIVE else shaped  # user +y (up) -> up
                if isinstance(mapping, AxisMapping):
                    if mapping.output in TRIGGERS:  # the positive side only
                        shaped = max(shaped, 0.0)
                    analog[mapping.output] += shaped
                else:
                    velocity[mapping.output] += shaped * mapping.velocity_scale
            else:
                if not self._activators[name].update(float(value), t_us):
                    continue
                for out in mapping.presses:
                    if out in DPAD:
                        directions.add(out)
                    elif out in buttons:
                        buttons[out] = True
                    else:
                        keys.add(out)
        axes = {name: _to_axis(name, v) for name, v in analog.items()}
        hats = {"ABS_HAT0X": 0, "ABS_HAT0Y": 0}
        for out in directions:  # opposite directions together: centred
            hat, direction = DPAD[out]
            hats[hat] += direction
        axes.update(hats)
        rel = {name: self._pointer[name].step(velocity[name], t_us) for name in ("REL_X", "REL_Y")}
        for name, wheel in self._wheels.items():
            rel[name + "_HI_RES"], rel[name] = wheel.step(velocity[name], t_us)
        rel = {name: rel[name] for name in MOUSE_REL if rel[name]}
        touches: tuple = ()
        if self._touch is not None:
            touches = self._touch.update(estimate.contacts_mm, estimate.intensity_mm, estimate.resting)
        click = False
        if self._click is not None:
            value = float(inputs[self._click_input])
            if self._click_filter is not None:
                value = self._click_filter(value, t_us)
            click = self._click.update(float(value), t_us)
        state = ControllerState(
            t_us=t_us, axes=axes, buttons=buttons, keys=frozenset(keys), rel=rel, touches=touches, touch_click=click
        )
        if estimate.resting and self._quiet_after(state):
            self._quiet = state
        return state

    def _quiet_after(self, state: ControllerState) -> bool:
        """Whether this resting estimate's update left the mapper at its fixed point: another
        resting estimate (every input 0) would change nothing but the clocks. So: no motion, no
        activator held or suspended (a held one may be released, a long press or turbo moves
        with time), every filter called at exactly zero, the type forgotten (a wheel's
        remainder short of a detent waits as it is)."""
        if state.rel or self._kind is not None:
            return False
        activators = [*self._activators.values(), *self._switches.values()]
        if any(a.held or a._suspended for a in activators):
            return False
        if (self._touch is not None and self._touch.active) or (self._click is not None and self._click.held):
            return False
        if any(w.motion._rest for w in self._wheels.values()):  # the detents' remainder waits: no clock
            return False
        return all(f is None or f.at_zero() for f in self._called_filters())

    def _called_filters(self) -> list[OneEuroFilter | None]:
        """The filters an update calls: every layer switch's, and the current layer's mappings'."""
        mappings = self.profile.mappings
        layer = [self._filters[name] for name, m in mappings.items() if m.layer == self.layer]
        return [*self._switch_filters.values(), *layer, self._click_filter]

    @property
    def resting_state(self) -> ControllerState | None:
        """The state a resting estimate gives while the mapper rests at its fixed point (at that
        estimate's time), else None: a caller may then skip resting estimates and hand it only
        the last one before the rest ends (:meth:`update`), with the same states after."""
        return self._quiet

    def _rest_again(self, t_us: int) -> ControllerState:
        """:meth:`update` of a resting estimate at the fixed point: the kept state at ``t_us``.
        The clocks (filters, pointer, wheels) are not moved here, only noted: a zero sample moves
        nothing else, so moving them once to the last resting time when the rest ends
        (:meth:`_wake_clocks`) gives what moving them every window gives."""
        self._quiet_us = t_us
        last = self._quiet
        return ControllerState(
            t_us=t_us,
            axes=dict(last.axes),
            buttons=dict(last.buttons),
            keys=last.keys,
            rel={},
            touches=last.touches,
            touch_click=last.touch_click,
        )

    def _wake_clocks(self) -> None:
        """The rest at the fixed point ends: its clocks moved on to the last resting window."""
        t_us, self._quiet_us = self._quiet_us, None
        if t_us is None:
            return
        for f in self._called_filters():
            if f is not None:
                f.tick(t_us)
        for motion in (*self._pointer.values(), *(w.motion for w in self._wheels.values())):
            motion.step(0.0, t_us)


def _shape(mapping: StickMapping | AxisMapping | PointerMapping | RelMapping, magnitude_mm: float) -> float:
    return response(
        magnitude_mm,
        mapping.deadzone_mm,
        mapping.saturation,
        mapping.exponent,
        mapping.expo,
        mapping.gain,
        mapping.anti_deadzone,
    )
