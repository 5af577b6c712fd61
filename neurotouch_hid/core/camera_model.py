"""The camera model from the marker grid at rest: image px -> gel mm (not in the paper).

The paper converts pixels to millimetres with one scale. The camera inside the dome sees its rim
nearer than its apex, and its lens distorts, so px/mm changes over the image (the ``camera``
physics family: 2.27 px/mm at the centre, ~2.9 px/mm radially at the rim, against sensor.yaml's
nominal 2.5). The gel carries its own calibration target: 1 mm markers on a 4 mm grid (paper,
section "System Overview"), laid on the dome's surface. :func:`fit_camera_model` recovers, from
the markers of one rest frame, the radial model of :class:`~neurotouch_hid.core.sensor.SensorGeometry`
(``px_per_mm`` at the centre and ``radial_k``):

1. the grid's orientation in the image: the directions to each marker's nearest neighbour
   repeat every 90 degrees (the 4-fold order ``arg mean exp(4 i theta) / 4``);
2. each marker's grid index (i, j): its position mapped to the gel with the current model,
   unrolled from the dome to arc lengths (``s = R asin(rho / R)``, the grid is laid on the
   sphere of radius :data:`DOME_SPHERE_MM` with its centre on the apex), in pitches, rounded;
3. where that grid point lies in the user frame (the base plane, as the simulator's labels and
   intensities): ``rho = R sin(s / R)`` at arc length ``s = 4 mm * |(i, j)|``;
4. a linear least-squares fit of ``rho = r (b0 + b1 x^2 + b2 x^4)`` (r the image radius about
   the gel's centre in px, x = r / gel_radius_px), i.e. px_per_mm = 1 / b0 and
   ``radial_k = (b1 / b0, b2 / b0)``.

Steps 2-4 are repeated from the nominal scale (first with the markers within 60 % of the gel's
radius, whose rounding holds even with a 15 % scale error), then with all markers. The fit is
refused (None) when the indices are not a grid (two markers on one index, or a residual above
:data:`MAX_RESIDUAL_MM`): then the linear mapping stays.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from neurotouch_hid.core.sensor import DOME_SPHERE_MM, MARKER_SPACING_MM, SensorGeometry, one_to_one

#: Largest RMS residual (mm) of an accepted fit: a tenth of the pitch.
MAX_RESIDUAL_MM = 0.4
#: Fewest markers a fit needs (3 unknowns, and the grid's orientation).
MIN_MARKERS = 12


def grid_orientation(points_px: np.ndarray) -> float:
    """The marker grid's angle in the image (rad, in [-pi/4, pi/4)): the 4-fold mean direction
    of the vectors from each marker to its nearest neighbour. points_px: (M, 2) px, M >= 2."""
    d = points_px[:, None, :] - points_px[None, :, :]
    dist = np.hypot(d[..., 0], d[..., 1])
    np.fill_diagonal(dist, np.inf)
    nearest = np.argmin(dist, axis=1)
    v = points_px[nearest] - points_px
    theta = np.arctan2(v[:, 1], v[:, 0])
    return float(np.angle(np.mean(np.exp(4j * theta))) / 4.0)


def _expected_radius_mm(index: np.ndarray) -> np.ndarray:
    """(M,) base-plane radius (mm) of grid points (M, 2) int: the arc length from the apex
    ``s = pitch |(i, j)|`` on the dome seen from below, ``R sin(s / R)``."""
    s = MARKER_SPACING_MM * np.hypot(index[:, 0], index[:, 1])
    return DOME_SPHERE_MM * np.sin(np.minimum(s / DOME_SPHERE_MM, math.pi / 2))


def fit_camera_model(points_px: np.ndarray, sensor: SensorGeometry) -> SensorGeometry | None:
    """``sensor`` with the camera model fitted to the markers of a rest frame (module docstring).

    Args:
        points_px: (M, 2) float, marker centroids of a frame of the gel at rest, image px.
        sensor: the geometry: gel centre and radius (the model's centre and normalisation), and
            the nominal px_per_mm the indexing starts from.
    Returns:
        A copy of ``sensor`` with ``px_per_mm`` (at the centre, rounded to 1e-4) and
        ``radial_k`` fitted, or None when the markers do not index as the 4 mm grid (fewer than
        :data:`MIN_MARKERS`, two markers on one grid point, or an RMS residual above
        :data:`MAX_RESIDUAL_MM`) or the fit folds (:func:`~neurotouch_hid.core.sensor.one_to_one`).
    """
    points = np.asarray(points_px, dtype=np.float64).reshape(-1, 2)
    if len(points) < MIN_MARKERS:
        return None
    d = points - np.asarray(sensor.gel_center_px, dtype=np.float64)
    r = np.hypot(d[:, 0], d[:, 1])
    x2 = (r / sensor.gel_radius_px) ** 2
    angle = grid_orientation(points)
    rotate = np.array([[math.cos(angle), math.sin(angle)], [-math.sin(angle), math.cos(angle)]])  # by -angle
    coef = np.array([1.0 / sensor.px_per_mm, 0.0, 0.0])
    design = np.stack([r, r * x2, r * x2 * x2], axis=1)
    for inner in (True, False, False):
        rho = design @ coef  # the current model's base-plane radius (mm)
        arc = DOME_SPHERE_MM * np.arcsin(np.minimum(rho / DOME_SPHERE_MM, 1.0))
        unit = d / np.where(r > 0, r, 1.0)[:, None]
        index = np.rint((unit * arc[:, None]) @ rotate.T / MARKER_SPACING_MM).astype(np.int64)
        use = x2 <= 0.36 if inner else np.ones(len(points), dtype=bool)
        if np.count_nonzero(use) < MIN_MARKERS:
            return None
        coef = np.linalg.lstsq(design[use], _expected_radius_mm(index[use]), rcond=None)[0]
        if not coef[0] > 0:
            return None
    if len(np.unique(index, axis=0)) < len(index):
        return None
    residual = design @ coef - _expected_radius_mm(index)
    if float(np.sqrt(np.mean(residual**2))) > MAX_RESIDUAL_MM:
        return None
    radial_k = (round(float(coef[1] / coef[0]), 5), round(float(coef[2] / coef[0]), 5))
    try:
        one_to_one(radial_k)
    except ValueError:  # a folded model: two radii of the gel on one
        return None
    return replace(sensor, px_per_mm=round(1.0 / float(coef[0]), 4), radial_k=radial_k)
