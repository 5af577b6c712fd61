"""The profile's input quantities for one estimate (mm, user frame; the inputs of
:mod:`neurotouch_hid.mapping.profile`, docs/profiles.md): :func:`gesture_inputs` reads them off a
:class:`~neurotouch_hid.core.estimate.GestureEstimate`, :data:`TYPE_INPUTS` are those that belong
to one gesture type, and :func:`felt_level` is the lowest of them at which a profile's output can be
on. :class:`~neurotouch_hid.mapping.mapper.Mapper` maps them.
"""

from __future__ import annotations

import math

import numpy as np

from neurotouch_hid.core.estimate import GestureEstimate, GestureType
from neurotouch_hid.mapping.profile import ButtonMapping, Profile

_ZERO2 = np.zeros(2)


def gesture_inputs(estimate: GestureEstimate) -> dict[str, np.ndarray | float]:
    """Every input quantity of the profile schema for one estimate (mm, user frame).

    The inputs of no one type (``intensity``, ``contact``, ``contact_x``, ``contact_y``) also
    follow a window whose type is not decided yet (``none`` with an intensity above 0 and not
    resting: the pipeline waits for a second finger; docs/method.md, "Episode vote"), so an output
    mapped from them neither waits for the type nor drops back while it is decided.

    Returns:
        name -> float, or (2,) float64 for ``push`` and ``contact``. All zero when the gel rests
        or the window is ``none`` without intensity; the typed inputs are zero while ``none``;
        non-finite estimate values count as 0.
    """
    gesture = estimate.gesture
    moving = not estimate.resting and math.isfinite(estimate.intensity_mm) and estimate.intensity_mm > 0
    active = moving and gesture != GestureType.NONE
    any_intensity = float(estimate.intensity_mm) if moving else 0.0
    intensity = any_intensity if active else 0.0
    push = _ZERO2
    if gesture == GestureType.PUSH and intensity > 0:
        dx, dy = float(estimate.translation_mm[0]), float(estimate.translation_mm[1])
        norm = float(np.hypot(dx, dy)) if math.isfinite(dx) and math.isfinite(dy) else 0.0
        if norm > 0:
            push = np.array((dx / norm * intensity, dy / norm * intensity))
    contact = _ZERO2
    if moving and estimate.n_contacts > 0 and len(estimate.contacts_mm) > 0:
        cx, cy = float(estimate.contacts_mm[0][0]), float(estimate.contacts_mm[0][1])
        contact = np.array((cx, cy)) if math.isfinite(cx) and math.isfinite(cy) else _ZERO2
    twist = {GestureType.TWIST_CCW: intensity, GestureType.TWIST_CW: -intensity}.get(gesture, 0.0)
    pinch = intensity if gesture == GestureType.PINCH else 0.0
    zoom = intensity if gesture == GestureType.ZOOM else 0.0
    return {
        "push": push,
        "contact": contact,
        "intensity": any_intensity,
        "push_intensity": intensity if gesture == GestureType.PUSH else 0.0,
        "push_x": float(push[0]),
        "push_y": float(push[1]),
        "push_up": max(float(push[1]), 0.0),
        "push_down": max(-float(push[1]), 0.0),
        "push_left": max(-float(push[0]), 0.0),
        "push_right": max(float(push[0]), 0.0),
        "twist": twist,
        "twist_ccw": max(twist, 0.0),
        "twist_cw": max(-twist, 0.0),
        "pinch": pinch,
        "zoom": zoom,
        "pinch_zoom": zoom - pinch,
        "contact_x": float(contact[0]),
        "contact_y": float(contact[1]),
    }


#: Inputs that belong to one gesture type (zero under any other): a type change hands them over.
#: ``intensity`` and ``contact*`` go on through a change.
TYPE_INPUTS = frozenset(
    ("push", "push_intensity", "push_x", "push_y", "push_up", "push_down", "push_left", "push_right")
    + ("twist", "twist_ccw", "twist_cw", "pinch", "zoom", "pinch_zoom")
)


def felt_level(profile: Profile) -> float:
    """The lowest input (mm) at which an output of one gesture type (:data:`TYPE_INPUTS`) can be
    on in ``profile``: the dead zone of an axis, stick, pointer or wheel, the ``release_mm`` of a
    button or layer switch (a held one stays held down to it); ``inf`` when no mapping or switch
    takes a typed input."""
    levels = [
        m.release_mm if isinstance(m, ButtonMapping) else m.deadzone_mm
        for m in profile.mappings.values()
        if m.input in TYPE_INPUTS
    ]
    levels += [s.release_mm for s in profile.layers.values() if s.input in TYPE_INPUTS]
    click = profile.touchpad.click if profile.touchpad is not None else None
    if click is not None and click.input in TYPE_INPUTS:
        levels.append(click.release_mm)
    return min(levels, default=math.inf)
