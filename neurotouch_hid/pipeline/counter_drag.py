"""How far the gel moves against a lone contact's own drag: zero for one finger, the first sign of
a second finger dragging another way (not in the paper; docs/method.md, "Episode vote").

One finger's tangential load on an elastic half-space moves the surface along the load everywhere:
Cerruti's surface displacement along the load is Q / (2 pi G rho) ((1 - nu) + nu x^2 / rho^2) > 0
at every distance rho and bearing (Johnson, *Contact Mechanics*, 1985, ch. 3: Cerruti's
concentrated tangential force); its normal load moves the surface radially only by a term in
(1 - 2 nu) (Boussinesq's concentrated normal force), nil for an incompressible gel such as
silicone (nu ~ 0.5). Several fingers pushing together drag the same way. The fingers of
a pinch, zoom or twist drag in opposing directions about their centre: where the next finger
lands, the gel moves against the first finger's drag, from its first tenths of a millimetre on,
before the contact step can tell its bump from the first finger's tail (about 0.3 mm).
"""

from __future__ import annotations

import numpy as np

#: Markers within this many marker pitches of the contact give the lone finger's drag direction.
NEAR_PITCHES = 1.5
#: The rank of the largest counter-motion read (1: the largest): a finger moves several markers,
#: one marker's tracking error one.
RANK = 3


def counter_drag_mm(
    rest_px: np.ndarray,
    current_px: np.ndarray,
    valid: np.ndarray,
    contact: int,
    pitch_px: float,
    px_per_mm: float,
) -> float:
    """How far (mm) the markers move against the drag of a lone contact at marker ``contact``.

    The drag's direction is the summed displacement of the valid markers within
    :data:`NEAR_PITCHES` marker pitches of the contact at rest; each valid marker's displacement
    against it (its component along minus that direction, 0 when along it) is read, and the
    :data:`RANK`-th largest returned (0 with fewer valid markers). Positions are on the gel, as the
    contact step reads them: undistorted (one px = 1 / ``px_per_mm`` base-plane mm everywhere) and
    without the gel's motion in its mount.

    Args:
        rest_px, current_px: (N, 2) float64 marker positions at rest and now (px).
        valid: (N,) bool, markers tracked now.
        contact: index of the contact's marker (0 <= contact < N).
        pitch_px: the marker pitch (px, > 0).
        px_per_mm: the scale (px per mm, > 0).

    Returns:
        mm >= 0; 0 when no marker near the contact has moved.

    Raises:
        ValueError: shapes that do not match, or ``contact`` out of range.
    """
    rest = np.asarray(rest_px, dtype=np.float64)
    cur = np.asarray(current_px, dtype=np.float64)
    ok = np.asarray(valid, dtype=bool)
    if rest.ndim != 2 or rest.shape[1:] != (2,) or cur.shape != rest.shape or ok.shape != rest.shape[:1]:
        raise ValueError(f"rest {rest.shape}, current {cur.shape} and valid {ok.shape} must be (N, 2), (N, 2), (N,)")
    if not 0 <= contact < len(rest):
        raise ValueError(f"contact {contact} is not a marker index (0 <= contact < {len(rest)})")
    v = (cur[ok] - rest[ok]) / px_per_mm
    near = np.sum((rest[ok] - rest[contact]) ** 2, axis=1) <= (NEAR_PITCHES * pitch_px) ** 2
    drag = v[near].sum(axis=0)
    norm = float(np.hypot(drag[0], drag[1]))
    if norm == 0.0 or len(v) < RANK:
        return 0.0
    against = -(v @ (drag / norm))
    return max(0.0, float(np.partition(against, len(against) - RANK)[len(against) - RANK]))
