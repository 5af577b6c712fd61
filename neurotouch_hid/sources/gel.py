"""The simulated gel's mechanics: the dome and its markers at rest, and how gestures deform it.

What is modelled (paper, sections "System Overview" and "Problem Statement"):

* **The gel** -- a 60 mm silicone dome (a spherical cap of radius :data:`DOME_SPHERE_MM` over a
  30 mm base) with white 1 mm markers on a 4 mm grid laid on its surface (the grid is centred on
  the apex and kept where the arc length from the apex is below :data:`MARKER_ARC_MM`: exactly
  177 markers). The camera inside looks up through the base: a marker at arc length s from the
  apex is seen at base-plane radius ``R sin(s / R)`` (orthographic), i.e. 2.5 px/mm at the
  centre and foreshortened towards the rim. All markers lie inside the gel circle of
  ``sensor.yaml`` (the base, 30 mm = 75 px). Deformations are modelled in the base plane, which
  is the user frame of docs/dataset.md (mm, x right, y up, seen from outside); image positions come
  from :meth:`SensorGeometry.user_to_image` (the mirror included).
* **A gesture's motion** (:class:`SimGesture`) -- attack (cosine ramp up), hold (the maximum, with
  a small tremor) and release (cosine ramp down), then the gel creeps back (exponential, tau ~
  0.1 s) from a small residual. A finger drags the markers under it with it; the others follow
  with a Gaussian falloff whose width is the finger's footprint, widened for large displacements
  (and for fingers pushing together) so that the gel never folds; where fingers' falloffs overlap
  their motions blend. Pressing also spreads the markers under a finger radially (<= 0.35 mm) and
  dims them (<= 25 %); the whole gel moves a little with the gesture (<= 0.35 mm translation, <=
  0.35 deg rotation). The rim is clamped: the displacement fades out towards it and nothing is
  pushed past 98 % of the radius (:func:`deform`).

The physics families (:mod:`neurotouch_hid.sources.physics`) change the falloff, the contact
mechanics, the indentation, the camera and the gel's creep. Who makes the gestures is
:mod:`neurotouch_hid.sources.hands`; the camera that watches the gel,
:mod:`neurotouch_hid.sources.simulator`.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from typing import Sequence

import numba
import numpy as np

from neurotouch_hid.core.estimate import GestureType
from neurotouch_hid.core.sensor import DOME_SPHERE_MM, MARKER_SPACING_MM, SensorGeometry
from neurotouch_hid.sources.physics import (
    PHYSICS,
    DomeCamera,
    Physics,
    hertz_deflection,
    pasternak_falloff,
    sls_deformation,
)

#: Marker grid spacing on the gel surface (mm: the sensor's) and the marker diameter (mm).
MARKER_PITCH_MM = MARKER_SPACING_MM
MARKER_DIAMETER_MM = 1.0
#: Markers are printed where the arc length from the apex is below this (mm): 177 markers.
MARKER_ARC_MM = 29.8
#: Grey levels: gel background (at the centre), outside the gel, marker peak above background.
BACKGROUND_GREY = 20.0
OUTSIDE_GREY = 6.0
MARKER_GREY = 200.0
#: The displacement fades out towards this multiple of the gel radius (the clamped base), over
#: at least RIM_EASE_MM (mm).
RIM_CLAMP = 1.0
RIM_EASE_MM = 6.0
#: How long after its release a gesture still deforms the gel, in creep time constants.
CREEP_SPAN_TAUS = 7.0
#: Time step (us) of a viscoelastic gel's deformation history (SimGesture.profile).
SLS_STEP_US = 1000


# --- the gel ----------------------------------------------------------------------------------
class Gel:
    """The dome and its markers as the camera sees them at rest.

    Attributes:
        sensor: the geometry (image <-> user frame).
        rest_mm: (N, 2) float64 marker rest positions, user frame (mm).
        rest_px: (N, 2) float64 the same in the image (px).
        sigma_px: (N,) float64 blob sigma of each marker's image (px).
        brightness: (N,) float64 peak grey level of each marker above the background.
        background: (H, W) float64 the gel's image without markers (grey levels).
    """

    def __init__(
        self,
        sensor: SensorGeometry,
        rng: np.random.Generator,
        physics: Physics = PHYSICS["default"],
        physics_rng: np.random.Generator | None = None,
    ) -> None:
        self.sensor = sensor
        self.camera = DomeCamera(sensor, physics)
        half = int(MARKER_ARC_MM // MARKER_PITCH_MM) + 1
        g = np.arange(-half, half + 1) * MARKER_PITCH_MM
        gx, gy = np.meshgrid(g, g)
        arc = np.stack([gx.ravel(), gy.ravel()], axis=1)
        s = np.hypot(arc[:, 0], arc[:, 1])
        keep = s < MARKER_ARC_MM
        arc, s = arc[keep], s[keep]
        radial = np.where(s > 0, DOME_SPHERE_MM * np.sin(s / DOME_SPHERE_MM) / np.maximum(s, 1e-12), 1.0)
        self.rest_mm = arc * radial[:, None]
        self.rest_px = self.camera.project(self.rest_mm)
        tilt = np.cos(s / DOME_SPHERE_MM)  # foreshortening of the 1 mm dots towards the rim
        marker_px = MARKER_DIAMETER_MM * sensor.px_per_mm
        self.sigma_px = marker_px * 0.38 * (0.8 + 0.2 * tilt) * self.camera.size_gain(self.rest_mm)
        r_rel = np.hypot(self.rest_mm[:, 0], self.rest_mm[:, 1]) / sensor.gel_radius_mm
        spread = rng.normal(0.0, physics.brightness_spread, len(s)).clip(-0.5, 0.4)
        self.brightness = (
            MARKER_GREY * (1.0 - 0.12 * r_rel**2) * (1.0 + spread) * self.camera.vignetting_mm(self.rest_mm)
        )
        if physics.size_spread > 0:
            prng = physics_rng if physics_rng is not None else np.random.default_rng(0)
            self.sigma_px = self.sigma_px * prng.lognormal(0.0, physics.size_spread, len(s)).clip(0.7, 1.5)
        yy, xx = np.mgrid[0 : sensor.height, 0 : sensor.width]
        r_img = np.hypot(xx - sensor.gel_center_px[0], yy - sensor.gel_center_px[1]) / sensor.gel_radius_px
        self.background = np.where(r_img <= 1.0, BACKGROUND_GREY * (1.0 - 0.2 * r_img**2), OUTSIDE_GREY)
        if physics.perspective:
            self.background = self.background * self.camera.vignetting_image()

    @property
    def n_markers(self) -> int:
        return len(self.rest_mm)


# --- gestures ---------------------------------------------------------------------------------
@dataclass(frozen=True)
class SimGesture:
    """One gesture instance: its timing, fingers and motion, user frame.

    Attributes:
        gesture: the gesture type.
        t_start_us, attack_us, hold_us, release_us: attack start and phase durations (us).
        fingers_mm: (K, 2) where the finger centres touch the gel at the start (user mm).
        amplitude_mm: displacement of each finger at the hold (push, pinch, zoom) or the chord
            a twist's fingers travel (mm).
        direction: (2,) unit vector of a push (user frame).
        finger_mm: footprint sigma (mm). press: 0..1, how hard the fingers press (indentation).
        tremor: (relative amplitude, frequency Hz, phase rad) of the hold's tremor.
        global_mm: (2,) whole-gel translation at full deformation (mm); global_rad: rotation (rad).
        residual: deformation left when the release ends (fraction); creep_us: its time constant.
        lags_us: per finger, how long after t_start_us it starts moving (us, each < attack_us;
            empty: all at once); strengths: per finger, its share of the motion (0..1; empty:
            all 1) -- the ``fingers`` and ``late`` families.
        squeeze: radial contraction of the markers under a pressing finger (mm; 0: the default
            spread) -- the ``strong`` family.
        sls: (delayed share q, retardation time tau us) of the gel's standard linear solid, or
            empty for an elastic gel -- the ``viscoelastic`` family (:func:`physics.sls_deformation`).
        slide: (start us after t_start_us, duration us, dx mm, dy mm): every finger on the gel
            moves together by (dx, dy) x sin(pi u), u from 0 to 1 over the duration, on top of the
            gesture's own motion (a hand sliding for a moment: push-like), or empty -- the
            ``starts`` family.
    """

    gesture: GestureType
    t_start_us: int
    attack_us: int
    hold_us: int
    release_us: int
    fingers_mm: np.ndarray
    amplitude_mm: float
    direction: np.ndarray
    finger_mm: float
    press: float
    tremor: tuple[float, float, float]
    global_mm: np.ndarray
    global_rad: float
    residual: float
    creep_us: int
    lags_us: tuple[int, ...] = ()
    strengths: tuple[float, ...] = ()
    squeeze: float = 0.0
    sls: tuple[float, int] = ()
    slide: tuple[int, int, float, float] = ()

    def slide_displacement(self, t_us: np.ndarray) -> np.ndarray:
        """(T, 2) float64 the common slide of the fingers at t_us (T,) int64 us (user mm; zeros
        without a slide)."""
        out = np.zeros((len(t_us), 2))
        if not self.slide:
            return out
        start, duration, dx, dy = self.slide
        u = (np.asarray(t_us, dtype=np.float64) - self.t_start_us - start) / duration
        m = (u > 0) & (u < 1)
        out[m] = np.sin(math.pi * u[m])[:, None] * np.array([dx, dy])
        return out

    @property
    def t_end_us(self) -> int:
        """End of the release: the fingers have left the gel (us)."""
        return self.t_start_us + self.attack_us + self.hold_us + self.release_us

    @property
    def t_settled_us(self) -> int:
        """After this the gesture no longer deforms the gel at all (us)."""
        tau = max(self.creep_us, self.sls[1]) if self.sls else self.creep_us
        return self.t_end_us + int(CREEP_SPAN_TAUS * tau)

    def profile(self, t_us: np.ndarray) -> np.ndarray:
        """(T,) float64 deformation level in 0..~1 at times t_us (T,) int64 us: attack ramp, hold
        (1 + tremor), release ramp down to ``residual``, then exponential creep to 0; on a
        viscoelastic gel (``sls``) that is the load, and the level is the standard linear solid's
        response to it (sampled every ms, interpolated)."""
        if not self.sls:
            return self._load(t_us)
        t = np.asarray(t_us, dtype=np.float64) - self.t_start_us
        return np.interp(t, self._sls_grid_us, self._sls_levels, left=0.0, right=0.0)

    @functools.cached_property
    def _sls_grid_us(self) -> np.ndarray:
        return np.arange(-SLS_STEP_US, self.t_settled_us - self.t_start_us + SLS_STEP_US, SLS_STEP_US, dtype=np.float64)

    @functools.cached_property
    def _sls_levels(self) -> np.ndarray:
        load = self._load(self._sls_grid_us.astype(np.int64) + self.t_start_us)
        return sls_deformation(load, float(SLS_STEP_US), self.sls[0], float(self.sls[1]))

    def _load(self, t_us: np.ndarray) -> np.ndarray:
        """The elastic gel's deformation level (:meth:`profile` without ``sls``)."""
        t = np.asarray(t_us, dtype=np.float64) - self.t_start_us
        a, h, r = self.attack_us, self.hold_us, self.release_us
        amp, freq, phase = self.tremor
        out = np.zeros_like(t)
        m = (t >= 0) & (t < a)
        out[m] = 0.5 - 0.5 * np.cos(math.pi * t[m] / a)
        m = (t >= a) & (t < a + h)
        th = (t[m] - a) * 1e-6
        out[m] = 1.0 + amp * np.sin(2 * math.pi * freq * th + phase) * np.sin(math.pi * (t[m] - a) / h)
        m = (t >= a + h) & (t < a + h + r)
        tr = (t[m] - a - h) / r
        out[m] = self.residual + (1.0 - self.residual) * (0.5 + 0.5 * np.cos(math.pi * tr))
        m = (t >= a + h + r) & (t < self.t_settled_us - self.t_start_us)
        out[m] = self.residual * np.exp(-(t[m] - a - h - r) / self.creep_us)
        return out

    def finger_levels(self, t_us: np.ndarray) -> np.ndarray:
        """(T, K) float64 each finger's deformation level at t_us (T,) int64 us: the gesture's
        :meth:`profile`, except that a lagging finger's attack ramp starts ``lags_us[k]`` late
        (and ends with the others'), times the finger's strength."""
        base = self.profile(t_us)
        levels = np.repeat(base[:, None], len(self.fingers_mm), axis=1)
        t = np.asarray(t_us, dtype=np.float64) - self.t_start_us
        for k, lag in enumerate(self.lags_us):
            if lag <= 0:
                continue
            m = (t >= 0) & (t < self.attack_us)
            ramp = np.clip((t[m] - lag) / (self.attack_us - lag), 0.0, 1.0)
            levels[m, k] = 0.5 - 0.5 * np.cos(math.pi * ramp)
        if self.strengths:
            levels = levels * np.asarray(self.strengths, dtype=np.float64)[None, :]
        return levels

    def finger_displacements(self, level: np.ndarray) -> np.ndarray:
        """(T, K, 2) float64 displacement of each finger (user mm) at deformation levels (T,)
        (the same for every finger) or (T, K) (:meth:`finger_levels`)."""
        level = np.asarray(level, dtype=np.float64)
        centre = self.fingers_mm.mean(axis=0)
        rel = self.fingers_mm - centre
        if level.ndim == 1:
            level = np.repeat(level[:, None], len(rel), axis=1)
        if self.gesture is GestureType.PUSH:
            return level[:, :, None] * self.amplitude_mm * self.direction[None, None, :]
        if self.gesture in (GestureType.PINCH, GestureType.ZOOM):
            unit = rel / np.linalg.norm(rel, axis=1, keepdims=True)
            sign = -1.0 if self.gesture is GestureType.PINCH else 1.0
            return sign * level[:, :, None] * self.amplitude_mm * unit[None]
        # twist: rotate about the fingers' centroid; counter-clockwise (user frame, y up) is > 0
        radius = float(np.linalg.norm(rel, axis=1).mean())
        theta_max = 2.0 * math.asin(min(1.0, self.amplitude_mm / (2.0 * radius)))
        theta = level * theta_max * (1.0 if self.gesture is GestureType.TWIST_CCW else -1.0)
        c, s = np.cos(theta), np.sin(theta)
        rx = c * rel[None, :, 0] - s * rel[None, :, 1]
        ry = s * rel[None, :, 0] + c * rel[None, :, 1]
        return np.stack([rx - rel[None, :, 0], ry - rel[None, :, 1]], axis=-1)


