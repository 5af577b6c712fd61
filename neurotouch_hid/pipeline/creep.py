"""The fingers' load behind a creeping gel's deformation (not in the paper).

A soft silicone gel creeps: under a held load its deformation keeps growing, and once the
fingers leave it relaxes slowly back to rest. A standard linear solid (Zener: a spring in
parallel with a Maxwell element; Findley, Lai & Onaran, *Creep and Relaxation of Nonlinear
Viscoelastic Materials*, 1976, ch. 5) describes it with two numbers, the delayed share q of the
deformation and its retardation time tau: under a load f (in px of the elastic deformation it
would cause) the deformation is::

    d = (1 - q) f + q y,        tau dy/dt = f - y

Markers show d, and the gesture step reads a window as a gesture while d is above
``min_intensity_px``: after a release, that is as long as the creep takes to relax (on the
simulated ``viscoelastic`` gel, q = 0.3 and tau = 0.3 s, ~0.4 s after the fingers have left;
docs/method.md, "Creep"). The load follows from d alone when q and tau are known: eliminating
f gives ``(1 - q) tau dy/dt = d - y``, so y is d low-passed with the time constant (1 - q) tau,
and ``f = (d - q y) / (1 - q)``. The pipeline (with the gel's ``creep`` in
sensor.yaml; docs/method.md, "Creep") takes d as :func:`amplitude` (the measure the creep was
calibrated on) and answers ``none`` in a window whose load, as a share f / d of the gesture's
intensity, is below ``min_intensity_px`` plus :data:`LOAD_MARGIN` times q y, the part of the
deformation the load was separated from, in the same share (and, once read gone, until the load
is back at :data:`REARM` times that or the gel is seen still): the fingers have left, whatever
the gel still shows. Without a creep model (an elastic gel,
q = 0) the load is the deformation and nothing changes.

q and tau are the gel's: ``calibrate --press`` measures them on a recording of one press
(:func:`fit_creep`): the tracked deformation's amplitude, and the (q, tau) whose load is flattest
while the finger holds still and nearest zero after it left, kept only when it explains the press
much better than an elastic gel does.
"""

from __future__ import annotations

import numpy as np

#: The (q, tau) grid :func:`fit_creep` searches: q from 0 (elastic) to 0.6, tau 0.05-3 s.
SHARES = np.arange(0.0, 0.61, 0.02)
TIMES_S = np.geomspace(0.05, 3.0, 40)
#: A recording whose amplitude never reaches this (px) shows no press (tracking noise: ~0.1 px).
MIN_PRESS_PX = 1.0
#: A press is the frames at or above this fraction of the recording's peak amplitude.
PRESS_FRACTION = 0.5
#: The hold: from this long after a press starts (the attack's end, us) ...
HOLD_AFTER_US = 120_000
#: ... to this long before it ends (the release's start, us).
HOLD_BEFORE_US = 80_000
#: After a release: from this long after the press ends (the release's end, us) for this long (us).
RELEASED_AFTER_US = 120_000
RELEASED_FOR_US = 1_500_000
#: The best creep model is kept only when its misfit (px^2) is at most this share of an elastic
#: gel's (q = 0): a small creep explains part of what any press shows after a quick lift, the
#: tracker's blobs left up to half a marker pitch behind until the gel is seen near rest, and a
#: finger that does not leave at once (docs/method.md, "Creep").
MISFIT_SHARE = 0.5
#: The load is read to within this share of the delayed deformation q y: a creep measured on one
#: press is off the gel's (``compound``'s tau 0.27 s for its 0.3 s), and the tracked deformation
#: relaxes more slowly than the markers (its noise and lag do not relax), so after a release the
#: load read stays 0.1-0.5 mm above zero for as long as the creep lasts; in a hold the load is y
#: itself, far above 0.2 q y (docs/method.md, "Creep").
LOAD_MARGIN = 0.2
#: Hysteresis: once read gone, the fingers are read back only when the load reaches this many
#: times the threshold (or the gel was seen still): in a tail the load read rises ~0.25 mm between
#: two APS frames' corrections and would switch the output on and off (docs/method.md, "Creep").
REARM = 1.5


#: The gel's deformation is read as the mean displacement of this many markers, the most displaced.
AMPLITUDE_MARKERS = 10


