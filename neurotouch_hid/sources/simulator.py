"""The simulated NeuroTouch gel: dome, markers, fingers, gestures, camera, labels.

What is simulated (paper, sections "System Overview", "Problem Statement" and "Creation of the
Gesture Detection Dataset"):

* **The gel** -- a 60 mm silicone dome (a spherical cap of radius :data:`DOME_SPHERE_MM` over a
  30 mm base) with white 1 mm markers on a 4 mm grid laid on its surface (the grid is centred on
  the apex and kept where the arc length from the apex is below :data:`MARKER_ARC_MM`: exactly
  177 markers). The camera inside looks up through the base: a marker at arc length s from the
  apex is seen at base-plane radius ``R sin(s / R)`` (orthographic), i.e. 2.5 px/mm at the
  centre and foreshortened towards the rim. All markers lie inside the gel circle of
  ``sensor.yaml`` (the base, 30 mm = 75 px). Deformations are modelled in the base plane, which
  is the user frame of docs/dataset.md (mm, x right, y up, seen from outside); image positions come
  from :meth:`SensorGeometry.user_to_image` (the mirror included).
* **Fingers and gestures** -- push, pinch, zoom, twist_cw, twist_ccw with 1-3 fingers, each
  with attack (cosine ramp up), hold (the maximum, with a small tremor) and release (cosine ramp
  down), then the gel creeps back (exponential, tau ~ 0.1 s) from a small residual. A finger
  drags the markers under it with it; the others follow with a Gaussian falloff whose width is
  the finger's footprint, widened for large displacements (and for fingers pushing together)
  so that the gel never folds; where fingers' falloffs overlap their motions blend. Pressing
  also spreads the markers under a finger radially (<= 0.35 mm) and dims them (<= 25 %); the whole
  gel moves a little with the gesture (<= 0.35 mm translation, <= 0.35 deg rotation). The rim is
  clamped: the displacement fades out towards it and nothing is pushed past 98 % of the radius.
* **Users** -- :data:`USERS` defines 10 simulated users with their own finger size, speed,
  intensity and hold/rest habits. Users 0-4 (:data:`TEST_USERS`) are the test users, users
  5-9 (:data:`TUNING_USERS`) are for tuning; the ``paper`` preset takes the test users for an
  even seed and the tuning users for an odd seed (:func:`preset_users`), so tuning never sees a
  test user. Contacts are drawn around the gel's centre with a slight bias to the right of the
  image, as the paper's contact distribution shows.
* **The camera** -- a DAVIS-346 (346x260): APS frames at 25 Hz (exposure 4 ms, averaged over
  several renders, read noise and shot noise, uint8, background ~20, markers ~220) and events
  from ESIM (:mod:`neurotouch_hid.sources.esim`).

* **Physics families** -- everything above is the ``default`` family; other families
  (:mod:`neurotouch_hid.sources.physics`, ``simulate --physics NAME|mix``) change one aspect of
  it (displacement falloff, contact mechanics, indentation, camera model, global motion, finger
  timing and strength, very strong presses, marker spread, sensor noise, light flicker, a
  viscoelastic gel that creeps and relaxes slowly, a gel on a shear-coupled foundation, a longer
  APS exposure in dim light, an event sensor biased for a higher contrast threshold).

Labels (docs/dataset.md) per APS frame: a gesture is labelled from its attack's start (the first
instant its fingers move the gel) up to, not including, the end of its release (the fingers have
left the gel); everything else is ``none`` with no contact. ``resting`` is 0 during a gesture
and after it until every marker is back within :data:`REST_TOLERANCE_MM` of its rest position.
The contact points are the surface points that were under the finger centres when the gesture
began, where they are now (the gel's largest deformation under each finger); ``intensity_mm``
is their mean displacement since the gesture began, in the user frame (mm). A frame's
timestamp is the start of its 4 ms exposure (as DV records it) and its label describes the gel
at that instant.
"""

from __future__ import annotations

import functools
import itertools
import math
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Iterable, Iterator, Sequence

import numba
import numpy as np

from neurotouch_hid.core.dataset import LabelRow, write_labels, write_pressed
from neurotouch_hid.core.errors import NeurotouchError
from neurotouch_hid.core.estimate import GestureType
from neurotouch_hid.core.sensor import DOME_SPHERE_MM, MARKER_SPACING_MM, SensorGeometry
from neurotouch_hid.sources import EVENT_DTYPE, Frame, StreamItem
from neurotouch_hid.sources.esim import (
    CONTRAST,
    CONTRAST_SIGMA,
    NOISE_RATE_HZ,
    EventCamera,
    noise_sigma,
    read_out,
    render_exposure,
    render_frame,
)
from neurotouch_hid.sources.physics import (
    PHYSICS,
    DomeCamera,
    Physics,
    hertz_deflection,
    mix_families,
    pasternak_falloff,
    physics_family,
    sls_deformation,
)
from neurotouch_hid.sources.recording import RecordingWriter, split_batches

#: Gesture types that the simulated users perform (paper, section "Problem Statement").
SIM_GESTURES: tuple[GestureType, ...] = (
    GestureType.PUSH,
    GestureType.PINCH,
    GestureType.ZOOM,
    GestureType.TWIST_CW,
    GestureType.TWIST_CCW,
)
#: The live steady hand's cycle (:class:`SimulatedSource`): four pushes, up, right, down and left
#: in turn (:data:`PUSH_TURNS`), between the other types, so that one cycle tries a stick, a
#: d-pad or a key of each direction and each twist.
STEADY_GESTURES: tuple[GestureType, ...] = (
    GestureType.PUSH,
    GestureType.TWIST_CW,
    GestureType.PUSH,
    GestureType.TWIST_CCW,
    GestureType.PUSH,
    GestureType.PINCH,
    GestureType.PUSH,
    GestureType.ZOOM,
)
#: The steady hand's push directions, one push after the other: up, right, down, left (user
#: frame, rad counter-clockwise from x right).
PUSH_TURNS: tuple[float, ...] = (math.pi / 2, 0.0, -math.pi / 2, math.pi)
#: Marker grid spacing on the gel surface (mm: the sensor's) and the marker diameter (mm).
MARKER_PITCH_MM = MARKER_SPACING_MM
MARKER_DIAMETER_MM = 1.0
#: Markers are printed where the arc length from the apex is below this (mm): 177 markers.
MARKER_ARC_MM = 29.8
#: APS frame period and exposure (us); the DAVIS-346 frames at 25 Hz.
FRAME_PERIOD_US = 40_000
EXPOSURE_US = 4_000
#: Time of a sequence's first APS frame (us, camera clock).
START_US = 1_000_000
#: The gel is at rest when every marker is within this of its rest position (mm).
REST_TOLERANCE_MM = 0.1
#: A finger has pressed once the gel under it has moved this far (mm): about where the tracker
#: sees a finger (docs/dataset.md, "Per-gesture metrics").
PRESSED_MM = 0.3
#: Grey levels: gel background (at the centre), outside the gel, marker peak above background.
BACKGROUND_GREY = 20.0
OUTSIDE_GREY = 6.0
MARKER_GREY = 200.0
#: APS noise: read noise sigma (grey levels) and shot noise sigma at grey level 1 (~ sqrt(level)).
READ_NOISE = 1.5
SHOT_NOISE = 0.22
#: Fastest intensity change a simulated user makes (mm/s; paper: up to 210 mm/s).
MAX_SPEED_MM_S = 205.0
#: Largest finger displacement at the hold (mm): with the clamped rim holding the gel back, the
#: contacts move up to ~18 mm (paper: local deformations up to 18 mm).
MAX_INTENSITY_MM = 23.0
#: The displacement fades out towards this multiple of the gel radius (the clamped base), over
#: at least RIM_EASE_MM (mm).
RIM_CLAMP = 1.0
RIM_EASE_MM = 6.0
#: How long after its release a gesture still deforms the gel, in creep time constants.
CREEP_SPAN_TAUS = 7.0
#: Spread (sigma of the log) of a user's gesture strengths about the median for the type.
STRENGTH_SIGMA = 0.55
#: A late finger (the ``late`` family) starts moving at most this share of the attack after the
#: first, so that it still ramps up before the hold.
LATEST_LAG = 0.8
#: Distance of a multi-finger gesture's fingers from their centre (mm, uniform in this range).
FINGER_SPREAD_MM = (9.0, 15.0)
#: Time step (us) of a viscoelastic gel's deformation history (SimGesture.profile).
SLS_STEP_US = 1000