@numba.njit(cache=True, nogil=True)
def _finger_field(
    pts: np.ndarray,
    finger: np.ndarray,
    d: np.ndarray,
    finger_mm: float,
    widen: float,
    press: float,
    level: np.ndarray,
    flevel: np.ndarray,
    falloff: int,
    squeeze: float,
    indent: float,
    drag: np.ndarray,
    weight: np.ndarray,
    disp: np.ndarray,
    dim: np.ndarray,
    grow: np.ndarray,
) -> None:
    """Add one finger's field at the points ``pts`` (M, 2) mm, for times T.

    The finger (rest centre ``finger`` (2,) mm, displacement ``d`` (T, 2) mm, its own level
    ``flevel`` (T,)) drags the points with a falloff w(r) that is 1 under the finger, of width
    s = sqrt(finger_mm^2 + (widen |d|)^2), wider for large displacements so that the gel never
    folds (the strain of a Gaussian drag peaks at |d| / (s sqrt(e))): adds w * d to ``drag``
    (T, M, 2) and w to ``weight`` (T, M). ``falloff`` (physics.FALLOFF_*): Gaussian
    exp(-r^2 / 2 s^2); power law (1 + r^2 / 2 s^2)^(-3/4); stick/slip: 1 in the stick disc
    c = a (1 - min(level, 0.9))^(1/3), easing to 0.85 over the slip annulus up to the contact
    radius a = sqrt(finger_mm^2 + (1.5 widen |d|)^2), then 0.85 a / r (Cattaneo-Mindlin);
    Pasternak foundation K0(sqrt(r^2 + s^2) / lambda) / K0(s / lambda), lambda = 1.25 s
    (:func:`physics.pasternak_falloff`).
    The gesture's pressure ``press * level`` (T,) spreads the points under it radially
    (<= 0.35 mm, or contracts them by <= ``squeeze`` mm when squeeze > 0; added to ``disp``
    (T, M, 2)), dims them (<= 25 %, 40 % when squeezed; max into ``dim`` (T, M)) and, when
    ``indent`` > 0, magnifies them by up to ``indent`` following the Hertz deflection with contact
    radius finger_mm (max into ``grow`` (T, M)).
    """
    inv_f2 = 1.0 / (2.0 * finger_mm * finger_mm)
    spread = 0.35 if squeeze <= 0.0 else -squeeze
    dim_max = 0.25 if squeeze <= 0.0 else 0.4
    for t in range(d.shape[0]):
        if level[t] == 0.0 and flevel[t] == 0.0:
            continue
        dn2 = d[t, 0] * d[t, 0] + d[t, 1] * d[t, 1]
        s2 = finger_mm * finger_mm + widen * widen * dn2
        inv_s2 = 1.0 / (2.0 * s2)
        a_c = math.sqrt(finger_mm * finger_mm + 2.25 * widen * widen * dn2)
        c_s = a_c * (1.0 - min(flevel[t], 0.9)) ** (1.0 / 3.0)
        for m in range(pts.shape[0]):
            rx = pts[m, 0] - finger[0]
            ry = pts[m, 1] - finger[1]
            dist2 = rx * rx + ry * ry
            if falloff == 0:
                w = math.exp(-dist2 * inv_s2)
            elif falloff == 1:
                w = (1.0 + dist2 * inv_s2) ** -0.75
            elif falloff == 3:
                w = pasternak_falloff(dist2, s2)
            else:
                r = math.sqrt(dist2)
                if r <= c_s:
                    w = 1.0
                elif r <= a_c:
                    w = 1.0 - 0.15 * (0.5 - 0.5 * math.cos(math.pi * (r - c_s) / max(a_c - c_s, 1e-9)))
                else:
                    w = 0.85 * a_c / r
            drag[t, m, 0] += w * d[t, 0]
            drag[t, m, 1] += w * d[t, 1]
            weight[t, m] += w
            p = press * level[t] * math.exp(-dist2 * inv_f2)
            disp[t, m, 0] += spread * p * rx / finger_mm
            disp[t, m, 1] += spread * p * ry / finger_mm
            if dim_max * p > dim[t, m]:
                dim[t, m] = dim_max * p
            if indent > 0.0:
                gr = indent * press * level[t] * hertz_deflection(math.sqrt(dist2) / finger_mm)
                if gr > grow[t, m]:
                    grow[t, m] = gr