def amplitude(positions_px: np.ndarray, rest_px: np.ndarray, valid: np.ndarray) -> float:
    """The gel's deformation amplitude (px): the mean displacement from rest of the
    :data:`AMPLITUDE_MARKERS` most displaced valid markers (all of them when fewer; 0 when none).

    What ``calibrate --press`` fits the creep on and the pipeline's filter reads: the same measure
    for both, whatever the gesture (the gesture's intensity, a mean about its contacts, is another
    share of the gel's field in a hold than in a tail). Args: (N, 2) float positions and rest
    positions (px), (N,) bool valid."""
    moved = np.hypot(*(np.asarray(positions_px, dtype=np.float64) - rest_px).T)[np.asarray(valid, dtype=bool)]
    moved = moved[np.isfinite(moved)]
    if not len(moved):
        return 0.0
    k = min(AMPLITUDE_MARKERS, len(moved))
    return float(np.partition(moved, len(moved) - k)[-k:].mean())


class CreepFilter:
    """The load of :mod:`creep`'s module docstring, window after window.

    Fingers press and never pull, so the load is never negative: the delayed part y is at most
    d / q. When the deformation falls faster than the model lets y follow (a creep calibrated
    slower than the gel's, or the gel seen still after a release), y is brought down to that bound:
    a gel seen at rest holds no creep, and the next press is read from its first window instead of
    being taken for the last one's relaxation.

    Args:
        share: q in [0, 1), the delayed share of the gel's deformation.
        time_s: tau > 0, its retardation time (s).
        floor: the deformation (same unit as :meth:`update`'s) below which a window reads as
            still; a deformation given below it may be up to it, so y is bounded by floor / q
            then (>= 0; 0: the deformation is exact).
        margin: the share of the delayed deformation q y within which the load is known
            (:data:`LOAD_MARGIN`, >= 0): :meth:`released` reads the fingers gone below the floor
            plus that much, and back at :data:`REARM` times that (or once a deformation below the
            floor was given: the gel seen still).
    Raises:
        ValueError: q, tau, the floor or the margin out of range.
    """

    def __init__(self, share: float, time_s: float, floor: float = 0.0, margin: float = LOAD_MARGIN) -> None:
        if not (0.0 <= share < 1.0) or not time_s > 0.0 or not floor >= 0.0 or not margin >= 0.0:
            raise ValueError(
                f"a creep model needs 0 <= q < 1, tau > 0 s, a floor >= 0 and a margin >= 0, "
                f"got q={share}, tau={time_s}, floor={floor}, margin={margin}"
            )
        self.share = float(share)
        self.time_us = float(time_s) * 1e6 * (1.0 - self.share)  # y's time constant (1 - q) tau
        self.floor = float(floor)
        self.margin = float(margin)
        self._y = 0.0
        self._t_us: int | None = None
        self._gone = False

    def reset(self) -> None:
        """Forget the history (a new stream): the gel at rest."""
        self._y = 0.0
        self._t_us = None
        self._gone = False

    def update(self, deformation: float, t_us: int) -> float:
        """The load (same unit as ``deformation``, e.g. px) at ``t_us`` (us, non-decreasing),
        given the deformation then; the first call takes the gel to have been at rest before."""
        dt = 0.0 if self._t_us is None else max(t_us - self._t_us, 0)
        self._t_us = t_us
        deformation = float(deformation)
        if deformation <= 0.0 or deformation < self.floor:  # the gel seen still: nothing to read back
            self._gone = False
        self._y, load = _step(self._y, deformation, dt, self.share, self.time_us)
        if self.share > 0.0 and load < 0.0:  # no pull: y <= max(d, floor) / q
            self._y = min(self._y, max(deformation, self.floor) / self.share)
            load = (deformation - self.share * self._y) / (1.0 - self.share)
        return float(load)

    @property
    def threshold(self) -> float:
        """The load (same unit as :meth:`update`'s) below which the fingers are read gone now: the
        floor plus ``margin`` times the delayed deformation q y the load was separated from."""
        return self.floor + self.margin * self.share * self._y

    def released(self, load: float, scale: float = 1.0) -> bool:
        """Whether ``load`` (the last :meth:`update`'s, times ``scale``) says the fingers have
        left: below :attr:`threshold` (its delayed part times ``scale``); once they have, until
        the load is back at :data:`REARM` times it (hysteresis) or the gel was seen still.
        ``scale`` (> 0) takes the deformation :meth:`update` was given to the unit of the floor:
        the pipeline gives the gel's :func:`amplitude` and reads the gesture's intensity, the
        floor's unit (docs/method.md, "Creep")."""
        threshold = self.floor + self.margin * self.share * self._y * scale
        self._gone = load < (REARM * threshold if self._gone else threshold)
        return self._gone


