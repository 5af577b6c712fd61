"""The guided part of ``calibrate``: mirror and rotation from two guided pushes, then a guided check.

A rest frame cannot show which way the user looks at the gel (:mod:`neurotouch_hid.calibration.measure`):
the image is a mirror of the user's view when the camera looks from inside, and the camera may
be mounted turned. Both are measured from what the gel does when the user is told what to do:

1. **Two guided pushes** -- "push the gel towards the top of your view", then "towards your
   right". The pipeline (:class:`~neurotouch_hid.pipeline.pipeline.GesturePipeline`, public
   entry points only) runs with the rest frames' geometry but no mirror and no rotation, so its
   ``translation_mm`` is the push as the image shows it (x right, y up). With the sensor's
   convention (:mod:`neurotouch_hid.core.sensor`: user = rotate(mirror(image))), the handedness of
   the two pushes gives the mirror -- right-then-up turns counter-clockwise in the user's view,
   so it turns clockwise in the image exactly when the image is mirrored -- and each push then
   gives the rotation; the two are averaged (circular mean). A push that is too weak, is read as
   another gesture, wanders, or a pair not about a right angle apart is refused with one line
   saying why, and asked again (:data:`ATTEMPTS` times).
2. **The guided check** -- with the measured geometry, a fresh pipeline watches a push up, down,
   left and right, a pinch, a zoom and a twist each way; each is reported right or wrong, with
   what to do when wrong (a push read turned: the rotation; a twist read the other way: the mirror).

Who performs the gestures is a :class:`GuidedSource`: a person at the live camera
(:class:`LiveCamera`, who reads the prompts) or the simulated hand (:class:`SimulatedHand`,
which does each gesture when asked). Every wait is bounded in the stream's own time
(:data:`STEP_S`), so nothing waits for a keyboard and a run without a terminal cannot hang.
"""

from __future__ import annotations

import contextlib
import dataclasses
import math
from collections import Counter
from dataclasses import dataclass
from typing import Callable, Iterator, Protocol, Sequence

import numpy as np

from neurotouch_hid.core.errors import SensorError
from neurotouch_hid.core.estimate import GestureEstimate, GestureType
from neurotouch_hid.core.sensor import SensorGeometry
from neurotouch_hid.sources import Frame, StreamItem

#: How long to wait for a gesture after asking for it (s of stream time); one started in that
#: time is watched until its release, for at most STEP_S more.
STEP_S = 12.0
#: A gesture ends when the pipeline has seen no gesture for this long (s of stream time).
RELEASE_S = 0.3
#: A gesture's held windows: those with at least this share of its largest intensity.
HELD_SHARE = 0.6
#: A guided gesture must reach this intensity (mm; the simulated hand's: 2.5-4 mm).
MIN_INTENSITY_MM = 1.0
#: A guided push must be read as a push in at least this share of its held windows, move the
#: gel at least MIN_PUSH_MM (the pipeline's translation, mm), and keep its direction: the
#: held windows' directions within MAX_WANDER_DEG (circular standard deviation) of each other.
PUSH_SHARE = 0.6
MIN_PUSH_MM = 0.5
MAX_WANDER_DEG = 20.0
#: The two calibration pushes (up, then right) must be 90 +- RIGHT_ANGLE_TOLERANCE_DEG apart.
RIGHT_ANGLE_TOLERANCE_DEG = 35.0
#: A checked push is right within this angle of the asked direction (degrees).
CHECK_PUSH_DEG = 45.0
#: Tries per calibration push before giving up.
ATTEMPTS = 3
#: Time the simulated hand leaves between being asked and starting (us).
SIM_REACTION_US = 200_000


@dataclass(frozen=True)
class Step:
    """One gesture asked of the user.

    Attributes:
        gesture: what to perform.
        direction: a push's direction, user frame (x right, y up), unit; (0, 0) for the others.
        name: short, for reports ("push up").
        prompt: the instruction, for the user.
    """

    gesture: GestureType
    direction: tuple[float, float]
    name: str
    prompt: str


