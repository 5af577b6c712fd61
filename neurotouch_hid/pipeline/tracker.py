"""Event-by-event blob tracking of the gel's markers (paper, section Marker Tracking).

The paper tracks its markers with the asynchronous event-blob tracker of Wang et al.
("Asynchronous Blob Tracker for Event Cameras", IEEE T-RO 2024, AEB-Tracker), restricted to
circular blobs of one fixed size Lambda, which makes that tracker's EKF linear. This module is
that linear filter, per blob and per event:

* state per blob and per image axis: position p, velocity v and the polarity offset q of
  AEB-Tracker (white markers on black: ON events lead the true centre along the motion, OFF events
  trail it, so an ON event measures p + q and an OFF event p - q);
* prediction over the time dt since the blob's last update: a constant-velocity model whose
  velocity decays with time constant ``velocity_tau_us`` (a blob that stops producing events has
  stopped moving), process noise scaled by dt, at most ``max_gap_us`` (a pause in a blob's
  events is evidence that it stands still, not growing uncertainty);
* measurement: the event's pixel, H = [1, 0, +-1], noise Lambda^2, Lambda = ``sigma_mm`` in px;
* constraint: |q| <= ``max_offset_mm`` (about the marker's radius), enforced by projection after
  each update.

The prediction's advance between two events of a blob is capped at ``max_step_mm`` (a marker moves
a fraction of a pixel between two of its events), which keeps the filter linear in practice.

The x and y axes share one 3x3 covariance: the model is isotropic and both axes see the same
measurements, so their covariances are equal at all times (half the arithmetic).

Association: each event goes to the blob that owns its pixel in a label image (per-pixel lookup,
O(1) per event, no scan of the blobs). There is one label image per polarity: a blob owns the
pixels within ``assoc_mm`` of where it expects its events of that polarity (p + q for ON, p - q
for OFF), nearest blob first, so a neighbour's leading edge does not steal a blob's trailing
events when markers are squeezed together under a finger. A blob's ownership is repainted when
p +- q has moved 1 px from where it was painted. Events on pixels no blob owns are noise and
are skipped. A per-blob event-rate gate skips isolated events (background-activity noise near a
blob at rest): an event updates its blob only when the blob's leaky event count (time constant
``rate_tau_us``) reaches ``min_rate_count``. After each batch, a blob is lost (``valid`` False,
no longer updated) when it has left the gel circle or come within ``merge_mm`` of another blob
(then both are). The pipeline re-initialises the tracker at rest with :meth:`BlobTracker.reset`
(paper, section Resting Position Detection). Optionally, :meth:`BlobTracker.correct` fuses the
markers detected on an APS frame (not in the paper; see docs/method.md, "Tracker"), after
:func:`swapped_blobs` has found the blobs left on another marker than their own and
:meth:`BlobTracker.relocate` has put them back (docs/method.md, "Frame correction").

Displacements v_i = p_i(t) - p_i(t0) are computed downstream from ``positions_px`` and the rest
positions.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba
import numpy as np
from numpy.lib import recfunctions
from pydantic import BaseModel, ConfigDict

from neurotouch_hid.core.sensor import SensorGeometry
from neurotouch_hid.pipeline.order import median_head
from neurotouch_hid.pipeline.tracker_kernels import (
    _C00,
    _C11,
    _C22,
    _N_APPLIED,
    _N_GATED,
    _N_NEIGHBOURS,
    _N_NOISE,
    _N_REPAINTS,
    _P_CX,
    _P_CY,
    _P_R2,
    _check_lost,
    _correct,
    _disc_shapes,
    _frame_matches,
    _neighbours,
    _paint_all,
    _reset_if_painted,
    _track,
)
from neurotouch_hid.sources import EVENT_DTYPE


class TrackerConfig(BaseModel):
    """Parameters of :class:`BlobTracker` in units on the gel: lengths in mm, the filter's
    variances in um^2 (velocities in um/ms, i.e. mm/s), times in microseconds; converted to the
    image's pixels with the sensor's px_per_mm (:meth:`in_pixels`: lengths times px_per_mm,
    variances times (px_per_mm / 1000)^2). A pydantic model: a value of the wrong
    type, or an unknown field, raises ``pydantic.ValidationError`` (a ValueError) naming the field.
    The reasons for the values: docs/method.md, "Tracker".

    Attributes:
        sigma_mm: fixed blob size Lambda (mm); the measurement noise is its square.
        assoc_mm: association threshold (mm): an event can update a blob only within this distance
            of the pixel where the blob expects events of its polarity (p +- q, repainted with a
            1 px hysteresis). Below half the marker spacing (4 mm).
        q_pos_um2: position process noise (um^2 per ms).
        q_vel_um2: velocity process noise ((um/ms)^2 per ms).
        q_offset_um2: polarity-offset process noise (um^2 per ms).
        p0_pos_um2, p0_vel_um2, p0_offset_um2: initial variances (um^2, (um/ms)^2, um^2) at
            init/reset.
        velocity_tau_us: time constant of the velocity's decay between a blob's events (us).
        max_step_mm: largest move (mm) the velocity may predict between two events of a blob.
        rate_tau_us: time constant of the per-blob leaky event count (us).
        min_rate_count: leaky event count a blob needs for an event to update it (1 = no gate).
        frame_gate_mm: :meth:`BlobTracker.correct` matches a blob to an APS-frame detection only
            within this distance (mm).
        frame_sigma_mm: noise of an APS-frame detection (mm) in :meth:`BlobTracker.correct`.
        frame_motion_us: time over which an APS frame integrates motion (its exposure, us): a
            blob moving at v px/us adds (v * frame_motion_us)^2 to the detection's noise.
        merge_mm: two blobs closer than this (mm) are both lost.
        gel_margin_mm: a blob farther than gel radius + margin (mm) from the gel centre is lost.
        max_offset_mm: largest length (mm) of the polarity offset q: an ON event cannot lead a
            marker's centre by more than its radius (1 mm marker) plus its blurred edge. After
            each update a longer q is shortened to this length (projection onto the constraint).
            Without it (0 = no bound), q and p drift apart along their weakly observed directions
            during a held gesture (few events, mostly of one polarity), and a blob squeezed
            ~1.6 mm from its neighbours slides onto a neighbour's marker (docs/method.md,
            "Tracker").
        max_gap_us: the process noise of a prediction over a longer pause in a blob's events is
            that of this pause (us; 0 = no bound). A marker that moves makes events: a pause says
            it did not move, so its uncertainty must not keep growing. Without the bound, the
            first events after a long pause of a held marker (its tremor, a squeezed
            neighbour's edge) meet a large covariance and throw the blob px away.
    """

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    sigma_mm: float = 0.4
    assoc_mm: float = 1.6
    q_pos_um2: float = 48.0
    q_vel_um2: float = 16.0
    q_offset_um2: float = 4800.0
    p0_pos_um2: float = 16_000.0
    p0_vel_um2: float = 1600.0
    p0_offset_um2: float = 80_000.0
    velocity_tau_us: float = 10_000.0
    max_step_mm: float = 0.1
    rate_tau_us: float = 1_000.0
    min_rate_count: float = 2.0
    frame_gate_mm: float = 0.6
    frame_sigma_mm: float = 0.04
    frame_motion_us: float = 4_000.0
    merge_mm: float = 0.8
    gel_margin_mm: float = 1.6
    max_offset_mm: float = 0.6
    max_gap_us: float = 10_000.0

    def in_pixels(self, px_per_mm: float) -> "TrackerPixels":
        """These settings in the image's pixels at ``px_per_mm`` (lengths px, variances px^2,
        velocities px/ms, times us)."""
        s = px_per_mm

        def variance(um2: float) -> float:  # um^2 -> px^2 (exact at 2.5 px/mm for the defaults)
            return um2 * s * s / 1e6

        return TrackerPixels(
            sigma_px=self.sigma_mm * s,
            assoc_px=self.assoc_mm * s,
            q_pos=variance(self.q_pos_um2),
            q_vel=variance(self.q_vel_um2),
            q_offset=variance(self.q_offset_um2),
            p0_pos=variance(self.p0_pos_um2),
            p0_vel=variance(self.p0_vel_um2),
            p0_offset=variance(self.p0_offset_um2),
            velocity_tau_us=self.velocity_tau_us,
            max_step_px=self.max_step_mm * s,
            rate_tau_us=self.rate_tau_us,
            min_rate_count=self.min_rate_count,
            frame_gate_px=self.frame_gate_mm * s,
            frame_sigma_px=self.frame_sigma_mm * s,
            frame_motion_us=self.frame_motion_us,
            merge_px=self.merge_mm * s,
            gel_margin_px=self.gel_margin_mm * s,
            max_offset_px=self.max_offset_mm * s,
            max_gap_us=self.max_gap_us,
        )


@dataclass(frozen=True)
class TrackerPixels:
    """:class:`TrackerConfig` in the image's pixels at one scale (:meth:`TrackerConfig.in_pixels`):
    what :class:`BlobTracker` runs on. Same fields with ``_px`` for ``_mm``; ``q_*`` and ``p0_*``
    in px^2 (velocities px/ms)."""

    sigma_px: float
    assoc_px: float
    q_pos: float
    q_vel: float
    q_offset: float
    p0_pos: float
    p0_vel: float
    p0_offset: float
    velocity_tau_us: float
    max_step_px: float
    rate_tau_us: float
    min_rate_count: float
    frame_gate_px: float
    frame_sigma_px: float
    frame_motion_us: float
    merge_px: float
    gel_margin_px: float
    max_offset_px: float
    max_gap_us: float


class BlobTracker:
    """Asynchronous event-blob tracker of the gel's markers (paper, section Marker Tracking).

    Args:
        initial_px: (N, 2) float, initial marker positions (x, y), image frame, px (from
            :func:`neurotouch_hid.pipeline.markers.detect_markers` on an APS frame at rest).
        width, height: image size (px).
        config: :class:`TrackerConfig` (mm; the product's defaults if None).
        sensor: its ``px_per_mm`` converts ``config`` to pixels, and a blob farther than the gel
            radius + ``config.gel_margin_mm`` from the gel centre is lost. Without it: the default
            :class:`~neurotouch_hid.core.sensor.SensorGeometry`'s scale, and only a blob beyond the
            image's circumscribed circle is lost (a blob outside the image owns no pixel and gets
            no events).

    Attributes:
        positions_px: (N, 2) float64 current positions, image frame, px (a copy).
        valid: (N,) bool, False for a lost marker (a copy).
        velocities_px_per_s: (N, 2) float64 current velocity estimates, px/s (a copy).
        counts: dict of event counters since construction: applied, gated (rate gate), noise.
        config: the :class:`TrackerConfig` (mm); ``pixels``: it at the sensor's scale.
    """

    def __init__(
        self,
        initial_px: np.ndarray,
        width: int = 346,
        height: int = 260,
        config: TrackerConfig | None = None,
        *,
        sensor: SensorGeometry | None = None,
    ) -> None:
        self.config = config or TrackerConfig()
        self.width = int(width)
        self.height = int(height)
        if not 0 < self.config.assoc_mm:
            raise ValueError(f"TrackerConfig.assoc_mm must be positive, got {self.config.assoc_mm}")
        self.pixels = c = self.config.in_pixels((sensor or SensorGeometry()).px_per_mm)
        if sensor is not None:
            cx, cy = sensor.gel_center_px
            r = sensor.gel_radius_px + c.gel_margin_px
        else:  # the image's circumscribed circle: blobs are lost only when leaving the image
            cx, cy = (self.width - 1) / 2.0, (self.height - 1) / 2.0
            r = math.hypot(self.width, self.height) / 2.0
        self._params = np.array(
            [
                c.sigma_px**2,
                c.q_pos,
                c.q_vel,
                c.q_offset,
                c.velocity_tau_us * 1e-3,
                float(c.rate_tau_us),
                c.min_rate_count,
                c.merge_px**2,
                cx,
                cy,
                r * r,
                c.assoc_px**2,
                c.max_step_px,
                c.max_offset_px**2 if c.max_offset_px > 0 else np.inf,
                c.max_gap_us * 1e-3 if c.max_gap_us > 0 else np.inf,
            ],
            dtype=np.float64,
        )
        self._offs, self._n_offs = _disc_shapes(c.assoc_px)
        self._label = np.full((2, self.height, self.width), -1, dtype=np.int32)
        self._counts = np.zeros(4, dtype=np.int64)
        self._reset_px: np.ndarray | None = None
        #: the initial variances (position, velocity, offset; px^2) a reset gives
        self._p0 = np.array([c.p0_pos, c.p0_vel, c.p0_offset], dtype=np.float64)
        #: (the blobs' validity, the event loop's repaints) when the labels were last painted by
        #: a reset, None once anything else repainted them (``_reset_if_painted``)
        self._painted: tuple[np.ndarray, int] | None = None
        self.reset(initial_px)

    def reset(self, positions_px: np.ndarray) -> None:
        """Re-initialise every blob at ``positions_px`` (N, 2) float px, image frame, at rest
        (paper, section Resting Position Detection): zero velocity and offset, initial covariance,
        ownership repainted. N may differ from the previous N. Blobs outside the gel (or image)
        start lost. Raises ValueError when ``positions_px`` is not (N, 2) finite."""
        p = np.asarray(positions_px, dtype=np.float64)
        # at rest the pipeline resets to the same positions at every APS frame (25 Hz): while
        # the label images are still those that reset painted, one compiled pass resets the state
        if self._painted is not None and p.flags.c_contiguous and self._reset_px.shape == p.shape:
            if _reset_if_painted(p, self._reset_px, *self._painted, self._counts, *self._blob_arrays(), self._p0):
                return
        if p.ndim != 2 or p.shape[1] != 2 or not np.all(np.isfinite(p)):
            raise ValueError(f"positions_px must be a finite (N, 2) array, got shape {p.shape}")
        n = len(p)
        c = self.pixels
        self._state = np.zeros((n, 6), dtype=np.float64)
        self._state[:, :2] = p
        self._cov = np.zeros((n, 6), dtype=np.float64)
        self._cov[:, _C00] = c.p0_pos
        self._cov[:, _C11] = c.p0_vel
        self._cov[:, _C22] = c.p0_offset
        self._t_upd = np.full(n, -1, dtype=np.int64)
        self._t_seen = np.full(n, -1, dtype=np.int64)
        self._rate = np.zeros(n, dtype=np.float64)
        cx, cy, r2 = self._params[_P_CX], self._params[_P_CY], self._params[_P_R2]
        in_image = (p[:, 0] >= 0) & (p[:, 1] >= 0) & (p[:, 0] <= self.width - 1) & (p[:, 1] <= self.height - 1)
        self._valid = in_image & ((p[:, 0] - cx) ** 2 + (p[:, 1] - cy) ** 2 <= r2)
        self._cell = np.zeros((n, 2, 2), dtype=np.int64)
        # the pipeline resets to the same rest positions at every resting APS frame (25 Hz):
        # their neighbour lists (an (N, N) sort, ~0.7 ms for 177 markers) are kept
        if self._reset_px is None or not np.array_equal(p, self._reset_px):
            self._neigh = _neighbours(p, _N_NEIGHBOURS)
            self._reset_px = p.copy()
        _paint_all(self._state, self._valid, self._cell, self._label, self._offs, self._n_offs)
        self._painted = (self._valid.copy(), int(self._counts[_N_REPAINTS]))

    def _blob_arrays(self) -> tuple[np.ndarray, ...]:
        """The per-blob arrays a reset sets: state, covariance, last update and last event (us),
        event rate, validity."""
        return self._state, self._cov, self._t_upd, self._t_seen, self._rate, self._valid

    def correct(self, detections_px: np.ndarray, t_us: int | None = None) -> int:
        """Fuse marker detections of an APS frame into the blobs (optional; not in the paper).

        Between events a blob's position is a running average of its recent events, which lags
        a little behind a marker that has just stopped, and a held gesture makes no more events
        to correct it. The APS frame shows the markers where they are: each valid blob whose
        nearest detection is within ``config.frame_gate_mm``, is nearest to no other blob and has
        no other blob within twice that distance (two squeezed markers seen as one), gets a Kalman
        position update from it, with noise ``config.frame_sigma_mm``^2 plus the blur of its
        motion over ``config.frame_motion_us``. Call it with the frame's marker centroids when
        the frame arrives (the stream yields it before the events at or after its timestamp):
        :func:`~neurotouch_hid.pipeline.markers.detect_markers`'s, or the resting detector's
        (``RestingResult.centroids_px``, what the pipeline's frame correction passes).

        Args:
            detections_px: (M, 2) float marker centroids on the frame, image frame, px.
            t_us: the frame's timestamp (us): each matched blob is first predicted to it (its
                velocity fades over a pause in its events). None: no prediction.
        Returns:
            the number of blobs corrected.
        """
        det = np.asarray(detections_px, dtype=np.float64).reshape(-1, 2)
        n = len(self._state)
        if n == 0 or len(det) == 0:
            return 0
        c = self.pixels
        self._painted = None  # its updates may repaint
        match = _frame_matches(self._state, self._valid, det, c.frame_gate_px**2)
        t = -1 if t_us is None else int(t_us)
        _correct(
            det,
            match,
            t,
            self._state,
            self._cov,
            self._t_upd,
            self._valid,
            self._cell,
            self._label,
            self._offs,
            self._n_offs,
            self._neigh,
            self._params,
            c.frame_sigma_px**2,
            c.frame_motion_us * 1e-3,
        )
        return int(np.count_nonzero(match >= 0))

    def relocate(self, indices: np.ndarray, positions_px: np.ndarray) -> None:
        """Move blobs ``indices`` ((K,) int) to ``positions_px`` ((K, 2) float px, image frame)
        as :meth:`reset` places a blob: zero velocity and offset, initial covariance; every blob's
        ownership repainted. For a blob found on another marker than its own
        (:func:`swapped_blobs`). Raises ValueError when the positions are not (K, 2) finite."""
        idx = np.asarray(indices, dtype=np.int64).reshape(-1)
        p = np.asarray(positions_px, dtype=np.float64).reshape(-1, 2)
        if len(p) != len(idx) or not np.all(np.isfinite(p)):
            raise ValueError(f"relocate needs one finite position per blob, got {len(idx)} blobs and {p.shape}")
        if not len(idx):
            return
        c = self.pixels
        self._painted = None  # repainted below around the moved blobs
        self._state[idx] = 0.0
        self._state[idx, :2] = p
        self._cov[idx] = 0.0
        self._cov[idx, _C00] = c.p0_pos
        self._cov[idx, _C11] = c.p0_vel
        self._cov[idx, _C22] = c.p0_offset
        _paint_all(self._state, self._valid, self._cell, self._label, self._offs, self._n_offs)

    def update(self, events: np.ndarray) -> None:
        """Track through a batch of events, event by event (numba).

        Args:
            events: structured array of :data:`neurotouch_hid.sources.EVENT_DTYPE`, time-ordered
                (timestamp int64 us, x/y int16 px image frame, polarity 1 = ON, 0 = OFF).
        Raises:
            ValueError: ``events`` lacks the EVENT_DTYPE fields.
        """
        if events.dtype != EVENT_DTYPE:  # (the sets only for another dtype: ~1.5 us a batch)
            if events.dtype.names is None or not set(EVENT_DTYPE.names) <= set(events.dtype.names):
                raise ValueError(f"events must have the EVENT_DTYPE fields {EVENT_DTYPE.names}, got {events.dtype}")
            events = recfunctions.require_fields(events, EVENT_DTYPE)  # the kernel's one layout (a copy)
        elif not events.flags.c_contiguous:
            events = np.ascontiguousarray(events)
        if len(events) == 0 or len(self._state) == 0:
            return
        _track(events, *self.kernel_state())
        _check_lost(
            self._cell, self._label, self._offs, self._n_offs, self._neigh, self._valid, self._state, self._params
        )

    def kernel_state(self) -> tuple:
        """The arrays :meth:`update` hands the event kernels (``_track``, ``_check_lost``), in
        ``_track``'s order after the events: for a compiled caller that runs them itself
        (``rest_window.py``)."""
        return (
            self._state,
            self._cov,
            self._t_upd,
            self._t_seen,
            self._rate,
            self._valid,
            self._cell,
            self._label,
            self._offs,
            self._n_offs,
            self._neigh,
            self._params,
            self._counts,
        )

    @property
    def positions_px(self) -> np.ndarray:
        """(N, 2) float64 copy of the blobs' positions (x, y), image frame, px."""
        return self._state[:, :2].copy()

    @property
    def velocities_px_per_s(self) -> np.ndarray:
        """(N, 2) float64 velocity estimates, image frame, px/s."""
        return self._state[:, 2:4] * 1e3

    @property
    def valid(self) -> np.ndarray:
        """(N,) bool copy: False for a lost blob (left the gel, or merged with another)."""
        return self._valid.copy()

    @property
    def counts(self) -> dict[str, int]:
        """Events since construction: ``applied`` (updated a blob), ``gated`` (owned by a blob but
        isolated: the rate gate), ``noise`` (on a pixel no blob owns, or outside the image)."""
        names = {"applied": _N_APPLIED, "gated": _N_GATED, "noise": _N_NOISE}
        return {name: int(self._counts[k]) for name, k in names.items()}

    def owner_image(self, polarity: int = 1) -> np.ndarray:
        """(height, width) int32 copy of the label image of ``polarity`` (1 = ON, 0 = OFF): index
        of the blob that owns each pixel's events of that polarity, -1 for none."""
        return self._label[1 if polarity else 0].copy()


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _suspects(positions, valid, rest, neighbours, limit, shared):
    """(N,) bool: the valid blobs with at least 3 valid neighbours whose displacement from rest is
    more than ``limit`` px from the median of their neighbours'; ``shared`` ((N, 2) float64)
    gets that median where it is computed (:func:`swapped_blobs`)."""
    n, k = neighbours.shape
    out = np.zeros(n, dtype=np.bool_)
    xs = np.empty(k)
    ys = np.empty(k)
    for i in range(n):
        if not valid[i]:
            continue
        m = 0
        for j in neighbours[i]:
            if j >= 0 and valid[j]:
                xs[m] = positions[j, 0] - rest[j, 0]
                ys[m] = positions[j, 1] - rest[j, 1]
                m += 1
        if m < 3:
            continue
        mx = median_head(xs, m)
        my = median_head(ys, m)
        shared[i, 0], shared[i, 1] = mx, my
        dx = positions[i, 0] - rest[i, 0] - mx
        dy = positions[i, 1] - rest[i, 1] - my
        out[i] = dx * dx + dy * dy > limit * limit
    return out


