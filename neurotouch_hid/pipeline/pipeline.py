"""The gesture detection pipeline (paper, section "Methodology", Figure "Complete gesture
detection framework"): events and APS frames in, one :class:`GestureEstimate` per window out.

Stages, one module each:

1. markers (``markers.py``): the first APS frame is the rest reference (the paper's t0 is a
   resting timestep); its markers are detected and checked to look like the gel's grid (a few
   first frames may fail, e.g. under-exposed, before "no gel found" is raised);
2. tracker (``tracker.py``): event-by-event blob tracking gives p_i(t_k), v_i = p_i(t_k) - p_i(t0);
3. contacts (``contacts.py``): RANSAC homography outliers, local displacement maxima;
4. gesture (``gesture.py``): 4-DoF similarity about the contacts -> type, intensity;
5. resting (``resting.py``): Chamfer distance of each APS frame to the reference; at rest the
   gesture is ``none`` and the tracker is reset to the rest positions.

Stale resting verdicts (``PipelineConfig.motion_override_px``, not in the paper): a verdict
comes from an APS frame, i.e. is up to 40 ms old at 25 Hz, so a gesture starting after a
resting frame would be answered ``none``/resting for up to four 10 ms windows. The paper
(section "Resting Position Detection") uses the APS frames because the scene is static at rest,
and the events for dynamics; so the event path may overrule a resting verdict: the tracker was
reset to the rest positions with that verdict, and when, at a window's end, at least
``override_min_markers`` tracked markers have moved more than ``motion_override_px`` from rest, the window is processed
as a gesture window (``resting`` False). The verdict itself stays in force (no further tracker
reset); the next APS frame's verdict decides again.

Smooth override (``PipelineConfig.override_smooth``, not in the paper): a gel's displacement
field is smooth, a finger moves a marker's neighbours with it; tracker noise is not. Under a
flickering light (the ``flicker`` family) every marker's edges fire events at rest, the tracker
jitters by up to ~0.8 px in random directions between two frames, and 12 jittering markers
overruled the resting verdict on ~9 % of the resting windows (docs/accuracy.md, "Round 3").
With the option, the override counts markers whose displacement *median-filtered over the
marker and its nearest neighbours at rest* (:func:`grid_neighbours`, per component) exceeds
``motion_override_px``: a coherent bump passes unchanged, scattered jitter is voted down. It is
asked only when the markers' own displacements would overrule (so it never overrules more).

Near rest (``PipelineConfig.centroid_reset_threshold``, not in the paper): the centroid
distance (``resting_centroids``) sees the last tenth of a millimetre of a gel creeping back after
a release, which the pixel-set distance did not: such frames are rightly not at rest (the labels'
rest is every marker within 0.1 mm), but the tracker, not reset since the gesture began, then
reports its own accumulated error (~0.4-0.5 mm on the ``camera`` family) as a gesture. A frame
whose centroids are within ``centroid_reset_threshold`` of the reference's (about the pixel-set
rule's old sensitivity) re-anchors the tracker at rest without being called resting: the windows
after it read ``none``, not resting, until the gel moves again.

APS-frame correction (``PipelineConfig.frame_correction``, not in the paper): the tracker runs
on events (paper, "Marker Tracking"), and a held marker makes none, so its blob stays where its
last events left it, ~0.3-0.6 px short. The resting detector finds every frame's marker
centroids anyway (``resting_centroids``); on a frame that is neither at rest nor near rest the
pipeline fuses them into the blobs (:meth:`BlobTracker.correct`: gated, mutual-nearest matches,
the frame's noise widened by the blob's motion over the exposure). Near rest the re-anchoring
wins: the frame's centroids are then not fused.

Gesture decision over one gesture (``PipelineConfig.episode_vote``, not in the paper): the
paper decides the type window by window, so a pinch whose first finger leads reads as push in
its first windows and again in its release. With the vote, the windows from a gesture's onset (the
first window with a gesture) to its end (the next ``none`` or resting window) form one episode;
each window adds its intensity (mm) to the votes of its own type, and every window of the
episode reports the type with the most votes so far. The first window of an episode is answered
as before (no added latency at onset); a later window changes the answer only once its type has
outweighed the others' accumulated intensity (the latency of such a change is measured in
docs/accuracy.md). With ``vote_restart``, a push decided on fewer contacts than
a later window sees restarts the votes at that window (a leading finger's push gives way to the
pinch, zoom or twist once its other fingers are seen; ``gesture.EpisodeVote``).

A creeping gel (``PipelineConfig.creep_load``, with sensor.yaml's ``creep``; not in the paper):
after a release a soft gel relaxes slowly and still shows a gesture's deformation for a while.
With the gel's creep measured (``calibrate --press``), each window's intensity runs through the
standard linear solid's inverse (``creep.py``) and a window whose load is below
``min_intensity_px`` answers ``none``: the fingers have left.

Windows: ``window_us`` long (10 ms default, paper, section "Runtime Performance"; anything
down to 1 ms), aligned on multiples of ``window_us`` from the first event after the reference
frame. An estimate is emitted for every window end crossed, even by a window without events,
with ``t_us`` = the window's end; events at ``t`` belong to the window ending after ``t``.
Events before the reference frame are dropped (there is nothing to track them against).

Threads: the resting detector may run in another thread on the frames (paper: "operating in
parallel to the main pipeline"); set ``PipelineConfig.detect_resting = False`` and hand its
results to :meth:`GesturePipeline.set_resting`, which is thread-safe (the result is applied by
the pipeline's own thread at its next item, so the tracker is never reset mid-batch).
"""

from __future__ import annotations

import dataclasses
import threading
import time
from collections.abc import Callable, Iterable, Iterator

import numba
import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationInfo, field_validator, model_validator

from neurotouch_hid.camera_model import fit_camera_model
from neurotouch_hid.errors import SensorError
from neurotouch_hid.estimate import GestureEstimate, GestureType
from neurotouch_hid.pipeline.contacts import HOMOGRAPHY_METHODS, detect_contacts
from neurotouch_hid.pipeline.contacts_plateau import rest_neighbours
from neurotouch_hid.pipeline.creep import CreepFilter
from neurotouch_hid.pipeline.episode import EpisodeVote
from neurotouch_hid.pipeline.gel_motion import compile_gel_motion_kernels, estimate_gel_motion, rim_markers
from neurotouch_hid.pipeline.gesture import compile_camera_model_kernels, estimate_gesture, points_to_user
from neurotouch_hid.pipeline.learned import gesture_features, learned_gesture
from neurotouch_hid.pipeline.markers import MARKER_SPACING_MM, detect_markers, looks_like_marker_grid
from neurotouch_hid.pipeline.noise import EventNoiseFilter, check_noise_filter
from neurotouch_hid.pipeline.resting import RestingDetector, RestingResult, compile_resting_kernels
from neurotouch_hid.pipeline.tracker import BlobTracker, TrackerConfig
from neurotouch_hid.sensor import SensorGeometry
from neurotouch_hid.sources import EVENT_DTYPE, Frame, StreamItem

#: Shortest window accepted (us).
MIN_WINDOW_US = 1_000
#: After :meth:`GesturePipeline.restart`, how many APS frames may fail to match the kept rest
#: reference (2 s at 25 Hz) before a frame that is merely still (unchanged from the frame before)
#: re-initialises the markers instead: the gel or the light may have changed while the camera was
#: away, and the driver must not wait for ever.
RESUME_MATCH_FRAMES = 50