_HOLD = "hold it about a second, then let go"
#: The calibration's two pushes: towards the top of the user's view, then towards the right.
CALIBRATION_PUSHES: tuple[Step, Step] = (
    Step(
        GestureType.PUSH, (0.0, 1.0), "push up", f"push the gel towards the top of your view (away from you), {_HOLD}"
    ),
    Step(GestureType.PUSH, (1.0, 0.0), "push right", f"push the gel towards your right, {_HOLD}"),
)
#: The guided check's gestures, in the order asked.
CHECK_STEPS: tuple[Step, ...] = (
    Step(GestureType.PUSH, (0.0, 1.0), "push up", f"push the gel up (away from you), {_HOLD}"),
    Step(GestureType.PUSH, (0.0, -1.0), "push down", f"push the gel down (towards you), {_HOLD}"),
    Step(GestureType.PUSH, (-1.0, 0.0), "push left", f"push the gel to your left, {_HOLD}"),
    Step(GestureType.PUSH, (1.0, 0.0), "push right", f"push the gel to your right, {_HOLD}"),
    Step(
        GestureType.PINCH, (0.0, 0.0), "pinch", f"pinch: two fingers on the gel, move them towards each other, {_HOLD}"
    ),
    Step(GestureType.ZOOM, (0.0, 0.0), "zoom", f"zoom: two fingers on the gel, move them apart, {_HOLD}"),
    Step(
        GestureType.TWIST_CW,
        (0.0, 0.0),
        "twist clockwise",
        f"twist clockwise (as you look at the gel): two fingers turning like a key, {_HOLD}",
    ),
    Step(GestureType.TWIST_CCW, (0.0, 0.0), "twist counter-clockwise", f"twist counter-clockwise, {_HOLD}"),
)
_NAMES = {
    GestureType.PUSH: "a push",
    GestureType.PINCH: "a pinch",
    GestureType.ZOOM: "a zoom",
    GestureType.TWIST_CW: "a clockwise twist",
    GestureType.TWIST_CCW: "a counter-clockwise twist",
}


class GuidedSource(Protocol):
    """Where a guided calibration's frames and gestures come from."""

    #: True when a person performs the gestures (the prompts are for them).
    by_hand: bool

    def rest_frames(self, n: int) -> list[Frame]:
        """The next ``n`` APS frames (the gel at rest), uint8 (H, W)."""

    def stream(self) -> Iterator[StreamItem]:
        """The stream after the rest frames (frames and EVENT_DTYPE batches), endless."""

    def perform(self, step: Step) -> None:
        """Called when ``step`` is asked for (the simulated hand starts it; a person reads the prompt)."""


class SimulatedHand:
    """The simulated gel, seen by a camera mounted with ``camera``'s mirror and rotation, and a
    hand that performs each guided gesture when asked (:func:`~neurotouch_hid.sources.hands.guided_gesture`).

    Args:
        camera: the simulated camera's geometry (the mirror and rotation a calibration must find).
        seed: the simulation's seed.
        push_mm: the travel of the hand's successive pushes (mm), for trying weak or missing
            pushes; when used up, or None, the guided hand's own (GUIDED_PUSH_MM).
    """

    by_hand = False

    def __init__(self, camera: SensorGeometry, seed: int = 0, push_mm: Sequence[float] | None = None) -> None:
        from neurotouch_hid.sources.simulator import GelSimulator

        self.camera = camera
        self._sim = GelSimulator(camera, seed=seed, stream_seed=(0xCA1,), script=())
        self._free_us = self._sim.t_us
        self._push_mm = list(push_mm or ())

    def rest_frames(self, n: int) -> list[Frame]:
        """The next ``n`` simulated APS frames, uint8 (260, 346), the gel at rest."""
        return [self._sim.step().frame for _ in range(n)]

    def stream(self) -> Iterator[StreamItem]:
        """Endless: each frame period's APS frame, then its events in 1 ms EVENT_DTYPE batches."""
        from neurotouch_hid.sources.batches import split_batches

        for chunk in self._sim.run():
            yield chunk.frame
            yield from split_batches(chunk.events, 1000)

    def perform(self, step: Step) -> None:
        """Start ``step`` SIM_REACTION_US after the simulator's time (or the last gesture's settling)."""
        from neurotouch_hid.sources.hands import guided_gesture

        start = max(self._sim.t_us, self._free_us) + SIM_REACTION_US
        gesture = guided_gesture(step.gesture, start, step.direction)
        if step.gesture is GestureType.PUSH and self._push_mm:
            gesture = dataclasses.replace(gesture, amplitude_mm=self._push_mm.pop(0))
        self._sim.perform(gesture)
        self._free_us = gesture.t_settled_us


