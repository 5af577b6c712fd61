"""The gel's contact points as a touchpad's touch points (a profile's ``touchpad:`` section).

:class:`TouchTracker` keeps up to two touch points, one per slot, across windows: a contact
that moves less than ``match_mm`` between two windows is the same touch (same slot, same
tracking id), a new contact takes a free slot and the next tracking id (0..127, then 0 again),
and a touch whose contact is gone lifts (its point stays in its slot, not touching, with its
last id and position, as a DualSense reports a lifted finger). The contacts touch while the
gesture's intensity is held (pressed at ``press_mm``, released below ``release_mm``); whatever
the pipeline's gesture type, a contact point is where a finger presses the gel (paper, "Contact
Point Detection"). Positions go from the user frame (mm, x right, y up, origin at the gel's
centre; docs/architecture.md) to the pad's (x 0..1919 right, y 0..1079 down).

Pairing is greedy by distance: the closest (touch, contact) pair first, then the next closest
of those left, each within ``match_mm``; the contacts come strongest first and only the
strongest ``max_points`` may make a new touch.
"""

from __future__ import annotations

import math

import numpy as np

from neurotouch_hid.core.controller import TOUCH_SLOTS, TOUCHPAD_HEIGHT, TOUCHPAD_WIDTH, TRACKING_IDS, TouchPoint
from neurotouch_hid.mapping.profile import TouchpadMapping


def pad_position(spec: TouchpadMapping, x_mm: float, y_mm: float) -> tuple[int, int]:
    """The pad's (x, y) for a point of the gel (user frame, mm): the ``spec``'s rectangle
    stretched over 0..1919 x 0..1079, user +y up to the pad's top (y 0), clamped to the edges."""
    u = (x_mm - spec.centre_x_mm) / spec.width_mm + 0.5
    v = 0.5 - (y_mm - spec.centre_y_mm) / spec.height_mm
    x = int(round(min(max(u, 0.0), 1.0) * (TOUCHPAD_WIDTH - 1)))
    y = int(round(min(max(v, 0.0), 1.0) * (TOUCHPAD_HEIGHT - 1)))
    return x, y


class TouchTracker:
    """Touch points from the contact points, window after window (see the module doc).

    Args:
        spec: the profile's ``touchpad:`` section.
    """

    def __init__(self, spec: TouchpadMapping) -> None:
        self.spec = spec
        self.slots = min(spec.max_points, TOUCH_SLOTS)
        self.touching = False  # the intensity's hysteresis
        self._next_id = 0
        # per slot: (tracking id, x mm, y mm, touching) of its last point, None before any
        self._points: list[tuple[int, float, float, bool] | None] = [None] * self.slots

    def lift(self) -> None:
        """Every touch lifts (a layer change, a reset); the next contact is a new touch with
        the next tracking id."""
        self.touching = False
        self._points = [None if p is None else (p[0], p[1], p[2], False) for p in self._points]

    @property
    def active(self) -> bool:
        """A touch point is down."""
        return any(p is not None and p[3] for p in self._points)

    def update(self, contacts_mm: np.ndarray, intensity_mm: float, resting: bool) -> tuple[TouchPoint | None, ...]:
        """The touch points (one per slot; None for a slot never touched) for one window.

        Args:
            contacts_mm: (K, 2) float64, the window's contact points (user frame, mm),
                strongest first; rows that are not finite are skipped.
            intensity_mm: the window's gesture intensity (mm), any type; not finite counts as 0.
            resting: the gel rests (no touch).
        """
        spec = self.spec
        intensity = float(intensity_mm) if math.isfinite(intensity_mm) else 0.0
        if resting or intensity < spec.release_mm:
            self.touching = False
        elif intensity >= spec.press_mm:
            self.touching = True
        contacts: list[tuple[float, float]] = []
        if self.touching:
            for row in np.asarray(contacts_mm, dtype=np.float64).reshape(-1, 2):
                x, y = float(row[0]), float(row[1])
                if math.isfinite(x) and math.isfinite(y):
                    contacts.append((x, y))
        self._follow(contacts)
        return tuple(self._point(slot) for slot in range(self.slots))

    def _follow(self, contacts: list[tuple[float, float]]) -> None:
        """Pair the touches that are down with ``contacts`` (greedy, closest first, within
        ``match_mm``); lift the touches left over; give free slots to the strongest new contacts."""
        down = [slot for slot, p in enumerate(self._points) if p is not None and p[3]]
        pairs = sorted(
            (math.hypot(cx - self._points[slot][1], cy - self._points[slot][2]), slot, k)  # type: ignore[index]
            for slot in down
            for k, (cx, cy) in enumerate(contacts)
        )
        taken_slots: set[int] = set()
        taken_contacts: set[int] = set()
        for distance, slot, k in pairs:
            if distance > self.spec.match_mm or slot in taken_slots or k in taken_contacts:
                continue
            taken_slots.add(slot)
            taken_contacts.add(k)
            ident = self._points[slot][0]  # type: ignore[index]
            self._points[slot] = (ident, contacts[k][0], contacts[k][1], True)
        for slot in down:
            if slot not in taken_slots:
                ident, x, y, _ = self._points[slot]  # type: ignore[misc]
                self._points[slot] = (ident, x, y, False)
        new = [k for k in range(min(len(contacts), self.slots)) if k not in taken_contacts]
        for slot in range(self.slots):
            if not new:
                break
            point = self._points[slot]
            if point is None or not point[3]:
                k = new.pop(0)
                self._points[slot] = (self._next_id, contacts[k][0], contacts[k][1], True)
                self._next_id = (self._next_id + 1) % TRACKING_IDS

    def _point(self, slot: int) -> TouchPoint | None:
        point = self._points[slot]
        if point is None:
            return None
        ident, x_mm, y_mm, down = point
        x, y = pad_position(self.spec, x_mm, y_mm)
        return TouchPoint(ident, x, y, down)