def _keep_inside(points_mm: np.ndarray, gel_radius_mm: float) -> np.ndarray:
    """Pull points (..., 2) mm pushed beyond 90 % of the gel radius smoothly back under 98 % of
    it (r -> r0 + (R - r0) tanh((r - r0) / (R - r0)): monotonic, so nothing folds)."""
    r0, r_max = 0.9 * gel_radius_mm, 0.98 * gel_radius_mm
    r = np.hypot(points_mm[..., 0], points_mm[..., 1])
    far = r > r0
    if not far.any():
        return points_mm
    scale = np.ones_like(r)
    scale[far] = (r0 + (r_max - r0) * np.tanh((r[far] - r0) / (r_max - r0))) / r[far]
    return points_mm * scale[..., None]


def deform(
    gestures: Sequence[SimGesture],
    points_mm: np.ndarray,
    t_us: np.ndarray,
    gel_radius_mm: float,
    physics: Physics = PHYSICS["default"],
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Where material points of the gel are at times t_us, how much they are dimmed and magnified.

    Args:
        gestures: the gestures that may deform the gel in this time span.
        points_mm: (M, 2) float64 rest positions, user frame (mm).
        t_us: (T,) int64 times (us).
        gel_radius_mm: the clamped rim's radius (mm).
        physics: the family (its falloff and indentation; :mod:`neurotouch_hid.sources.physics`).
    Returns:
        positions (T, M, 2) float64 user frame (mm); dimming (T, M) float64 in 0..1 (0 = none);
        magnification (T, M) float64 >= 0 (relative growth of the marker's image, 0 = none).
    """
    pts = np.asarray(points_mm, dtype=np.float64)
    n_t = len(t_us)
    to_rim = RIM_CLAMP * gel_radius_mm - np.hypot(pts[:, 0], pts[:, 1])  # (M,) mm
    disp = np.zeros((n_t, len(pts), 2))
    dim = np.zeros((n_t, len(pts)))
    grow = np.zeros((n_t, len(pts)))
    levels = []
    for g in gestures:
        level = g.profile(t_us)
        levels.append(level)
        if not level.any():
            continue
        f_levels = g.finger_levels(t_us)  # (T, K)
        d_f = g.finger_displacements(f_levels)  # (T, K, 2)
        if g.slide:  # the fingers on the gel slide together (the ``starts`` family)
            d_f = d_f + g.slide_displacement(t_us)[:, None, :] * (f_levels > 0)[..., None]
        local = np.zeros_like(disp)
        drag = np.zeros_like(disp)
        weight = np.zeros_like(dim)
        # fingers pushing together add their strains: widen their falloff with their number
        widen = 0.8 * (len(g.fingers_mm) if g.gesture is GestureType.PUSH else 1)
        for k in range(len(g.fingers_mm)):
            _finger_field(
                pts,
                g.fingers_mm[k],
                np.ascontiguousarray(d_f[:, k]),
                g.finger_mm,
                widen,
                g.press,
                level,
                np.ascontiguousarray(f_levels[:, k]),
                physics.falloff,
                g.squeeze,
                physics.indent,
                drag,
                weight,
                local,
                dim,
                grow,
            )
        # where fingers' falloffs overlap, blend their motions instead of adding them (the
        # surface under a finger moves with that finger, whatever the others do)
        local += drag / np.maximum(weight, 1.0)[..., None]
        # the clamped rim holds the gel: the displacement eases out over a length that grows
        # with the fingers' displacement (strain <= 2 |u| / length <= 0.8 at the rim)
        length = np.maximum(RIM_EASE_MM, 2.5 * np.linalg.norm(d_f, axis=-1).max(axis=1))  # (T,)
        x = np.clip(to_rim[None, :] / length[:, None], 0.0, 1.0)
        disp += local * (1.0 - (1.0 - x) ** 2)[..., None]
    out = _keep_inside(pts[None] + disp, gel_radius_mm)
    for g, level in zip(gestures, levels):
        if not level.any():
            continue
        phi = level * g.global_rad
        c, s = np.cos(phi)[:, None], np.sin(phi)[:, None]
        x = c * out[..., 0] - s * out[..., 1] + level[:, None] * g.global_mm[0]
        y = s * out[..., 0] + c * out[..., 1] + level[:, None] * g.global_mm[1]
        out = np.stack([x, y], axis=-1)
    return out, dim, grow