class LiveCamera:
    """The live DAVIS-346, with a person who performs the gestures (a context manager: the camera
    stays open from the rest frames to the end of the check).

    Args:
        wait_s: how long to wait for the rest frames (s of the camera's clock).
        backend: the capture backend of :class:`~neurotouch_hid.sources.davis.DavisSource`
            (None: dv-processing's cameras).
        serial: the camera's serial number (None: the first DAVIS-346 that opens).

    Raises:
        DeviceError: no camera (on entering).
    """

    by_hand = True

    def __init__(self, wait_s: float, backend: object = None, serial: str | None = None) -> None:
        self._wait_s = wait_s
        self._backend = backend
        self._serial = serial
        self._stack = contextlib.ExitStack()
        self._items: Iterator[StreamItem] | None = None

    def __enter__(self) -> "LiveCamera":
        from neurotouch_hid.sources.davis import DavisConfig, DavisSource

        camera = self._stack.enter_context(DavisSource(DavisConfig(serial=self._serial), backend=self._backend))
        self._items = self._stack.enter_context(contextlib.closing(camera.stream()))
        return self

    def __exit__(self, *exc) -> None:
        self._stack.close()

    def rest_frames(self, n: int) -> list[Frame]:
        """Up to ``n`` APS frames within the first ``wait_s`` s of the camera's clock (its
        frames' and events' timestamps; a camera that sends nothing raises DeviceError, stalled)."""
        frames: list[Frame] = []
        start = None
        for item in self._items:
            t_us = stream_time_us(item)
            start = t_us if start is None else start
            if t_us is not None and t_us - start > self._wait_s * 1e6:
                break
            if isinstance(item, Frame):
                frames.append(item)
                if len(frames) == n:
                    break
        return frames

    def stream(self) -> Iterator[StreamItem]:
        return self._items

    def perform(self, step: Step) -> None:
        """Nothing: the person reads the prompt."""


@dataclass(frozen=True)
class Attempt:
    """What the pipeline saw of one asked gesture (its held windows: :data:`HELD_SHARE`).

    Attributes:
        seen: the held windows' gesture types, most frequent first ((type, windows) pairs);
            empty when nothing was seen within STEP_S.
        peak_mm: the largest intensity (mm).
        translation_mm: (2,) median translation of the held windows (the pipeline's frame, mm).
        wander_deg: circular standard deviation of the held translations' directions (degrees).
        rotation_rad: median rotation of the held windows (the pipeline's frame, ccw > 0).
    """

    seen: tuple[tuple[GestureType, int], ...]
    peak_mm: float
    translation_mm: np.ndarray
    wander_deg: float
    rotation_rad: float

    @property
    def gesture(self) -> GestureType:
        """The gesture read (NONE when nothing was seen)."""
        return self.seen[0][0] if self.seen else GestureType.NONE

    @property
    def share(self) -> float:
        """The read gesture's share of the held windows (0 when nothing was seen)."""
        return self.seen[0][1] / sum(n for _, n in self.seen) if self.seen else 0.0

    @property
    def angle_deg(self) -> float:
        """The translation's direction (degrees, counter-clockwise from x, in (-180, 180])."""
        angle = math.degrees(math.atan2(self.translation_mm[1], self.translation_mm[0]))
        return 180.0 if angle <= -180.0 else angle


def summarise(episode: Sequence[GestureEstimate]) -> Attempt:
    """The :class:`Attempt` of the windows of one gesture (all of them; empty: nothing seen)."""
    moving = [e for e in episode if e.gesture is not GestureType.NONE]
    if not moving:
        return Attempt((), 0.0, np.zeros(2), 0.0, 0.0)
    peak = max(e.intensity_mm for e in moving)
    held = [e for e in moving if e.intensity_mm >= HELD_SHARE * peak]
    seen = tuple(Counter(e.gesture for e in held).most_common())
    translations = np.array([e.translation_mm for e in held])
    angles = np.arctan2(translations[:, 1], translations[:, 0])
    resultant = min(1.0, float(abs(np.mean(np.exp(1j * angles)))))
    wander = math.degrees(math.sqrt(-2.0 * math.log(resultant))) if resultant > 0 else 180.0
    return Attempt(
        seen,
        float(peak),
        np.median(translations, axis=0),
        wander,
        float(np.median([e.rotation_rad for e in held])),
    )


