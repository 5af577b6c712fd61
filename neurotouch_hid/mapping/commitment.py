"""Whether a profile reads the distinction the episode vote's one-contact wait makes.

The pipeline holds a gesture whose windows show one contact undecided for up to
``episode.first_finger_us`` (docs/method.md, "Episode vote"): a multi-finger gesture whose first
finger leads reads as a one-finger push until its next finger is found, and the wait keeps a
pinch, zoom or twist from pressing push's outputs. A profile whose outputs do not depend on which
of those types is read (every type moves the same outputs: a one-switch user's "any gesture is
the switch") reads nothing of the distinction, and the wait is only a delay there. A profile that
maps only push still reads it: a pinch must press nothing.
"""

from __future__ import annotations

from neurotouch_hid.core.estimate import GestureType
from neurotouch_hid.mapping.profile import Profile

#: The types the one-contact wait tells apart: push (one finger) from the multi-finger types.
WAIT_SEPARATES = (
    GestureType.PUSH,
    GestureType.PINCH,
    GestureType.ZOOM,
    GestureType.TWIST_CW,
    GestureType.TWIST_CCW,
)


def waits_for_type(profile: Profile) -> bool:
    """Whether the pipeline should wait for the fingers before committing a type under ``profile``.

    False when every type of :data:`WAIT_SEPARATES` sets the same outputs active through the
    profile, as ``eval --profile`` probes them (each type alone, ramped to 6 mm and held; a push in
    eight directions: :func:`~neurotouch_hid.evaluation.through_profile.outputs_by_type`); True
    otherwise, a profile that maps only some of them included. Costs one probe of the profile
    (about a thousand mapper updates, a few tens of ms).
    """
    from neurotouch_hid.evaluation.through_profile import outputs_by_type

    outputs = outputs_by_type(profile)
    return len({outputs[kind] for kind in WAIT_SEPARATES}) > 1