# --- users ------------------------------------------------------------------------------------
@dataclass(frozen=True)
class SimUser:
    """One simulated user's habits.

    Attributes:
        user_id: 0..9; sequences are named ``u{user_id}_{gesture}``.
        finger_mm: footprint of a fingertip on the gel, the sigma of the displacement falloff (mm).
        speed: multiplies the speed of attacks and releases (1 = median user).
        intensity_mm: median hold intensity of a push (mm); other gestures are weaker.
        hold: multiplies the hold duration; rest: multiplies the rests between gestures.
        bias_mm: how far right of the gel's centre, in the image, the user's contacts centre (mm).
    """

    user_id: int
    finger_mm: float
    speed: float
    intensity_mm: float
    hold: float
    rest: float
    bias_mm: float


#: The simulated users (ids 0-9).
USERS: tuple[SimUser, ...] = (
    SimUser(0, 7.0, 1.00, 5.0, 1.0, 1.0, 1.5),
    SimUser(1, 6.2, 1.35, 4.0, 0.8, 0.9, 2.5),
    SimUser(2, 7.8, 0.80, 6.5, 1.3, 1.2, 1.0),
    SimUser(3, 6.6, 1.15, 3.5, 0.9, 1.0, 3.0),
    SimUser(4, 7.4, 0.90, 7.0, 1.1, 1.1, 0.5),
    SimUser(5, 6.4, 1.25, 4.5, 0.9, 0.9, 2.0),
    SimUser(6, 7.6, 0.85, 5.5, 1.2, 1.1, 1.2),
    SimUser(7, 6.8, 1.05, 6.0, 1.0, 1.0, 2.8),
    SimUser(8, 7.2, 0.95, 3.8, 1.1, 1.2, 0.8),
    SimUser(9, 6.0, 1.20, 5.2, 0.8, 0.9, 1.8),
)
#: Users of evaluations (paper preset, even seeds) and of tuning (paper preset, odd seeds).
TEST_USERS: tuple[int, ...] = (0, 1, 2, 3, 4)
TUNING_USERS: tuple[int, ...] = (5, 6, 7, 8, 9)
#: Dataset presets: simulated seconds per sequence (``quick``, ``paper``: one sequence per user
#: and gesture type; ``sessions``: one game session per user, :func:`gesture_script` with ``session``).
PRESET_SECONDS: dict[str, float] = {"quick": 3.0, "paper": 60.0, "sessions": 10.0}


def preset_users(preset: str, seed: int) -> tuple[int, ...]:
    """The user ids a preset simulates for a seed.

    ``paper`` and ``sessions``: the 5 test users (0-4) for an even seed, the 5 tuning users (5-9)
    for an odd seed. ``quick``: one user, ``seed % 10``. Raises NeurotouchError for an unknown
    preset.
    """
    if preset in ("paper", "sessions"):
        return TEST_USERS if seed % 2 == 0 else TUNING_USERS
    if preset == "quick":
        return (seed % len(USERS),)
    raise NeurotouchError(f"unknown simulation preset {preset!r}: expected one of {', '.join(PRESET_SECONDS)}")


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


