"""A button-like output's hysteresis and activator on the camera clock (``hold``, ``tap``,
``toggle``, ``long_press``, ``double_press``, ``turbo``: the modes of
:class:`~neurotouch_hid.mapping.profile.ButtonMapping`, docs/profiles.md), its hold carried over or
suspended through a gesture's type change. Times are the estimates' ``t_us`` (int us), so every
mode is table-testable. :class:`~neurotouch_hid.mapping.mapper.Mapper` holds one per mapping.
"""

from __future__ import annotations

from neurotouch_hid.mapping.profile import ButtonMapping, LayerSwitch, TouchClick


class Activator:
    """A button-like output's hysteresis and activator, on the camera clock.

    The input is *held* from reaching ``press_mm`` (>=) until it falls below ``release_mm`` (<).
    ``update(value_mm, t_us) -> bool`` is the output's state at ``t_us`` (int us, camera clock,
    never decreasing) for the modes of :class:`~neurotouch_hid.mapping.profile.ButtonMapping`:
    ``hold``, ``tap`` (down from ``dwell_ms`` after the hold began for at most ``tap_ms``, once
    per hold), ``toggle``, ``long_press`` (down from ``dwell_ms`` after the hold began),
    ``double_press`` (a second hold that starts within ``double_press_ms`` of the first one's
    start is down while held), ``turbo`` (while held: down for the first half of each
    ``1 / turbo_hz`` period, up for the second).
    """

    def __init__(
        self,
        mode: str = "hold",
        press_mm: float = 2.0,
        release_mm: float = 1.0,
        *,
        dwell_ms: float = 500.0,
        double_press_ms: float = 400.0,
        turbo_hz: float = 10.0,
        tap_ms: float = 100.0,
    ) -> None:
        self.mode = mode
        self.press_mm, self.release_mm = press_mm, release_mm
        self.dwell_us = int(round(dwell_ms * 1000))
        self.double_us = int(round(double_press_ms * 1000))
        self.half_period_us = 1e6 / (2.0 * turbo_hz)
        self.tap_us = int(round(tap_ms * 1000))
        self._tap_from_us: int | None = None  # tap: when this hold's keystroke went down
        self.held = False
        self._since_us = 0  # start of the current hold
        self._first_us: int | None = None  # start of a press that may be the first of a double
        self._double = False  # the current hold is a double press's second
        self._toggled = False
        self._suspended = False  # released by a type change: the next press goes on with this hold

    def carry(self, source: "Activator") -> None:
        """Go on with the hold ``source`` (another mapping's activator of the same output) began,
        when a gesture's type changed under it: held with no press, so a toggle does not flip and
        the output shows no release-and-press. The hold keeps its timing: a long press's dwell
        and turbo's phase count from where ``source``'s hold began, a tap's keystroke goes on for
        what is left of it (or, given, is not given again), a double press's second press stays
        the second."""
        if self.held:
            return
        self.held, self._since_us = True, source._since_us
        self._first_us, self._double = source._first_us, source._double
        if source.mode == "tap":
            self._tap_from_us = source._tap_from_us
        else:  # the hold's output was down already: no new keystroke
            self._tap_from_us = source._since_us - self.tap_us

    def suspend(self) -> None:
        """The input is gone because the gesture's type changed: if the type comes back within
        the gesture, that is this hold going on, not a new press (:meth:`settle` ends it)."""
        self._suspended = self.held

    def settle(self) -> None:
        """The gesture is over: the next press is a new one."""
        self._suspended = False

    @classmethod
    def of(cls, mapping: ButtonMapping | LayerSwitch | TouchClick) -> "Activator":
        """The activator a mapping (or a layer switch, or the touchpad's click) describes."""
        if isinstance(mapping, LayerSwitch):
            return cls(mapping.mode, mapping.press_mm, mapping.release_mm)
        if isinstance(mapping, TouchClick):
            return cls(mapping.mode, mapping.press_mm, mapping.release_mm, dwell_ms=mapping.dwell)
        return cls(
            mapping.mode,
            mapping.press_mm,
            mapping.release_mm,
            dwell_ms=mapping.dwell,
            double_press_ms=mapping.double_press_ms,
            turbo_hz=mapping.turbo_hz,
            tap_ms=mapping.tap_ms,
        )

    def update(self, value_mm: float, t_us: int) -> bool:
        """The output's state for the input ``value_mm`` (mm) at ``t_us`` (us, camera clock)."""
        t_us = int(t_us)
        was, resumed = self.held, False
        if not self.held and (value_mm >= self.press_mm or (self._suspended and value_mm >= self.release_mm)):
            self.held, resumed = True, self._suspended
            self._since_us = self._since_us if resumed else t_us
            self._suspended = False
        elif self.held and value_mm < self.release_mm:
            self.held = False
        pressed, released = self.held and not was and not resumed, was and not self.held
        mode = self.mode
        if mode == "hold":
            return self.held
        if mode == "tap":
            if pressed:
                self._tap_from_us = None
            if self.held and self._tap_from_us is None and t_us - self._since_us >= self.dwell_us:
                self._tap_from_us = t_us
            return self.held and self._tap_from_us is not None and t_us - self._tap_from_us < self.tap_us
        if mode == "toggle":
            if pressed:
                self._toggled = not self._toggled
            return self._toggled
        if mode == "long_press":
            return self.held and t_us - self._since_us >= self.dwell_us
        if mode == "turbo":
            return self.held and int((t_us - self._since_us) // self.half_period_us) % 2 == 0
        # double_press
        if pressed:
            if self._first_us is not None and t_us - self._first_us <= self.double_us:
                self._double, self._first_us = True, None
            else:
                self._first_us = t_us
        if released:
            self._double = False
        return self.held and self._double
