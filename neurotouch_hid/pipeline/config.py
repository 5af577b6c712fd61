"""The product's pipeline settings (:class:`PipelineConfig`) and how they follow the sensor's scale.

Every number has one default, the product's; each stage's reasons are in docs/method.md (one
section per stage). The paper's method has its own settings (:class:`~neurotouch_hid.pipeline.paper.PaperConfig`).
"""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict, Field, ValidationInfo, field_validator, model_validator

from neurotouch_hid.pipeline.contacts import HOMOGRAPHY_METHODS
from neurotouch_hid.pipeline.noise import check_noise_filter
from neurotouch_hid.pipeline.tracker import TrackerConfig
from neurotouch_hid.sensor import SensorGeometry

#: Shortest window accepted (us).
MIN_WINDOW_US = 1_000


class PipelineConfig(BaseModel):
    """Every threshold of the product's pipeline (docs/method.md, one section per stage).

    A pydantic model: a value of the wrong type, out of range, or an unknown field raises
    ``pydantic.ValidationError`` (a ValueError) naming the field; the CLI's ``--set NAME=VALUE``
    is converted through it (``evaluation/runner.py``). Pixel settings are given at
    :data:`REFERENCE_PX_PER_MM` (2.5 px/mm: 1 mm = 2.5 px) and follow the sensor's scale
    (:func:`scaled_to_sensor`).

    Attributes:
        window_us: window length (us), >= 1000; paper: 10 ms.
        r_px: radius r of the contact neighbourhoods and of the set A (px; 10 mm).
        a: dynamic reprojection threshold coefficient of the contact homography (paper's 0.6).
        n_min: minimum number of candidates in a contact's neighbourhood.
        homography_max_iters: iteration cap of the contact homography's RANSAC.
        homography_method: ``usac_fast`` or ``ransac`` (``contacts.HOMOGRAPHY_METHODS``).
        centroid_threshold: centroid Chamfer distance (px^2 per reference marker) at or below
            which the gel rests (docs/method.md, "Resting").
        centroid_reset_threshold: centroid distance (px^2 per marker, >= ``centroid_threshold``)
            at or below which a frame not at rest still re-anchors the tracker ("Resting").
        min_intensity_px: below this intensity (px), nothing moves: ``none``.
        gesture_reproj_factor: the similarity's RANSAC threshold as a multiple of A's mean
            displacement (docs/method.md, "Gesture").
        min_gesture_reproj_px: floor of that threshold (px).
        intensity_sigma_px: sigma (px) of the proximity-weighted intensity ("Gesture").
        contact_refine_px: radius (px) of the sub-marker refinement of a peak ("Contacts").
        plateau_fraction: in (0, 1): maxima on one plateau at this fraction of its peak are one
            flat top ("Contacts").
        marker_pitch_px: the marker pitch (px; 4 mm), for the plateaus, lone markers and bumps.
        spike_fraction: in (0, 1]: a marker displaced more than 1 / spike_fraction times its
            neighbours' median takes that median in the contact step ("Contacts").
        origin_radius_px: the gesture's translation term is taken at the best origin within
            this distance (px) of the contacts' mean ("Gesture").
        motion_override_px: displacement from rest (px) beyond which ``override_min_markers``
            markers (median-filtered over their neighbours) overrule a resting verdict ("Resting").
        override_min_markers: how many markers must have moved for that override (>= 1).
        rest_match_pitch: a candidate rest reference is refused while its markers are off the
            calibrated rest layout (sensor.yaml ``rest_markers_px``) by more than this many
            marker pitches (docs/method.md, "Markers").
        marker_threshold: grey level of marker pixels (0..255); None = Otsu's threshold on the
            reference frame.
        reference_attempts: how many first APS frames may fail to show a marker grid before the
            pipeline says "no gel found".
        noise_filter: the dv-processing noise filter run on every event batch before the tracker
            (``noise.NOISE_FILTERS``), or None for none (docs/method.md, "Noise filter").
        noise_filter_us: the filter's time parameter (us, >= 1); None = that filter's own
            (``noise.NOISE_FILTERS``).
        tracker: the blob tracker's parameters (docs/method.md, "Tracker").
    """

    window_us: int = 10_000
    r_px: float = 25.0
    a: float = 0.6
    n_min: int = 12
    homography_max_iters: int = 2000
    homography_method: str = "usac_fast"
    centroid_threshold: float = 0.01
    centroid_reset_threshold: float = 0.05
    min_intensity_px: float = 0.3
    gesture_reproj_factor: float = 2.0
    min_gesture_reproj_px: float = 0.5
    intensity_sigma_px: float = 3.0
    contact_refine_px: float = 20.0
    plateau_fraction: float = 0.8
    marker_pitch_px: float = 10.0
    spike_fraction: float = 0.6
    origin_radius_px: float = 10.0
    motion_override_px: float = 0.3
    override_min_markers: int = 12
    rest_match_pitch: float = 0.1
    marker_threshold: int | None = None
    reference_attempts: int = 3
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
            check_window(value)
        else:
            check_noise_filter(info.data.get("noise_filter"), value)
        return value

    @model_validator(mode="after")
    def _consistent(self) -> "PipelineConfig":
        check_window(self.window_us)
        check_homography(self.homography_method, self.r_px, self.a, self.n_min)
        check_noise_filter(self.noise_filter, self.noise_filter_us)
        positive = ("intensity_sigma_px", "contact_refine_px", "motion_override_px", "origin_radius_px")
        positive += ("marker_pitch_px", "rest_match_pitch")
        for name in positive:
            if not getattr(self, name) > 0:
                raise ValueError(f"{name} must be positive, got {getattr(self, name)}")
        if self.centroid_reset_threshold < self.centroid_threshold:
            raise ValueError(
                f"centroid_reset_threshold ({self.centroid_reset_threshold}) must be at least centroid_threshold "
                f"({self.centroid_threshold})"
            )
        if not 0.0 < self.spike_fraction <= 1.0:
            raise ValueError(f"spike_fraction must be in (0, 1], got {self.spike_fraction}")
        if not 0.0 < self.plateau_fraction < 1.0:
            raise ValueError(f"plateau_fraction must be in (0, 1), got {self.plateau_fraction}")
        if self.override_min_markers < 1:
            raise ValueError(f"override_min_markers must be >= 1, got {self.override_min_markers}")
        check_attempts(self.reference_attempts)
        return self