def draw_gesture(
    rng: np.random.Generator,
    user: SimUser,
    gesture: GestureType,
    t_start_us: int,
    sensor: SensorGeometry,
    physics: Physics = PHYSICS["default"],
    physics_rng: np.random.Generator | None = None,
    steady: bool = False,
    direction_rad: float | None = None,
) -> SimGesture:
    """Draw one gesture of ``user`` starting at ``t_start_us`` (us): fingers, intensity, speed.

    The distributions follow the paper's dataset statistics (appendix figures): hold intensities
    mostly 0-6 mm with a tail to 18 mm, zoom the weakest and push the strongest; intensity
    speeds up to ~210 mm/s; push mostly with 1 finger, the others with 2-3; contacts anywhere on
    the gel but the rim, with a slight rightward bias in the image.

    A family that changes the gestures (:attr:`Physics.changes_gestures`: ``strong``, ``drift``,
    ``fingers``) draws its changes from ``physics_rng`` after the default draws from ``rng``, so
    that the default family's gestures stay what they were.

    ``steady``: every gesture of a type as strong as the next, firmly (one :data:`STRENGTH_SIGMA`
    above the user's median for the type, within the narrowest finger spread's cap for pinch and
    zoom; pushes with one finger), so that the two twists and the push directions weigh the same
    and a profile's saturations are reached (the live simulated hand, :class:`SimulatedSource`); the same draws
    are made, so nothing else changes.

    ``direction_rad``: a push's direction (user frame, counter-clockwise from x, rad) instead of a
    drawn one (a prompted push, :func:`prompted_gesture`; the steady hand's turns,
    :data:`PUSH_TURNS`); the draw is still made.
    """
    prng = physics_rng if physics_rng is not None else np.random.default_rng(0)
    if gesture is GestureType.PUSH:
        n_fingers = int(rng.choice([1, 2, 3], p=[0.75, 0.18, 0.07]))
        n_fingers = 1 if steady else n_fingers  # wider hands reach the rim sooner: a weaker push
    else:
        n_fingers = int(rng.choice([2, 3], p=[0.65, 0.35]))
    finger = user.finger_mm * rng.uniform(0.9, 1.1)
    factor = {GestureType.PUSH: 1.2, GestureType.ZOOM: 0.7}.get(gesture, 0.85)
    median = user.intensity_mm * factor
    amplitude = float(np.clip(rng.lognormal(math.log(median), STRENGTH_SIGMA), 0.8, MAX_INTENSITY_MM))
    if steady:
        amplitude = min(median * math.exp(STRENGTH_SIGMA), MAX_INTENSITY_MM)
    if physics.strong > 0 and prng.random() < physics.strong:
        amplitude = float(prng.uniform(12.0, 20.0))
    bias = sensor.vectors_image_to_user(np.array([user.bias_mm * sensor.px_per_mm, 0.0]))
    limit = 0.8 * sensor.gel_radius_mm  # fingers stay off the rim

    if gesture is GestureType.PUSH:
        angle = rng.uniform(0, 2 * math.pi)
        angle = angle if direction_rad is None else direction_rad
        direction = np.array([math.cos(angle), math.sin(angle)])
        across = np.array([-direction[1], direction[0]])
        offsets = (np.arange(n_fingers) - (n_fingers - 1) / 2)[:, None] * across * rng.uniform(14.0, 18.0)
    else:
        direction = np.zeros(2)
        spread = rng.uniform(*FINGER_SPREAD_MM)
        angles = rng.uniform(0, 2 * math.pi) + 2 * math.pi * np.arange(n_fingers) / n_fingers
        angles += rng.normal(0.0, 0.15, n_fingers)
        offsets = spread * np.stack([np.cos(angles), np.sin(angles)], axis=1)
        cap = {GestureType.PINCH: 0.55, GestureType.ZOOM: 0.5}.get(gesture, 1.2) * spread
        if physics.strong > 0:  # very strong pinches and zooms: the fingers travel further
            cap = {GestureType.PINCH: 0.7, GestureType.ZOOM: 0.65}.get(gesture, 1.2) * spread
        amplitude = min(amplitude, cap * FINGER_SPREAD_MM[0] / spread if steady else cap)
    reach = float(np.linalg.norm(offsets, axis=1).max())
    # the centre: Gaussian about the (biased) gel centre, kept so that fingers stay off the rim
    room = max(0.0, limit - reach - (amplitude if gesture in (GestureType.PUSH, GestureType.ZOOM) else 0.0))
    if room == 0.0 and gesture is GestureType.PUSH:
        amplitude = max(0.8, limit - reach)
        room = max(0.0, limit - reach - amplitude)
    centre = rng.normal(0.0, 7.0, 2) + bias
    norm = float(np.linalg.norm(centre))
    if norm > room:
        centre *= room / max(norm, 1e-9)
    fingers = centre + offsets

    speed = user.speed * rng.lognormal(0.0, 0.45)
    min_ramp_us = math.pi * amplitude / (2 * MAX_SPEED_MM_S) * 1e6  # cosine ramp peak speed
    attack = int(max(min_ramp_us, 0.4e6 * rng.lognormal(0.0, 0.45) / speed))
    release = int(max(min_ramp_us, 0.3e6 * rng.lognormal(0.0, 0.45) / speed))
    hold = int(1.0e6 * user.hold * rng.lognormal(0.0, 0.5))
    extra: dict = {}
    if physics.lag > 0 or physics.lag_ms > 0:
        top = physics.lag * attack if physics.lag > 0 else min(physics.lag_ms * 1000.0, LATEST_LAG * attack)
        low = min(physics.lag_ms_min * 1000.0, top)
        lags = prng.uniform(low, top, n_fingers)
        lags[int(prng.integers(n_fingers))] = 0.0  # the first finger starts the gesture
        extra["lags_us"] = tuple(int(v) for v in lags)
    if physics.slide > 0 and gesture is not GestureType.PUSH and prng.random() < physics.slide:
        angle = prng.uniform(0, 2 * math.pi)
        size = prng.uniform(0.4, 0.8) * amplitude
        start, duration = int(prng.uniform(10e3, 160e3)), int(prng.uniform(20e3, 40e3))
        extra["slide"] = (start, duration, size * math.cos(angle), size * math.sin(angle))
    if physics.strength_min < 1:
        strengths = prng.uniform(physics.strength_min, 1.0, n_fingers)
        extra["strengths"] = tuple(float(v) for v in strengths / strengths.max())
    if physics.squeeze > 0:
        extra["squeeze"] = physics.squeeze
    if physics.creep > 0:
        extra["sls"] = (physics.creep, int(physics.creep_s * 1e6))
    # the default stream's draws, in their historical order
    press = float(rng.uniform(0.3, 1.0))
    tremor = (float(rng.uniform(0.01, 0.04)), float(rng.uniform(3.0, 8.0)), float(rng.uniform(0, 2 * math.pi)))
    global_mm = rng.normal(0.0, 0.15, 2).clip(-0.3, 0.3)
    global_rad = float(rng.normal(0.0, 0.003))
    residual = float(rng.uniform(0.02, 0.05))
    creep_us = int(rng.uniform(60e3, 120e3))
    if physics.global_mm != (0.15, 0.3) or physics.global_rad != (0.003, math.inf):
        global_mm = prng.normal(0.0, physics.global_mm[0], 2).clip(-physics.global_mm[1], physics.global_mm[1])
        global_rad = float(
            np.clip(prng.normal(0.0, physics.global_rad[0]), -physics.global_rad[1], physics.global_rad[1])
        )
    return SimGesture(
        gesture=gesture,
        t_start_us=int(t_start_us),
        attack_us=attack,
        hold_us=hold,
        release_us=release,
        fingers_mm=fingers,
        amplitude_mm=amplitude,
        direction=direction,
        finger_mm=finger,
        press=press,
        tremor=tremor,
        global_mm=global_mm,
        global_rad=global_rad,
        residual=residual,
        creep_us=creep_us,
        **extra,
    )


def draw_rest_us(rng: np.random.Generator, user: SimUser) -> int:
    """A rest (us) between a gesture's settling (creep done) and the next gesture's attack."""
    return int(max(0.3e6, 0.9e6 * user.rest * rng.lognormal(0.0, 0.35)))


def gesture_script(
    rng: np.random.Generator,
    user: SimUser,
    gestures: Iterable[GestureType],
    start_us: int,
    sensor: SensorGeometry,
    first_rest_us: int = 600_000,
    physics: Physics = PHYSICS["default"],
    physics_rng: np.random.Generator | None = None,
    steady: bool = False,
    session: bool = False,
) -> Iterator[SimGesture]:
    """An endless succession of gestures of ``user`` drawn for the family ``physics`` (the first
    starts ``first_rest_us`` after ``start_us``): cycling through ``gestures``
    (:func:`draw_gesture`, ``steady`` or not: a steady hand pushes in the :data:`PUSH_TURNS` in
    turn), each after the previous one has settled and a rest
    (:func:`draw_rest_us`); or, with ``session``, a game session: the type changes from one
    gesture to the next, taps, ordinary gestures and long holds (:func:`session_gesture`), rests
    of a fraction of a second (:data:`SESSION_REST_US`, from the release's end: the gel may
    still creep back when the next gesture begins)."""
    order = list(gestures)
    t = start_us + first_rest_us
    k, previous, pushes = 0, None, 0
    while True:
        if session:
            g = session_gesture(rng, user, order, previous, t, sensor, physics, physics_rng)
        else:
            kind = order[k % len(order)]
            turn = PUSH_TURNS[pushes % len(PUSH_TURNS)] if steady and kind is GestureType.PUSH else None
            pushes += kind is GestureType.PUSH
            g = draw_gesture(rng, user, kind, t, sensor, physics, physics_rng, steady, direction_rad=turn)
        yield g
        previous, k = g.gesture, k + 1
        t = g.t_end_us + int(rng.uniform(*SESSION_REST_US)) if session else g.t_settled_us + draw_rest_us(rng, user)