class Watcher:
    """Feeds a stream to a pipeline and cuts it into asked gestures.

    Args:
        items: the stream (endless; a finite one ends the watch as a timeout would).
        sensor: the pipeline's geometry.
    """

    def __init__(self, items: Iterator[StreamItem], sensor: SensorGeometry) -> None:
        from neurotouch_hid.pipeline.pipeline import GesturePipeline

        self._items = items
        self._pipeline = GesturePipeline(sensor)

    def watch(self) -> list[GestureEstimate]:
        """The windows of the next gesture: from its first window read as a gesture to its
        release (:data:`RELEASE_S` without one); [] when none started within :data:`STEP_S` of
        stream time (frames' and events' timestamps). A gesture started late is watched to its
        release (not cut at STEP_S, its rest would be read as the next gesture asked), or what
        there is of it after 2 STEP_S."""
        start = None
        episode: list[GestureEstimate] = []
        last_moving = 0
        for item in self._items:
            t_us = stream_time_us(item)
            start = t_us if start is None else start
            for estimate in self._pipeline.process(item):
                if estimate.gesture is not GestureType.NONE:
                    episode.append(estimate)
                    last_moving = estimate.t_us
                elif episode:
                    episode.append(estimate)
                    if estimate.t_us - last_moving >= RELEASE_S * 1e6:
                        return episode
            if start is not None and t_us is not None and t_us - start > (2 if episode else 1) * STEP_S * 1e6:
                break
        return episode


def stream_time_us(item: StreamItem) -> int | None:
    """The camera time of a stream item (us): a frame's, an event batch's last event's; None for
    an empty batch or a status."""
    if isinstance(item, Frame):
        return int(item.t_us)
    if isinstance(item, np.ndarray) and len(item):
        return int(item["timestamp"][-1])
    return None


def _angle_between(a: np.ndarray, b: np.ndarray) -> float:
    """The signed angle from vector a to vector b (degrees, counter-clockwise > 0, in (-180, 180])."""
    return math.degrees(math.atan2(a[0] * b[1] - a[1] * b[0], a[0] * b[0] + a[1] * b[1]))


def push_problem(attempt: Attempt) -> str | None:
    """Why a calibration push cannot be used (one line: what was seen, what to do), or None."""
    if not attempt.seen:
        return f"no push seen in {STEP_S:g} s: press one finger into the gel and slide it ~4 mm that way"
    if attempt.peak_mm < MIN_INTENSITY_MM:
        return f"the push moved the gel only {attempt.peak_mm:.1f} mm: push harder, about 3-4 mm"
    if attempt.gesture is not GestureType.PUSH or attempt.share < PUSH_SHARE:
        read = ", ".join(f"{_NAMES[g]} {n}" for g, n in attempt.seen)
        return (
            f"that was read as {_NAMES[attempt.gesture]} (windows: {read}): "
            "push with one finger, sliding it, not turning"
        )
    if float(np.hypot(*attempt.translation_mm)) < MIN_PUSH_MM:
        return "the gel was pressed in but hardly slid: slide the finger that way, about 3-4 mm"
    if attempt.wander_deg > MAX_WANDER_DEG:
        return f"the push changed direction ({attempt.wander_deg:.0f} degrees of wander): push in one straight line"
    return None


def orientation(asked: Sequence[Step], seen: Sequence[np.ndarray]) -> tuple[bool, float]:
    """The mirror and rotation (degrees, counter-clockwise, in (-180, 180]) that take the pushes
    ``seen`` -- (2,) each, in the image as displayed (x right, y up: the pipeline's translation with
    no mirror, no rotation) -- to the directions ``asked`` (user frame), two pushes (module docstring).

    Raises:
        SensorError: the two pushes are not 90 +- RIGHT_ANGLE_TOLERANCE_DEG degrees apart (what to do is said).
    """
    asked_vectors = [np.asarray(s.direction, dtype=np.float64) for s in asked]
    turn_asked = _angle_between(*asked_vectors)
    turn_seen = _angle_between(*seen)
    if abs(abs(turn_seen) - abs(turn_asked)) > RIGHT_ANGLE_TOLERANCE_DEG:
        raise SensorError(
            f"the pushes {asked[0].name} and {asked[1].name} were {abs(turn_seen):.0f} degrees apart, not "
            f"{abs(turn_asked):.0f}: push straight towards each side asked"
        )
    mirror = (turn_asked > 0) != (turn_seen > 0)
    offsets = []
    for want, got in zip(asked_vectors, seen):
        image = np.array([-got[0], got[1]]) if mirror else np.asarray(got, dtype=np.float64)
        offsets.append(math.atan2(want[1], want[0]) - math.atan2(image[1], image[0]))
    mean = math.degrees(math.atan2(np.mean(np.sin(offsets)), np.mean(np.cos(offsets))))
    rotation = round(mean, 1)
    return mirror, 180.0 if rotation == -180.0 else rotation + 0.0


