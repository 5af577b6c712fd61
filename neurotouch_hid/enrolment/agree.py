"""Whether what the gel did at a prompt agrees with what the prompt asked (``enrol --from``).

A label is only as good as the prompt it comes from: a person may do another gesture than the
one shown, or a recording may not follow the plan at all. What the gel did is told from the
tracked markers alone, not from the recogniser that the labels are meant to adapt (its learned
type, thresholds and episode vote): at the gesture's peak (its window of largest motion,
:mod:`neurotouch_hid.enrolment.label`), the markers that moved at least :data:`MOVED_SHARE` of
the largest displacement (the :data:`TOP_QUANTILE` quantile, a lost marker aside) since the
gesture's start, once the whole gel's slip in its mount is removed (the rim's shared rigid
motion, :func:`~neurotouch_hid.pipeline.gel_motion.estimate_gel_motion`; docs/method.md,
"Gel motion": without it a pinch on a sliding gel reads as motion along), are taken into the user
frame (mm, :meth:`SensorGeometry.image_to_user`), and
their displacements fitted by least squares, about the displacement-weighted centre of those
markers, with the linear motion ``v = t + a q + b J q`` (q the offset from that centre, J the
quarter turn counter-clockwise): the small-motion form of the paper's 4-DoF similarity
(paper, "Gesture Classification"; docs/method.md, "Gesture"). As lengths at the markers' RMS
radius rho (mm): ``along = ||t||``, ``apart = a rho`` (> 0 apart, < 0 together) and
``around = b rho`` (> 0 counter-clockwise, < 0 clockwise, user frame).

A push is motion along (towards the asked direction, within :data:`DIRECTION_DEG`), a pinch
together, a zoom apart, a twist around (clockwise or counter-clockwise). A prompt disagrees when
another of these dominates the asked one by more than 1 / :data:`AGREE_SHARE`, when a push's
spread or turn exceeds :data:`PUSH_SHARE` of its motion along, when a pinch, zoom
or twist shows a single contact at the peak (the contact stage's count with the shipped settings:
they take two fingers or more), or when a push goes the other way. Fewer than
:data:`MIN_MARKERS` moving markers tell nothing: no disagreement is claimed.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from neurotouch_hid.core.estimate import GestureType
from neurotouch_hid.core.sensor import SensorGeometry
from neurotouch_hid.pipeline.gel_motion import estimate_gel_motion, rim_markers

#: The markers of a gesture: those that moved at least this share of the largest displacement.
MOVED_SHARE = 0.3
#: The largest displacement: this quantile of the markers' (one mis-tracked marker aside).
TOP_QUANTILE = 0.97
#: Fewer moving markers than this tell nothing about the motion.
MIN_MARKERS = 6
#: The asked motion agrees while it is at least this share of the dominant one.
AGREE_SHARE = 0.5
#: A push agrees while the spread and turn stay below this share of its motion along: fingers
#: that all move one way show almost none (under a tenth in the simulated enrolments), while a
#: pinch, zoom or twist whose fingers are off-centre or unequal shows some motion along too.
PUSH_SHARE = 0.35
#: A push agrees with its asked direction within this angle (deg): a diagonal push passes, a push
#: towards a neighbouring direction (90 deg off) does not.
DIRECTION_DEG = 67.5

#: The motion each prompted type makes.
ASKED: dict[GestureType, str] = {
    GestureType.PUSH: "along",
    GestureType.PINCH: "together",
    GestureType.ZOOM: "apart",
    GestureType.TWIST_CW: "around clockwise",
    GestureType.TWIST_CCW: "around counter-clockwise",
}
#: The type each motion is, for the messages.
_TYPE_OF = {motion: gesture.value for gesture, motion in ASKED.items()}


@dataclass(frozen=True)
class GelDid:
    """What the gel did at a gesture's peak (module docstring).

    Attributes:
        contacts: the contact stage's count at the peak (0 when it found none).
        along_mm: the common translation's length (mm).
        apart_mm: the spread term (mm; > 0 apart, < 0 together).
        around_mm: the turn term (mm; > 0 counter-clockwise, < 0 clockwise, user frame).
        direction_deg: the translation's direction (deg, counter-clockwise from x, user frame).
        markers: the moving markers the fit used.
    """

    contacts: int
    along_mm: float
    apart_mm: float
    around_mm: float
    direction_deg: float
    markers: int

    def motions(self) -> dict[str, float]:
        """Each motion's size (mm; 0 for the other sign of a signed term)."""
        return {
            "along": self.along_mm,
            "together": max(0.0, -self.apart_mm),
            "apart": max(0.0, self.apart_mm),
            "around clockwise": max(0.0, -self.around_mm),
            "around counter-clockwise": max(0.0, self.around_mm),
        }

    @property
    def motion(self) -> str:
        """The dominant motion's name."""
        sizes = self.motions()
        return max(sizes, key=sizes.__getitem__)

    def describe(self) -> str:
        """E.g. ``2 contacts moving together (a pinch)``."""
        count = {0: "no contact", 1: "1 contact"}.get(self.contacts, f"{self.contacts} contacts")
        return f"{count} moving {self.motion} (a {_TYPE_OF[self.motion]})"