# --- game sessions ----------------------------------------------------------------------------
#: How long the gestures of a game session last, and how often: a tap (attack start to release
#: end, us), an ordinary gesture (:func:`draw_gesture`'s timing) or a long hold (the hold alone, us).
SESSION_KINDS: dict[str, float] = {"tap": 0.3, "ordinary": 0.45, "hold": 0.25}
TAP_US = (250_000, 500_000)
LONG_HOLD_US = (2_500_000, 5_000_000)
#: A session's rests: from a gesture's release end (the fingers have left) to the next attack (us).
SESSION_REST_US = (150_000, 700_000)
#: Sessions' random streams start here (stream_seed (user, SESSION_STREAM + k)), apart from the
#: per-gesture sequences' (user, 0..4).
SESSION_STREAM = 100


def session_gesture(
    rng: np.random.Generator,
    user: SimUser,
    gestures: Sequence[GestureType],
    previous: GestureType | None,
    t_start_us: int,
    sensor: SensorGeometry,
    physics: Physics = PHYSICS["default"],
    physics_rng: np.random.Generator | None = None,
) -> SimGesture:
    """One gesture of a game session: a type other than ``previous`` (drawn uniformly among
    ``gestures``; the same only when there is one type), drawn by :func:`draw_gesture`, then made
    a tap, an ordinary gesture or a long hold (:data:`SESSION_KINDS`).

    A tap lasts :data:`TAP_US` from attack start to release end (:func:`as_tap`). A long hold
    holds for :data:`LONG_HOLD_US`.
    """
    choices = [g for g in gestures if g is not previous] or list(gestures)
    kind = choices[int(rng.integers(len(choices)))]
    g = draw_gesture(rng, user, kind, t_start_us, sensor, physics, physics_rng)
    names = list(SESSION_KINDS)
    length = names[int(rng.choice(len(names), p=list(SESSION_KINDS.values())))]
    if physics.short_taps and kind is not GestureType.PUSH:  # the family's own taps (``starts``)
        prng = physics_rng if physics_rng is not None else np.random.default_rng(0)
        share, shortest, longest = physics.short_taps
        if prng.random() < share:
            return as_tap(g, int(prng.uniform(shortest, longest)), physics)
    if length == "tap":
        return as_tap(g, int(rng.uniform(*TAP_US)), physics)
    if length == "hold":
        return replace(g, hold_us=int(rng.uniform(*LONG_HOLD_US)))
    return g


def as_tap(g: SimGesture, total_us: int, physics: Physics = PHYSICS["default"]) -> SimGesture:
    """``g`` made a tap of ``total_us`` from attack start to release end (attack 35 %, hold 30 %,
    release 35 %), its intensity capped so that the attack stays under :data:`MAX_SPEED_MM_S`; a
    lagging finger's lag (the ``fingers`` family) scales with the attack, a late one (``late``)
    lands as late, within the shorter attack."""
    attack, hold = int(0.35 * total_us), int(0.3 * total_us)
    amplitude = min(g.amplitude_mm, 2.0 * MAX_SPEED_MM_S * attack * 1e-6 / math.pi)
    if physics.lag_ms > 0:
        lags = tuple(int(min(lag, LATEST_LAG * attack)) for lag in g.lags_us)
    else:
        lags = tuple(int(lag * attack / g.attack_us) for lag in g.lags_us)
    return replace(
        g,
        attack_us=attack,
        hold_us=hold,
        release_us=int(total_us) - attack - hold,
        amplitude_mm=amplitude,
        lags_us=lags,
    )


#: A prompted gesture held for less than this (s) is a tap (:func:`prompted_gesture`).
TAP_MAX_S = 1.0


def prompted_gesture(
    rng: np.random.Generator,
    user: SimUser,
    gesture: GestureType,
    t_start_us: int,
    seconds: float,
    sensor: SensorGeometry,
    physics: Physics = PHYSICS["default"],
    physics_rng: np.random.Generator | None = None,
    direction: Sequence[float] | None = None,
) -> SimGesture:
    """A gesture a prompt asked for, as ``user`` performs it (an enrolment's simulated hand):
    drawn by :func:`draw_gesture` (a push towards ``direction``, user frame, when given), then
    a tap lasting ``seconds`` in all (:func:`as_tap`) when ``seconds`` < :data:`TAP_MAX_S`, else
    held for ``seconds`` (its attack and release as drawn).

    Raises:
        ValueError: ``gesture`` is NONE, ``seconds`` is not positive, or ``direction`` has no length.
    """
    if gesture is GestureType.NONE:
        raise ValueError("a prompted gesture needs a gesture type, not none")
    if not seconds > 0:
        raise ValueError(f"a prompted gesture lasts a positive time, got {seconds} s")
    angle = None
    if direction is not None:
        if math.hypot(*direction) == 0:
            raise ValueError("a prompted push needs a direction")
        angle = math.atan2(direction[1], direction[0])
    g = draw_gesture(rng, user, gesture, t_start_us, sensor, physics, physics_rng, direction_rad=angle)
    if seconds < TAP_MAX_S:
        return as_tap(g, int(seconds * 1e6), physics)
    return replace(g, hold_us=int(seconds * 1e6))


#: The guided hand (:func:`guided_gesture`): a push's travel, a pinch's, zoom's and twist's
#: finger travel (mm; the same for both twists, so neither reads weaker), its two fingers' distance
#: from the gel's centre (mm), and its attack, hold and release (us).
GUIDED_PUSH_MM = 4.0
GUIDED_TRAVEL_MM = 3.0
GUIDED_SPREAD_MM = 8.0
GUIDED_PHASES_US = (300_000, 900_000, 300_000)


def guided_gesture(
    gesture: GestureType, t_start_us: int, direction: Sequence[float] = (0.0, 1.0), user: SimUser = USERS[0]
) -> SimGesture:
    """The gesture a calibration asks for, as a steady hand performs it: one finger at the gel's
    centre pushing :data:`GUIDED_PUSH_MM` towards ``direction`` (user frame, normalised), or two
    fingers :data:`GUIDED_SPREAD_MM` left and right of the centre moving :data:`GUIDED_TRAVEL_MM`
    (pinch, zoom, twist either way); :data:`GUIDED_PHASES_US`, no tremor, no global motion.

    Raises:
        ValueError: ``gesture`` is NONE, or a push's ``direction`` has no length.
    """
    if gesture is GestureType.NONE:
        raise ValueError("a guided gesture needs a gesture type, not none")
    if gesture is GestureType.PUSH:
        fingers = np.zeros((1, 2))
        norm = math.hypot(*direction)
        if norm == 0:
            raise ValueError("a guided push needs a direction")
        unit = np.asarray(direction, dtype=np.float64) / norm
        amplitude = GUIDED_PUSH_MM
    else:
        fingers = np.array([[-GUIDED_SPREAD_MM, 0.0], [GUIDED_SPREAD_MM, 0.0]])
        unit = np.zeros(2)
        amplitude = GUIDED_TRAVEL_MM
    attack, hold, release = GUIDED_PHASES_US
    return SimGesture(
        gesture=gesture,
        t_start_us=int(t_start_us),
        attack_us=attack,
        hold_us=hold,
        release_us=release,
        fingers_mm=fingers,
        amplitude_mm=amplitude,
        direction=unit,
        finger_mm=user.finger_mm,
        press=0.6,
        tremor=(0.0, 5.0, 0.0),
        global_mm=np.zeros(2),
        global_rad=0.0,
        residual=0.03,
        creep_us=80_000,
    )


