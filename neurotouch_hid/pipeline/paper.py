"""The paper's method as its own composition (paper, section "Methodology"; docs/method.md,
"The paper's method"): ``track``/``eval``/``run --method paper``.

:class:`PaperPipeline` is the product's pipeline (:class:`~neurotouch_hid.pipeline.pipeline.GesturePipeline`:
the same windows, frames, tracker and resting thread) with the paper's steps in place of the
product's: no noise filter, the first frame with a marker grid as rest, fixed pixels and
sensor.yaml's one scale, the Chamfer distance's raw sum over marker pixels with its threshold
2.5, no re-anchoring near rest, no frame correction, no override of a resting verdict, the
homography's outliers and their local maxima at the current positions as the contacts, the
4-DoF similarity with the same dynamic threshold rule about the contacts' mean as the type, the
uniform mean displacement over A as the intensity, each window's own type, an elastic gel.
Its hyperparameters are the paper's (section "Results"): r = 30 px, a = 0.6, N_min = 4.
"""

from __future__ import annotations

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

from neurotouch_hid.core.estimate import GestureType
from neurotouch_hid.core.sensor import SensorGeometry
from neurotouch_hid.pipeline.config import check_attempts, check_homography, check_window
from neurotouch_hid.pipeline.contacts import Contacts, _no_contacts, local_maxima, outlier_candidates
from neurotouch_hid.pipeline.episode import EpisodeVote
from neurotouch_hid.pipeline.gesture import GestureResult, estimate_gesture
from neurotouch_hid.pipeline.moves import _largest_move_sq
from neurotouch_hid.pipeline.pipeline import GesturePipeline
from neurotouch_hid.pipeline.resting import RestingDetector, RestingResult
from neurotouch_hid.pipeline.tracker import TrackerConfig


class PaperConfig(BaseModel):
    """The paper's hyperparameters (paper, section "Results"), in the image's pixels as they are
    (no scaling to the sensor). A pydantic model like
    :class:`~neurotouch_hid.pipeline.config.PipelineConfig`; ``--set`` works on its fields.

    Attributes:
        window_us: window length (us), >= 1000; paper: 10 ms.
        r_px: radius r of the contact neighbourhoods and of the set A (px); paper: 30.
        a: dynamic reprojection threshold coefficient, of the contact homography and of the
            gesture's similarity (the paper states one rule); paper: 0.6.
        n_min: minimum number of candidates in a contact's neighbourhood; paper: 4.
        homography_max_iters: iteration cap of the contact homography's RANSAC.
        homography_method: ``usac_fast`` or ``ransac`` (``contacts.HOMOGRAPHY_METHODS``).
        chamfer_threshold: the Chamfer distance's raw sum over marker pixels (px^2) at or below
            which the gel rests; paper: 2.5.
        min_gesture_reproj_px: floor of the similarity's RANSAC threshold (px; OpenCV needs a
            positive one).
        marker_threshold: grey level of marker pixels (0..255); None = Otsu's threshold.
        reference_attempts: how many first APS frames may fail to show a marker grid.
        tracker: the blob tracker's parameters (mm and us: the product's tracker, at sensor.yaml's
            scale).
    """

    window_us: int = 10_000
    r_px: float = 30.0
    a: float = 0.6
    n_min: int = 4
    homography_max_iters: int = 2000
    homography_method: str = "usac_fast"
    chamfer_threshold: float = 2.5
    min_gesture_reproj_px: float = 0.5
    marker_threshold: int | None = None
    reference_attempts: int = 3
    tracker: TrackerConfig = Field(default_factory=TrackerConfig)

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    @field_validator("window_us", mode="before")
    @classmethod
    def _as_given(cls, value):
        """The window is checked as given, before pydantic converts it."""
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            check_window(value)
        return value

    @model_validator(mode="after")
    def _consistent(self) -> "PaperConfig":
        check_window(self.window_us)
        check_homography(self.homography_method, self.r_px, self.a, self.n_min)
        check_attempts(self.reference_attempts)
        return self


