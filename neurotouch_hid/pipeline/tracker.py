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
* measurement: the event's pixel, H = [1, 0, +-1], noise Lambda^2 = ``sigma_px``^2;
* constraint: |q| <= ``max_offset_px`` (about the marker's radius), enforced by projection after
  each update.

The prediction's advance between two events of a blob is capped at ``max_step_px`` (a marker moves
a fraction of a pixel between two of its events), which keeps the filter linear in practice.

The x and y axes share one 3x3 covariance: the model is isotropic and both axes see the same
measurements, so their covariances are equal at all times (half the arithmetic).

Association: each event goes to the blob that owns its pixel in a label image (per-pixel lookup,
O(1) per event, no scan of the blobs). There is one label image per polarity: a blob owns the
pixels within ``assoc_px`` of where it expects its events of that polarity (p + q for ON, p - q
for OFF), nearest blob first, so a neighbour's leading edge does not steal a blob's trailing
events when markers are squeezed together under a finger. A blob's ownership is repainted when
p +- q has moved 1 px from where it was painted. Events on pixels no blob owns are noise and
are skipped. A per-blob event-rate gate skips isolated events (background-activity noise near a
blob at rest): an event updates its blob only when the blob's leaky event count (time constant
``rate_tau_us``) reaches ``min_rate_count``. After each batch, a blob is lost (``valid`` False,
no longer updated) when it has left the gel circle or come within ``merge_px`` of another blob
(then both are). The pipeline re-initialises the tracker at rest with :meth:`BlobTracker.reset`
(paper, section Resting Position Detection). Optionally, :meth:`BlobTracker.correct` fuses the
markers detected on an APS frame (not in the paper; see docs/performance.md, Tracker).

