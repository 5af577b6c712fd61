"""The simulated NeuroTouch: the gel and the camera run together, one APS frame period at a time.

What is simulated (paper, sections "System Overview", "Problem Statement" and "Creation of the
Gesture Detection Dataset"):

* **The gel** -- :mod:`neurotouch_hid.sources.gel`: the dome, its markers and how gestures
  deform it.
* **Fingers and gestures** -- :mod:`neurotouch_hid.sources.hands`: the simulated users and the
  gestures they make.
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

Writing labelled datasets of it is :mod:`neurotouch_hid.sources.sim_dataset`.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass
from typing import Iterable, Iterator, Sequence

import numpy as np

from neurotouch_hid.core.dataset import LabelRow
from neurotouch_hid.core.errors import NeurotouchError
from neurotouch_hid.core.estimate import GestureType
from neurotouch_hid.core.sensor import SensorGeometry
from neurotouch_hid.sources import EVENT_DTYPE, Frame, StreamItem
from neurotouch_hid.sources.batches import split_batches
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
from neurotouch_hid.sources.gel import Gel, SimGesture, deform
from neurotouch_hid.sources.hands import SIM_GESTURES, STEADY_GESTURES, USERS, SimUser, gesture_script
from neurotouch_hid.sources.physics import PHYSICS, Physics

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
#: APS noise: read noise sigma (grey levels) and shot noise sigma at grey level 1 (~ sqrt(level)).
READ_NOISE = 1.5
SHOT_NOISE = 0.22


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