#: The stages :attr:`GesturePipeline.timings` measures.
STAGES = ("noise_filter", "tracker", "contacts", "gesture", "resting", "frame_correction")


class PipelineConfig(BaseModel):
    """Every threshold of the pipeline. The defaults are this project's tuned settings, not the
    paper's; the paper's method and hyperparameters are the ``paper`` preset
    (:data:`PIPELINE_PRESETS`, ``track/eval --preset paper``).

    A pydantic model: a value of the wrong type, out of range, or an unknown field raises
    ``pydantic.ValidationError`` (a ValueError) naming the field and what was expected; the
    CLI's ``--set NAME=VALUE`` is converted through it (``evaluation/runner.py``).

    The defaults are tuned on the simulator's tuning users (5-9, ``paper`` preset, odd seed 1,
    5 simulated minutes) with ``benchmarks/tune_pipeline.py``, never on the test users; each
    departure from the paper, and why (measured there, docs/accuracy.md "Tuning protocol"):

    - ``r_px`` 25 (paper 30) and ``n_min`` 12 (paper 4): with the options below, r = 30 read
      multi-finger gestures as push more often (gesture accuracy 92.9-93.7 % against 95.2 %),
      and n_min < 8 let the noise of weakly deformed windows make extra contacts (contact
      count accuracy 85-89 % against 90.8 %). ``a`` stays the paper's 0.6.
    - ``chamfer_threshold`` 0.4 (paper 2.5) with ``chamfer_per_marker`` on: our Chamfer
      distance is normalised per reference marker (the sum of squared nearest distances over both
      marker-pixel sets divided by the number of reference markers, px^2, ``resting.py``), not
      the paper's raw sum, so the paper's 2.5 is on another scale; per APS frame, resting F1
      97.5 % at 0.4 against 92.0 % at 2.5; the detector's own rest noise is ~0.4, so 0.2 fails (51 %).
    - ``min_intensity_px`` 0.3 (was 0.5, not in the paper): gesture accuracy +0.1 point.
    - ``intensity_sigma_px`` 3 (paper: uniform mean over A): intensity MAE 1.36 -> 0.28 mm.
    - ``field_fallback`` on: gesture accuracy +1.8 points (wide multi-finger pushes).
    - ``contact_refine_px`` 20: contact distance error 2.76 -> 1.82 mm.
    - ``plateau_fraction`` 0.8, ``maxima_at_rest``, ``spike_fraction`` 0.6, ``camera_model`` and
      ``gesture_classifier`` (issue 9, round 3) were decided on the development physics families instead
      (docs/accuracy.md, "Round 3: contact points and the camera model"), each below.
    - ``origin_radius_px`` 10 (one marker pitch): gesture accuracy 95.24 -> 95.62 % (5 px:
      95.51, 15: 95.37, 25: 94.87 -- larger radii let a push's rotation noise cancel its
      translation).
    - ``motion_override_px`` 0.3: resting F1 +0.1 point, gesture accuracy +0.07 point (the
      stale-verdict windows at onsets mostly move less than the tracker noise).
    - ``noise_filter`` ``BackgroundActivityNoiseFilter`` with 20 ms (not in the paper; chosen
      over off, ``FastDecayNoiseFilter`` and ``KNoiseFilter`` at several times, on the tuning
      set simulated at 0.1, 1 and 3 Hz per pixel of background activity): at 0.1 Hz (the
      simulator's default) the metrics stay within 0.1 point of off except contact count
      accuracy (-0.9 point; test set: +0.04), at 3 Hz contact count accuracy 80.8 -> 87.1 %,
      distance 2.74 -> 2.02 mm, gesture 92.3 -> 94.2 %. Shorter times or the other filters
      drop too many marker events at 0.1 Hz (gesture accuracy below 95 %); longer fast-decay
      half-lives let 3 Hz noise through. Cost: ~2 M events/s with its conversions
      (docs/performance.md, "Noise filter").

    Issue 9, round 3 (decided on the physics families other than the final ones, per family in
    docs/accuracy.md "Round 3: resting detection and gel drift"; not in the paper):

    - ``resting_centroids`` with ``centroid_threshold`` 0.01 (``chamfer_threshold`` then unused):
      the Chamfer distance over the markers' centroids, which a flickering light does not move
      (``flicker``: resting F1 32.7 -> 85.8 %, gesture 82.9 -> 92.8 %).
    - ``override_smooth``: tracker jitter under flicker no longer overrules a resting verdict
      (``flicker``: resting F1 85.8 -> 95.0 %).
    - ``centroid_reset_threshold`` 0.05: a frame near rest re-anchors the tracker (``camera``
      gesture +0.6, ``strong`` +1.0, ``flicker`` -0.6 points).
    - ``gel_motion``: the rim's shared rigid motion (the gel sliding in its mount) is removed
      before the contact and gesture steps (``drift``: gesture 83.8 -> 94.6 %).

    The paper's pipeline is ``--preset paper`` (:data:`PIPELINE_PRESETS`): r 30 px, a 0.6 (for
    both RANSAC fits: the paper states one dynamic threshold), N_min 4, the raw Chamfer sum of
    the paper's equation with its threshold 2.5, no minimum intensity and none of the options
    above. docs/accuracy.md's earlier "paper's pipeline" figures used a nearer variant
    (``--set`` list there: per-marker Chamfer at 2.5, minimum intensity 0.5 px, the similarity's
    threshold 2.0).

    Attributes:
        window_us: window length (us), >= 1000; paper: 10 ms.
        r_px: radius r of the contact neighbourhoods and of the set A (px); paper: 30 px.
        a: dynamic reprojection threshold coefficient of the contact homography; paper: 0.6.
        n_min: minimum number of candidates in a contact's neighbourhood; paper: 4.
        homography_max_iters: iteration cap of the contact homography's RANSAC (OpenCV's
            default 2000; it stops earlier at 0.995 confidence).
        homography_method: ``usac_fast`` (OpenCV's USAC: RANSAC with local optimisation; as
            accurate as classic RANSAC on the simulated gel, ~2.5x faster) or ``ransac``
            (classic RANSAC), see ``contacts.HOMOGRAPHY_METHODS``.
        chamfer_threshold: Chamfer distance (px^2, see ``resting.py``) at or below which the
            gel rests; paper: 2.5 (on its raw sum).
        chamfer_per_marker: True: the Chamfer distance is divided by the reference's number of
            markers (``resting.py``; not in the paper); False: the paper's raw sum.
        resting_centroids: True: the resting detector's Chamfer distance is taken over the
            markers' weighted centroids instead of their pixels (``resting.py``, "Marker
            centroids"; not in the paper), so that a flickering or dimming light does not read
            as motion, with ``centroid_threshold`` in place of ``chamfer_threshold``; False: over
            the marker pixels (paper). Measured per physics family in docs/accuracy.md, "Round 3".
        centroid_threshold: the centroid distance (px^2 per reference marker) at or below which
            the gel rests, with ``resting_centroids``. 0.01 (decided on the development families,
            docs/accuracy.md "Round 3"): a gel at rest gives 0.002-0.01 under a steady or a
            flickering light; with the near-rest re-anchoring at 0.05, 0.01 against 0.02 gave
            resting F1 +0.1 to +1.6 points on six families and gesture accuracy within 0.05
            point (flicker -0.4).
        centroid_reset_threshold: None, or a centroid distance (px^2 per reference marker, >=
            ``centroid_threshold``) at or below which a frame that is not at rest still re-anchors
            the tracker at the rest positions (module docstring, "Near rest"; not in the paper).
            0.05: the loosest resting threshold tried (there resting F1 fell ~2 points: such
            frames are not rest, but near enough that the tracker's own error exceeds the gel's).
        min_intensity_px: below this intensity (px), nothing moves: ``none``.
        gesture_reproj_factor: the similarity's RANSAC threshold, as a multiple of A's mean
            displacement. A loose 2.0 keeps most of A (RANSAC then only drops grossly mistracked
            markers): on the simulated gel 0.6 let one finger's markers win the consensus, so
            pinch, zoom and twists read as push on ~45 % of their windows, against ~10 % at 2.0.
        min_gesture_reproj_px: floor of that threshold (px).
        intensity_sigma_px: the intensity profile (``gesture.weighted_intensity``): None = the
            paper's mean ||v_i|| over A; > 0 = a mean weighted by proximity to the contacts
            (Gaussian of this sigma, px), which estimates the contact points' own displacement.
        field_fallback: when the homography's outliers give no contact, look for the local
            maxima over the whole displacement field (``contacts.py``; not in the paper).
        contact_refine_px: None: a contact point is the position of its peak marker (paper);
            > 0: refined below the marker pitch by quadratic fits over the markers within this
            radius (px) (``contacts.refine_peak``; not in the paper).
        plateau_fraction: None: every local maximum is a contact (paper); in (0, 1): maxima on
            one plateau of the field at this fraction of its peak are one flat top, whose
            contacts are read off its area (one per fingertip footprint pi r^2, at most 3) and
            placed along its principal axis (``contacts.plateau_contacts``; not in the paper).
            0.8, decided on the development families (docs/accuracy.md, "Round 3"): contact
            count +2.7 to +6.2 points, distance 2.26 -> 1.49 mm on ``default``; 0.7 and 0.85
            within 1.6 points of count and 0.15 mm of it.
        marker_pitch_px: the marker pitch (px; 4 mm at 2.5 px/mm), for the plateaus.
        maxima_at_rest: False: a contact's neighbourhood N(i) is the candidates within r of its
            current position (paper); True: within r of its rest position, i.e. on the gel
            (``contacts.py``, "Neighbourhoods on the gel"; not in the paper). On (development
            families, docs/accuracy.md "Round 3"): contact count +0.05 to +3.1 points (``drift``
            +3.1, ``strong`` +2.5, ``markers`` +2.2), gesture ``drift`` +3.0; no family loses more
            than 0.05 point.
        spike_fraction: None: every marker's ||v|| as tracked (paper); in (0, 1]: a marker displaced
            more than 1 / spike_fraction times the median of its neighbours on the gel (within 1.5
            pitches at rest) counts with that median in the contact stage (``contacts.py``, "Lone
            markers"; not in the paper). 0.6, decided on the development families
            (docs/accuracy.md "Round 3"; 0.3, 0.5 and 0.7 measured): contact count +0.2 to +5.3
            points (``noise`` +5.3), distance -0.03 to -0.21 mm, gesture -0.3 to +0.4 points.
        bump_fit: False: a contact point is its displacement maximum (paper, "Contact Point
            Detection"); True: where there are at least two contacts and no multi-finger flat
            top, their centres are fitted as radial bumps of one profile measured on the
            window's own field (knots one ``marker_pitch_px`` apart up to sensor.yaml's gel
            radius), which long-tailed fields push away from the maxima (``contacts.bump_fit``;
            not in the paper). The gesture step still reads A and the intensity about the
            maxima. On (issue 9, round 4, docs/accuracy.md "Round 4: contact points on
            long-tailed fields"): contact distance lower on all twelve families (``powerlaw``
            4.42 -> 3.71 mm, ``stickslip`` 4.69 -> 3.41 mm, ``default`` 1.39 -> 1.15 mm), the
            other metrics unchanged.
        gesture_classifier: False: the gesture type is the largest similarity term (paper);
            True: a window the rule calls a gesture gets the type of a logistic regression on the
            similarity terms and the contacts' relative motion (``learned.py``, constants in
            ``gesture_model.py``, trained by ``benchmarks/train_gesture_classifier.py`` on the
            tuning users of the development families; not in the paper). On: trained without a
            family and scored on its test users, it wins on ``powerlaw`` (+9.1 points of the
            windows' type), ``drift`` (+6.3) and ``fingers`` (+1.1) and loses at most 0.31 point
            elsewhere (docs/accuracy.md, "Round 3").
        origin_radius_px: None: the translation term of the gesture type is taken about the
            contacts' mean (paper); > 0: at the best origin within this distance (px) of it
            (``gesture.py``, "Origin"; not in the paper).
        motion_override_px: None, or the displacement from rest (px) beyond which at least
            ``override_min_markers`` tracked markers overrule a resting verdict (module
            docstring; not in the paper).
        rest_match_pitch: a candidate rest reference (the first APS frame with a marker grid)
            is refused while its markers are off the calibrated rest layout (sensor.yaml
            ``rest_markers_px``) by more than this many marker pitches in the median
            (``_matches_calibrated_rest``; not in the paper); None: any frame (paper).
        follow_px_per_mm: every pixel setting here and in ``tracker`` is given at 2.5 px/mm
            (:data:`REFERENCE_PX_PER_MM`) and follows sensor.yaml's px_per_mm
            (:func:`scaled_to_sensor`; not in the paper); False: fixed pixels (paper).
        camera_model: when sensor.yaml has no camera model (``radial_k``, written by
            ``calibrate``), fit one to the rest reference's markers, the 4 mm grid at rest
            (``camera_model.fit_camera_model``; not in the paper): its px_per_mm at the centre
            replaces sensor.yaml's for the pixel settings, and every mm figure (intensity,
            contact points, translation) is converted through it. False: sensor.yaml as it is
            (the paper's one scale when it has no model).
        episode_vote: the type of every window of a gesture episode is the intensity-weighted
            vote of its windows so far (module docstring; not in the paper); False: each window's
            own type (paper). On (decided on the development families before the final one was
            run, docs/accuracy.md "Physics families"): gesture accuracy +0.6 to +3.6 points on 8
            of the 10 development families, -1.3 on ``fingers`` (lagging fingers: the first
            finger's push windows outvote the pinch) and -0.2 on ``strong``; type changes per
            gesture 2.4-14.7 -> 0.6-3.0; median onset latency -5 to +15 ms (mean +2.8 ms).
        vote_restart: with ``episode_vote``, a push decided on fewer contacts than a later
            window of the episode sees gives way: that window (another type) restarts the votes
            (``gesture.EpisodeVote``; not in the paper). Decided on the twelve development
            families of round 4 (docs/accuracy.md "Round 4"): ``fingers`` +1.8 points (a
            leading finger's push outvoted the pinch, zoom or twist that followed), every other
            family within -0.11 to +0.24 points.
        frame_correction: fuse each APS frame's marker centroids (the resting detector's,
            ``RestingResult.centroids_px``, so no second detection per frame) into the tracker's
            blobs (:meth:`BlobTracker.correct`; not in the paper, whose tracker runs on events
            only), on frames neither at rest nor near rest (those re-anchor the tracker at the
            rest positions instead; fusing their centroids afterwards put back the few hundredths
            of a pixel that the re-anchoring removed and made release tails read as gestures). A
            held marker makes no events, so its blob stays where its last events left it; the
            frame shows where it is. Its first version (commit a3ce67e, before the near-rest rule)
            lowered gesture accuracy for another reason: on one held twist the corrected blobs
            removed a spurious third contact, and the two contacts' similarity, rotated about a
            point off their centre, carried a 1.9 mm translation that that version's analytic rule
            read as push; today's gesture step reads that twist as twist either way
            (docs/accuracy.md "Round 4"). Decided on the thirteen development families of round 4
            (docs/accuracy.md "Round 4"): count +0.6 to +6.0 points on every family, contact
            distance -0.13 to -0.56 mm, intensity MAE about halved, gesture +0.3 to +0.9 points on
            12 families (``fingers`` -0.2).
        creep_load: when sensor.yaml has the gel's creep (``creep``, measured by ``calibrate
            --press``), a window whose load (``creep.py``: the intensity through the standard
            linear solid's inverse) is below ``min_intensity_px`` answers ``none`` (not in the
            paper, whose gel is taken as elastic). Without a measured creep it changes nothing.
            Decided on the development families of round 5 (docs/accuracy.md "Round 5"), each
            calibrated on its own simulated press: ``viscoelastic`` gesture accuracy 88.49 ->
            95.9 % (its release tails), every other family within -0.5 to +0.1 points.
        override_smooth: the motion override counts a marker as moved by the median of its and
            its nearest neighbours' displacements (module docstring, "Smooth override"; not in
            the paper); False: by its own displacement.
        gel_motion: the whole gel's rigid motion in its mount, read off the rim markers, is
            removed before the contact homography and the gesture's similarity and put back on
            the contact points (``gel_motion.py``; not in the paper); False: none (paper).
        override_min_markers: how many markers must have moved for the motion override (>= 1).
            It used to be ``n_min``, a contact-neighbourhood size with another meaning: with the
            paper's N_min = 4, four markers' tracker noise overruled a resting verdict.
        marker_threshold: grey level of marker pixels for marker detection and resting
            detection (0..255); None = Otsu's threshold on the reference frame.
        reference_attempts: how many first APS frames may fail to show a marker grid (e.g. an
            under-exposed first frame) before the pipeline says "no gel found"; the first frame
            that shows one is the rest reference.
        detect_resting: True: :meth:`GesturePipeline.process` runs the resting detector on
            every frame itself; False: the caller does, via :meth:`GesturePipeline.set_resting`.
        noise_filter: None (off), or the dv-processing noise filter run on every event batch
            before the tracker (not in the paper): ``BackgroundActivityNoiseFilter``,
            ``FastDecayNoiseFilter`` or ``KNoiseFilter`` (``noise.py``; docs/accuracy.md, "Noise
            filter", for what each does to accuracy on noisy simulated data). Windows still
            start and close on the unfiltered events' timestamps.
        noise_filter_us: the filter's time parameter (us, >= 1): the background-activity
            duration, the fast-decay half-life or the k-noise time delta; None = that filter's
            time in ``noise.NOISE_FILTERS`` (20 000, 50 000, 1000 us). Only with a
            ``noise_filter``.
        tracker: the blob tracker's parameters.
    """

    window_us: int = 10_000
    r_px: float = 25.0
    a: float = 0.6
    n_min: int = 12
    homography_max_iters: int = 2000
    homography_method: str = "usac_fast"
    chamfer_threshold: float = 0.4
    chamfer_per_marker: bool = True
    resting_centroids: bool = True
    centroid_threshold: float = 0.01
    centroid_reset_threshold: float | None = 0.05
    min_intensity_px: float = 0.3
    gesture_reproj_factor: float = 2.0
    min_gesture_reproj_px: float = 0.5
    intensity_sigma_px: float | None = 3.0
    field_fallback: bool = True
    contact_refine_px: float | None = 20.0
    plateau_fraction: float | None = 0.8
    marker_pitch_px: float = 10.0
    maxima_at_rest: bool = True
    spike_fraction: float | None = 0.6
    bump_fit: bool = True
    gesture_classifier: bool = True
    origin_radius_px: float | None = 10.0
    motion_override_px: float | None = 0.3
    override_min_markers: int = 12
    override_smooth: bool = True
    gel_motion: bool = True
    episode_vote: bool = True
    vote_restart: bool = True
    frame_correction: bool = True
    creep_load: bool = True
    rest_match_pitch: float | None = 0.1
    follow_px_per_mm: bool = True
    camera_model: bool = True
    marker_threshold: int | None = None
    reference_attempts: int = 3
    detect_resting: bool = True
    noise_filter: str | None = "BackgroundActivityNoiseFilter"
    noise_filter_us: int | None = None
    tracker: TrackerConfig = Field(default_factory=TrackerConfig)

    model_config = ConfigDict(extra="forbid")

    @field_validator("window_us", "noise_filter_us", mode="before")
    @classmethod
    def _as_given(cls, value, info: ValidationInfo):
        """Numbers are checked as given, before pydantic converts them (text from ``--set`` is
        converted first, then checked by :meth:`_consistent`)."""
        if isinstance(value, str):
            return value
        if info.field_name == "window_us":
            if value < MIN_WINDOW_US:
                raise ValueError(f"window_us must be at least {MIN_WINDOW_US} us, got {value}")
        else:
            check_noise_filter(info.data.get("noise_filter"), value)
        return value

    @model_validator(mode="after")
    def _consistent(self) -> "PipelineConfig":
        if self.window_us < MIN_WINDOW_US:
            raise ValueError(f"window_us must be at least {MIN_WINDOW_US} us, got {self.window_us}")
        if self.homography_method not in HOMOGRAPHY_METHODS:
            raise ValueError(
                f"homography_method must be one of {', '.join(HOMOGRAPHY_METHODS)}, got {self.homography_method!r}"
            )
        check_noise_filter(self.noise_filter, self.noise_filter_us)
        for name in ("intensity_sigma_px", "contact_refine_px", "motion_override_px", "origin_radius_px"):
            value = getattr(self, name)
            if value is not None and not value > 0:
                raise ValueError(f"{name} must be positive or None, got {value}")
        if self.centroid_reset_threshold is not None and self.centroid_reset_threshold < self.centroid_threshold:
            raise ValueError(
                f"centroid_reset_threshold ({self.centroid_reset_threshold}) must be at least centroid_threshold "
                f"({self.centroid_threshold}) or None"
            )
        if self.spike_fraction is not None and not 0.0 < self.spike_fraction <= 1.0:
            raise ValueError(f"spike_fraction must be in (0, 1] or None, got {self.spike_fraction}")
        if self.plateau_fraction is not None and not 0.0 < self.plateau_fraction < 1.0:
            raise ValueError(f"plateau_fraction must be in (0, 1) or None, got {self.plateau_fraction}")
        if not self.marker_pitch_px > 0:
            raise ValueError(f"marker_pitch_px must be positive, got {self.marker_pitch_px}")
        if self.override_min_markers < 1:
            raise ValueError(f"override_min_markers must be >= 1, got {self.override_min_markers}")
        if self.reference_attempts < 1:
            raise ValueError(f"reference_attempts must be >= 1, got {self.reference_attempts}")
        if self.r_px <= 0 or self.a <= 0 or self.n_min < 1:
            raise ValueError(
                f"r_px and a must be positive and n_min >= 1, got r_px={self.r_px}, a={self.a}, n_min={self.n_min}"
            )
        return self