def _step(y, deformation: float, dt_us: float, share, time_us):
    """One step of the inverse: (y, load) after ``dt_us`` (us) with the deformation then, from
    y before; ``share`` q and ``time_us`` = (1 - q) tau (us) scalars or arrays of one shape."""
    y = y + (deformation - y) * -np.expm1(-dt_us / time_us)
    return y, (deformation - share * y) / (1.0 - share)


def load_estimate(deformation: np.ndarray, t_us: np.ndarray, share, time_s) -> np.ndarray:
    """:class:`CreepFilter` over a whole series, for a grid of models at once.

    Args:
        deformation: (T,) float, the deformation (e.g. px) at each time.
        t_us: (T,) int, non-decreasing times (us).
        share, time_s: q and tau (s): scalars, or arrays of one shape S.
    Returns:
        (T, *S) float64 loads.
    """
    q = np.asarray(share, dtype=np.float64)
    time_us = np.asarray(time_s, dtype=np.float64) * 1e6 * (1.0 - q)
    y = np.zeros(np.broadcast(q, time_us).shape)
    out = np.empty((len(deformation), *y.shape))
    dt = np.diff(np.asarray(t_us, dtype=np.float64), prepend=float(t_us[0]) if len(t_us) else 0.0)
    for k, d in enumerate(np.asarray(deformation, dtype=np.float64)):
        y, out[k] = _step(y, d, dt[k], q, time_us)
    return out


def at_search_edge(share: float, time_s: float) -> bool:
    """Whether a creep from :func:`fit_creep` lies on the edge of its grid (the largest q, or the
    shortest or longest tau): the press did not look like a standard linear solid's (e.g. not
    held still, a very strong press whose markers were lost), and the true creep may lie beyond."""
    return share >= SHARES[-1] - 1e-9 or time_s <= TIMES_S[0] * (1 + 1e-9) or time_s >= TIMES_S[-1] * (1 - 1e-9)


def creep_misfit(t_us: np.ndarray, amplitude: np.ndarray) -> np.ndarray:
    """How far each creep model of the grid is from a recording of presses (``calibrate --press``).

    Args:
        t_us: (T,) int64 window times (us), non-decreasing.
        amplitude: (T,) float, the deformation's amplitude then (px; e.g. the mean of the
            largest tracked marker displacements).
    Returns:
        (len(:data:`SHARES`), len(:data:`TIMES_S`)) float64 misfit (px^2) of each (q, tau): how much
        its load (:func:`load_estimate`) varies about its median over the holds plus how far it is
        from 0 after the releases (least squares); row 0 (q = 0) is the elastic gel's. A press is a
        run of windows at >= :data:`PRESS_FRACTION` of the peak; its hold starts
        :data:`HOLD_AFTER_US` after it and ends :data:`HOLD_BEFORE_US` before its end, its released
        part lasts :data:`RELEASED_FOR_US` from :data:`RELEASED_AFTER_US` after it.
    Raises:
        ValueError: the amplitude never reaches :data:`MIN_PRESS_PX`, or no press has a hold of
            at least 3 windows and a released part of at least 3 windows (a press too short, or
            the recording stops too soon).
    """
    t = np.asarray(t_us, dtype=np.int64)
    a = np.asarray(amplitude, dtype=np.float64)
    if len(a) == 0 or not np.all(np.isfinite(a)) or a.max() < MIN_PRESS_PX:
        peak = float(np.nanmax(a)) if len(a) and np.any(np.isfinite(a)) else 0.0
        raise ValueError(f"the recording shows no press (the markers moved {peak:.2f} px at most, < {MIN_PRESS_PX:g})")
    pressed = a >= PRESS_FRACTION * a.max()
    hold = np.zeros(len(a), dtype=bool)
    released = np.zeros(len(a), dtype=bool)
    bounds = np.concatenate(([0], np.flatnonzero(np.diff(pressed.astype(np.int8))) + 1, [len(a)]))
    for start, stop in zip(bounds[:-1], bounds[1:]):
        if pressed[start]:
            hold |= (t >= t[start] + HOLD_AFTER_US) & (t <= t[stop - 1] - HOLD_BEFORE_US)
            end = t[stop - 1]
            released |= (t > end + RELEASED_AFTER_US) & (t <= end + RELEASED_AFTER_US + RELEASED_FOR_US) & ~pressed
    if hold.sum() < 3 or released.sum() < 3:
        raise ValueError(
            "no press held still and released: press one finger into the gel, hold it still ~2 s, "
            "lift it quickly and leave the gel alone ~2 s"
        )
    q, tau = np.meshgrid(SHARES, TIMES_S, indexing="ij")
    load = load_estimate(a, t, q, tau)
    level = np.median(load[hold], axis=0)
    return ((load[hold] - level) ** 2).sum(axis=0) + (load[released] ** 2).sum(axis=0)