# --- the simulation engine --------------------------------------------------------------------
@dataclass(frozen=True)
class SimChunk:
    """One APS frame period of simulation.

    Attributes:
        frame: the APS frame at the period's start.
        events: EVENT_DTYPE events with frame.t_us <= timestamp < next frame's t_us, time-ordered.
        label: the frame's label (docs/dataset.md).
        t_us: (T,) int64 1 ms grid from frame.t_us (T = 40 at 25 Hz).
        positions_px: (T, N, 2) float32 true marker positions (image px) at t_us.
    """

    frame: Frame
    events: np.ndarray
    label: LabelRow
    t_us: np.ndarray
    positions_px: np.ndarray


@dataclass(frozen=True)
class RestPeriod:
    """What an APS frame period of the gel at rest is made of, the same for every such period
    (no gesture deforms the gel, the light is steady): computed once, reused while the gel rests.

    Attributes:
        positions_px, amp, sigma, positions_mm: :meth:`GelSimulator.marker_state` on a frame
            period's 1 ms grid (T samples): (T, N, 2) float64 image px, (T, N) grey levels, (T, N)
            px, (T, N, 2) float64 user mm.
        image: (H, W) float64 the light of the APS frame's exposure (:func:`esim.render_exposure`);
            image_sigma: (H, W) float64 its read-out noise (:func:`esim.noise_sigma`).
        settled: every marker within :data:`REST_TOLERANCE_MM` of its rest position (the label's
            ``resting``).
    """

    positions_px: np.ndarray
    amp: np.ndarray
    sigma: np.ndarray
    positions_mm: np.ndarray
    image: np.ndarray
    image_sigma: np.ndarray
    settled: bool