#: A blob whose displacement from rest is this many marker pitches from the median of its
#: neighbours' on the gel is on another marker than its own (:func:`swapped_blobs`) ...
SWAP_PITCHES = 0.7
#: ... when a detection of the frame lies within this many pitches of where that median puts it
#: (and a blob this far from that median with no detection within this distance of it is a suspect too).
SWAP_FOUND_PITCHES = 0.3


def swapped_blobs(
    positions_px: np.ndarray,
    valid: np.ndarray,
    rest_px: np.ndarray,
    neighbours: np.ndarray,
    detections_px: np.ndarray,
    pitch_px: float,
) -> tuple[np.ndarray, np.ndarray]:
    """The blobs that sit on another marker than their own, and where their own marker is on an
    APS frame (not in the paper; docs/method.md, "Frame correction").

    A fast, large motion (a deep press let go at once) can leave blobs on their neighbours'
    markers, a chain of them each one pitch along, or between two markers, a cluster of them
    under the finger; the frame correction then holds each on the wrong marker or, beyond its
    gate, leaves it where it is, and only a frame at rest re-anchors them, which a creeping gel may
    not show for seconds. The gel is continuous: a marker moves as its neighbours do. A valid blob
    whose displacement from rest is more than :data:`SWAP_PITCHES` pitches from the median of its
    valid neighbours' (at least 3) is a suspect; so is one more than :data:`SWAP_FOUND_PITCHES`
    pitches from that median that sits on no marker of the frame (no detection within that
    distance of it: a cluster of blobs left between markers, each other's neighbours, leans their
    median towards them). Each suspect is assigned the frame's detection nearest where that
    median puts it, when that detection is within :data:`SWAP_FOUND_PITCHES` pitches of it and no
    blob that is not a suspect is as near to it (closest pairs first, each detection once: markers
    lie more than twice that apart, so a chain is undone at once).

    Args:
        positions_px: (N, 2) float64 the blobs' positions (px, image frame).
        valid: (N,) bool, the tracked blobs.
        rest_px: (N, 2) float64 their rest positions (px).
        neighbours: (N, K) int64 each marker's neighbours on the gel, -1 padded
            (``contacts_plateau.rest_neighbours``).
        detections_px: (M, 2) float64 the frame's marker centroids (px).
        pitch_px: the marker pitch (px, > 0).
    Returns:
        (indices (K,) int64 of the blobs to move, positions (K, 2) float64 px where to).
    """
    none = (np.zeros(0, dtype=np.int64), np.zeros((0, 2)))
    det = np.asarray(detections_px, dtype=np.float64).reshape(-1, 2)
    if not len(det):
        return none
    shared = np.full((len(valid), 2), np.nan)
    reach = SWAP_FOUND_PITCHES * float(pitch_px)
    off = np.flatnonzero(  # more than the reach from their neighbours' median
        _suspects(
            np.ascontiguousarray(positions_px, dtype=np.float64),
            np.ascontiguousarray(valid, dtype=np.bool_),
            np.ascontiguousarray(rest_px, dtype=np.float64),
            np.ascontiguousarray(neighbours, dtype=np.int64),
            reach,
            shared,
        )
    )
    if not len(off):
        return none
    wanted = shared[off] + rest_px[off]  # (S, 2) where each one's marker should be
    far = np.hypot(*(positions_px[off] - wanted).T) > SWAP_PITCHES * float(pitch_px)
    astray = np.hypot(*(positions_px[off][:, None, :] - det[None, :, :]).transpose(2, 0, 1)).min(axis=1) > reach
    keep = far | astray
    suspects, wanted = off[keep], wanted[keep]
    if not len(suspects):
        return none
    return moves_to_free_detections(positions_px, valid, suspects, wanted, det, reach)


