"""The product's pipeline settings (:class:`PipelineConfig`, one group per stage, mm and us) and
their pixels at a sensor's scale (:func:`scaled_to_sensor`; the tracker converts its own group).

Every number has one default, the product's; each stage's reasons are in docs/method.md (one
section per stage). The paper's method has its own settings (:class:`~neurotouch_hid.pipeline.paper.PaperConfig`).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationInfo, field_validator, model_validator

from neurotouch_hid.core.limits import short
from neurotouch_hid.core.sensor import MARKER_SPACING_MM, SensorGeometry
from neurotouch_hid.pipeline.contacts import HOMOGRAPHY_METHODS
from neurotouch_hid.pipeline.episode import CORRECTION_US, FIRM_MM, FIRST_FINGER_US, PROVISIONAL_MM
from neurotouch_hid.pipeline.learned import CLASSES, FEATURES, Classifier
from neurotouch_hid.pipeline.noise import check_noise_filter
from neurotouch_hid.pipeline.tracker import TrackerConfig

#: Shortest window accepted (us).
MIN_WINDOW_US = 1_000
#: Longest window accepted (us): a second is 100 of the paper's 10 ms windows, longer than any
#: gesture's onset; a window past the recording's length gave no window at all, and one of 2^63 us
#: overflowed the int64 clock.
MAX_WINDOW_US = 1_000_000
#: Longest intensity lead accepted (us): a lead is a few ms of the tracker's lag, not a forecast.
MAX_LEAD_US = 50_000


class NoiseConfig(BaseModel):
    """The noise filter in front of the tracker (docs/method.md, "Noise filter").

    Attributes:
        kind: the dv-processing noise filter run on every event batch before the tracker (a key
            of ``noise.NOISE_FILTERS``), or None for none: a product choice (the live camera's
            source runs the filter itself, and ``eval --set noise.kind=none`` measures without).
        time_us: the filter's time parameter (us, >= 1); None = that kind's own time
            (``noise.NOISE_FILTERS``), so that another kind gets its own.
    """

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    kind: str | None = "BackgroundActivityNoiseFilter"
    time_us: int | None = None

    @field_validator("time_us", mode="before")
    @classmethod
    def _as_given(cls, value, info: ValidationInfo):
        """The time is checked as given, before pydantic converts it (text from ``--set`` is
        converted first, then checked by :meth:`_consistent`)."""
        if not isinstance(value, str):
            check_noise_filter(info.data.get("kind"), value)
        return value

    @model_validator(mode="after")
    def _consistent(self) -> "NoiseConfig":
        check_noise_filter(self.kind, self.time_us)
        return self


class ContactsConfig(BaseModel):
    """The contact step (docs/method.md, "Contacts"); lengths in mm on the gel.

    Attributes:
        r_mm: radius r of the contact neighbourhoods and of the gesture's set A (mm).
        a: dynamic reprojection threshold coefficient of the contact homography (paper's 0.6).
        n_min: minimum number of candidates in a contact's neighbourhood.
        homography_max_iters: iteration cap of the contact homography's RANSAC.
        homography_method: ``usac_fast`` or ``ransac`` (``contacts.HOMOGRAPHY_METHODS``).
        refine_mm: radius (mm) of the sub-marker refinement of a peak.
        plateau_fraction: in (0, 1): maxima on one plateau at this fraction of its peak are one
            flat top.
        spike_fraction: in (0, 1]: a marker displaced more than 1 / spike_fraction times its
            neighbours' median takes that median.
        min_move_mm: >= 0: a marker displaced more than this (mm) and than the dynamic threshold
            counts in an outlier's neighbourhood even where the homography keeps it (a weak
            finger's markers).
    """

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    r_mm: float = 10.0
    a: float = 0.6
    n_min: int = 12
    homography_max_iters: int = 2000
    homography_method: str = "usac_fast"
    refine_mm: float = 8.0
    plateau_fraction: float = 0.8
    spike_fraction: float = 0.6
    min_move_mm: float = 0.24

    @model_validator(mode="after")
    def _consistent(self) -> "ContactsConfig":
        check_homography(self.homography_method, self.r_mm, self.a, self.n_min)
        if not self.refine_mm > 0:
            raise ValueError(f"refine_mm must be positive, got {self.refine_mm}")
        if not 0.0 < self.spike_fraction <= 1.0:
            raise ValueError(f"spike_fraction must be in (0, 1], got {self.spike_fraction}")
        if not 0.0 < self.plateau_fraction < 1.0:
            raise ValueError(f"plateau_fraction must be in (0, 1), got {self.plateau_fraction}")
        if not self.min_move_mm >= 0.0:
            raise ValueError(f"min_move_mm must be >= 0, got {self.min_move_mm}")
        return self


class ClassifierConfig(BaseModel):
    """The learned gesture type's parameters (``learned.py``; docs/method.md, "Gesture" and
    "Adaptation"): a multinomial logistic regression over the standardised features.

    Attributes:
        mean, scale: (9,) each, the features' standardisation (``learned.FEATURES`` order; scale > 0).
        weights: (5, 9), one row per class (``learned.CLASSES`` order).
        intercept: (5,).
    """

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False, frozen=True)

    mean: tuple[float, ...]
    scale: tuple[float, ...]
    weights: tuple[tuple[float, ...], ...]
    intercept: tuple[float, ...]

    @model_validator(mode="after")
    def _consistent(self) -> "ClassifierConfig":
        n, k = len(FEATURES), len(CLASSES)
        if len(self.mean) != n or len(self.scale) != n:
            raise ValueError(
                f"mean and scale must have {n} values (one per feature), got {len(self.mean)} and {len(self.scale)}"
            )
        if len(self.weights) != k or any(len(row) != n for row in self.weights):
            raise ValueError(f"weights must be {k} rows (one per class) of {n} values")
        if len(self.intercept) != k:
            raise ValueError(f"intercept must have {k} values (one per class), got {len(self.intercept)}")
        if not all(s > 0 for s in self.scale):
            raise ValueError("every scale must be positive")
        return self

    def arrays(self) -> Classifier:
        """The parameters as float64 arrays (:class:`~neurotouch_hid.pipeline.learned.Classifier`;
        the shipped object itself when they are the shipped ones)."""
        return _arrays(self)

    @classmethod
    def shipped(cls) -> "ClassifierConfig":
        """The shipped parameters (``gesture_model.py``)."""
        c = Classifier.shipped()
        return cls(
            mean=tuple(c.mean.tolist()),
            scale=tuple(c.scale.tolist()),
            weights=tuple(tuple(row) for row in c.weights.tolist()),
            intercept=tuple(c.intercept.tolist()),
        )


@functools.lru_cache(maxsize=16)
def _arrays(config: ClassifierConfig) -> Classifier:
    """:meth:`ClassifierConfig.arrays`, made once per distinct parameters (the config is frozen)."""
    c = Classifier.of(config.mean, config.scale, config.weights, config.intercept)
    shipped = Classifier.shipped()
    same = all(np.array_equal(getattr(c, f), getattr(shipped, f)) for f in ("mean", "scale", "weights", "intercept"))
    return shipped if same else c


class GestureConfig(BaseModel):
    """The gesture step (docs/method.md, "Gesture"); lengths in mm on the gel.

    Attributes:
        reproj_factor: the similarity's RANSAC threshold as a multiple of A's mean displacement.
        min_reproj_mm: floor of that threshold (mm).
        min_intensity_mm: below this intensity (mm), nothing moves: ``none`` (also the creeping
            gel's load threshold, "Creep").
        intensity_sigma_mm: sigma (mm) of the proximity-weighted intensity.
        origin_radius_mm: the translation term is taken at the best origin within this distance
            (mm) of the contacts' mean.
        intensity_gain: > 0, the intensity (mm) is multiplied by it: 1 but for a gel adapted by
            ``neurotouch-hid adapt`` (docs/method.md, "Adaptation").
        intensity_lead_us: the answered intensity is extrapolated this far ahead (us, 0 to
            :data:`MAX_LEAD_US`) along its change since the window before, within a gesture:
            the tracked blobs lag their markers (docs/method.md, "Gesture": intensity lead).
        classifier: the learned type's parameters (:class:`ClassifierConfig`): the shipped ones
            (``gesture_model.py``) but for an adapted model (docs/method.md, "Adaptation").
    """

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    reproj_factor: float = 2.0
    min_reproj_mm: float = 0.2
    min_intensity_mm: float = 0.12
    intensity_sigma_mm: float = 1.2
    origin_radius_mm: float = 4.0
    intensity_gain: float = 1.0
    intensity_lead_us: int = 3_000
    classifier: ClassifierConfig = Field(default_factory=ClassifierConfig.shipped)

    @model_validator(mode="after")
    def _consistent(self) -> "GestureConfig":
        for name in ("intensity_sigma_mm", "origin_radius_mm", "intensity_gain"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name} must be positive, got {getattr(self, name)}")
        if not 0 <= self.intensity_lead_us <= MAX_LEAD_US:
            raise ValueError(f"intensity_lead_us must be 0 to {MAX_LEAD_US} us, got {self.intensity_lead_us}")
        return self


class EpisodeConfig(BaseModel):
    """The episode vote (docs/method.md, "Episode vote"; ``episode.EpisodeVote``).

    Attributes:
        first_finger_us: how long an episode that shows one contact stays undecided (us, >= 0).
        correction_us: how long after the onset the one correction may come (us, >= 0).
        provisional_mm: below this intensity (mm, >= 0) an undecided window answers the vote so far.
        firm_mm: from this intensity (mm, >= 0) on, a type answered the window before changes
            only when two windows in a row say so.
    """

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    first_finger_us: int = FIRST_FINGER_US
    correction_us: int = CORRECTION_US
    provisional_mm: float = PROVISIONAL_MM
    firm_mm: float = FIRM_MM

    @model_validator(mode="after")
    def _consistent(self) -> "EpisodeConfig":
        for name in ("first_finger_us", "correction_us", "provisional_mm", "firm_mm"):
            if not getattr(self, name) >= 0:
                raise ValueError(f"{name} must be >= 0, got {getattr(self, name)}")
        return self


class RestingConfig(BaseModel):
    """The rest reference and the resting detection (docs/method.md, "Markers", "Resting").

    Attributes:
        centroid_threshold_mm2: centroid Chamfer distance (mm^2 per reference marker) at or
            below which the gel rests.
        centroid_reset_threshold_mm2: centroid distance (mm^2 per marker, >= the resting one) at
            or below which a frame not at rest still re-anchors the tracker.
        motion_override_mm: displacement from rest (mm) beyond which ``override_min_markers``
            markers (median-filtered over their neighbours) overrule a resting verdict.
        override_min_markers: how many markers must have moved for that override (>= 1).
        press_mm: a frame near rest still corrects the blobs, instead of re-anchoring them,
            while the press it shows (``RestingResult.press_px``) is beyond this (mm) and
            deeper than the frame before's: a press growing from rest (the labels' rest
            tolerance, docs/dataset.md).
        rest_match_pitch: a candidate rest reference is refused while its markers are off the
            calibrated rest layout (sensor.yaml ``rest_markers_px``) by more than this many
            marker pitches.
        marker_threshold: grey level of marker pixels (0..255); None = Otsu's threshold on the
            reference frame.
        reference_attempts: how many first APS frames may fail to show a marker grid before the
            pipeline says "no gel found".
    """

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    centroid_threshold_mm2: float = 0.0016
    centroid_reset_threshold_mm2: float = 0.008
    motion_override_mm: float = 0.12
    override_min_markers: int = 12
    press_mm: float = 0.1
    rest_match_pitch: float = 0.1
    marker_threshold: int | None = None
    reference_attempts: int = 3

    @model_validator(mode="after")
    def _consistent(self) -> "RestingConfig":
        for name in ("motion_override_mm", "press_mm", "rest_match_pitch"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name} must be positive, got {getattr(self, name)}")
        if self.centroid_reset_threshold_mm2 < self.centroid_threshold_mm2:
            raise ValueError(
                f"centroid_reset_threshold_mm2 ({self.centroid_reset_threshold_mm2}) must be at least "
                f"centroid_threshold_mm2 ({self.centroid_threshold_mm2})"
            )
        if self.override_min_markers < 1:
            raise ValueError(f"override_min_markers must be >= 1, got {self.override_min_markers}")
        check_attempts(self.reference_attempts)
        return self


class PipelineConfig(BaseModel):
    """Every setting of the product's pipeline, one group per stage (docs/method.md, one section
    per stage), in physical units: mm on the gel (converted to pixels with the sensor's scale,
    :func:`scaled_to_sensor`) and us. The marker pitch is the sensor's (4 mm).

    A pydantic model: a value of the wrong type, out of range, or an unknown field raises
    ``pydantic.ValidationError`` (a ValueError) naming the field; the CLI's ``--set GROUP.NAME=VALUE``
    is converted through it (``evaluation/runner.py``).

    Attributes:
        window_us: window length (us), >= 1000; paper: 10 ms.
        noise: the noise filter in front of the tracker (:class:`NoiseConfig`; kind, time in us).
        tracker: the blob tracker's parameters (:class:`~neurotouch_hid.pipeline.tracker.TrackerConfig`,
            mm and us; docs/method.md, "Tracker").
        contacts, gesture, episode, resting: the stages' settings (:class:`ContactsConfig`,
            :class:`GestureConfig`, :class:`EpisodeConfig`, :class:`RestingConfig`).
    """

    window_us: int = 10_000
    noise: NoiseConfig = Field(default_factory=NoiseConfig)
    tracker: TrackerConfig = Field(default_factory=TrackerConfig)
    contacts: ContactsConfig = Field(default_factory=ContactsConfig)
    gesture: GestureConfig = Field(default_factory=GestureConfig)
    episode: EpisodeConfig = Field(default_factory=EpisodeConfig)
    resting: RestingConfig = Field(default_factory=RestingConfig)

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    @field_validator("window_us", mode="before")
    @classmethod
    def _as_given(cls, value):
        """The window is checked as given, before pydantic converts it (text from ``--set`` is
        converted first, then checked by :meth:`_consistent`)."""
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            check_window(value)
        return value

    @model_validator(mode="after")
    def _consistent(self) -> "PipelineConfig":
        check_window(self.window_us)
        return self


def check_window(window_us: int) -> None:
    """Raise ValueError when ``window_us`` is below :data:`MIN_WINDOW_US` or above :data:`MAX_WINDOW_US`."""
    if window_us < MIN_WINDOW_US:
        raise ValueError(f"window_us must be at least {MIN_WINDOW_US} us, got {window_us}")
    if window_us > MAX_WINDOW_US:
        shown = str(window_us) if len(str(window_us)) <= 20 else f"a number of {len(str(window_us))} digits"
        raise ValueError(f"window_us must be at most {MAX_WINDOW_US} us (1 s), got {shown}")


def check_homography(method: str, r: float, a: float, n_min: int) -> None:
    """Raise ValueError for an unknown RANSAC variant, r (any unit) or a not positive, or n_min < 1."""
    if method not in HOMOGRAPHY_METHODS:
        raise ValueError(f"homography_method must be one of {', '.join(HOMOGRAPHY_METHODS)}, got {short(method)}")
    if r <= 0 or a <= 0 or n_min < 1:
        raise ValueError(f"r and a must be positive and n_min >= 1, got r={r}, a={a}, n_min={n_min}")


def check_attempts(reference_attempts: int) -> None:
    """Raise ValueError when ``reference_attempts`` < 1."""
    if reference_attempts < 1:
        raise ValueError(f"reference_attempts must be >= 1, got {reference_attempts}")


@dataclass(frozen=True)
class PixelSettings:
    """:class:`PipelineConfig` in the image's pixels for one sensor scale: what the stages run on
    (lengths px, areas px^2, times us; names as the stage functions' arguments). The noise filter and
    the tracker take their groups of :class:`PipelineConfig` as they are."""

    window_us: int
    r_px: float
    a: float
    n_min: int
    homography_max_iters: int
    homography_method: str
    contact_refine_px: float
    plateau_fraction: float
    spike_fraction: float
    min_move_px: float
    marker_pitch_px: float
    gesture_reproj_factor: float
    min_gesture_reproj_px: float
    min_intensity_px: float
    intensity_sigma_px: float
    origin_radius_px: float
    intensity_gain: float
    intensity_lead_us: int
    classifier: Classifier
    centroid_threshold: float
    centroid_reset_threshold: float
    motion_override_px: float
    override_min_markers: int
    press_px: float
    rest_match_pitch: float
    marker_threshold: int | None
    reference_attempts: int


def scaled_to_sensor(config: PipelineConfig, sensor: SensorGeometry) -> PixelSettings:
    """``config`` in pixels at the sensor's scale (docs/method.md, "Camera model").

    Lengths in mm are multiplied by ``sensor.px_per_mm``, areas by its square; the marker pitch is
    :data:`~neurotouch_hid.core.sensor.MARKER_SPACING_MM` there, so that a camera nearer the gel or
    with more pixels keeps the same contact radius and thresholds on the gel. The tracker's
    settings are converted by the tracker itself, with the same sensor
    (:meth:`~neurotouch_hid.pipeline.tracker.TrackerConfig.in_pixels`)."""
    s = sensor.px_per_mm
    c, g, r = config.contacts, config.gesture, config.resting
    return PixelSettings(
        window_us=config.window_us,
        r_px=c.r_mm * s,
        a=c.a,
        n_min=c.n_min,
        homography_max_iters=c.homography_max_iters,
        homography_method=c.homography_method,
        contact_refine_px=c.refine_mm * s,
        plateau_fraction=c.plateau_fraction,
        spike_fraction=c.spike_fraction,
        min_move_px=c.min_move_mm * s,
        marker_pitch_px=MARKER_SPACING_MM * s,
        gesture_reproj_factor=g.reproj_factor,
        min_gesture_reproj_px=g.min_reproj_mm * s,
        min_intensity_px=g.min_intensity_mm * s,
        intensity_sigma_px=g.intensity_sigma_mm * s,
        origin_radius_px=g.origin_radius_mm * s,
        intensity_gain=g.intensity_gain,
        intensity_lead_us=g.intensity_lead_us,
        classifier=g.classifier.arrays(),
        centroid_threshold=r.centroid_threshold_mm2 * s * s,
        centroid_reset_threshold=r.centroid_reset_threshold_mm2 * s * s,
        motion_override_px=r.motion_override_mm * s,
        override_min_markers=r.override_min_markers,
        press_px=r.press_mm * s,
        rest_match_pitch=r.rest_match_pitch,
        marker_threshold=r.marker_threshold,
        reference_attempts=r.reference_attempts,
    )