def measure_orientation(
    source: GuidedSource, items: Iterator[StreamItem], sensor: SensorGeometry, say: Callable[[str], None]
) -> tuple[bool, float]:
    """Mirror and rotation (degrees) from the two guided pushes (:data:`CALIBRATION_PUSHES`),
    asking each again when it cannot be used (:func:`push_problem`, :func:`orientation`).

    Args:
        source: who performs the pushes; items: its stream (after the rest frames);
        sensor: the rest frames' geometry (its mirror and rotation are not used); say: prints a line.
    Raises:
        SensorError: no usable pair of pushes in :data:`ATTEMPTS` tries (what to do is said).
    """
    watcher = Watcher(items, dataclasses.replace(sensor, mirror=False, rotation_deg=0.0))
    problem = ""
    for _ in range(ATTEMPTS):
        seen = []
        for step in CALIBRATION_PUSHES:
            for _ in range(ATTEMPTS):
                say(f"{step.prompt}{'' if source.by_hand else ' (the simulated hand does it)'}")
                source.perform(step)
                attempt = summarise(watcher.watch())
                problem = push_problem(attempt)
                if problem is None:
                    say(
                        f"  {step.name}: seen, {attempt.peak_mm:.1f} mm, "
                        f"towards {attempt.angle_deg:.0f} degrees in the image"
                    )
                    seen.append(attempt.translation_mm)
                    break
                say(f"  {step.name}: not used: {problem}")
            else:
                raise SensorError(
                    f"no usable {step.name} in {ATTEMPTS} tries ({problem}): calibrate again, or give "
                    "--mirror/--no-mirror and --rotation DEG"
                )
        try:
            return orientation(CALIBRATION_PUSHES, seen)
        except SensorError as exc:
            problem = str(exc)
            say(f"  not used: {problem}; again, both")
    raise SensorError(f"{problem} ({ATTEMPTS} tries): calibrate again, or give --mirror/--no-mirror and --rotation DEG")


@dataclass(frozen=True)
class CheckResult:
    """One gesture of the guided check.

    Attributes:
        step: what was asked; attempt: what the pipeline saw; right: whether it came out right;
        fix: what to do when not ("" when right).
        again: the gesture was not done as asked (too weak, another gesture): worth asking again,
            unlike a gesture read turned or the other way round (the calibration's fault).
    """

    step: Step
    attempt: Attempt
    right: bool
    fix: str
    again: bool = False

    def line(self) -> str:
        """One line for the user: the gesture, right or wrong, what was read, what to do."""
        a = self.attempt
        if not a.seen:
            read = "nothing seen"
        elif a.gesture is GestureType.PUSH:
            towards = _direction_name(a.translation_mm)
            read = f"read as a push towards {towards} ({round(a.angle_deg)} degrees), {a.peak_mm:.1f} mm"
        else:
            read = f"read as {_NAMES[a.gesture]}, {a.peak_mm:.1f} mm"
        verdict = "right" if self.right else "WRONG"
        return f"{self.step.name}: {verdict}: {read}" + (f"; {self.fix}" if self.fix else "")