def paper_contacts(
    rest_px: np.ndarray,
    current_px: np.ndarray,
    valid: np.ndarray | None = None,
    *,
    r_px: float = 30.0,
    a: float = 0.6,
    n_min: int = 4,
    max_iters: int = 2000,
    method: str = "usac_fast",
) -> Contacts:
    """The contact points of one window by the paper's rule (paper, "Contact Point Detection"):
    RANSAC's outliers (:func:`~neurotouch_hid.pipeline.contacts.outlier_candidates`) and their
    local displacement maxima within ``r_px`` of each marker's current position, with at least
    ``n_min`` candidates there; a contact point is its marker's position (px, image frame).
    Arguments and errors as :func:`~neurotouch_hid.pipeline.contacts.detect_contacts`."""
    c = outlier_candidates(rest_px, current_px, valid, a=a, max_iters=max_iters, method=method)
    if isinstance(c, int):
        return _no_contacts(c)
    chosen = np.flatnonzero(c.outliers)
    rows = chosen[local_maxima(c.current_px[chosen], c.magnitudes[chosen], r_px, n_min)]
    points = np.ascontiguousarray(c.current_px[rows], dtype=np.float64).reshape(-1, 2)
    return c.contacts(rows, points, points)


class PaperPipeline(GesturePipeline):
    """The paper's method over the same stream handling as the product's
    (:class:`~neurotouch_hid.pipeline.pipeline.GesturePipeline`: arguments, attributes and
    errors the same; ``config`` a :class:`PaperConfig`)."""

    #: its motion override differs (:meth:`_moving`): every window takes the general path
    rests_compiled = False

    def __init__(self, sensor: SensorGeometry, config: PaperConfig | None = None, **kwargs) -> None:
        super().__init__(sensor, config, **kwargs)

    @staticmethod
    def default_config() -> PaperConfig:
        """The paper's hyperparameters."""
        return PaperConfig()

    # --- the paper's steps, in the order of the product's composition -----------------------
    def _scaled(self, settings: PaperConfig, sensor: SensorGeometry) -> PaperConfig:
        """Fixed pixels."""
        return settings

    def _episode_vote(self) -> EpisodeVote:
        """Not used: each window answers its own type (:meth:`_vote`)."""
        return EpisodeVote()

    def _creep_filter(self, sensor: SensorGeometry) -> None:
        """None whatever sensor.yaml's creep: the paper's gel is elastic."""
        return None

    def _noise_filter(self) -> None:
        """Every event reaches the tracker."""
        return None

    def _rest_reference_ok(self, points_px: np.ndarray) -> bool:
        """The first frame with a marker grid is t0, "a timestep where the gel is in resting position"."""
        return True

    def _use_camera_model(self) -> None:
        """sensor.yaml's scale as it is."""

    def _resting_detector(self, reference: np.ndarray) -> RestingDetector:
        """The paper's Chamfer distance: the raw sum over the marker pixels (paper, "Resting
        Position Detection")."""
        c = self.config
        return RestingDetector(
            reference, self.sensor, c.chamfer_threshold, c.marker_threshold, per_marker=False, centroids=False
        )

    def _near_rest(self, result: RestingResult) -> bool:
        """Only a resting verdict resets the tracker."""
        return False

    def _moving(self, current: np.ndarray, valid: np.ndarray) -> bool:
        """A resting verdict stands until the next frame's."""
        return False

    def _still(self, current: np.ndarray, valid: np.ndarray) -> bool:
        """No minimum intensity: still only without a valid marker."""
        return _largest_move_sq(current, valid, self.rest_px) < 0.0

    def _released(self, intensity_px: float, t_us: int) -> bool:
        """An elastic gel: its deformation is the fingers' load."""
        return False

    def _vote(self, gesture: GestureType, intensity_mm: float, n_contacts: int, t_us: int) -> GestureType:
        """Each window's own type."""
        return gesture

    def _led(self, intensity_mm: float, t_us: int) -> float:
        """Each window's own intensity."""
        return intensity_mm

    def _fit(
        self, rest_px: np.ndarray, current: np.ndarray, valid: np.ndarray, held: object = None
    ) -> tuple[Contacts, GestureResult]:
        """The paper's contacts and the gesture's similarity, type and intensity about them."""
        c = self.config
        begin = self._clock()
        contacts = paper_contacts(
            rest_px,
            current,
            valid,
            r_px=c.r_px,
            a=c.a,
            n_min=c.n_min,
            max_iters=c.homography_max_iters,
            method=c.homography_method,
        )
        self._record("contacts", begin)
        begin = self._clock()
        result = estimate_gesture(
            rest_px,
            current,
            valid,
            contacts.peaks_px,
            self.sensor,
            r_px=c.r_px,
            reproj_factor=c.a,
            min_reproj_px=c.min_gesture_reproj_px,
            min_intensity_px=0.0,
            intensity_sigma_px=0.0,
            origin_radius_px=0.0,
        )
        self._record("gesture", begin)
        return contacts, result