def check_window(window_us: int) -> None:
    """Raise ValueError when ``window_us`` is below :data:`MIN_WINDOW_US`."""
    if window_us < MIN_WINDOW_US:
        raise ValueError(f"window_us must be at least {MIN_WINDOW_US} us, got {window_us}")


def check_homography(method: str, r_px: float, a: float, n_min: int) -> None:
    """Raise ValueError for an unknown RANSAC variant, r or a not positive, or n_min < 1."""
    if method not in HOMOGRAPHY_METHODS:
        raise ValueError(f"homography_method must be one of {', '.join(HOMOGRAPHY_METHODS)}, got {method!r}")
    if r_px <= 0 or a <= 0 or n_min < 1:
        raise ValueError(f"r_px and a must be positive and n_min >= 1, got r_px={r_px}, a={a}, n_min={n_min}")


def check_attempts(reference_attempts: int) -> None:
    """Raise ValueError when ``reference_attempts`` < 1."""
    if reference_attempts < 1:
        raise ValueError(f"reference_attempts must be >= 1, got {reference_attempts}")


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
    """``config`` with its pixel settings following the sensor's scale (docs/method.md, "Camera model").

    Every pixel setting is given at :data:`REFERENCE_PX_PER_MM`; they are multiplied by
    ``sensor.px_per_mm / REFERENCE_PX_PER_MM`` (squared for the tracker's variances and the
    centroid thresholds, px^2), so that a camera nearer the gel or with more pixels keeps the same
    contact radius, tracker gates and thresholds on the gel. Returns ``config`` itself at the
    reference scale."""
    k = sensor.px_per_mm / REFERENCE_PX_PER_MM
    if k == 1.0:
        return config
    changes = {name: getattr(config, name) * k for name in _PX_FIELDS}
    changes["centroid_threshold"] = config.centroid_threshold * k * k  # px^2 between centroids
    changes["centroid_reset_threshold"] = config.centroid_reset_threshold * k * k
    t = config.tracker
    tracker = t.model_copy(
        update={**{n: getattr(t, n) * k for n in _TRACKER_PX}, **{n: getattr(t, n) * k * k for n in _TRACKER_PX2}}
    )
    return config.model_copy(update={"tracker": tracker, **changes})
