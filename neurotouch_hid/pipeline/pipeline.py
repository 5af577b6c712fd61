"""The gesture detection pipeline, the product's composition (paper, section "Methodology";
docs/method.md, "Overview"): events and APS frames in, one :class:`GestureEstimate` per window out.

The frame path (``frame_path.py``, :class:`~neurotouch_hid.pipeline.frame_path.FramePath`): the
first APS frame showing the gel's marker grid at its calibrated rest is the rest reference
(``markers.py``; the camera model is fitted to it, ``camera_model.py``); every later frame goes to
the resting detector (``resting.py``); at rest, or near it unless a press is growing from rest,
the tracker is re-anchored at the rest positions, otherwise the frame's marker centroids correct
the blobs (``tracker.py``).

The window path (``window_path.py``, :class:`~neurotouch_hid.pipeline.window_path.WindowPath`,
and :meth:`GesturePipeline._estimate`): events pass the noise filter (``noise.py``) to the
event-blob tracker (``tracker.py``); at each window's end: a resting verdict answers ``none``
unless the event path overrules it (``override.py``); a gel that has not moved answers
``none``; else the window is fitted (``fit_path.py``,
:class:`~neurotouch_hid.pipeline.fit_path.FitPath`): the gel's motion in its mount is removed
(``gel_motion.py``), the contacts are found (``contacts.py``), the gesture's similarity, type and
intensity fitted (``gesture.py``, ``learned.py``); the gel's creep says whether the fingers
have left (``creep.py``), and the episode's vote gives the type (``episode.py``).

The paper's method is :class:`~neurotouch_hid.pipeline.paper.PaperPipeline`, this composition
with the paper's steps in place of the product's (``paper.py``).

Windows: ``window_us`` long, aligned on multiples of ``window_us`` from the first event after the
reference frame. An estimate is emitted for every window end crossed, even by a window without
events, with ``t_us`` = the window's end; events at ``t`` belong to the window ending after ``t``;
but for a gap in the timestamps longer than :data:`GAP_US`: its first second of windows is
emitted (the gel settling as the last events left it), the rest skipped (a year's gap made 3
billion windows; the predictions format asks for no empty window). Events before the reference
frame are dropped. :meth:`GesturePipeline.process_newest` (batches that queued up behind a
real-time run) decides only the newest window a batch closes.

Threads: the resting detector may run in another thread (paper: "operating in parallel to the
main pipeline"): ``detect_resting=False`` and hand its results to
:meth:`GesturePipeline.set_resting`, which is thread-safe (applied by the pipeline's own thread at
its next item, so the tracker is never reset mid-batch).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Iterable, Iterator

import numpy as np

from neurotouch_hid.core.errors import SensorError
from neurotouch_hid.core.estimate import GestureEstimate, GestureType, MarkerPositions
from neurotouch_hid.core.sensor import SensorGeometry
from neurotouch_hid.pipeline.config import MIN_WINDOW_US, PipelineConfig, PixelSettings, scaled_to_sensor
from neurotouch_hid.pipeline.contacts_held import compile_held_kernels
from neurotouch_hid.pipeline.contacts_plateau import rest_neighbours
from neurotouch_hid.pipeline.creep import TAIL_PRESS_MARKERS, TAIL_PRESS_SHARE, CreepFilter, TailWatch
from neurotouch_hid.pipeline.creep import amplitude as creep_amplitude
from neurotouch_hid.pipeline.episode import EpisodeVote
from neurotouch_hid.pipeline.fit_path import FitPath
from neurotouch_hid.pipeline.frame_path import RESUME_MATCH_FRAMES, FramePath
from neurotouch_hid.pipeline.gel_motion import compile_gel_motion_kernels
from neurotouch_hid.pipeline.gesture import (
    compile_camera_model_kernels,
    points_to_user,
)
from neurotouch_hid.pipeline.markers import MARKER_SPACING_MM
from neurotouch_hid.pipeline.moves import _largest_move_sq, _unchanged
from neurotouch_hid.pipeline.noise import EventNoiseFilter, time_surface
from neurotouch_hid.pipeline.override import grid_neighbours, overrules_rest, shared_distances
from neurotouch_hid.pipeline.rest_window import rest_window
from neurotouch_hid.pipeline.resting import compile_resting_kernels
from neurotouch_hid.pipeline.synthetic import synthetic_windows
from neurotouch_hid.pipeline.tracker import BlobTracker, swapped_blobs
from neurotouch_hid.pipeline.window_path import GAP_US, WindowPath
from neurotouch_hid.sources import Frame, StreamItem

__all__ = ["GAP_US", "MIN_WINDOW_US", "PipelineConfig", "GesturePipeline", "RESUME_MATCH_FRAMES", "STAGES"]


#: The stages :attr:`GesturePipeline.timings` measures.
STAGES = ("noise_filter", "tracker", "contacts", "gesture", "resting", "frame_correction")


def _same_held(a: tuple[np.ndarray, np.ndarray] | None, b: tuple[np.ndarray, np.ndarray] | None) -> bool:
    """Whether two :attr:`Contacts.held` (or None) hold the same markers at the same ||v|| (their
    bytes: int64 and float64 arrays, ~1 us where ``np.array_equal`` takes ~4)."""
    if a is None or b is None:
        return a is b
    return a[0].tobytes() == b[0].tobytes() and a[1].tobytes() == b[1].tobytes()


class GesturePipeline(WindowPath, FramePath, FitPath):
    """Events and APS frames -> one :class:`GestureEstimate` per window (paper, "Methodology").

    Args:
        sensor: the geometry (image size, gel disc, px/mm, image -> user frame).
        config: thresholds (default: PipelineConfig(), the product's; the paper's method is
            :class:`~neurotouch_hid.pipeline.paper.PaperPipeline`).
        on_window: called with each estimate right after its window closes, while the tracker
            holds that window's end positions (e.g. to record :meth:`marker_positions`).
        profile: record per-stage processing times (ns) in :attr:`timings`.
        detect_resting: True: :meth:`process` runs the resting detector on every frame itself;
            False: the caller does, via :meth:`set_resting` (e.g. in another thread).

    Attributes:
        rest_px: (N, 2) float64, rest marker positions (image px), None before the first frame.
        tracker: the :class:`BlobTracker`, None before the first frame.
        resting_detector: the :class:`RestingDetector`, None before the first frame.
        timings: stage name -> list of wall-clock durations (ns) when ``profile`` is set:
            "noise_filter" (conversions included) and
            "tracker" per event batch, "contacts" and "gesture" per window, "resting" per frame.
        cpu_timings: the same stages' CPU time of the calling thread (ns), which a machine
            shared with other work does not inflate.
    """

    def __init__(
        self,
        sensor: SensorGeometry,
        config: PipelineConfig | None = None,
        *,
        on_window: Callable[[GestureEstimate], None] | None = None,
        profile: bool = False,
        detect_resting: bool = True,
    ) -> None:
        self.sensor = sensor
        #: the settings as given (mm, us); ``config`` is what runs (in pixels at the sensor's scale)
        self.settings = config or self.default_config()
        self.config = self._scaled(self.settings, sensor)
        self.detect_resting = detect_resting
        self.on_window = on_window
        self.timings: dict[str, list[int]] | None = {s: [] for s in STAGES} if profile else None
        self.cpu_timings: dict[str, list[int]] | None = {s: [] for s in STAGES} if profile else None
        self._next_end: int | None = None
        self._init_frame_path()
        #: the current gesture episode's decision (docs/method.md, "Episode vote")
        self._episode = self._episode_vote()
        #: whether a window of the current press had a long flat top: fingertips side by side
        #: (docs/method.md, "Contacts"; ends with the press, at a window without a gesture)
        self._long_press = False
        #: (rest reference, :attr:`Contacts.held`) of the window before in the current press: the
        #: maxima a finger held where the homography follows it keeps ("Contacts"; ends with the press)
        self._held: tuple[np.ndarray, tuple[np.ndarray, np.ndarray]] | None = None
        #: the centres the last fitted window read its type about, None: its maxima ("Gesture")
        self._type_read_about: np.ndarray | None = None
        #: (t_us, intensity_mm) of the window before when it had a gesture ("Gesture": intensity lead)
        self._last_intensity: tuple[int, float] | None = None
        #: the fingers' load behind the deformation of a gel whose creep sensor.yaml has ("Creep")
        self._creep = self._creep_filter(sensor)
        #: a new press in the creep's release tail, and the rest reference and re-anchoring it is
        #: watched against (docs/method.md, "Creep")
        self._tail = TailWatch()
        self._tail_of: tuple | None = None
        #: what the fits derive from a rest reference, by name: (that reference, the value)
        self._of_rest_kept: dict[str, tuple[np.ndarray, np.ndarray]] = {}
        #: the last window's fit: (rest_px, current, valid, long press, contacts, gesture result)
        self._last_fit: tuple | None = None
        #: what the episode vote's window was fitted on: (rest reference, current, valid, contacts)
        self._voted: tuple | None = None
        #: the last fit's positions on the gel: (its contacts, rest, current; :meth:`_on_gel`)
        self._fitted_on_gel: tuple | None = None
        #: the noise filter in front of the tracker (one per pipeline, its state kept across
        #: batches; it starts afresh by itself when the clock goes back, ``noise.py``)
        self.noise_filter = self._noise_filter()

    #: Whether a resting window may take the compiled path (``rest_window.py``, which does in one
    #: call what this class's motion override and window estimate, ``_moving`` and ``_estimate``,
    #: do at rest); False: every window takes the general path. A subclass that overrides either
    #: must say which (:meth:`__init_subclass__`), and an instance may be set to False.
    rests_compiled: bool = True

    def __init_subclass__(cls, **kwargs) -> None:
        """Refuse a subclass that overrides ``_moving`` or ``_estimate`` without setting
        :attr:`rests_compiled`: the compiled path would silently stand for the methods it replaced
        (TypeError naming the class and the methods)."""
        super().__init_subclass__(**kwargs)
        overrides = [name for name in ("_moving", "_estimate") if name in cls.__dict__]
        if overrides and "rests_compiled" not in cls.__dict__:
            raise TypeError(
                f"{cls.__name__} overrides {' and '.join(overrides)}: set rests_compiled (False: its "
                "resting windows take the general path; True: the compiled path computes the same)"
            )

    @staticmethod
    def default_config() -> PipelineConfig:
        """The method's settings when none are given."""
        return PipelineConfig()

    # --- the product's composition: the steps a method may take differently ------------------
    def _scaled(self, settings: PipelineConfig, sensor: SensorGeometry) -> PixelSettings:
        """The settings that run: in pixels at the sensor's scale (``config.py``)."""
        return scaled_to_sensor(settings, sensor)

    def _episode_vote(self) -> EpisodeVote:
        """The episode vote with the settings' ``episode`` group (docs/method.md, "Episode vote")."""
        e = self.settings.episode
        return EpisodeVote(e.first_finger_us, e.correction_us, e.provisional_mm, firm_mm=e.firm_mm)

    def _creep_filter(self, sensor: SensorGeometry) -> CreepFilter | None:
        """The fingers' load behind the deformation when ``sensor.creep`` is measured, else None
        (docs/method.md, "Creep")."""
        return CreepFilter(*sensor.creep, floor=self.config.min_intensity_px) if sensor.creep is not None else None

    def _noise_filter(self) -> EventNoiseFilter | None:
        """The noise filter in front of the tracker (docs/method.md, "Noise filter")."""
        noise = self.settings.noise
        if noise.kind is None:
            return None
        return EventNoiseFilter(noise.kind, self.sensor.width, self.sensor.height, noise.time_us)

    # --- inputs -----------------------------------------------------------------------------
    def process(self, item: StreamItem) -> list[GestureEstimate]:
        """Feed one stream item (an EVENT_DTYPE batch, time-ordered, or a :class:`Frame`).

        Returns:
            the estimates of the windows whose end this item crossed (possibly none), in time
            order.
        Raises:
            SensorError: none of the first ``reference_attempts`` APS frames shows a marker grid
                ("no gel found"), or a frame has the wrong size.
        """
        self._apply_pending()
        if isinstance(item, Frame):
            return self._process_frame(item)
        return self._process_events(item)

    def run(self, stream: Iterable[StreamItem]) -> Iterator[GestureEstimate]:
        """Process a whole stream, yielding each window's estimate as it closes.

        Raises:
            SensorError: no gel found on the first frame, or the stream had no APS frame.
        """
        for item in stream:
            yield from self.process(item)
        if self.rest_px is None:
            raise SensorError("the stream has no APS frame: the pipeline needs one to find the gel's markers at rest")

    def compile_kernels(self) -> None:
        """Compile the pipeline's numba code (noise filter, tracker, gel motion, contacts, gesture) now, on a synthetic
        marker grid with a finger-like bump of displacement, a flat top, a pinch and a three-finger twist, instead of
        on the first real events: on a fresh install that takes seconds, which a real-time run would spend dropping
        data. Later runs load the code from numba's cache. Leaves the pipeline as it was."""
        self.compile_tracker_kernels()
        self.compile_window_kernels()

    def compile_tracker_kernels(self) -> None:
        """The per-event part of :meth:`compile_kernels`: the noise filter and the tracker's
        event-by-event kernels (a first run compiles them apart from the rest, first:
        ``warmup.TRACKER``)."""
        rest, _, _, _, _, events = synthetic_windows(self.sensor)
        tracker = BlobTracker(rest, self.sensor.width, self.sensor.height, self.settings.tracker, sensor=self.sensor)
        tracker.update(events)  # the batch whole: one version for batches of any length
        if self.noise_filter is not None:  # a fresh one: this pipeline's keeps its state
            self._noise_filter()(events)
        surface = time_surface(self.sensor.width, self.sensor.height)  # a resting window's one call
        end = int(events["timestamp"][-1])
        rest_window(events, surface, 1, end, True, *tracker.kernel_state(), rest, 1.0, len(rest) + 1)

    def compile_window_kernels(self) -> None:
        """The per-window part of :meth:`compile_kernels`: resting detection, gel motion, the
        camera model, the checks before a fit, contacts and gesture, then the tracker's APS-frame
        correction and its look for blobs on another marker (last: the per-event kernels it calls
        are compiled, or cached, by then)."""
        rest, moved, flat, pinch, three, events = synthetic_windows(self.sensor)
        all_valid = np.ones(len(rest), dtype=bool)
        compile_resting_kernels()  # its frames come later, possibly in the runtime's thread
        compile_gel_motion_kernels()  # the grid's rim barely moves: its fits stop before them
        compile_camera_model_kernels()  # the sensor gets its camera model at the rest frame
        compile_held_kernels()  # a press's held peaks: the synthetic windows below hold none
        _largest_move_sq(moved, all_valid, rest)  # every window's checks before a fit
        overrules_rest(moved, all_valid, rest, grid_neighbours(rest), 0.5, 1)  # the motion override's, at rest
        _unchanged(moved, flat, all_valid, all_valid)
        timings, self.timings = self.timings, None  # not a window: no stage time recorded
        try:
            self._fit(rest, moved, all_valid)
            self._fit(rest, flat, all_valid)
            self._fit(rest, pinch, all_valid)
            self._fit(rest, three, all_valid)  # three contacts: their centres' fit, called from Python
        finally:
            self.timings = timings
        tracker = BlobTracker(rest, self.sensor.width, self.sensor.height, self.settings.tracker, sensor=self.sensor)
        tracker.reset(rest)  # the re-anchoring at every APS frame at rest
        pitch = MARKER_SPACING_MM * self.sensor.px_per_mm  # the paper's settings have no pitch of their own
        swapped_blobs(tracker.positions_px, tracker.valid, rest, rest_neighbours(rest, pitch), rest + 0.5, pitch)
        tracker.correct(rest + 0.5, int(events["timestamp"][-1]))  # the frame correction's fusion

    def set_type_wait(self, wait: bool) -> None:
        """Whether a gesture whose windows show one contact stays undecided for the settings'
        ``episode.first_finger_us`` (True, the default) or commits its type at once (False: no
        wait, for a profile that reads no difference between the types the wait tells apart,
        ``mapping/commitment.py``). Takes effect from the next window; may be called from another
        thread than the one feeding the pipeline (one attribute written)."""
        self._episode.first_finger_us = self.settings.episode.first_finger_us if wait else 0

    def restart(self) -> None:
        """Start a new session after the source was interrupted (the camera was unplugged or
        stalled). A DAVIS stamps Unix time (us), so the new session's clock carries on.

        The tracked markers and open windows are dropped, but the rest reference is kept: the
        first APS frame that the resting detector finds at rest against it (paper, section
        "Resting Position Detection") re-initialises the markers, as the first frame did at the
        start (paper, section "Marker Tracking": t0 is a resting timestep). Until then events are
        dropped and no window closes. If :data:`RESUME_MATCH_FRAMES` frames in a row do not match
        the reference, the first frame unchanged from the one before it is taken instead. Before
        any reference exists this is a plain start again.
        """
        self._restart_frame_path()
        self._next_end = None
        self._episode.reset()
        self._long_press = False
        self._held = None
        self._last_intensity = None
        if self._creep is not None:
            self._creep.reset()
        self._tail.reset()

    # --- outputs ----------------------------------------------------------------------------
    def marker_positions(self) -> np.ndarray:
        """(N, 2) float32 current tracked positions (image px), NaN rows for lost markers;
        (0, 2) before the first frame."""
        if self.tracker is None:
            return np.zeros((0, 2), dtype=np.float32)
        positions = self.tracker.positions_px.astype(np.float32)
        positions[~self.tracker.valid] = np.nan
        return positions

    def markers(self) -> MarkerPositions | None:
        """The markers at the last window's end (:class:`~neurotouch_hid.core.stages.Pipeline`): rest
        and tracked positions, (N, 2) float64 image px, NaN rows for lost markers; None before the
        first APS frame."""
        if self.tracker is None or self.rest_px is None:
            return None
        return MarkerPositions(np.array(self.rest_px, dtype=np.float64), self.marker_positions().astype(np.float64))

    # --- internals --------------------------------------------------------------------------

    def _moving(self, current: np.ndarray, valid: np.ndarray) -> bool:
        """Whether the event path overrules the resting verdict: enough markers moved
        (``override.py``; docs/method.md, "Resting")."""
        c = self.config
        return overrules_rest(
            current, valid, self.rest_px, self._grid_neighbours, c.motion_override_px, c.override_min_markers
        )

    def _still(self, current: np.ndarray, valid: np.ndarray) -> bool:
        """True when no valid marker is ``min_intensity_px`` or more from rest: the intensity (a
        mean of displacements) is then below it and the gesture step answers ``none`` whatever
        the contacts, so the window skips the homography and the similarity (same estimate;
        e.g. a gel near rest after the tracker was re-anchored)."""
        largest = _largest_move_sq(current, valid, self.rest_px)  # < 0: no valid marker; NaN: not still
        limit = self.config.min_intensity_px
        return largest < 0.0 or largest < limit * limit

    def _vote(self, gesture: GestureType, intensity_mm: float, n_contacts: int, t_us: int) -> GestureType:
        """The window's type: the episode's committed type, ``none`` while undecided
        (docs/method.md, "Episode vote"); an undecided window of one contact felt at all also
        reads how far the gel moves against that contact's drag (:meth:`_counter_drag`)."""
        counter = math.inf
        if (
            n_contacts == 1
            and gesture is not GestureType.NONE
            and intensity_mm >= self._episode.provisional_mm
            and self._episode.undecided
        ):
            counter = self._counter_drag()
        return self._episode.update(gesture, intensity_mm, n_contacts, t_us, counter)

    def _estimate(self, t_us: int) -> GestureEstimate:
        current = self.tracker.positions_px
        valid = self.tracker.valid
        if self._resting.resting and not self._moving(current, valid):
            return self._none(t_us, resting=True)
        if self._still(current, valid):  # what the gesture step would answer, without its fits
            return self._none(t_us, resting=False)
        rest = self.rest_px
        contacts, result = self._contacts_and_gesture(rest, current, valid)
        if result.gesture is GestureType.NONE:
            return self._none(t_us, resting=False)
        if self._released(result.intensity_px, t_us):
            rest = self._new_press_in_tail(current, valid)
            if rest is None:
                return self._none(t_us, resting=False, fed=True)
            contacts, result = self._fit(rest, current, valid)  # the new press alone
            if result.gesture is GestureType.NONE:
                return self._none(t_us, resting=False, fed=True)
        self._voted = (rest, current, valid, contacts)
        return GestureEstimate(
            t_us=t_us,
            gesture=self._vote(result.gesture, result.intensity_mm, len(contacts.points_px), t_us),
            resting=False,
            intensity_mm=self._led(result.intensity_mm, t_us),
            contacts_px=contacts.points_px,
            contacts_mm=points_to_user(contacts.points_px, self.sensor),
            translation_mm=result.translation_mm,
            rotation_rad=result.rotation_rad,
            scale=result.similarity.scale,
        )

    def _led(self, intensity_mm: float, t_us: int) -> float:
        """The window's intensity (mm) extrapolated ``gesture.intensity_lead_us`` ahead along its
        change since the window before, when that one had a gesture too; never below 0. The
        stages before (vote, creep filter) keep the measured intensity (docs/method.md, "Gesture":
        intensity lead)."""
        before, self._last_intensity = self._last_intensity, (t_us, intensity_mm)
        if before is None:
            return intensity_mm
        slope = (intensity_mm - before[1]) / (t_us - before[0])
        return max(0.0, intensity_mm + slope * self.config.intensity_lead_us)

    def _none(self, t_us: int, *, resting: bool, fed: bool = False) -> GestureEstimate:
        """A window without a gesture: the vote hears ``none``, the creep filter (when not
        ``fed`` already) a gel below the intensity threshold (taken as 0 px), and the press ends."""
        if not fed and self._creep is not None:
            self._creep.update(0.0, t_us)
        self._vote(GestureType.NONE, 0.0, 0, t_us)
        self._last_intensity = None
        self._long_press = False
        self._held = None
        return GestureEstimate(t_us=t_us, gesture=GestureType.NONE, resting=resting)

    def _released(self, intensity_px: float, t_us: int) -> bool:
        """Whether the fingers' load behind the window's intensity (px) is below
        ``min_intensity_px`` plus the load's margin, with hysteresis (``CreepFilter.released``;
        docs/method.md, "Creep"; False without the gel's creep). The filter reads the gel's
        deformation as ``calibrate --press`` measured its creep on (``creep.amplitude``), and the
        share of it that is load scales the intensity."""
        if self._creep is None:
            return False
        amplitude = creep_amplitude(self.tracker.positions_px, self.rest_px, self.tracker.valid)
        load = self._creep.update(amplitude, t_us)
        scale = intensity_px / amplitude if amplitude > 0.0 else 1.0
        if not self._creep.released(load * scale, scale):
            self._tail.reset()
            return False
        return True

    def _new_press_in_tail(self, current: np.ndarray, valid: np.ndarray) -> np.ndarray | None:
        """While the creep filter reads the fingers gone: None, or (N, 2) px the gel as the tail
        left it when a new press has begun there (``creep.TailWatch``: markers, each by the median
        over its neighbourhood as the motion override takes it, ``TAIL_PRESS_SHARE`` of
        ``motion_override_px`` plus the gel's jitter beyond their least distance from rest, on
        ``TAIL_PRESS_MARKERS`` of ``override_min_markers``; docs/method.md, "Creep"). Watched
        afresh at a new rest reference or re-anchoring."""
        c = self.config
        if self._tail_of is None or self._tail_of[0] is not self.rest_px or self._tail_of[1] != self._anchorings:
            self._tail.reset()
            self._tail_of = (self.rest_px, self._anchorings)
        distance, jitter = shared_distances(current, valid, self.rest_px, self._grid_neighbours)
        positions = np.where(valid[:, None], current, self.rest_px)
        threshold = TAIL_PRESS_SHARE * c.motion_override_px + jitter
        markers = max(1, round(TAIL_PRESS_MARKERS * c.override_min_markers))
        return self._tail.update(distance, positions, threshold, markers)

    def _contacts_and_gesture(self, rest_px: np.ndarray, current: np.ndarray, valid: np.ndarray):
        """Contact points (paper, "Contact Point Detection") and the gesture's similarity, type and
        intensity (paper, "Gesture Classification and Intensity Prediction") of one window.

        Work that scales with what changed: when no tracked marker moved since the window before
        (the same rest reference, positions and lost markers, bit for bit: about half of the
        moving windows of a simulated session, e.g. a held gesture whose markers made no event)
        the previous window's contacts and gesture are returned as they are, without a new
        homography (both stages are deterministic functions of these inputs, of whether the
        press had a long flat top and of the fingers' peaks it holds; OpenCV's RANSAC and USAC
        draw from fixed seeds, so the predictions are byte-identical)."""
        last = self._last_fit
        long_before = self._long_press
        held = self._held[1] if self._held is not None and self._held[0] is rest_px else None
        if (
            last is not None
            and last[0] is rest_px
            and last[3] == long_before
            and _same_held(last[6], held)
            and _unchanged(last[1], current, last[2], valid)
        ):
            begin = self._clock()
            self._record("contacts", begin)
            self._record("gesture", begin)
            contacts, result = last[4], last[5]
        else:
            contacts, result = self._fit(rest_px, current, valid, held)
            self._last_fit = (rest_px, current.copy(), valid.copy(), long_before, contacts, result, held)
        self._long_press = long_before or contacts.long_flat_top
        self._held = (rest_px, contacts.held)
        return contacts, result

    def _image_neighbours(self, rest_px: np.ndarray) -> np.ndarray:
        """(N, K) int64 each marker's neighbours on the gel at rest in the image (``rest_neighbours``
        at the marker pitch), kept per rest reference: the frame correction's (the contacts stage
        takes its own on the undistorted rest positions, :meth:`_fit`)."""
        pitch = self.config.marker_pitch_px
        return self._of_rest("image neighbours", rest_px, lambda rest: rest_neighbours(rest, pitch))

    def _of_rest(self, name: str, rest_px: np.ndarray, make: Callable[[np.ndarray], np.ndarray]) -> np.ndarray:
        """``make(rest_px)``, computed once per rest reference (the pipeline's own, or
        :meth:`compile_kernels`' synthetic grid) and kept under ``name``: the gel's rim markers
        (gel_motion), the rest positions undistorted and neighbour tables."""
        kept = self._of_rest_kept.get(name)
        if kept is None or kept[0] is not rest_px:
            kept = self._of_rest_kept[name] = (rest_px, make(rest_px))
        return kept[1]

    def _clock(self) -> tuple[int, int] | None:
        if self.timings is None:
            return None
        return time.perf_counter_ns(), time.thread_time_ns()

    def _record(self, stage: str, start: tuple[int, int] | None) -> None:
        if start is not None:
            self.timings[stage].append(time.perf_counter_ns() - start[0])
            self.cpu_timings[stage].append(time.thread_time_ns() - start[1])