def moves_to_free_detections(
    positions_px: np.ndarray, valid: np.ndarray, suspects: np.ndarray, wanted: np.ndarray, det: np.ndarray, reach: float
) -> tuple[np.ndarray, np.ndarray]:
    """The second half of :func:`swapped_blobs`: each suspect blob (``suspects`` (S,) int64
    indices into ``positions_px`` (N, 2) px; ``wanted`` (S, 2) px where its marker should be)
    paired, nearest first, with a free detection (``det`` (M, 2) px: within ``reach`` px of
    where it is wanted, and of no other valid blob), one each. Returns the indices of the blobs
    that move (more than ``reach`` from where they were) and their new positions (K, 2) px."""
    none = (np.zeros(0, dtype=np.int64), np.zeros((0, 2)))
    cost = np.hypot(*(wanted[:, None, :] - det[None, :, :]).transpose(2, 0, 1))  # (S, M)
    near = np.flatnonzero((cost <= reach).any(axis=0))  # the detections within reach of one
    if not len(near):
        return none
    others = valid.copy()
    others[suspects] = False
    gap = np.hypot(*(positions_px[others][:, None, :] - det[near][None, :, :]).transpose(2, 0, 1))
    free = near[~(gap <= reach).any(axis=0)] if len(gap) else near  # no other blob holds them
    pairs = [(cost[i, j], i, j) for i in range(len(suspects)) for j in free.tolist() if cost[i, j] <= reach]
    taken_s, taken_d, rows, cols = set(), set(), [], []
    for _, i, j in sorted(pairs):
        if i not in taken_s and j not in taken_d:
            taken_s.add(i)
            taken_d.add(j)
            rows.append(i)
            cols.append(j)
    rows_a, cols_a = np.array(rows, dtype=np.int64), np.array(cols, dtype=np.int64)
    moved = np.hypot(*(positions_px[suspects[rows_a]] - det[cols_a]).reshape(-1, 2).T) > reach
    return suspects[rows_a[moved]], det[cols_a[moved]].reshape(-1, 2)
