"""The pipeline's frame path (paper, "Resting Position Detection" and "Marker Tracking";
docs/method.md, "Markers", "Resting" and "Frame correction"): what each APS frame does to the
gesture pipeline (:class:`~neurotouch_hid.pipeline.pipeline.GesturePipeline`, which composes it
with the window path).

The first APS frame showing the gel's marker grid at its calibrated rest is the rest reference
(``markers.py``; the camera model is fitted to it, ``camera_model.py``); every later frame goes to
the resting detector (``resting.py``), inline or in another thread (:meth:`FramePath.set_resting`);
at rest, or near it unless a press is growing from rest, the tracker is re-anchored at the rest
positions, otherwise the frame's marker centroids correct the blobs (``tracker.py``), the blobs
left on another marker than their own first put back on theirs. After a
restart the kept reference is matched again before the markers are re-initialised.
"""

from __future__ import annotations

import threading

import numpy as np

from neurotouch_hid.core.camera_model import fit_camera_model
from neurotouch_hid.core.errors import SensorError
from neurotouch_hid.core.estimate import GestureEstimate
from neurotouch_hid.pipeline.markers import MARKER_SPACING_MM, detect_markers, looks_like_marker_grid
from neurotouch_hid.pipeline.moves import _off_layout
from neurotouch_hid.pipeline.override import grid_neighbours
from neurotouch_hid.pipeline.resting import RestingDetector, RestingResult
from neurotouch_hid.pipeline.tracker import BlobTracker, swapped_blobs
from neurotouch_hid.sources import Frame

__all__ = ["FramePath", "MAX_PENDING_VERDICTS", "RESUME_MATCH_FRAMES"]

#: After a restart, how many APS frames may fail to match the kept rest
#: reference (2 s at 25 Hz) before a frame that is merely still (unchanged from the frame before)
#: re-initialises the markers instead: the gel or the light may have changed while the camera was
#: away, and the driver must not wait for ever.
RESUME_MATCH_FRAMES = 50

#: Verdicts handed over for frames the stream has not yet brought the pipeline to, kept at most
#: (:meth:`FramePath.set_resting`; 0.64 s at 25 Hz: older ones are superseded anyway).
MAX_PENDING_VERDICTS = 16