Displacements v_i = p_i(t) - p_i(t0) are computed downstream from ``positions_px`` and the rest
positions.
"""

from __future__ import annotations

import math

import numba
import numpy as np
from pydantic import BaseModel, ConfigDict

from neurotouch_hid.sensor import SensorGeometry
from neurotouch_hid.sources import EVENT_DTYPE

#: A blob's ownership is repainted when its expected event position is this far (px, in x or y)
#: from the pixel it was painted around.
_HYSTERESIS_PX = 1.0
#: A pixel coordinate far outside any image (releasing every pixel of a lost blob).
_FAR = 1 << 30
#: Number of neighbours per blob remembered for ownership hand-over and merge detection.
_N_NEIGHBOURS = 12


class TrackerConfig(BaseModel):
    """Parameters of :class:`BlobTracker` (units: px, microseconds; velocities px/ms). A pydantic
    model: a value of the wrong type, or an unknown field, raises ``pydantic.ValidationError``
    (a ValueError) naming the field.

    Attributes:
        sigma_px: fixed blob size Lambda (px); the measurement noise is sigma_px^2.
        assoc_px: association threshold (px): an event can update a blob only within this distance
            of the pixel where the blob expects events of its polarity (p +- q, repainted with a
            1 px hysteresis). Below half the marker spacing (~10 px).
        q_pos: position process noise (px^2 per ms).
        q_vel: velocity process noise ((px/ms)^2 per ms).
        q_offset: polarity-offset process noise (px^2 per ms).
        p0_pos, p0_vel, p0_offset: initial variances (px^2, (px/ms)^2, px^2) at init/reset.
        velocity_tau_us: time constant of the velocity's decay between a blob's events (us).
        max_step_px: largest move (px) the velocity may predict between two events of a blob.
        rate_tau_us: time constant of the per-blob leaky event count (us).
        min_rate_count: leaky event count a blob needs for an event to update it (1 = no gate).
        frame_gate_px: :meth:`BlobTracker.correct` matches a blob to an APS-frame detection only
            within this distance (px).
        frame_sigma_px: noise of an APS-frame detection (px) in :meth:`BlobTracker.correct`.
        frame_motion_us: time over which an APS frame integrates motion (its exposure, us): a
            blob moving at v px/us adds (v * frame_motion_us)^2 to the detection's noise.
        merge_px: two blobs closer than this are both lost.
        gel_margin_px: a blob farther than gel radius + margin from the gel centre is lost.
        max_offset_px: largest length (px) of the polarity offset q: an ON event cannot lead a
            marker's centre by more than its radius (1 mm marker, 1.25 px at 2.5 px/mm) plus its
            blurred edge. After each update a longer q is shortened to this length (projection
            onto the constraint). Without it (0 = no bound), q and p drift apart along their
            weakly observed directions during a held gesture (few events, mostly of one
            polarity), and a blob squeezed ~4 px from its neighbours slides onto a neighbour's
            marker (docs/performance.md, Tracker).
        max_gap_us: the process noise of a prediction over a longer pause in a blob's events is
            that of this pause (us; 0 = no bound). A marker that moves makes events: a pause says
            it did not move, so its uncertainty must not keep growing. Without the bound, the
            first events after a long pause of a held marker (its tremor, a squeezed
            neighbour's edge) meet a large covariance and throw the blob px away.
    """

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    sigma_px: float = 1.0
    assoc_px: float = 4.0
    q_pos: float = 3e-4
    q_vel: float = 1e-4
    q_offset: float = 3e-2
    p0_pos: float = 0.1
    p0_vel: float = 1e-2
    p0_offset: float = 0.5
    velocity_tau_us: float = 10_000.0
    max_step_px: float = 0.25
    rate_tau_us: float = 1_000.0
    min_rate_count: float = 2.0
    frame_gate_px: float = 1.5
    frame_sigma_px: float = 0.1
    frame_motion_us: float = 4_000.0
    merge_px: float = 2.0
    gel_margin_px: float = 4.0
    max_offset_px: float = 1.5
    max_gap_us: float = 10_000.0


# Indices into the float parameter vector handed to the numba kernel.
(
    _P_SIGMA2,
    _P_QPOS,
    _P_QVEL,
    _P_QOFF,
    _P_TAUV,
    _P_TAUR,
    _P_MINRATE,
    _P_MERGE2,
    _P_CX,
    _P_CY,
    _P_R2,
    _P_ASSOC2,
    _P_MAXSTEP,
    _P_MAXOFF2,
    _P_MAXGAP,
) = range(15)
# Columns of the per-blob state: position, velocity (px/ms), polarity offset (px).
_PX, _PY, _VX, _VY, _QX, _QY = range(6)
# Columns of the shared per-axis covariance [p, v, q]: P00 P01 P02 P11 P12 P22.
_C00, _C01, _C02, _C11, _C12, _C22 = range(6)
# Counters: events applied, gated out by the rate gate, noise (no blob owns the pixel).
_N_APPLIED, _N_GATED, _N_NOISE = range(3)


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _release(i, pol, cx, cy, offs, n, keep_x, keep_y, cell, label, neigh, valid, state, assoc2):
    """Hand the pixels (cx, cy) + offs[:n] that blob ``i`` owns for polarity ``pol``, except those
    within the association threshold of (keep_x, keep_y), to the valid neighbour whose expected
    event position (p +- q) is nearest and within the association threshold (else to no one)."""
    h, w = label.shape[1], label.shape[2]
    s = 1.0 if pol == 1 else -1.0
    for k in range(n):
        x = cx + offs[k, 0]
        y = cy + offs[k, 1]
        if x < 0 or y < 0 or x >= w or y >= h or label[pol, y, x] != i:
            continue
        kx = x - keep_x
        ky = y - keep_y
        if kx * kx + ky * ky <= assoc2:
            continue
        best = -1
        best_d = 1e30
        for m in range(neigh.shape[1]):
            j = neigh[i, m]
            if j < 0 or not valid[j]:
                continue
            ddx = x - cell[j, pol, 0]
            ddy = y - cell[j, pol, 1]
            if ddx * ddx + ddy * ddy > assoc2:
                continue
            fx = x - (state[j, _PX] + s * state[j, _QX])
            fy = y - (state[j, _PY] + s * state[j, _QY])
            d = fx * fx + fy * fy
            if d < best_d:
                best_d = d
                best = j
        label[pol, y, x] = best


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _claim(i, pol, cx, cy, offs, n, label, state):
    """Give blob ``i`` the pixels (cx, cy) + offs[:n] of polarity ``pol`` that no blob owns or
    whose owner's expected event position (p +- q) is farther than its own."""
    h, w = label.shape[1], label.shape[2]
    s = 1.0 if pol == 1 else -1.0
    px = state[i, _PX] + s * state[i, _QX]
    py = state[i, _PY] + s * state[i, _QY]
    for k in range(n):
        x = cx + offs[k, 0]
        y = cy + offs[k, 1]
        if x < 0 or y < 0 or x >= w or y >= h:
            continue
        o = label[pol, y, x]
        if o >= 0 and o != i:
            fx = x - px
            fy = y - py
            gx = x - (state[o, _PX] + s * state[o, _QX])
            gy = y - (state[o, _PY] + s * state[o, _QY])
            if fx * fx + fy * fy >= gx * gx + gy * gy:
                continue
        label[pol, y, x] = i


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _repaint(i, cell, label, offs, n_offs, neigh, valid, state, assoc2):
    """Move blob ``i``'s ownership (both polarities) to its current expected event positions p +- q
    once one is more than 1 px (in x or y) from the pixel it was painted around (hysteresis:
    no repainting back and forth across a pixel border). A one-pixel move releases only the
    pixels that leave the disc (the precomputed rings of :func:`_disc_shapes`); the whole new
    disc is claimed (a blob that came nearer takes pixels from its neighbour)."""
    for pol in range(2):
        s = 1.0 if pol == 1 else -1.0
        ex = state[i, _PX] + s * state[i, _QX]
        ey = state[i, _PY] + s * state[i, _QY]
        ox = cell[i, pol, 0]
        oy = cell[i, pol, 1]
        if abs(ex - ox) > _HYSTERESIS_PX or abs(ey - oy) > _HYSTERESIS_PX:
            nx = int(math.floor(ex + 0.5))
            ny = int(math.floor(ey + 0.5))
            sx = nx - ox
            sy = ny - oy
            cell[i, pol, 0] = nx
            cell[i, pol, 1] = ny
            if -1 <= sx <= 1 and -1 <= sy <= 1:
                r = (sx + 1) * 3 + (sy + 1)
                _release(
                    i, pol, ox, oy, offs[1 + r], n_offs[1 + r], _FAR, _FAR, cell, label, neigh, valid, state, assoc2
                )
            else:
                _release(i, pol, ox, oy, offs[0], n_offs[0], nx, ny, cell, label, neigh, valid, state, assoc2)
            _claim(i, pol, nx, ny, offs[0], n_offs[0], label, state)


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _lose(i, cell, label, offs, n_offs, neigh, valid, state, assoc2):
    """Mark blob ``i`` lost and hand its pixels to its neighbours."""
    valid[i] = False
    for pol in range(2):
        _release(
            i,
            pol,
            cell[i, pol, 0],
            cell[i, pol, 1],
            offs[0],
            n_offs[0],
            _FAR,
            _FAR,
            cell,
            label,
            neigh,
            valid,
            state,
            assoc2,
        )


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _paint_all(state, valid, cell, label, offs, n_offs):
    """Reset the label images and let every valid blob claim its discs (nearest blob wins)."""
    label[:, :, :] = -1
    for i in range(state.shape[0]):
        for pol in range(2):
            s = 1.0 if pol == 1 else -1.0
            cell[i, pol, 0] = int(math.floor(state[i, _PX] + s * state[i, _QX] + 0.5))
            cell[i, pol, 1] = int(math.floor(state[i, _PY] + s * state[i, _QY] + 0.5))
            if valid[i]:
                _claim(i, pol, cell[i, pol, 0], cell[i, pol, 1], offs[0], n_offs[0], label, state)


@numba.njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _predict(state, cov, i, dt, inv_tau_v, max_step2, q_pos, q_vel, q_off, max_gap):
    """Predict blob ``i`` over ``dt`` ms with the damped constant-velocity model (state and
    covariance in place)."""
    d = 1.0 / (1.0 + dt * inv_tau_v)
    a = dt * d
    # A moving marker makes tens of events per pixel it moves: between two of its events it
    # moves a fraction of a pixel, however long the gap (a long gap means it stopped).
    speed2 = state[i, _VX] * state[i, _VX] + state[i, _VY] * state[i, _VY]
    if a * a * speed2 > max_step2:
        a = math.sqrt(max_step2 / speed2)
    state[i, _PX] += a * state[i, _VX]
    state[i, _PY] += a * state[i, _VY]
    state[i, _VX] *= d
    state[i, _VY] *= d
    c01 = cov[i, _C01]
    c11 = cov[i, _C11]
    c12 = cov[i, _C12]
    dn = min(dt, max_gap)
    cov[i, _C00] += 2.0 * a * c01 + a * a * c11 + q_pos * dn
    cov[i, _C01] = d * (c01 + a * c11)
    cov[i, _C02] += a * c12
    cov[i, _C11] = d * d * c11 + q_vel * dn
    cov[i, _C12] = d * c12
    cov[i, _C22] += q_off * dn


@numba.njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _gain(state, i, k0, k1, k2, rx, ry):
    """Kalman state update of blob ``i`` with gains (k0, k1, k2) on [p, v, q] and innovation (rx, ry)."""
    state[i, _PX] += k0 * rx
    state[i, _PY] += k0 * ry
    state[i, _VX] += k1 * rx
    state[i, _VY] += k1 * ry
    state[i, _QX] += k2 * rx
    state[i, _QY] += k2 * ry


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _track(ts, xs, ys, ps, state, cov, t_upd, t_seen, rate, valid, cell, label, offs, n_offs, neigh, prm, counts):
    """The event loop: per-pixel association, rate gate, linear Kalman predict + update, repaint."""
    sigma2 = prm[_P_SIGMA2]
    q_pos = prm[_P_QPOS]
    q_vel = prm[_P_QVEL]
    q_off = prm[_P_QOFF]
    inv_tau_v = 1.0 / prm[_P_TAUV]
    inv_tau_r = 1.0 / prm[_P_TAUR]
    min_rate = prm[_P_MINRATE]
    assoc2 = prm[_P_ASSOC2]
    max_step2 = prm[_P_MAXSTEP] ** 2
    max_off2 = prm[_P_MAXOFF2]
    max_gap = prm[_P_MAXGAP]
    h, w = label.shape[1], label.shape[2]
    for k in range(ts.shape[0]):
        x = np.int64(xs[k])
        y = np.int64(ys[k])
        if x < 0 or y < 0 or x >= w or y >= h:
            counts[_N_NOISE] += 1
            continue
        pol = 1 if ps[k] > 0 else 0
        i = label[pol, y, x]
        if i < 0:
            counts[_N_NOISE] += 1
            continue
        t = ts[k]
        # Per-blob event-rate gate: leaky count of the events this blob owned.
        if t_seen[i] >= 0:
            dts = max(t - t_seen[i], 0) * 1.0
            rate[i] = rate[i] / (1.0 + dts * inv_tau_r) + 1.0
        else:
            rate[i] = 1.0
        t_seen[i] = t
        if rate[i] < min_rate:
            counts[_N_GATED] += 1
            continue
        counts[_N_APPLIED] += 1
        dt = 0.0
        if t_upd[i] >= 0:
            dt = max(t - t_upd[i], 0) * 1e-3
        t_upd[i] = t
        _predict(state, cov, i, dt, inv_tau_v, max_step2, q_pos, q_vel, q_off, max_gap)
        c00 = cov[i, _C00]
        c01 = cov[i, _C01]
        c02 = cov[i, _C02]
        c11 = cov[i, _C11]
        c12 = cov[i, _C12]
        c22 = cov[i, _C22]
        # Update with the event: z = p + s*q, s = +1 for ON, -1 for OFF.
        s = 1.0 if pol == 1 else -1.0
        h0 = c00 + s * c02
        h1 = c01 + s * c12
        h2 = c02 + s * c22
        inv_s = 1.0 / (h0 + s * h2 + sigma2)
        k0 = h0 * inv_s
        k1 = h1 * inv_s
        k2 = h2 * inv_s
        _gain(state, i, k0, k1, k2, x - (state[i, _PX] + s * state[i, _QX]), y - (state[i, _PY] + s * state[i, _QY]))
        cov[i, _C00] = c00 - k0 * h0
        cov[i, _C01] = c01 - k0 * h1
        cov[i, _C02] = c02 - k0 * h2
        cov[i, _C11] = c11 - k1 * h1
        cov[i, _C12] = c12 - k1 * h2
        cov[i, _C22] = c22 - k2 * h2
        qx = state[i, _QX]
        qy = state[i, _QY]
        q2 = qx * qx + qy * qy
        if q2 > max_off2:
            f = math.sqrt(max_off2 / q2)
            state[i, _QX] = qx * f
            state[i, _QY] = qy * f
        # Repaint only when needed (checked inline: a call passing the arrays costs more than the
        # whole Kalman update).
        px = state[i, _PX]
        py = state[i, _PY]
        qx = state[i, _QX]
        qy = state[i, _QY]
        if (
            abs(px + qx - cell[i, 1, 0]) > _HYSTERESIS_PX
            or abs(py + qy - cell[i, 1, 1]) > _HYSTERESIS_PX
            or abs(px - qx - cell[i, 0, 0]) > _HYSTERESIS_PX
            or abs(py - qy - cell[i, 0, 1]) > _HYSTERESIS_PX
        ):
            _repaint(i, cell, label, offs, n_offs, neigh, valid, state, assoc2)


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _check_lost(cell, label, offs, n_offs, neigh, valid, state, prm):
    """Lose every valid blob that left the gel circle, and both blobs of every pair of valid
    neighbours closer than the merge distance (they now follow the same marker)."""
    gcx = prm[_P_CX]
    gcy = prm[_P_CY]
    gr2 = prm[_P_R2]
    merge2 = prm[_P_MERGE2]
    assoc2 = prm[_P_ASSOC2]
    for i in range(state.shape[0]):
        if not valid[i]:
            continue
        gx = state[i, _PX] - gcx
        gy = state[i, _PY] - gcy
        lost = gx * gx + gy * gy > gr2
        for m in range(neigh.shape[1]):
            j = neigh[i, m]
            if j < 0 or not valid[j]:
                continue
            fx = state[i, _PX] - state[j, _PX]
            fy = state[i, _PY] - state[j, _PY]
            if fx * fx + fy * fy < merge2:
                _lose(j, cell, label, offs, n_offs, neigh, valid, state, assoc2)
                lost = True
        if lost:
            _lose(i, cell, label, offs, n_offs, neigh, valid, state, assoc2)


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _frame_matches(state: np.ndarray, valid: np.ndarray, det: np.ndarray, gate2: float) -> np.ndarray:
    """(N,) int64: the APS-frame detection (row of det, (M, 2) float64 px) each blob is fused
    with in :meth:`BlobTracker.correct`, or -1. Blob i (a valid row of state, position in columns
    0-1, px) matches its nearest detection j when their squared distance is <= gate2 (px^2), i is
    j's nearest valid blob too, and j has no second valid blob within twice the gate (two
    markers squeezed together under a finger seen as one). Ties go to the lower index.

    Only the pairs less than twice the gate apart in x are measured (the detections sorted by
    x, a binary search per blob): every distance the rule compares with the gate or its double
    is among them, so the matches are those of all N x M pairs at a tenth of the cost."""
    n = state.shape[0]
    m = det.shape[0]
    first = np.full(m, -1, np.int64)  # each detection's nearest valid blob
    best = np.full(m, np.inf)
    second = np.full(m, np.inf)  # and the squared distance of its second nearest
    nearest = np.full(n, -1, np.int64)  # each valid blob's nearest detection
    near_d2 = np.full(n, np.inf)
    order = np.argsort(det[:, 0])
    xs = det[order, 0]
    reach = 2.0 * math.sqrt(gate2) * (1.0 + 1e-9) + 1e-9  # twice the gate, rounded outwards
    for i in range(n):  # blobs in index order: each detection's ties go to the lower blob
        if not valid[i]:
            continue
        x = state[i, 0]
        y = state[i, 1]
        for k in range(np.searchsorted(xs, x - reach), np.searchsorted(xs, x + reach, side="right")):
            j = order[k]
            dx = x - det[j, 0]
            dy = y - det[j, 1]
            d2 = dx * dx + dy * dy
            if d2 < near_d2[i] or (d2 == near_d2[i] and j < nearest[i]):
                near_d2[i] = d2
                nearest[i] = j
            if d2 < best[j]:
                second[j] = best[j]
                best[j] = d2
                first[j] = i
            elif d2 < second[j]:
                second[j] = d2
    match = np.full(n, -1, np.int64)
    for i in range(n):
        j = nearest[i]
        if j >= 0 and near_d2[i] <= gate2 and first[j] == i and second[j] > 4.0 * gate2:
            match[i] = j
    return match


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _correct(det, match, t, state, cov, t_upd, valid, cell, label, offs, n_offs, neigh, prm, sigma2_frame, motion_ms):
    """Fuse APS-frame detections into the blobs: predict each matched blob to the frame's time t
    (us; none when t < 0), then a Kalman update of its position (H = [1, 0, 0]) with noise
    sigma2_frame + (speed * motion_ms)^2 (a moving marker is blurred on the frame)."""
    for i in range(state.shape[0]):
        m = match[i]
        if m < 0 or not valid[i]:
            continue
        if t >= 0 and t_upd[i] >= 0:
            _predict(
                state,
                cov,
                i,
                max(t - t_upd[i], 0) * 1e-3,
                1.0 / prm[_P_TAUV],
                prm[_P_MAXSTEP] ** 2,
                prm[_P_QPOS],
                prm[_P_QVEL],
                prm[_P_QOFF],
                prm[_P_MAXGAP],
            )
            t_upd[i] = t
        vx = state[i, _VX]
        vy = state[i, _VY]
        r = sigma2_frame + (vx * vx + vy * vy) * motion_ms * motion_ms
        c00 = cov[i, _C00]
        c01 = cov[i, _C01]
        c02 = cov[i, _C02]
        inv_s = 1.0 / (c00 + r)
        k0 = c00 * inv_s
        k1 = c01 * inv_s
        k2 = c02 * inv_s
        _gain(state, i, k0, k1, k2, det[m, 0] - state[i, _PX], det[m, 1] - state[i, _PY])
        cov[i, _C11] -= k1 * c01
        cov[i, _C12] -= k1 * c02
        cov[i, _C22] -= k2 * c02
        cov[i, _C00] = c00 - k0 * c00
        cov[i, _C01] = c01 - k0 * c01
        cov[i, _C02] = c02 - k0 * c02
        _repaint(i, cell, label, offs, n_offs, neigh, valid, state, prm[_P_ASSOC2])
    _check_lost(cell, label, offs, n_offs, neigh, valid, state, prm)


def _disc_shapes(radius_px: float) -> tuple[np.ndarray, np.ndarray]:
    """Pixel offsets of a blob's ownership disc and of the rings a one-pixel move leaves.

    Returns ``offs`` (10, K, 2) int64 and ``n_offs`` (10,) int64: row 0 is the disc (the K pixel
    offsets within ``radius_px`` of a pixel centre); for a move by (sx, sy) in {-1, 0, 1}^2,
    row 1 + (sx + 1) * 3 + (sy + 1) lists the disc pixels that leave it (offsets from the old
    centre).
    """
    r = int(math.ceil(radius_px))
    dy, dx = np.mgrid[-r : r + 1, -r : r + 1]
    inside = dx * dx + dy * dy <= radius_px * radius_px
    disc = np.stack([dx[inside], dy[inside]], axis=1).astype(np.int64)
    members = {tuple(d) for d in disc.tolist()}
    offs = np.zeros((10, len(disc), 2), dtype=np.int64)
    n_offs = np.zeros(10, dtype=np.int64)
    offs[0], n_offs[0] = disc, len(disc)
    for sx in (-1, 0, 1):
        for sy in (-1, 0, 1):
            k = (sx + 1) * 3 + (sy + 1)
            leave = [d for d in disc.tolist() if (d[0] - sx, d[1] - sy) not in members]
            n_offs[1 + k] = len(leave)
            if leave:
                offs[1 + k, : len(leave)] = leave
    return offs, n_offs


def _neighbours(positions: np.ndarray, k: int) -> np.ndarray:
    """(N, k) int64 indices of each point's k nearest other points (-1 pads when N - 1 < k)."""
    n = len(positions)
    out = np.full((n, k), -1, dtype=np.int64)
    if n < 2:
        return out
    d = np.hypot(positions[:, None, 0] - positions[None, :, 0], positions[:, None, 1] - positions[None, :, 1])
    np.fill_diagonal(d, np.inf)
    m = min(k, n - 1)
    out[:, :m] = np.argsort(d, axis=1)[:, :m]
    return out


class BlobTracker:
    """Asynchronous event-blob tracker of the gel's markers (paper, section Marker Tracking).

    Args:
        initial_px: (N, 2) float, initial marker positions (x, y), image frame, px (from
            :func:`neurotouch_hid.pipeline.markers.detect_markers` on an APS frame at rest).
        width, height: image size (px).
        config: :class:`TrackerConfig` (defaults if None).
        sensor: when given, a blob farther than the gel radius + ``config.gel_margin_px`` from the
            gel centre is lost; without it, only a blob beyond the image's circumscribed circle is
            (a blob outside the image owns no pixel and gets no events).

    Attributes:
        positions_px: (N, 2) float64 current positions, image frame, px (a copy).
        valid: (N,) bool, False for a lost marker (a copy).
        velocities_px_per_s: (N, 2) float64 current velocity estimates, px/s (a copy).
        counts: dict of event counters since construction: applied, gated (rate gate), noise.
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
        c = self.config
        if not 0 < c.assoc_px:
            raise ValueError(f"TrackerConfig.assoc_px must be positive, got {c.assoc_px}")
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
        self._counts = np.zeros(3, dtype=np.int64)
        self._reset_px: np.ndarray | None = None
        self.reset(initial_px)

    def reset(self, positions_px: np.ndarray) -> None:
        """Re-initialise every blob at ``positions_px`` (N, 2) float px, image frame, at rest
        (paper, section Resting Position Detection): zero velocity and offset, initial covariance,
        ownership repainted. N may differ from the previous N. Blobs outside the gel (or image)
        start lost. Raises ValueError when ``positions_px`` is not (N, 2) finite."""
        p = np.asarray(positions_px, dtype=np.float64)
        if p.ndim != 2 or p.shape[1] != 2 or not np.all(np.isfinite(p)):
            raise ValueError(f"positions_px must be a finite (N, 2) array, got shape {p.shape}")
        n = len(p)
        c = self.config
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

    def correct(self, detections_px: np.ndarray, t_us: int | None = None) -> int:
        """Fuse marker detections of an APS frame into the blobs (optional; not in the paper).

        Between events a blob's position is a running average of its recent events, which lags
        a little behind a marker that has just stopped, and a held gesture makes no more events
        to correct it. The APS frame shows the markers where they are: each valid blob whose
        nearest detection is within ``config.frame_gate_px``, is nearest to no other blob and has
        no other blob within twice that distance (two squeezed markers seen as one), gets a Kalman
        position update from it, with noise ``config.frame_sigma_px``^2 plus the blur of its
        motion over ``config.frame_motion_us``. Call it with the frame's marker centroids when
        the frame arrives (the stream yields it before the events at or after its timestamp):
        :func:`~neurotouch_hid.pipeline.markers.detect_markers`'s, or the resting detector's
        (``RestingResult.centroids_px``, what the pipeline's ``frame_correction`` passes).

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
        match = _frame_matches(self._state, self._valid, det, self.config.frame_gate_px**2)
        c = self.config
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

    def update(self, events: np.ndarray) -> None:
        """Track through a batch of events, event by event (numba).

        Args:
            events: structured array of :data:`neurotouch_hid.sources.EVENT_DTYPE`, time-ordered
                (timestamp int64 us, x/y int16 px image frame, polarity 1 = ON, 0 = OFF).
        Raises:
            ValueError: ``events`` lacks the EVENT_DTYPE fields.
        """
        if events.dtype != EVENT_DTYPE and (
            events.dtype.names is None or not set(EVENT_DTYPE.names) <= set(events.dtype.names)
        ):  # (the sets only for another dtype: ~1.5 us a batch)
            raise ValueError(f"events must have the EVENT_DTYPE fields {EVENT_DTYPE.names}, got {events.dtype}")
        if len(events) == 0 or len(self._state) == 0:
            return
        _track(
            events["timestamp"],
            events["x"],
            events["y"],
            events["polarity"],
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
        _check_lost(
            self._cell, self._label, self._offs, self._n_offs, self._neigh, self._valid, self._state, self._params
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