def gel_did(positions_px: np.ndarray, start_px: np.ndarray, contacts: int, sensor: SensorGeometry) -> GelDid | None:
    """What the gel did between two moments (module docstring); None when fewer than
    :data:`MIN_MARKERS` markers moved.

    Args:
        positions_px: (N, 2) the markers at the peak (image px, NaN rows lost).
        start_px: (N, 2) the same markers at the gesture's start (image px).
        contacts: the contact stage's count at the peak.
        sensor: the geometry (image px -> user mm).
    """
    now = np.asarray(positions_px, dtype=np.float64)
    before = np.asarray(start_px, dtype=np.float64)
    if now.shape != before.shape or now.ndim != 2 or not len(now):
        return None
    ok = np.isfinite(now).all(axis=1) & np.isfinite(before).all(axis=1)
    if ok.sum() < MIN_MARKERS:
        return None
    centre = sensor.gel_center_px
    slip = estimate_gel_motion(before, now, ok, rim_markers(np.where(ok[:, None], before, 0.0), centre), centre)
    if slip is not None:  # the whole gel's slip in its mount is no finger's motion
        now = slip.remove(now)
    p0 = sensor.image_to_user(before[ok])
    v = sensor.image_to_user(now[ok]) - p0
    d = np.linalg.norm(v, axis=1)
    top = float(np.quantile(d, TOP_QUANTILE))
    moving = d >= MOVED_SHARE * top
    if top <= 0 or moving.sum() < MIN_MARKERS:
        return None
    p, v, w = p0[moving], v[moving], d[moving]
    q = p - (p * w[:, None]).sum(axis=0) / w.sum()
    design = np.zeros((2 * len(q), 4))
    design[0::2, 0] = 1.0
    design[1::2, 1] = 1.0
    design[0::2, 2], design[1::2, 2] = q[:, 0], q[:, 1]
    design[0::2, 3], design[1::2, 3] = -q[:, 1], q[:, 0]
    (tx, ty, a, b), *_ = np.linalg.lstsq(design, v.reshape(-1), rcond=None)
    rho = float(np.sqrt((q**2).sum(axis=1).mean()))
    return GelDid(
        int(contacts),
        float(math.hypot(tx, ty)),
        float(a * rho),
        float(b * rho),
        float(math.degrees(math.atan2(ty, tx))),
        int(moving.sum()),
    )


def disagreement(gesture: GestureType, direction: tuple[float, float] | None, did: GelDid | None) -> str | None:
    """Why what the gel did (``did``) is not the asked ``gesture`` (towards ``direction``, a
    user-frame vector, for a push), or None when it agrees or cannot be told (module docstring).

    Returns:
        what the gel showed, e.g. ``"the gel showed 2 contacts moving together (a pinch)"``."""
    if did is None or gesture not in ASKED:
        return None
    showed = f"the gel showed {did.describe()}"
    sizes = did.motions()
    asked = ASKED[gesture]
    if did.motion != asked and sizes[asked] < AGREE_SHARE * sizes[did.motion]:
        return showed
    others = {k: v for k, v in sizes.items() if k != "along"}
    other = max(others, key=others.__getitem__)
    count = {0: "no contact", 1: "1 contact"}.get(did.contacts, f"{did.contacts} contacts")
    if gesture is GestureType.PUSH and others[other] > PUSH_SHARE * did.along_mm:
        return f"the gel showed {count} moving along and {other} (a push moves its fingers one way)"
    if gesture is not GestureType.PUSH and did.contacts == 1:
        return f"the gel showed 1 contact moving {did.motion} (a {gesture.value} takes two fingers or more)"
    if gesture is GestureType.PUSH and direction is not None:
        off = abs((did.direction_deg - math.degrees(math.atan2(direction[1], direction[0])) + 180.0) % 360.0 - 180.0)
        if off > DIRECTION_DEG:
            return f"the gel showed a push {_nearest(did.direction_deg)} ({off:.0f} deg off the direction asked)"
    return None


def _nearest(direction_deg: float) -> str:
    """The name of the direction (:data:`~neurotouch_hid.enrolment.plan.DIRECTIONS`) nearest an angle."""
    from neurotouch_hid.enrolment.plan import DIRECTIONS

    def off(name: str) -> float:
        x, y = DIRECTIONS[name]
        return abs((direction_deg - math.degrees(math.atan2(y, x)) + 180.0) % 360.0 - 180.0)

    return min(DIRECTIONS, key=off)