class GelSimulator:
    """Runs a gesture script through the gel and the camera, one APS frame period at a time.

    Args:
        sensor: geometry (default: docs/dataset.md's DAVIS-346 NeuroTouch).
        user: the simulated user.
        gestures: gesture types to cycle through.
        seed: the camera's and gel's seed (thresholds, hot pixels, marker brightness).
        stream_seed: the script's and noise's seed.
        start_us: time of the first APS frame (us).
        script: the gestures to perform (time-ordered, each starting after the previous one's
            release ends; the earlier one's creep may overlap the next) instead of drawing them
            for ``user``; may be finite.
        hand: how the gestures are drawn when there is no ``script``: ``drawn`` cycles through
            ``gestures`` with rests until the gel settles (:func:`gesture_script`), ``steady`` the
            same with every gesture of a type equally strong (:func:`draw_gesture`), ``session``
            a game session (:func:`gesture_script` with ``session``).
        noise_rate_hz: the event camera's background-activity rate per pixel (Hz, >= 0;
            ``EventCamera``). The gestures do not depend on it; the noise's random stream (shared
            with the APS frames' noise) does. A family with its own rate (``noise``) overrides it.
        physics: the gel and camera family (:mod:`neurotouch_hid.sources.physics`; default
            today's model). Its own draws come from a separate random stream, so the default
            family's files do not change.
        reuse_rest: while the gel rests (no gesture deforms it, the light is steady) reuse what
            does not change from one APS frame period to the next (:class:`RestPeriod`; the
            camera's ESIM left out while the markers hold still, ``EventCamera(skip_still=)``): the
            same chunks, sooner. False computes every period from scratch.
    Raises:
        ValueError: ``noise_rate_hz`` < 0.
    """

    def __init__(
        self,
        sensor: SensorGeometry | None = None,
        user: SimUser = USERS[0],
        gestures: Iterable[GestureType] = SIM_GESTURES,
        seed: int = 0,
        stream_seed: Sequence[int] = (0,),
        start_us: int = START_US,
        script: Iterable[SimGesture] | None = None,
        noise_rate_hz: float = NOISE_RATE_HZ,
        physics: Physics = PHYSICS["default"],
        hand: str = "drawn",
        reuse_rest: bool = True,
    ) -> None:
        self.sensor = sensor or SensorGeometry()
        self.physics = physics
        camera_rng = np.random.default_rng(np.random.SeedSequence([seed, 0xCA3E]))
        script_ss, noise_ss = np.random.SeedSequence([seed, *stream_seed]).spawn(2)
        gel_ss, gesture_ss = np.random.SeedSequence([seed, *stream_seed, 0xFA3]).spawn(2)
        self.gel = Gel(self.sensor, camera_rng, physics, np.random.default_rng(gel_ss))
        rate = noise_rate_hz if physics.noise_hz is None else physics.noise_hz
        if not float(noise_rate_hz) >= 0.0:
            raise ValueError(f"noise_rate_hz must be >= 0 Hz per pixel, got {noise_rate_hz}")
        self.camera = EventCamera(
            self.gel.background,
            self.gel.rest_px,
            self.gel.brightness,
            self.gel.sigma_px,
            camera_rng,
            eps_px=0.05,
            contrast=CONTRAST if physics.contrast is None else physics.contrast,
            contrast_sigma=CONTRAST_SIGMA if physics.contrast_sigma is None else physics.contrast_sigma,
            noise_rate_hz=rate,
            n_hot=physics.n_hot,
            hot_rate_hz=physics.hot_rate_hz,
            skip_still=reuse_rest,
        )
        self.reuse_rest = bool(reuse_rest)
        self._rest: RestPeriod | None = None
        self._noise_rng = np.random.default_rng(noise_ss)
        self._noise_bank = camera_rng.standard_normal(1 << 20, dtype=np.float32)
        self._script = (
            iter(script)
            if script is not None
            else gesture_script(
                np.random.default_rng(script_ss),
                user,
                gestures,
                start_us,
                self.sensor,
                physics=physics,
                physics_rng=np.random.default_rng(gesture_ss),
                steady=hand == "steady",
                session=hand == "session",
            )
        )
        self._flicker_phase = float(np.random.default_rng(gel_ss).uniform(0, 2 * math.pi))
        self._known: list[SimGesture] = []
        self.performed: list[SimGesture] = []  # every gesture begun so far, in order
        self._carry = np.zeros(0, dtype=EVENT_DTYPE)
        self.t_us = int(start_us)
        self.user = user

    def _gestures_between(self, t0_us: int, t1_us: int) -> list[SimGesture]:
        while self._script is not None and (not self._known or self._known[-1].t_start_us <= t1_us):
            nxt = next(self._script, None)
            if nxt is None:
                self._script = None
            else:
                self._known.append(nxt)
                self.performed.append(nxt)
        self._known = [g for g in self._known if g.t_settled_us >= t0_us]
        return [g for g in self._known if g.t_start_us <= t1_us and g.t_settled_us >= t0_us]

    def perform(self, gesture: SimGesture) -> None:
        """Add ``gesture`` to what the simulated hand does, for a simulator made with ``script=()``
        that is told each gesture as it goes (a calibration's guided gestures, :func:`guided_gesture`).

        Raises:
            ValueError: the gesture starts before the simulator's time (``t_us``) or before the
                gestures already added have settled.
        """
        if gesture.t_start_us < self.t_us or any(g.t_settled_us > gesture.t_start_us for g in self._known):
            raise ValueError(
                f"a gesture added at {gesture.t_start_us} us starts before the simulator's time ({self.t_us} us) "
                "or before the previous gesture settled"
            )
        self._known.append(gesture)
        self.performed.append(gesture)

    def pressed_us(self, gesture: SimGesture) -> int | None:
        """When the gel under the last of ``gesture``'s fingers to press has moved
        :data:`PRESSED_MM` since the gesture's start (us, on the 1 ms grid; docs/dataset.md,
        "Per-gesture metrics": felt wrong counts from there), or None when no finger's gel moves
        that far. Reads every gesture begun so far (``performed``: a creeping one may overlap)."""
        t_us = np.arange(gesture.t_start_us, gesture.t_end_us + 1, 1000, dtype=np.int64)
        near = [g for g in self.performed if g.t_start_us <= gesture.t_end_us and g.t_settled_us >= gesture.t_start_us]
        pts = deform(near, gesture.fingers_mm, t_us, self.sensor.gel_radius_mm, self.physics)[0]  # (T, K, 2)
        moved = np.linalg.norm(pts - pts[:1], axis=-1) >= PRESSED_MM  # (T, K)
        pressed = [int(t_us[np.argmax(m)]) for m in moved.T if m.any()]
        return max(pressed) if pressed else None

    def light(self, t_us: np.ndarray) -> np.ndarray:
        """(T,) float64 relative brightness of the LED ring at t_us (1 unless the family flickers)."""
        t = np.asarray(t_us, dtype=np.float64)
        if self.physics.flicker <= 0:
            return np.ones_like(t)
        return 1.0 + self.physics.flicker * np.sin(
            2 * math.pi * self.physics.flicker_hz * t * 1e-6 + self._flicker_phase
        )

    def marker_state(
        self, t_us: np.ndarray, gestures: Sequence[SimGesture]
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """True marker positions at t_us (T,): (T, N, 2) float64 image px (the family's camera),
        brightness (T, N) grey levels, blob sigma (T, N) px and positions (T, N, 2) user mm."""
        pos_mm, dim, grow = deform(gestures, self.gel.rest_mm, t_us, self.sensor.gel_radius_mm, self.physics)
        amp = self.gel.brightness[None] * (1.0 - dim)
        if self.physics.flicker > 0:
            amp = amp * self.light(t_us)[:, None]
        sigma = self.gel.sigma_px[None] * (1.0 + grow)
        return self.gel.camera.project(pos_mm), amp, sigma, pos_mm

    def _settled(self, pos_mm: np.ndarray) -> bool:
        """Whether every marker at pos_mm (N, 2) user mm is within :data:`REST_TOLERANCE_MM` of
        its rest position."""
        return bool(np.linalg.norm(pos_mm - self.gel.rest_mm, axis=-1).max() < REST_TOLERANCE_MM)

    def _label(self, t_us: int, gestures: Sequence[SimGesture], pos_mm: np.ndarray) -> LabelRow:
        active = [g for g in gestures if g.t_start_us <= t_us < g.t_end_us]
        if not active:
            return LabelRow(t_us, GestureType.NONE, self._settled(pos_mm), 0.0, np.zeros((0, 2)))
        g = active[0]
        times = np.array([g.t_start_us, t_us], dtype=np.int64)
        pts_mm = deform(gestures, g.fingers_mm, times, self.sensor.gel_radius_mm, self.physics)[0]  # (2, K, 2)
        intensity = float(np.linalg.norm(pts_mm[1] - pts_mm[0], axis=-1).mean())
        return LabelRow(t_us, g.gesture, False, intensity, self.gel.camera.project(pts_mm[1]))

    def _exposure(
        self, grid_us: np.ndarray, grid_pos: np.ndarray, grid_amp: np.ndarray, grid_sigma: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """What the APS frame exposed from grid_us[0] sees, for the family's exposure
        (EXPOSURE_US unless ``physics.exposure_us``): renders at instants spaced so that no
        marker moves more than 0.3 px between them (positions interpolated linearly in the 1 ms
        grid; at most 6 renders per ms of exposure). Returns the background (H, W) float64 grey
        levels (the light averaged over the exposure) and the renders' marker positions (S, N, 2)
        float64 px, brightness (S, N) and sigma (S, N) px (:func:`esim.render_exposure`)."""
        t_us = int(grid_us[0])
        exposure = EXPOSURE_US if self.physics.exposure_us is None else self.physics.exposure_us
        last = int(np.searchsorted(grid_us, t_us + exposure))
        travel = float(np.abs(grid_pos[last] - grid_pos[0]).max())
        n = 1 if travel == 0.0 else int(np.clip(math.ceil(travel / 0.3) + 1, 2, 6 * exposure // 1000))
        times = t_us + np.linspace(0, exposure, n)
        k = np.clip(np.searchsorted(grid_us, times, side="right") - 1, 0, last - 1)
        a = ((times - grid_us[k]) / (grid_us[k + 1] - grid_us[k]))[:, None]
        pos = grid_pos[k] + a[..., None] * (grid_pos[k + 1] - grid_pos[k])
        amp = grid_amp[k] + a * (grid_amp[k + 1] - grid_amp[k])
        sigma = grid_sigma[k] + a * (grid_sigma[k + 1] - grid_sigma[k])
        background = self.gel.background
        if self.physics.flicker > 0:  # the exposure integrates the light over its duration
            background = background * float(self.light(np.linspace(t_us, t_us + exposure, 9)).mean())
        return background, pos, amp, sigma

    def _noise_offset(self) -> int:
        """Where the next APS frame's read-out noise starts in the noise bank (one draw)."""
        return int(self._noise_rng.integers(0, len(self._noise_bank) - self.sensor.width * self.sensor.height))

    def _frame(self, grid_us: np.ndarray, grid_pos: np.ndarray, grid_amp: np.ndarray, grid_sigma: np.ndarray) -> Frame:
        """The APS frame exposed from grid_us[0] (:meth:`_exposure`), plus read and shot noise,
        as uint8."""
        background, pos, amp, sigma = self._exposure(grid_us, grid_pos, grid_amp, grid_sigma)
        offset = self._noise_offset()
        return Frame(
            int(grid_us[0]),
            render_frame(background, pos, amp, sigma, READ_NOISE, SHOT_NOISE, self._noise_bank, offset),
        )

    def _rest_period(self, grid_us: np.ndarray) -> RestPeriod:
        """The gel at rest over a frame period's 1 ms grid ``grid_us`` (T,) int64 us, computed on
        the first call (:meth:`marker_state` with no gesture, :meth:`_exposure`, the exposure's
        image and noise sigma) and reused by later ones with as many samples: at rest nothing of
        it depends on the time (no gesture; the caller checks that the light is steady)."""
        if self._rest is None or len(self._rest.positions_px) != len(grid_us):
            pos, amp, sigma, pos_mm = self.marker_state(grid_us, ())
            background, f_pos, f_amp, f_sigma = self._exposure(grid_us, pos, amp, sigma)
            image = render_exposure(background, f_pos, f_amp, f_sigma)
            image_sigma = noise_sigma(image, READ_NOISE, SHOT_NOISE)
            self._rest = RestPeriod(pos, amp, sigma, pos_mm, image, image_sigma, self._settled(pos_mm[0]))
        return self._rest

    def step(self) -> SimChunk:
        """Simulate the next APS frame period."""
        t0 = self.t_us
        t1 = t0 + FRAME_PERIOD_US
        grid = np.arange(t0, t1 + 1, 1000, dtype=np.int64)
        gestures = self._gestures_between(t0, t1)
        rest = self._rest_period(grid) if self.reuse_rest and not gestures and self.physics.flicker <= 0 else None
        if rest is None:
            pos, amp, sigma, pos_mm = self.marker_state(grid, gestures)
        else:
            pos, amp, sigma, pos_mm = rest.positions_px, rest.amp, rest.sigma, rest.positions_mm
        events = self.camera.events(grid, pos, amp, self._noise_rng, sigma)
        if len(self._carry):
            events = np.concatenate([self._carry, events])
        cut = int(np.searchsorted(events["timestamp"], t1, side="left"))
        self._carry = events[cut:]
        if rest is None:
            frame = self._frame(grid, pos, amp, sigma)
            label = self._label(t0, gestures, pos_mm[0])
        else:
            frame = Frame(t0, read_out(rest.image, rest.image_sigma, self._noise_bank, self._noise_offset()))
            label = LabelRow(t0, GestureType.NONE, rest.settled, 0.0, np.zeros((0, 2)))
        chunk = SimChunk(
            frame=frame,
            events=events[:cut],
            label=label,
            t_us=grid[:-1],
            positions_px=pos[:-1].astype(np.float32),
        )
        self.t_us = t1
        return chunk

    def run(self, seconds: float | None = None) -> Iterator[SimChunk]:
        """Successive chunks for ``seconds`` of simulated time (endless when None)."""
        end = None if seconds is None else self.t_us + int(round(seconds * 1e6))
        while end is None or self.t_us < end:
            yield self.step()


# --- the live source --------------------------------------------------------------------------
class SimulatedSource:
    """A live stream from the simulated gel, for the runtime and the demo.

    Cycles through :data:`STEADY_GESTURES` (or ``gestures``) with rests in between, performed by
    user ``seed % 10`` with a steady hand: every gesture of a type equally strong (the two twists,
    the push directions), the pushes up, right, down and left in turn, so that a profile's
    mappings are tried both ways within one cycle (:meth:`cycle_seconds`). Same item kinds and
    order as ``RecordingReader.stream``: an APS :class:`Frame` every 40 ms, yielded before the
    events with timestamp >= its t_us, and event batches (EVENT_DTYPE, time-ordered) cut at the
    frame timestamps and every ``batch_us``.

    Args:
        sensor: geometry (default docs/dataset.md's); seed: simulation seed;
        gestures: sequence of GestureType or their names ("push", ...).
    """

    def __init__(self, sensor: SensorGeometry | None = None, seed: int = 0, gestures: Sequence | None = None) -> None:
        self.sensor = sensor or SensorGeometry()
        order = [GestureType(g) for g in gestures] if gestures else list(STEADY_GESTURES)
        if any(g is GestureType.NONE for g in order) or not order:
            raise NeurotouchError("the simulated gel needs gesture types among push, pinch, zoom, twist_cw, twist_ccw")
        self.seed = seed
        self._order = order
        self._sim = self._simulator()

    def _simulator(self) -> GelSimulator:
        return GelSimulator(
            self.sensor,
            USERS[self.seed % len(USERS)],
            self._order,
            seed=self.seed,
            stream_seed=(0xC0FFEE,),
            hand="steady",
        )

    def cycle_seconds(self) -> float:
        """Simulated time (s) from the stream's start until every gesture of the first cycle has
        been performed and the gel has settled after the last one (the same script, drawn again)."""
        first_cycle = list(itertools.islice(self._simulator()._script, len(self._order)))
        return (first_cycle[-1].t_settled_us - START_US) / 1e6

    @property
    def rest_px(self) -> np.ndarray:
        """(N, 2) float64 true marker rest positions (image px)."""
        return self._sim.gel.rest_px

    def chunks(self, seconds: float | None = None) -> Iterator[SimChunk]:
        """The simulation's frame periods with their labels and true marker positions."""
        return self._sim.run(seconds)

    def stream(self, seconds: float | None = None, batch_us: int = 1000) -> Iterator[StreamItem]:
        """Frames and event batches for ``seconds`` of simulated time (endless when None).

        Raises ValueError when batch_us < 1.
        """
        if batch_us < 1:
            raise ValueError("batch_us must be >= 1")
        for chunk in self._sim.run(seconds):
            yield chunk.frame
            yield from split_batches(chunk.events, batch_us)


# --- datasets ---------------------------------------------------------------------------------
def sequence_name(user_id: int, gesture: GestureType) -> str:
    """Name of the sequence of one user and gesture type, e.g. ``u3_push``."""
    return f"u{user_id}_{gesture.value}"


def write_sequence(out_dir: Path, name: str, sim: GelSimulator, seconds: float, on_chunk=None) -> None:
    """Simulate ``seconds`` (then on until the gel rests again) and write ``NAME.aedat4``,
    ``NAME.labels.csv``, ``NAME.pressed.csv`` and ``NAME.markers.npz`` into ``out_dir``.

    ``NAME.pressed.csv`` (docs/dataset.md, "Per-gesture metrics") gives, for each gesture whose
    fingers start apart (a finger lags), when the gel under its last finger to press has moved
    0.3 mm (:meth:`GelSimulator.pressed_us`).

    ``NAME.markers.npz`` holds the true marker positions: ``t_us`` (T,) int64 (every 1 ms, which
    includes every APS frame), ``positions_px`` (T, N, 2) float32 image px and ``rest_px`` (N, 2)
    float32. ``on_chunk(elapsed_us)`` is called after every frame period with the simulated
    time so far (progress).
    """
    start_us = sim.t_us
    end_us = start_us + int(round(seconds * 1e6))
    labels: list[LabelRow] = []
    times: list[np.ndarray] = []
    positions: list[np.ndarray] = []
    with RecordingWriter(out_dir / f"{name}.aedat4", width=sim.sensor.width, height=sim.sensor.height) as writer:
        while True:
            chunk = sim.step()
            writer.write_frame(chunk.frame)
            writer.write_events(chunk.events)
            labels.append(chunk.label)
            times.append(chunk.t_us)
            positions.append(chunk.positions_px)
            if on_chunk is not None:
                on_chunk(sim.t_us - start_us)
            if sim.t_us >= end_us and chunk.label.resting:
                break
    write_labels(out_dir / f"{name}.labels.csv", labels)
    apart = [g for g in sim.performed if g.t_start_us < sim.t_us and any(lag > 0 for lag in g.lags_us)]
    write_pressed(
        out_dir / f"{name}.pressed.csv",
        [(g.t_start_us, t) for g in apart if (t := sim.pressed_us(g)) is not None],
    )
    save_npz(
        out_dir / f"{name}.markers.npz",
        t_us=np.concatenate(times),
        positions_px=np.concatenate(positions),
        rest_px=sim.gel.rest_px.astype(np.float32),
    )


def save_npz(path: Path, **arrays: np.ndarray) -> None:
    """``numpy.savez_compressed`` with the fastest deflate level (the 1 ms marker positions of
    a minute are ~85 MB raw; level 1 keeps the paper preset's writing time small)."""
    import zipfile

    from neurotouch_hid.core.atomic import replacing

    with (
        replacing(path, what="arrays file") as tmp,
        zipfile.ZipFile(tmp, "w", compression=zipfile.ZIP_DEFLATED, compresslevel=1) as zf,
    ):
        for key, value in arrays.items():
            with zf.open(f"{key}.npy", "w", force_zip64=True) as fh:
                np.lib.format.write_array(fh, np.asanyarray(value), allow_pickle=False)


def write_dataset(out_dir: str | Path, *args, force: bool = False, **kw) -> Path:
    """:func:`write_whole_dataset` written whole (:class:`~neurotouch_hid.core.dataset.DatasetOut`):
    into a new folder beside ``out_dir``, put in its place at the end; a dataset already in
    ``out_dir`` is refused unless ``force`` (then replaced whole), any other file there always.

    Raises:
        DatasetError: ``out_dir`` holds a dataset or other files, or cannot be written (nothing
            changed); and what :func:`write_whole_dataset` raises (nothing changed either).
    """
    from neurotouch_hid.core.dataset import DatasetOut

    target = DatasetOut(out_dir, force=force)
    try:
        write_whole_dataset(target.work, *args, **kw)
    except BaseException:
        target.discard()
        raise
    return target.commit()


def write_whole_dataset(
    out_dir: str | Path,
    preset: str = "quick",
    seed: int = 0,
    minutes: float | None = None,
    progress: bool = True,
    users: Sequence[int] | None = None,
    gestures: Sequence[GestureType | str] | None = None,
    sensor: SensorGeometry | None = None,
    noise_hz: float = NOISE_RATE_HZ,
    physics: str = "default",
) -> Path:
    """Simulate and write a labelled dataset (docs/dataset.md): ``sensor.yaml`` and, per user and
    gesture type, ``u{user}_{gesture}.aedat4``, ``.labels.csv`` and ``.markers.npz`` (the
    ``sessions`` preset: per user and session, ``u{user}_session{k}.*``).

    Args:
        out_dir: the dataset folder (created if missing).
        preset: ``quick`` (1 user x 5 gestures x 3 s, for tests), ``paper`` (5 users x 5
            gestures x 60 s: the paper's 25 minutes; section "Creation of the Gesture Detection
            Dataset") or ``sessions`` (5 users x one 10 s game session, :func:`gesture_script` with ``session``:
            the type changes from one gesture to the next, taps, ordinary gestures, long holds,
            short rests).
        seed: the same seed writes the same files; it also picks the users (:func:`preset_users`).
        minutes: total simulated minutes instead of the preset's (split over the sequences;
            ``sessions``: as many 10 s sessions per user as make it up, at least one).
        progress: show a rich progress bar on stderr.
        users: user ids (0-9) instead of the preset's, e.g. ``TUNING_USERS``.
        gestures: gesture types instead of all five.
        sensor: geometry (default docs/dataset.md's).
        noise_hz: background-activity noise rate per pixel (Hz, >= 0) of the simulated event
            camera (default 0.1, a DAVIS-346 in good light; real sensors reach a few Hz in dim
            light). The gesture scripts and labels do not depend on it.
        physics: a family of :data:`~neurotouch_hid.sources.physics.PHYSICS` for every sequence,
            or ``mix`` (one family per sequence, :func:`~neurotouch_hid.sources.physics.mix_families`).
            ``physics.json`` in the folder maps each sequence to its family.
    Returns:
        the dataset folder.
    Raises:
        NeurotouchError: unknown preset, user id, gesture or physics family, minutes <= 0 or
            noise_hz < 0.
        RecordingError: the folder cannot be written.
    """
    if preset not in PRESET_SECONDS:
        raise NeurotouchError(f"unknown simulation preset {preset!r}: expected one of {', '.join(PRESET_SECONDS)}")
    user_ids = tuple(users) if users is not None else preset_users(preset, seed)
    bad = [u for u in user_ids if not 0 <= int(u) < len(USERS)]
    if bad or not user_ids:
        raise NeurotouchError(f"simulated users are 0 to {len(USERS) - 1}, got {list(user_ids)}")
    try:
        kinds = [GestureType(g) for g in gestures] if gestures is not None else list(SIM_GESTURES)
    except ValueError as exc:
        raise NeurotouchError(f"unknown gesture type: {exc}") from None
    if not kinds or GestureType.NONE in kinds:
        raise NeurotouchError("gestures must be among push, pinch, zoom, twist_cw, twist_ccw")
    if minutes is not None and not minutes > 0:
        raise NeurotouchError(f"--minutes must be positive, got {minutes}")
    sessions = preset == "sessions"
    if sessions:
        per_user = 1 if minutes is None else max(1, round(minutes * 60.0 / PRESET_SECONDS[preset] / len(user_ids)))
        pairs: list[tuple[int, GestureType | int]] = [(int(u), k) for u in user_ids for k in range(per_user)]
    else:
        pairs = [(int(u), g) for u in user_ids for g in kinds]
    n_seq = len(pairs)
    families = mix_families(n_seq, seed) if physics == "mix" else [physics_family(physics)] * n_seq
    if not noise_hz >= 0:
        raise NeurotouchError(f"--noise-hz must be >= 0 (events per pixel per second), got {noise_hz}")
    seconds = PRESET_SECONDS[preset] if minutes is None or sessions else minutes * 60.0 / n_seq
    sensor = sensor or SensorGeometry()
    out = Path(out_dir)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise NeurotouchError(f"{out}: cannot create the dataset folder: {exc.strerror}") from None
    sensor.save(out / "sensor.yaml")
    import json

    names = [f"u{u}_session{k}" if sessions else sequence_name(u, k) for u, k in pairs]
    from neurotouch_hid.core.atomic import AtomicFile

    with AtomicFile(out / "physics.json", what="physics file") as fh:
        fh.write(
            json.dumps({"physics": physics, "sequences": {name: f.name for name, f in zip(names, families)}}, indent=1)
            + "\n"
        )

    from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn

    columns = (
        TextColumn("{task.description}", style="bold", markup=False),
        BarColumn(),
        TextColumn("{task.completed:.0f}/{task.total:.0f} s"),
        TimeElapsedColumn(),
        TimeRemainingColumn(),
    )
    from rich.console import Console

    # on stderr: what goes to stdout is the command's result only (a pipe got the bar's last frame)
    with Progress(*columns, console=Console(stderr=True), disable=not progress, transient=False) as bar:
        task = bar.add_task("simulating", total=n_seq * seconds)
        for k, ((uid, kind), name) in enumerate(zip(pairs, names)):
            bar.update(task, description=name)
            sim = GelSimulator(
                sensor,
                USERS[uid],
                kinds if sessions else [kind],
                seed=seed,
                stream_seed=(uid, SESSION_STREAM + kind if sessions else SIM_GESTURES.index(kind)),
                noise_rate_hz=noise_hz,
                physics=families[k],
                hand="session" if sessions else "drawn",
            )
            write_sequence(
                out,
                name,
                sim,
                seconds,
                on_chunk=lambda us, k=k: bar.update(task, completed=k * seconds + min(us * 1e-6, seconds)),
            )
    return out
