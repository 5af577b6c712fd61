"""What the pipeline hands to the mapping, the outputs and the evaluation.

A :class:`GestureEstimate` is one window's answer (paper, section "Problem Statement"): the
gesture type, whether the gel rests, the contact points and the gesture intensity. It is a plain
value: nothing in it refers back to the pipeline's state.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass, field

import numpy as np


class GestureType(str, enum.Enum):
    """The gesture types of the paper (section "Problem Statement") plus ``none``.

    Clockwise / counter-clockwise are meant in the user frame (the gel seen from outside).
    """

    NONE = "none"
    PUSH = "push"
    PINCH = "pinch"
    ZOOM = "zoom"
    TWIST_CW = "twist_cw"
    TWIST_CCW = "twist_ccw"

    def __str__(self) -> str:  # "push", not "GestureType.PUSH"
        return self.value


#: The order used for confusion matrices and per-class tables.
GESTURE_ORDER: tuple[GestureType, ...] = tuple(GestureType)


def _empty_points() -> np.ndarray:
    return np.zeros((0, 2), dtype=np.float64)


@dataclass(frozen=True)
class GestureEstimate:
    """One window's estimate.

    Attributes:
        t_us: end of the window, int microseconds, camera clock.
        gesture: the dominant gesture type (``NONE`` at rest or when nothing moves).
        resting: True when the resting detector (Chamfer distance on APS frames) says the gel is
            undeformed.
        intensity_mm: mean displacement of the markers within r of the contacts (mm), led along
            its change within a gesture (3 ms by default; docs/method.md, "Gesture"), 0 for NONE except in a
            gesture's undecided first windows (``NONE`` with the window's intensity and contacts:
            its type is not committed yet; docs/method.md, "Episode vote").
        contacts_px: (K, 2) float64, contact points in the image frame (px), K in 0..3+.
        contacts_mm: (K, 2) float64, the same contact points in the user frame (mm).
        translation_mm: (2,) float64, the similarity's translation in the user frame (mm): a
            push's direction and size.
        rotation_rad: the similarity's rotation in the user frame (rad, counter-clockwise > 0).
        scale: the similarity's scale (1 = none; < 1 pinch, > 1 zoom).
    """

    t_us: int
    gesture: GestureType = GestureType.NONE
    resting: bool = True
    intensity_mm: float = 0.0
    contacts_px: np.ndarray = field(default_factory=_empty_points)
    contacts_mm: np.ndarray = field(default_factory=_empty_points)
    translation_mm: np.ndarray = field(default_factory=lambda: np.zeros(2))
    rotation_rad: float = 0.0
    scale: float = 1.0

    @property
    def n_contacts(self) -> int:
        """Number of contact points K."""
        return int(len(self.contacts_px))

    def to_json_dict(self) -> dict:
        """The docs/dataset.md predictions line (plus the similarity's terms, which readers ignore)."""
        return {
            "t_us": int(self.t_us),
            "gesture": self.gesture.value,
            "resting": bool(self.resting),
            "intensity_mm": round(float(self.intensity_mm), 4),
            "contacts_px": [[round(float(x), 3), round(float(y), 3)] for x, y in self.contacts_px],
            "contacts_mm": [[round(float(x), 3), round(float(y), 3)] for x, y in self.contacts_mm],
            "translation_mm": [round(float(v), 4) for v in self.translation_mm],
            "rotation_rad": round(float(self.rotation_rad), 5),
            "scale": round(float(self.scale), 5),
        }

    @classmethod
    def from_json_dict(cls, data: dict) -> "GestureEstimate":
        """Inverse of :meth:`to_json_dict`; the similarity's terms are optional."""
        return cls(
            t_us=int(data["t_us"]),
            gesture=GestureType(data["gesture"]),
            resting=bool(data["resting"]),
            intensity_mm=float(data["intensity_mm"]),
            contacts_px=np.asarray(data.get("contacts_px") or np.zeros((0, 2)), dtype=np.float64).reshape(-1, 2),
            contacts_mm=np.asarray(data.get("contacts_mm") or np.zeros((0, 2)), dtype=np.float64).reshape(-1, 2),
            translation_mm=np.asarray(data.get("translation_mm", [0.0, 0.0]), dtype=np.float64),
            rotation_rad=float(data.get("rotation_rad", 0.0)),
            scale=float(data.get("scale", 1.0)),
        )


@dataclass(frozen=True)
class MarkerPositions:
    """The markers the pipeline saw at a window's end.

    Attributes:
        rest_px: (N, 2) float64, the markers at rest (image frame, px).
        now_px: (N, 2) float64, where they are tracked now (image frame, px); NaN rows for
            markers lost.
    """

    rest_px: np.ndarray
    now_px: np.ndarray
