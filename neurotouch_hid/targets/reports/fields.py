"""Values of a :class:`~neurotouch_hid.controller.ControllerState` as report fields: clamped to
a field's logical range (HID 1.11, 5.8: a value outside Logical Minimum..Maximum is a null or an
error, so it never goes on the wire)."""

from __future__ import annotations

from neurotouch_hid.controller import AXES, ControllerState


def clamp(value: int, lo: int, hi: int) -> int:
    """``value`` as an int within ``lo..hi``."""
    return min(max(int(value), lo), hi)


def axis(state: ControllerState, name: str) -> int:
    """``state``'s axis ``name`` (an evdev name of :data:`~neurotouch_hid.controller.AXES`) clamped
    to its range; a missing axis is neutral."""
    lo, hi, neutral = AXES[name]
    return clamp(state.axes.get(name, neutral), lo, hi)