#: The smooth override's neighbours of a marker: the markers within this many times the median
#: nearest-neighbour distance at rest (on the square 4 mm grid: its four nearest, not the diagonals).
OVERRIDE_NEIGHBOUR_GAP = 1.25


def _median_of_sorted(values: np.ndarray) -> np.ndarray:
    """(N, 2) the median over axis 1 of ``values`` (N, k, 2) sorted along it with NaN last
    (NaN ignored, as ``np.nanmedian``, ~7x faster here); 0 where a row has no finite value (a
    marker whose neighbours are all lost has not moved)."""
    n = np.isfinite(values).sum(axis=1)  # (N, 2)
    lo = np.take_along_axis(values, np.maximum((n - 1) // 2, 0)[:, None, :], axis=1)[:, 0]
    hi = np.take_along_axis(values, np.maximum(n // 2, 0)[:, None, :], axis=1)[:, 0]
    return np.where(n > 0, 0.5 * (lo + hi), 0.0)


def grid_neighbours(rest_px: np.ndarray) -> np.ndarray:
    """(N, k) int64: each marker of ``rest_px`` (N, 2) px, then its neighbours at rest (within
    :data:`OVERRIDE_NEIGHBOUR_GAP` times the median nearest-neighbour distance), padded with N
    (a row of NaN is appended to the displacements it indexes)."""
    n = len(rest_px)
    gap = np.sqrt(((rest_px[:, None, :] - rest_px[None, :, :]) ** 2).sum(axis=-1))
    np.fill_diagonal(gap, np.inf)
    near = gap <= OVERRIDE_NEIGHBOUR_GAP * np.median(gap.min(axis=1)) if n > 1 else np.zeros((n, n), bool)
    k = int(near.sum(axis=1).max()) if n else 0
    out = np.full((n, k + 1), n, dtype=np.int64)
    out[:, 0] = np.arange(n)
    for i in range(n):
        idx = np.flatnonzero(near[i])
        out[i, 1 : 1 + len(idx)] = idx
    return out


#: Named sets of PipelineConfig values (``track/eval --preset NAME``; ``--set`` overrides them).
#: ``paper``: the paper's method and hyperparameters exactly (paper, sections "Methodology" and
#: "Results"): r = 30 px, a = 0.6, N_min = 4, Chamfer threshold 2.5 on the paper's raw sum,
#: the uniform mean intensity over A, the translation about the contacts' mean, and no option the
#: paper does not have (no minimum intensity, fallback, refinement, motion override or noise
#: filter). The paper gives one RANSAC threshold rule (a times the mean displacement); it is used
#: for the gesture's similarity too.
PIPELINE_PRESETS: dict[str, dict[str, object]] = {
    "default": {},
    "paper": {
        "r_px": 30.0,
        "a": 0.6,
        "n_min": 4,
        "chamfer_threshold": 2.5,
        "chamfer_per_marker": False,
        "resting_centroids": False,
        "centroid_reset_threshold": None,
        "min_intensity_px": 0.0,
        "gesture_reproj_factor": 0.6,
        "intensity_sigma_px": None,
        "field_fallback": False,
        "contact_refine_px": None,
        "plateau_fraction": None,
        "maxima_at_rest": False,
        "spike_fraction": None,
        "bump_fit": False,
        "gesture_classifier": False,
        "origin_radius_px": None,
        "motion_override_px": None,
        "override_smooth": False,
        "gel_motion": False,
        "noise_filter": None,
        "rest_match_pitch": None,
        "follow_px_per_mm": False,
        "camera_model": False,
        "episode_vote": False,
        "vote_restart": False,
        "frame_correction": False,
        "creep_load": False,
    },
}


#: The image scale (px/mm) at which PipelineConfig's and TrackerConfig's pixel settings are
#: given: the simulated DAVIS-346 NeuroTouch's (docs/dataset.md sensor.yaml), 4 mm marker pitch = 10 px.
REFERENCE_PX_PER_MM = 2.5
#: Pixel settings that are lengths (scale with px_per_mm), and tracker settings that are squared
#: lengths or squared velocities (scale with its square).
_PX_FIELDS = (
    "r_px",
    "min_intensity_px",
    "min_gesture_reproj_px",
    "intensity_sigma_px",
    "contact_refine_px",
    "marker_pitch_px",
    "origin_radius_px",
    "motion_override_px",
)
_TRACKER_PX = (
    "sigma_px",
    "assoc_px",
    "max_step_px",
    "frame_gate_px",
    "frame_sigma_px",
    "merge_px",
    "gel_margin_px",
    "max_offset_px",
)
_TRACKER_PX2 = ("q_pos", "q_vel", "q_offset", "p0_pos", "p0_vel", "p0_offset")


def scaled_to_sensor(config: PipelineConfig, sensor: SensorGeometry) -> PipelineConfig:
    """``config`` with its pixel settings following the sensor's scale (not in the paper).

    Every pixel setting is given at :data:`REFERENCE_PX_PER_MM` (i.e. in mm, or marker pitches,
    times that scale); with ``follow_px_per_mm`` they are multiplied by
    ``sensor.px_per_mm / REFERENCE_PX_PER_MM`` (squared for the tracker's variances), so that a
    camera nearer the gel or with more pixels keeps the same contact radius, tracker gates and
    thresholds on the gel. The Chamfer threshold (px^2 per marker, growing with the marker's
    pixel count too) is not scaled; the centroid thresholds (px^2 between centroids) are, with the
    square of the scale. Returns ``config`` itself at the reference scale or when
    ``follow_px_per_mm`` is off (the paper's fixed pixels)."""
    k = sensor.px_per_mm / REFERENCE_PX_PER_MM
    if not config.follow_px_per_mm or k == 1.0:
        return config
    changes = {name: getattr(config, name) * k for name in _PX_FIELDS if getattr(config, name) is not None}
    changes["centroid_threshold"] = config.centroid_threshold * k * k  # px^2 between centroids
    if config.centroid_reset_threshold is not None:
        changes["centroid_reset_threshold"] = config.centroid_reset_threshold * k * k
    t = config.tracker
    tracker = t.model_copy(
        update={**{n: getattr(t, n) * k for n in _TRACKER_PX}, **{n: getattr(t, n) * k * k for n in _TRACKER_PX2}}
    )
    return config.model_copy(update={"tracker": tracker, **changes})


def _off_layout(layout_px: np.ndarray, points_px: np.ndarray, tol_px: float) -> float:
    """Fraction of the layout's markers (N, 2) px without a point of ``points_px`` (M, 2) within
    ``tol_px`` (all pairs: only candidate reference frames are checked)."""
    d2 = ((layout_px[:, None, :] - points_px[None, :, :]) ** 2).sum(axis=-1).min(axis=1)
    return float(np.mean(d2 > tol_px * tol_px))


class GesturePipeline:
    """Events and APS frames -> one :class:`GestureEstimate` per window (paper, "Methodology").

    Args:
        sensor: the geometry (image size, gel disc, px/mm, image -> user frame).
        config: thresholds (default: PipelineConfig()'s tuned defaults; the paper's are PIPELINE_PRESETS["paper"]).
        on_window: called with each estimate right after its window closes, while the tracker
            holds that window's end positions (e.g. to record :meth:`marker_positions`).
        profile: record per-stage processing times (ns) in :attr:`timings`.

    Attributes:
        rest_px: (N, 2) float64, rest marker positions (image px), None before the first frame.
        tracker: the :class:`BlobTracker`, None before the first frame.
        resting_detector: the :class:`RestingDetector`, None before the first frame.
        timings: stage name -> list of wall-clock durations (ns) when ``profile`` is set:
            "noise_filter" (with ``PipelineConfig.noise_filter``, conversions included) and
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
    ) -> None:
        self.sensor = sensor
        #: the settings as given; ``config`` is what runs (pixel settings scaled to the sensor)
        self.settings = config or PipelineConfig()
        self.config = scaled_to_sensor(self.settings, sensor)
        self.on_window = on_window
        self.rest_px: np.ndarray | None = None
        self._grid_neighbours: np.ndarray | None = None
        self.tracker: BlobTracker | None = None
        self.resting_detector: RestingDetector | None = None
        self.timings: dict[str, list[int]] | None = {s: [] for s in STAGES} if profile else None
        self.cpu_timings: dict[str, list[int]] | None = {s: [] for s in STAGES} if profile else None
        self._resting = RestingResult(True, 0.0)
        self._pending: tuple[RestingResult, int] | None = None
        self._resting_t_us = -(2**62)
        self._lock = threading.Lock()
        self._next_end: int | None = None
        self._rejected_frames = 0
        #: reference candidates refused because the gel was pressed (see rest_match_pitch)
        self.pressed_frames = 0
        self._previous_points: np.ndarray | None = None
        self._resume_waited = 0
        self._previous_frame: Frame | None = None
        #: the current gesture episode's decision (episode_vote)
        self._episode = EpisodeVote(restart_on_contacts=self.config.vote_restart)
        #: the fingers' load behind a creeping gel's deformation (creep_load)
        self._creep = CreepFilter(*sensor.creep) if self.config.creep_load and sensor.creep is not None else None
        #: what the fits derive from a rest reference, by name: (that reference, the value)
        self._of_rest_kept: dict[str, tuple[np.ndarray, np.ndarray]] = {}
        #: the last window's fit: (rest_px, current, valid, contacts, gesture result)
        self._last_fit: tuple | None = None
        #: the optional noise filter in front of the tracker (one per pipeline, its state kept
        #: across batches; it starts afresh by itself when the clock goes back, ``noise.py``)
        self.noise_filter: EventNoiseFilter | None = None
        if self.config.noise_filter is not None:
            self.noise_filter = EventNoiseFilter(
                self.config.noise_filter, sensor.width, sensor.height, self.config.noise_filter_us
            )

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

    def set_resting(self, result: RestingResult | None, t_us: int) -> None:
        """Hand over a resting verdict computed elsewhere (e.g. another thread) for the frame at
        ``t_us``. Thread-safe; applied before the pipeline's next item: at rest the tracker is
        reset to the rest positions, and estimates say ``resting`` until a verdict says not.
        ``None`` (no verdict yet) and verdicts older than one already handed over are ignored."""
        if result is None:
            return
        with self._lock:
            if self._pending is None or t_us >= self._pending[1]:
                self._pending = (result, int(t_us))

    def compile_kernels(self) -> None:
        """Compile the pipeline's numba code (noise filter, tracker, gel motion, contacts, gesture) now, on a synthetic
        marker grid with a finger-like bump of displacement, a flat top and a pinch, instead of on the first real
        events: on a fresh install that takes seconds, which a real-time run would spend dropping data.
        Later runs load the code from numba's cache. Leaves the pipeline as it was."""
        cx, cy = self.sensor.gel_center_px
        k = np.arange(-6, 7) * 10.0
        rest = np.stack(np.meshgrid(k + cx, k + cy), axis=-1).reshape(-1, 2)
        bump = np.exp(-((rest - (cx, cy)) ** 2).sum(axis=1) / (2 * 12.0**2))[:, None]
        moved = rest + bump * np.array([4.0, 1.0])
        events = np.zeros(4, dtype=EVENT_DTYPE)
        events["timestamp"] = np.arange(4) * 100
        events["x"], events["y"], events["polarity"] = int(cx), int(cy), 1
        tracker = BlobTracker(rest, self.sensor.width, self.sensor.height, self.config.tracker, sensor=self.sensor)
        # numba compiles one version per array layout: a one-event batch's fields count as
        # contiguous, a longer batch's are strided views of the structured array; both occur
        tracker.update(events[:1])
        tracker.update(events[1:])
        tracker.correct(rest + 0.5, int(events["timestamp"][-1]))  # frame_correction's fusion
        if self.noise_filter is not None:  # a fresh one: this pipeline's keeps its state
            c = self.config
            EventNoiseFilter(c.noise_filter, self.sensor.width, self.sensor.height, c.noise_filter_us)(events)
        # a flat top several fingers wide (the contacts' plateau split) and a lone marker far
        # above its neighbours (the lone-marker median): the other paths of the contact step
        wide = np.exp(-((rest - (cx, cy)) ** 2).sum(axis=1) / (2 * 25.0**2))
        flat = rest + np.minimum(1.0, 2.0 * wide)[:, None] * np.array([3.0, 0.0])
        flat[len(rest) // 3] += (6.0, 0.0)
        # two fingers pinching: the fit of their centres (contacts.bump_fit)
        sides = [np.exp(-((rest - (cx + dx, cy)) ** 2).sum(axis=1) / (2 * 12.0**2))[:, None] for dx in (-30.0, 30.0)]
        pinch = rest + sides[0] * np.array([4.0, 0.0]) - sides[1] * np.array([4.0, 0.0])
        all_valid = np.ones(len(rest), dtype=bool)
        compile_resting_kernels()  # its frames come later, possibly in the runtime's thread
        compile_gel_motion_kernels()  # the grid's rim barely moves: its fits stop before them
        compile_camera_model_kernels()  # the sensor gets its camera model at the rest frame
        _largest_move_sq(moved, all_valid, rest)  # every window's checks before a fit
        _count_moved(moved, all_valid, rest, 1.0)  # and the motion override's, at rest
        _unchanged(moved, flat, all_valid, all_valid)
        timings, self.timings = self.timings, None  # not a window: no stage time recorded
        try:
            self._fit(rest, moved, all_valid)
            self._fit(rest, flat, all_valid)
            self._fit(rest, pinch, all_valid)
        finally:
            self.timings = timings

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
        self.tracker = None
        self._next_end = None
        with self._lock:
            self._pending = None
        self._resting_t_us = -(2**62)
        self._resting = RestingResult(True, 0.0)
        self._rejected_frames = 0
        self._resume_waited = 0
        self._previous_frame = None
        self._episode.reset()
        if self._creep is not None:
            self._creep.reset()

    # --- outputs ----------------------------------------------------------------------------
    def marker_positions(self) -> np.ndarray:
        """(N, 2) float32 current tracked positions (image px), NaN rows for lost markers;
        (0, 2) before the first frame."""
        if self.tracker is None:
            return np.zeros((0, 2), dtype=np.float32)
        positions = self.tracker.positions_px.astype(np.float32)
        positions[~self.tracker.valid] = np.nan
        return positions

    @property
    def resting(self) -> RestingResult:
        """The resting verdict currently in force."""
        return self._resting

    # --- internals --------------------------------------------------------------------------
    def _apply_pending(self) -> None:
        with self._lock:
            pending, self._pending = self._pending, None
        if pending is not None and pending[1] >= self._resting_t_us:
            self._resting_t_us = pending[1]
            self._apply_resting(pending[0], pending[1])

    def _apply_resting(self, result: RestingResult, t_us: int) -> None:
        """Take the verdict on the APS frame at ``t_us``: at rest (or near it) the tracker is
        re-anchored at the rest positions; otherwise, with ``frame_correction``, the frame's
        marker centroids are fused into the blobs (:meth:`BlobTracker.correct`)."""
        self._resting = result
        if self.tracker is None:
            return
        if result.resting or self._near_rest(result):
            self.tracker.reset(self.rest_px)
        elif self.config.frame_correction and result.centroids_px is not None:
            start = self._clock()
            self.tracker.correct(result.centroids_px, t_us)
            self._record("frame_correction", start)

    def _near_rest(self, result: RestingResult) -> bool:
        """Whether a frame not at rest is still near enough to re-anchor the tracker (with
        ``resting_centroids`` and ``centroid_reset_threshold``; module docstring, "Near rest")."""
        c = self.config
        return (
            c.resting_centroids
            and c.centroid_reset_threshold is not None
            and (result.distance <= c.centroid_reset_threshold)
        )

    def _matches_calibrated_rest(self, points_px: np.ndarray) -> bool:
        """Whether a candidate reference frame's markers (M, 2) px lie on the calibrated rest
        layout (sensor.yaml's ``rest_markers_px``, written by ``calibrate``; not in the paper).

        The paper takes the first frame as t0, "a timestep where the gel is in resting position";
        a run that starts with the gel pressed would take a deformed layout as rest and read every
        later rest as a gesture. The frame is rest when at most 5 % of the calibrated markers
        have no detected marker within ``rest_match_pitch`` marker pitches. Without a calibrated
        layout, or with ``rest_match_pitch`` None, every frame passes (paper). So that a gel
        that moved since its calibration cannot stop the driver for good, after
        :data:`RESUME_MATCH_FRAMES` refused frames a frame whose markers match the previous
        frame's (the gel is still) is taken, as after a restart."""
        layout = self.sensor.extra.get("rest_markers_px")
        if layout is None or self.config.rest_match_pitch is None or len(points_px) == 0:
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
        if not self._matches_calibrated_rest(markers.centroids_px):
            self.pressed_frames += 1
            return  # the gel is pressed: this frame is no rest reference; wait for one that is
        self.rest_px = markers.centroids_px.astype(np.float64)
        self._use_camera_model()
        self._grid_neighbours = grid_neighbours(self.rest_px)
        self.tracker = BlobTracker(
            self.rest_px, self.sensor.width, self.sensor.height, self.config.tracker, sensor=self.sensor
        )
        self.resting_detector = self._resting_detector(frame.image)
        self._resting = RestingResult(True, 0.0)

    def _resting_detector(self, reference: np.ndarray) -> RestingDetector:
        """A resting detector (paper, "Resting Position Detection") with ``reference`` as its rest
        image and this pipeline's settings. Raises SensorError when it shows no marker."""
        c = self.config
        threshold = c.centroid_threshold if c.resting_centroids else c.chamfer_threshold
        return RestingDetector(
            reference,
            self.sensor,
            threshold,
            c.marker_threshold,
            per_marker=c.chamfer_per_marker,
            centroids=c.resting_centroids,
        )

    def _use_camera_model(self) -> None:
        """With ``camera_model``, and no model in sensor.yaml: the sensor as fitted to the rest
        reference's markers (:func:`fit_camera_model`), and the pixel settings following its
        px_per_mm. Unchanged when the markers do not index as the 4 mm grid."""
        if not self.settings.camera_model or self.sensor.radial_k is not None:
            return
        fitted = fit_camera_model(self.rest_px, self.sensor)
        if fitted is not None:
            self.sensor = fitted
            self.config = scaled_to_sensor(self.settings, fitted)

    def _at_rest_after_restart(self, frame: Frame) -> bool:
        """After :meth:`restart`: whether ``frame`` may re-initialise the markers (see there)."""
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

    def _process_frame(self, frame: Frame) -> list[GestureEstimate]:
        if self.tracker is None:
            if self.rest_px is None or self._at_rest_after_restart(frame):
                self._initialise(frame)
            return []
        out = self._close_windows_until(frame.t_us)
        if self.config.detect_resting:
            start = self._clock()
            result = self.resting_detector.update(frame, verdict_only=True)
            self._record("resting", start)
            self._resting_t_us = frame.t_us
            self._apply_resting(result, frame.t_us)
        return out

    def _close_windows_until(self, t_us: int) -> list[GestureEstimate]:
        out = []
        while self._next_end is not None and self._next_end <= t_us:
            out.append(self._close_window())
        return out

    def _process_events(self, events: np.ndarray, *, filtered: bool = False) -> list[GestureEstimate]:
        if self.tracker is None or len(events) == 0:
            return []
        if self.noise_filter is not None and not filtered:
            # the tracker gets the kept events; the windows start and close on the unfiltered
            # timestamps, as without a filter (a batch of noise only still ends its windows)
            last_us = int(events["timestamp"][-1])
            if self._next_end is None:
                self._next_end = int(events["timestamp"][0]) + self.config.window_us
            begin = self._clock()
            kept = self.noise_filter(events)
            self._record("noise_filter", begin)
            return self._process_events(kept, filtered=True) + self._close_windows_until(last_us)
        ts = events["timestamp"]
        if self._next_end is None:
            self._next_end = int(ts[0]) + self.config.window_us
        out: list[GestureEstimate] = []
        start = 0
        while True:
            cut = start + int(np.searchsorted(ts[start:], self._next_end, side="left"))
            if cut > start:
                begin = self._clock()
                self.tracker.update(events[start:cut])
                self._record("tracker", begin)
            if cut >= len(events):
                return out
            out.append(self._close_window())
            start = cut

    def _close_window(self) -> GestureEstimate:
        t_us = self._next_end
        self._next_end += self.config.window_us
        estimate = self._estimate(t_us)
        if self.on_window is not None:
            self.on_window(estimate)
        return estimate

    def _moving(self, current: np.ndarray, valid: np.ndarray) -> bool:
        """True when ``motion_override_px`` is set and at least ``override_min_markers`` valid markers are
        further than it from rest (the event path sees a gesture the APS verdict missed)."""
        threshold = self.config.motion_override_px
        if threshold is None:
            return False
        moved = _count_moved(current, valid, self.rest_px, threshold * threshold)
        if moved < self.config.override_min_markers or not self.config.override_smooth:
            return moved >= self.config.override_min_markers
        # the smooth override only when the markers' own displacements would overrule (at rest,
        # nearly always not: the median filter's cost is spent on the few windows that need it)
        d = np.where(valid[:, None], current - self.rest_px, np.nan)
        d = _median_of_sorted(np.sort(np.concatenate([d, np.full((1, 2), np.nan)])[self._grid_neighbours], axis=1))
        moved = int(np.count_nonzero(d[:, 0] * d[:, 0] + d[:, 1] * d[:, 1] > threshold * threshold))
        return moved >= self.config.override_min_markers

    def _still(self, current: np.ndarray, valid: np.ndarray) -> bool:
        """True when no valid marker is ``min_intensity_px`` or more from rest: the intensity (a
        mean of displacements) is then below it and the gesture step answers ``none`` whatever
        the contacts, so the window skips the homography and the similarity (same estimate;
        e.g. a gel near rest after the tracker was re-anchored, ``centroid_reset_threshold``)."""
        largest = _largest_move_sq(current, valid, self.rest_px)  # < 0: no valid marker; NaN: not still
        limit = self.config.min_intensity_px
        return largest < 0.0 or largest < limit * limit

    def _vote(self, gesture: GestureType, intensity_mm: float, n_contacts: int = 0) -> GestureType:
        """The window's type: its own, or the episode's decision with ``episode_vote``."""
        if not self.config.episode_vote:
            return gesture
        return self._episode.update(gesture, intensity_mm, n_contacts)

    def _estimate(self, t_us: int) -> GestureEstimate:
        current = self.tracker.positions_px
        valid = self.tracker.valid
        if self._resting.resting and not self._moving(current, valid):
            return self._none(t_us, resting=True)
        if self._still(current, valid):  # what the gesture step would answer, without its fits
            return self._none(t_us, resting=False)
        contacts, result = self._contacts_and_gesture(self.rest_px, current, valid)
        if result.gesture is GestureType.NONE or self._released(result.intensity_px, t_us):
            return self._none(t_us, resting=False, fed=result.gesture is not GestureType.NONE)
        return GestureEstimate(
            t_us=t_us,
            gesture=self._vote(result.gesture, result.intensity_mm, len(contacts.points_px)),
            resting=False,
            intensity_mm=result.intensity_mm,
            contacts_px=contacts.points_px,
            contacts_mm=points_to_user(contacts.points_px, self.sensor),
            translation_mm=result.translation_mm,
            rotation_rad=result.rotation_rad,
            scale=result.similarity.scale,
        )

    def _none(self, t_us: int, *, resting: bool, fed: bool = False) -> GestureEstimate:
        """A window without a gesture: the vote hears ``none`` and the creep filter (when not
        ``fed`` already) a gel below the intensity threshold (taken as 0 px)."""
        if not fed and self._creep is not None:
            self._creep.update(0.0, t_us)
        self._vote(GestureType.NONE, 0.0)
        return GestureEstimate(t_us=t_us, gesture=GestureType.NONE, resting=resting)

    def _released(self, intensity_px: float, t_us: int) -> bool:
        """Whether the fingers' load behind the window's intensity (px) is below
        ``min_intensity_px`` (``creep_load``; False without the gel's creep)."""
        if self._creep is None:
            return False
        return self._creep.update(intensity_px, t_us) < self.config.min_intensity_px

    def _contacts_and_gesture(self, rest_px: np.ndarray, current: np.ndarray, valid: np.ndarray):
        """Contact points (paper, "Contact Point Detection") and the gesture's similarity, type and
        intensity (paper, "Gesture Classification and Intensity Prediction") of one window.

        Work that scales with what changed: when no tracked marker moved since the window before
        (the same rest reference, positions and lost markers, bit for bit: about half of the
        moving windows of a simulated session, e.g. a held gesture whose markers made no event)
        the previous window's contacts and gesture are returned as they are, without a new
        homography (both stages are deterministic functions of these inputs; OpenCV's RANSAC
        and USAC draw from fixed seeds, so the predictions are byte-identical)."""
        last = self._last_fit
        if last is not None and last[0] is rest_px and _unchanged(last[1], current, last[2], valid):
            begin = self._clock()
            self._record("contacts", begin)
            self._record("gesture", begin)
            return last[3], last[4]
        contacts, result = self._fit(rest_px, current, valid)
        self._last_fit = (rest_px, current.copy(), valid.copy(), contacts, result)
        return contacts, result

    def _fit(self, rest_px: np.ndarray, current: np.ndarray, valid: np.ndarray):
        """:meth:`_contacts_and_gesture` computed afresh."""
        c = self.config
        begin = self._clock()
        motion = None
        if c.gel_motion:
            centre = self.sensor.gel_center_px
            rim = self._of_rest("rim", rest_px, lambda rest: rim_markers(rest, centre))
            motion = estimate_gel_motion(rest_px, current, valid, rim, centre)
        contacts = detect_contacts(
            rest_px,
            current if motion is None else motion.remove(current),
            valid,
            r_px=c.r_px,
            a=c.a,
            n_min=c.n_min,
            max_iters=c.homography_max_iters,
            method=c.homography_method,
            field_fallback=c.field_fallback,
            refine_px=c.contact_refine_px,
            plateau_fraction=c.plateau_fraction,
            pitch_px=c.marker_pitch_px,
            maxima_at_rest=c.maxima_at_rest,
            spike_fraction=c.spike_fraction,
            neighbours=self._rest_neighbours(rest_px),
            bump_span_px=self.sensor.gel_radius_px if c.bump_fit else None,
        )
        if motion is not None:  # the contact points where they are, the gel's motion included
            points = motion.apply(contacts.points_px)
            peaks = points if contacts.peaks_px is contacts.points_px else motion.apply(contacts.peaks_px)
            contacts = dataclasses.replace(contacts, points_px=points, peaks_px=peaks)
        self._record("contacts", begin)
        begin = self._clock()
        result = estimate_gesture(
            rest_px,
            current,
            valid,
            contacts.peaks_px,  # A and the intensity about the largest deformation (paper)
            self.sensor,
            r_px=c.r_px,
            reproj_factor=c.gesture_reproj_factor,
            min_reproj_px=c.min_gesture_reproj_px,
            min_intensity_px=c.min_intensity_px,
            intensity_sigma_px=c.intensity_sigma_px,
            origin_radius_px=c.origin_radius_px,
            gel_motion=motion,
        )
        if c.gesture_classifier and result.gesture is not GestureType.NONE:
            features = gesture_features(
                result, contacts.peaks_px, rest_px, current, valid, self.sensor, c.r_px, c.origin_radius_px
            )
            result = dataclasses.replace(result, gesture=learned_gesture(features))
        self._record("gesture", begin)
        return contacts, result

    def _rest_neighbours(self, rest_px: np.ndarray) -> np.ndarray | None:
        """The markers' neighbours on the gel (``contacts.rest_neighbours``), once per rest
        reference; None when no contact option needs them."""
        c = self.config
        if c.plateau_fraction is None and c.spike_fraction is None:
            return None
        return self._of_rest("contacts", rest_px, lambda rest: rest_neighbours(rest, c.marker_pitch_px))

    def _of_rest(self, name: str, rest_px: np.ndarray, make: Callable[[np.ndarray], np.ndarray]) -> np.ndarray:
        """``make(rest_px)``, computed once per rest reference (the pipeline's own, or
        :meth:`compile_kernels`' synthetic grid) and kept under ``name``: the gel's rim markers
        (gel_motion) and the contacts' neighbour table."""
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


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _largest_move_sq(current: np.ndarray, valid: np.ndarray, rest: np.ndarray) -> float:
    """The largest squared displacement from rest (px^2) among the ``valid`` (N,) bool markers,
    ``current`` and ``rest`` (N, 2) float64 px: -1.0 when none is valid, NaN when one of theirs
    is NaN (as NumPy's ``max`` propagates it). One pass, no temporaries: every window runs it."""
    largest = -1.0
    for i in range(len(current)):
        if valid[i]:
            dx = current[i, 0] - rest[i, 0]
            dy = current[i, 1] - rest[i, 1]
            d2 = dx * dx + dy * dy
            if d2 != d2:
                return d2
            largest = max(largest, d2)
    return largest


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _count_moved(current: np.ndarray, valid: np.ndarray, rest: np.ndarray, threshold_sq: float) -> int:
    """How many ``valid`` (N,) bool markers are more than sqrt(``threshold_sq``) (px^2) from rest,
    ``current`` and ``rest`` (N, 2) float64 px (a NaN position is not). One pass, no
    temporaries: every resting window runs it (the motion override)."""
    moved = 0
    for i in range(len(current)):
        if valid[i]:
            dx = current[i, 0] - rest[i, 0]
            dy = current[i, 1] - rest[i, 1]
            if dx * dx + dy * dy > threshold_sq:
                moved += 1
    return moved


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _unchanged(last_current: np.ndarray, current: np.ndarray, last_valid: np.ndarray, valid: np.ndarray) -> bool:
    """Whether the window's tracked positions (N, 2) float64 px and lost markers (N,) bool are
    those of the last fit, bit for bit (``np.array_equal``: a NaN position never equals)."""
    return np.array_equal(last_current, current) and np.array_equal(last_valid, valid)