def fit_creep(t_us: np.ndarray, amplitude: np.ndarray) -> tuple[float, float] | None:
    """The gel's creep (q, tau s) from a recording of presses (``calibrate --press``).

    Args:
        t_us, amplitude: as :func:`creep_misfit`'s.
    Returns:
        (q, tau): the model of :data:`SHARES` x :data:`TIMES_S` with the least
        :func:`creep_misfit`; None (the gel does not creep) when that misfit is more than
        :data:`MISFIT_SHARE` of the elastic gel's (q = 0).
    Raises:
        ValueError: as :func:`creep_misfit`.
    """
    cost = creep_misfit(t_us, amplitude)
    i, j = np.unravel_index(np.argmin(cost), cost.shape)
    if SHARES[i] == 0.0 or cost[i, j] > MISFIT_SHARE * cost[0, 0]:  # SHARES[0] is 0: the elastic gel
        return None
    return float(SHARES[i]), float(TIMES_S[j])


#: A new press in a release tail (:class:`TailWatch`): this share of the motion override's
#: displacement (plus the gel's jitter) ...
TAIL_PRESS_SHARE = 0.5
#: ... on this share of its markers.
TAIL_PRESS_MARKERS = 0.5


class TailWatch:
    """A new press in a creeping gel's release tail (docs/method.md, "Creep").

    While :class:`CreepFilter` reads the fingers gone, a relaxing gel's markers only come back
    towards rest. A new press, in the tail of the last one, moves some away again; but the window's
    deformation, taken about contacts still on the old press, keeps falling with the tail, so the
    filter keeps reading the fingers gone. Each marker's least distance from rest since the filter
    read them gone is kept, with where the marker was then: once enough markers are a threshold
    beyond their least, a new press has begun, and those positions are the gel as the tail left it,
    the reference the new press is measured from.
    """

    def __init__(self) -> None:
        self._least: np.ndarray | None = None
        self._at: np.ndarray | None = None

    def reset(self) -> None:
        """Forget the tail (the fingers are read on the gel, a new rest reference or re-anchoring)."""
        self._least = self._at = None

    def update(
        self, distance: np.ndarray, positions: np.ndarray, threshold: float, min_markers: int
    ) -> np.ndarray | None:
        """One window of the tail.

        Args:
            distance: (N,) float64 each marker's distance from rest (px; NaN: not tracked).
            positions: (N, 2) float64 the markers' positions then (px).
            threshold: how much further than its least a marker must be to have moved again (px).
            min_markers: how many such markers make a new press.
        Returns:
            None, or (N, 2) float64 the positions (px) at each marker's least distance since the
            tail began (a lost marker's first position), when at least ``min_markers`` markers are
            more than ``threshold`` beyond their least.
        """
        if self._least is None:
            self._least, self._at = distance.copy(), positions.copy()
            return None
        lower = (distance < self._least) | (np.isnan(self._least) & ~np.isnan(distance))
        self._least = np.where(lower, distance, self._least)
        self._at = np.where(lower[:, None], positions, self._at)
        if np.count_nonzero(distance - self._least > threshold) < min_markers:
            return None
        return self._at
