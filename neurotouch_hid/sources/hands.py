"""The simulated hands: the users, and the gestures they make on the gel.

What is simulated (paper, sections "Problem Statement" and "Creation of the Gesture Detection
Dataset"):

* **Users** -- :data:`USERS` defines 10 simulated users with their own finger size, speed,
  intensity and hold/rest habits. Users 0-4 (:data:`TEST_USERS`) are the test users, users
  5-9 (:data:`TUNING_USERS`) are for tuning; the ``paper`` preset takes the test users for an
  even seed and the tuning users for an odd seed (:func:`~neurotouch_hid.sources.sim_dataset.preset_users`),
  so tuning never sees a test user. Contacts are drawn around the gel's centre with a slight bias
  to the right of the image, as the paper's contact distribution shows.
* **Gestures** -- push, pinch, zoom, twist_cw, twist_ccw with 1-3 fingers (:func:`draw_gesture`),
  drawn from the paper's dataset statistics, one after the other with rests
  (:func:`gesture_script`); a game session's taps, ordinary gestures and long holds
  (:func:`session_gesture`); the gesture a prompt asks for (:func:`prompted_gesture`) and a
  calibration's steady guided gestures (:func:`guided_gesture`).

Each gesture is a :class:`~neurotouch_hid.sources.gel.SimGesture`: its timing, fingers and motion,
which :func:`~neurotouch_hid.sources.gel.deform` turns into the gel's deformation.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Iterable, Iterator, Sequence

import numpy as np

from neurotouch_hid.core.estimate import GestureType
from neurotouch_hid.core.sensor import SensorGeometry
from neurotouch_hid.sources.gel import SimGesture
from neurotouch_hid.sources.physics import PHYSICS, Physics

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
#: Fastest intensity change a simulated user makes (mm/s; paper: up to 210 mm/s).
MAX_SPEED_MM_S = 205.0
#: Largest finger displacement at the hold (mm): with the clamped rim holding the gel back, the
#: contacts move up to ~18 mm (paper: local deformations up to 18 mm).
MAX_INTENSITY_MM = 23.0
#: Spread (sigma of the log) of a user's gesture strengths about the median for the type.
STRENGTH_SIGMA = 0.55
#: A late finger (the ``late`` family) starts moving at most this share of the attack after the
#: first, so that it still ramps up before the hold.
LATEST_LAG = 0.8
#: Distance of a multi-finger gesture's fingers from their centre (mm, uniform in this range).
FINGER_SPREAD_MM = (9.0, 15.0)


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