class FramePath:
    """The frame half of the gesture pipeline: the rest reference, the resting verdicts and what
    they do to the tracker. A base of :class:`~neurotouch_hid.pipeline.pipeline.GesturePipeline`,
    which provides ``sensor``, ``settings``, ``config`` (pixel settings), ``detect_resting``,
    ``_creep``, ``_scaled``, the stage clock (``_clock``, ``_record``), the markers' neighbours at
    rest (``_image_neighbours``) and ``_close_windows_until`` (the window path).

    Attributes:
        rest_px: (N, 2) float64, rest marker positions (image px), None before the first frame.
        tracker: the :class:`BlobTracker`, None before the first frame and after a restart.
        resting_detector: the :class:`RestingDetector`, None before the first frame.
        pressed_frames: reference candidates refused because the gel was pressed.
    """

    def _init_frame_path(self) -> None:
        """The frame path's state before the first frame."""
        self.rest_px: np.ndarray | None = None
        #: how many times the tracker was re-anchored at rest
        self._anchorings = 0
        self._grid_neighbours: np.ndarray | None = None
        self.resting_detector: RestingDetector | None = None
        self._lock = threading.Lock()
        #: reference candidates refused because the gel was pressed (:meth:`_rest_reference_ok`)
        self.pressed_frames = 0
        self._previous_points: np.ndarray | None = None
        self._pending: list[tuple[RestingResult, int]] = []
        self._restart_frame_path()

    def _restart_frame_path(self) -> None:
        """Drop the tracker and the verdicts; keep the rest reference (``GesturePipeline.restart``)."""
        self.tracker: BlobTracker | None = None
        with self._lock:
            #: verdicts handed over by :meth:`set_resting`, by increasing frame time, not yet applied
            self._pending = []
        self._resting = RestingResult(True, 0.0)
        self._resting_t_us = -(2**62)
        self._press_px = 0.0
        #: the time of the latest APS frame the stream has brought the pipeline to (us)
        self._frame_t_us = -(2**62)
        self._rejected_frames = 0
        self._resume_waited = 0
        self._previous_frame: Frame | None = None

    def set_resting(self, result: RestingResult | None, t_us: int) -> None:
        """Hand over a resting verdict computed elsewhere (e.g. another thread) for the frame at
        ``t_us``. Thread-safe. It is applied once the stream has brought the pipeline to that
        frame (at the frame, or before the next item when the verdict comes later), as a verdict
        computed inline is: at rest the tracker is reset to the rest positions, otherwise the
        frame's markers correct it, and estimates say ``resting`` until a verdict says not. A
        pipeline running behind its source (a cold start, a busy machine) would otherwise apply a
        later frame's verdict to earlier windows. ``None`` (no verdict yet) and verdicts older than
        one already handed over are ignored; of several reached at once, the latest is applied."""
        if result is None:
            return
        with self._lock:
            if not self._pending or t_us >= self._pending[-1][1]:
                self._pending.append((result, int(t_us)))
                del self._pending[:-MAX_PENDING_VERDICTS]

    @property
    def resting(self) -> RestingResult:
        """The resting verdict currently in force."""
        return self._resting

    def _process_frame(self, frame: Frame) -> list[GestureEstimate]:
        """One APS frame: the rest reference, or the windows it closes and its resting verdict."""
        self._frame_t_us = frame.t_us
        if self.tracker is None:
            if self.rest_px is None or self._at_rest_after_restart(frame):
                self._initialise(frame)
            return []
        out = self._close_windows_until(frame.t_us)
        if self.detect_resting:
            start = self._clock()
            result = self.resting_detector.update(frame, verdict_only=True)
            self._record("resting", start)
            self._resting_t_us = frame.t_us
            self._apply_resting(result, frame.t_us)
        else:
            self._apply_pending()  # this frame's verdict, when it was computed beside in time
        return out

    def _initialise(self, frame: Frame) -> None:
        markers = detect_markers(frame.image, self.sensor, self.config.marker_threshold)
        if not looks_like_marker_grid(markers, self.sensor):
            self._rejected_frames += 1
            if self._rejected_frames < self.config.reference_attempts:
                return  # e.g. an under-exposed first frame: try the next one
            raise SensorError(
                f"no gel found: the first {self._rejected_frames} APS frame(s) (the last at t = {frame.t_us} us, "
                f"{len(markers)} bright blobs) do not look like NeuroTouch's marker grid (1 mm dots, 4 mm apart, "
                "inside the gel disc of sensor.yaml); is this a NeuroTouch recording, and does sensor.yaml match it?"
            )
        if not self._rest_reference_ok(markers.centroids_px):
            self.pressed_frames += 1
            return  # the gel is pressed: this frame is no rest reference; wait for one that is
        self.rest_px = markers.centroids_px.astype(np.float64)
        self._use_camera_model()
        self._grid_neighbours = grid_neighbours(self.rest_px)
        self.tracker = BlobTracker(
            self.rest_px, self.sensor.width, self.sensor.height, self.settings.tracker, sensor=self.sensor
        )
        self.resting_detector = self._resting_detector(frame.image)
        self._resting = RestingResult(True, 0.0)

    def _rest_reference_ok(self, points_px: np.ndarray) -> bool:
        """Whether a candidate reference frame's markers (M, 2) px lie on the calibrated rest
        layout (sensor.yaml's ``rest_markers_px``; docs/method.md, "Markers"): at most 5 % of
        the calibrated markers without a detected marker within ``rest_match_pitch`` pitches.
        Without a calibrated layout every frame passes. After :data:`RESUME_MATCH_FRAMES`
        refused frames a frame whose markers match the previous frame's (the gel is still) is
        taken, so that a gel moved since its calibration cannot stop the driver for good."""
        layout = self.sensor.extra.get("rest_markers_px")
        if layout is None or len(points_px) == 0:
            return True
        tol = self.config.rest_match_pitch * MARKER_SPACING_MM * self.sensor.px_per_mm
        points = np.asarray(points_px, dtype=np.float64)
        previous, self._previous_points = self._previous_points, points
        if _off_layout(np.asarray(layout, dtype=np.float64).reshape(-1, 2), points, tol) <= 0.05:
            return True
        return (
            self.pressed_frames >= RESUME_MATCH_FRAMES
            and previous is not None
            and _off_layout(previous, points, tol) <= 0.05
        )

    def _resting_detector(self, reference: np.ndarray) -> RestingDetector:
        """A resting detector with ``reference`` as its rest image: the Chamfer distance over the
        markers' centroids (docs/method.md, "Resting"). Raises SensorError when it shows no marker."""
        c = self.config
        return RestingDetector(reference, self.sensor, c.centroid_threshold, c.marker_threshold)

    def _use_camera_model(self) -> None:
        """Without a model in sensor.yaml: the sensor as fitted to the rest reference's markers
        (:func:`fit_camera_model`; docs/method.md, "Camera model"), and the pixel settings
        following its px_per_mm. Unchanged when the markers do not index as the 4 mm grid."""
        if self.sensor.radial_k is not None:
            return
        fitted = fit_camera_model(self.rest_px, self.sensor)
        if fitted is not None:
            self.sensor = fitted
            self.config = self._scaled(self.settings, fitted)
            if self._creep is not None:
                self._creep.floor = self.config.min_intensity_px

    def _at_rest_after_restart(self, frame: Frame) -> bool:
        """After a restart (``GesturePipeline.restart``): whether ``frame`` may re-initialise the
        markers (see there)."""
        if self.resting_detector.update(frame, verdict_only=True).resting:
            return True
        self._resume_waited += 1
        previous, self._previous_frame = self._previous_frame, frame
        if self._resume_waited <= RESUME_MATCH_FRAMES or previous is None:
            return False
        try:
            still = self._resting_detector(previous.image)
        except SensorError:  # the frame before shows no marker at all
            return False
        return still.update(frame, verdict_only=True).resting

    def _apply_pending(self) -> None:
        """Apply the latest handed-over verdict of a frame the stream has reached (:meth:`set_resting`)."""
        if not self._pending:  # every item comes here: no lock while nothing is handed over (a
            return  # verdict handed over meanwhile is applied at the next item, as after the lock)
        with self._lock:  # nothing is allocated while nothing is reached
            n = 0
            while n < len(self._pending) and self._pending[n][1] <= self._frame_t_us:
                n += 1
            if n == 0:
                return
            pending = self._pending[n - 1]
            del self._pending[:n]
        if pending[1] >= self._resting_t_us:
            self._resting_t_us = pending[1]
            self._apply_resting(pending[0], pending[1])

    def _apply_resting(self, result: RestingResult, t_us: int) -> None:
        """The frame path after the resting detector: at rest (or near it, :meth:`_near_rest`)
        the tracker is re-anchored at the rest positions; otherwise the frame corrects the blobs."""
        self._resting = result
        if self.tracker is None:
            return
        near = self._near_rest(result)
        if result.resting or near:
            self.tracker.reset(self.rest_px)
            self._anchorings += 1
        else:
            self._correct(result, t_us)

    def _near_rest(self, result: RestingResult) -> bool:
        """Whether a frame not at rest is near enough to re-anchor the tracker: its distance is
        within the near-rest threshold and it shows no press growing beyond ``press_px``
        (docs/method.md, "Resting"). Called on every frame, in order: it keeps the frame's press
        for the next."""
        growing = self._press_px < result.press_px
        self._press_px = result.press_px
        if growing and result.press_px > self.config.press_px:
            return False
        return result.distance <= self.config.centroid_reset_threshold

    def _correct(self, result: RestingResult, t_us: int) -> None:
        """Fuse the frame's marker centroids into the blobs (:meth:`BlobTracker.correct`), after
        putting back on their own markers the blobs a fast motion left on another
        (:func:`~neurotouch_hid.pipeline.tracker.swapped_blobs`, :meth:`BlobTracker.relocate`;
        docs/method.md, "Frame correction")."""
        if result.centroids_px is not None:
            start = self._clock()
            c = self.config
            moved, where = swapped_blobs(
                self.tracker.positions_px,
                self.tracker.valid,
                self.rest_px,
                self._image_neighbours(self.rest_px),
                result.centroids_px,
                c.marker_pitch_px,
            )
            self.tracker.relocate(moved, where)
            self.tracker.correct(result.centroids_px, t_us)
            self._record("frame_correction", start)