def _direction_name(vector: np.ndarray) -> str:
    angle = math.degrees(math.atan2(vector[1], vector[0])) % 360
    return ("right", "up", "left", "down")[int(((angle + 45) % 360) // 90)]


def judge(step: Step, attempt: Attempt, orientation_given: bool = False) -> CheckResult:
    """Whether ``attempt`` (seen by a pipeline with the calibrated geometry, user frame) is the
    gesture ``step`` asked for, and what to do when it is not; ``orientation_given``: the mirror
    and rotation came from --mirror/--no-mirror and --rotation, not from guided pushes."""
    recalibrate = (
        "the --mirror/--no-mirror and --rotation given do not fit this camera (what to give is said after the check)"
        if orientation_given
        else "calibrate again and push exactly the ways asked"
    )
    if not attempt.seen or attempt.peak_mm < MIN_INTENSITY_MM:
        return CheckResult(step, attempt, False, "too weak or not seen: do it more firmly (3-4 mm)", again=True)
    if step.gesture is GestureType.PUSH:
        if attempt.gesture is not GestureType.PUSH:
            return CheckResult(
                step, attempt, False, "push with one finger, sliding it, not turning or spreading", again=True
            )
        off = _angle_between(np.asarray(step.direction), attempt.translation_mm)
        if abs(off) <= CHECK_PUSH_DEG:
            return CheckResult(step, attempt, True, "")
        return CheckResult(step, attempt, False, f"read turned by {round(off)} degrees: {recalibrate}")
    if attempt.gesture is step.gesture:
        return CheckResult(step, attempt, True, "")
    twists = {GestureType.TWIST_CW, GestureType.TWIST_CCW}
    if step.gesture in twists and attempt.gesture in twists:
        return CheckResult(step, attempt, False, f"read the other way round, the mirror is wrong: {recalibrate}")
    if {step.gesture, attempt.gesture} == {GestureType.PINCH, GestureType.ZOOM}:
        return CheckResult(step, attempt, False, "pinch closes the fingers, zoom opens them", again=True)
    return CheckResult(step, attempt, False, step.prompt, again=True)


def guided_check(
    source: GuidedSource,
    items: Iterator[StreamItem],
    sensor: SensorGeometry,
    say: Callable[[str], None],
    steps: Sequence[Step] = CHECK_STEPS,
    orientation_given: bool = False,
) -> list[CheckResult]:
    """Ask for each of ``steps`` and judge what a pipeline with ``sensor`` reads (:func:`judge`,
    ``orientation_given`` passed on), saying each result as it comes; a gesture not done as asked
    (``CheckResult.again``) is asked once more. Returns the last result of each step, in the
    order asked."""
    watcher = Watcher(items, sensor)
    results = []
    for step in steps:
        for attempt_no in range(2):
            say(f"{step.prompt}{'' if source.by_hand else ' (the simulated hand does it)'}")
            source.perform(step)
            result = judge(step, summarise(watcher.watch()), orientation_given)
            say(f"  {result.line()}" + ("; again:" if result.again and attempt_no == 0 else ""))
            if not result.again:
                break
        results.append(result)
    return results


def check_advice(results: Sequence[CheckResult], sensor: SensorGeometry, orientation_given: bool = False) -> str | None:
    """What to do when the check's gestures say the mirror or rotation is wrong (one line), or None.

    ``sensor`` is the geometry the check ran with. When a push came out wrong and the pushes up
    and right were read as pushes, they give the mirror and rotation themselves (as the guided
    pushes do, :func:`orientation`), and the line names them; when only both twists came out the
    other way round, the mirror is wrong. ``orientation_given``: the mirror and rotation were
    given as options, so the line says which options to give instead (no pushes were asked).
    """
    given = f"{'--mirror' if sensor.mirror else '--no-mirror'} --rotation {sensor.rotation_deg:g}"
    again = "give" if not orientation_given else f"give, instead of {given},"
    pushes = {r.step.name: r for r in results if r.step.gesture is GestureType.PUSH}
    calibrating = [pushes.get(step.name) for step in CALIBRATION_PUSHES]
    if any(not r.right for r in pushes.values()) and all(
        r is not None and push_problem(r.attempt) is None for r in calibrating
    ):
        neutral = dataclasses.replace(sensor, mirror=False, rotation_deg=0.0)
        seen = [
            neutral.vectors_image_to_user(sensor.vectors_user_to_image(r.attempt.translation_mm)) for r in calibrating
        ]
        with contextlib.suppress(SensorError):
            mirror, rotation = orientation(CALIBRATION_PUSHES, seen)
            return (
                f"the pushes say the image is {'a mirror of' if mirror else 'the same as'} your view, turned "
                f"{rotation:g} degrees: "
                + ("" if orientation_given else "calibrate again, pushing exactly the ways asked, or ")
                + f"{again} {'--mirror' if mirror else '--no-mirror'} --rotation {rotation:g}"
            )
    twists = [r for r in results if r.step.gesture in (GestureType.TWIST_CW, GestureType.TWIST_CCW)]
    if twists and all(
        not r.right and r.attempt.gesture in (GestureType.TWIST_CW, GestureType.TWIST_CCW) for r in twists
    ):
        flip = f"{'--no-mirror' if sensor.mirror else '--mirror'} --rotation {sensor.rotation_deg:g}"
        if orientation_given:
            return f"the twists read the other way round: {again} {flip}"
        return f"the twists read the other way round: calibrate again, pushing exactly the ways asked, or give {flip}"
    return None
