"""The event-blob tracker's numba kernels (``tracker.py``; paper, section "Marker Tracking";
docs/method.md, "Tracker"): the label images of which blob owns which pixel, the per-event
filter update, the lost-blob checks and the fusion of an APS frame's markers. Units: px, us
(velocities px/ms).
"""

from __future__ import annotations

import math

import numba
import numpy as np

#: A blob's ownership is repainted when its expected event position is this far (px, in x or y)
#: from the pixel it was painted around.
_HYSTERESIS_PX = 1.0
#: A pixel coordinate far outside any image (releasing every pixel of a lost blob); an int64, as
#: the positions it stands for (a plain int would be a literal to numba: a second compile).
_FAR = np.int64(1 << 30)
#: Number of neighbours per blob remembered for ownership hand-over and merge detection.
_N_NEIGHBOURS = 12


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
# Counters: events applied, gated out by the rate gate, noise (no blob owns the pixel); and the
# event loop's repaints (a label image changed: ``BlobTracker.reset`` at the same rest).
_N_APPLIED, _N_GATED, _N_NOISE, _N_REPAINTS = range(4)


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
def _track(events, state, cov, t_upd, t_seen, rate, valid, cell, label, offs, n_offs, neigh, prm, counts):
    """The event loop: per-pixel association, rate gate, linear Kalman predict + update, repaint.
    ``events`` is the batch itself (EVENT_DTYPE, C-contiguous), not its fields: one compiled
    version for batches of one event and of many alike."""
    ts = events["timestamp"]
    xs = events["x"]
    ys = events["y"]
    ps = events["polarity"]
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
        i = np.int64(label[pol, y, x])  # one type of index for the kernels it calls (one compile each)
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
            counts[_N_REPAINTS] += 1
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


#: The tracker's event update, for a compiled caller that holds the tracker's arrays
#: (``BlobTracker.kernel_state``; ``rest_window.py``): ``track_events(events, *kernel_state)``
#: tracks one batch (``events`` (E,) EVENT_DTYPE), then ``check_lost(cell, label, offs, n_offs,
#: neigh, valid, state, params)`` loses the blobs that left the gel or merged, as
#: ``BlobTracker.update`` runs them. The same compiled kernels under their public names (the
#: warmup's :func:`~neurotouch_hid.warmup.interpret` swaps every name bound to them).
track_events = _track
check_lost = _check_lost


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _reset_if_painted(p, rest, rest_valid, repaints, counts, state, cov, t_upd, t_seen, rate, valid, p0):
    """Re-initialise every blob at ``p`` (N, 2) float64 px as ``BlobTracker.reset`` does, in
    place, when its label images and cells are still those painted at that reset: ``p`` equals
    ``rest`` (the positions of that reset), no blob was lost since (``valid`` equals
    ``rest_valid``, the reset's) and the event loop repainted none (``counts[_N_REPAINTS]`` is
    still ``repaints``). The state's other arrays get the reset's values: zero velocity and
    offset, the initial covariance ``p0`` = (position, velocity, offset) px^2, no event seen.
    Returns whether it did (False: nothing changed, the caller repaints)."""
    if counts[_N_REPAINTS] != repaints or p.shape != rest.shape:
        return False
    for i in range(len(rest)):
        if valid[i] != rest_valid[i] or p[i, 0] != rest[i, 0] or p[i, 1] != rest[i, 1]:
            return False
    for i in range(len(rest)):
        for k in range(6):
            state[i, k] = 0.0
            cov[i, k] = 0.0
        state[i, _PX] = p[i, 0]
        state[i, _PY] = p[i, 1]
        cov[i, _C00] = p0[0]
        cov[i, _C11] = p0[1]
        cov[i, _C22] = p0[2]
        t_upd[i] = -1
        t_seen[i] = -1
        rate[i] = 0.0
    return True


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _frame_matches(state: np.ndarray, valid: np.ndarray, det: np.ndarray, gate2: float) -> np.ndarray:
    """(N,) int64: the APS-frame detection (row of det, (M, 2) float64 px) each blob is fused
    with in :meth:`BlobTracker.correct`, or -1. Blob i (a valid row of state, position in columns
    0-1, px) matches its nearest detection j when their squared distance is <= gate2 (px^2), i is
    j's nearest valid blob too, and j has no second valid blob within twice the gate (two
    markers squeezed together under a finger seen as one). Ties go to the lower index.

    Only the pairs less than twice the gate apart are measured: the detections are put in square
    cells at least twice the gate wide (a counting sort, no comparison sort: numba compiles this
    kernel on a first run in a fraction of a second), and each blob looks in its cell and the 8
    around it.
    Every distance the rule compares with the gate or its double is among them, so the matches
    are those of all N x M pairs at a tenth of the cost."""
    n = state.shape[0]
    m = det.shape[0]
    first = np.full(m, -1, np.int64)  # each detection's nearest valid blob
    best = np.full(m, np.inf)
    second = np.full(m, np.inf)  # and the squared distance of its second nearest
    nearest = np.full(n, -1, np.int64)  # each valid blob's nearest detection
    near_d2 = np.full(n, np.inf)
    match = np.full(n, -1, np.int64)
    if m == 0:
        return match
    reach = 2.0 * math.sqrt(gate2) * (1.0 + 1e-9) + 1e-9  # twice the gate, rounded outwards
    x0 = x1 = det[0, 0]
    y0 = y1 = det[0, 1]
    for j in range(1, m):
        x0, x1 = min(x0, det[j, 0]), max(x1, det[j, 0])
        y0, y1 = min(y0, det[j, 1]), max(y1, det[j, 1])
    width = x1 - x0
    height = y1 - y0
    reach = max(reach, math.sqrt(width * height / (4.0 * m)))  # a small gate: about 4 detections a cell
    cols = int(width / reach) + 1
    rows = int(height / reach) + 1
    start = np.zeros(cols * rows + 1, np.int64)  # detections of cell c: members[start[c]:start[c + 1]]
    home = np.empty(m, np.int64)
    for j in range(m):
        home[j] = int((det[j, 1] - y0) / reach) * cols + int((det[j, 0] - x0) / reach)
        start[home[j] + 1] += 1
    for c in range(cols * rows):
        start[c + 1] += start[c]
    fill = start.copy()
    members = np.empty(m, np.int64)
    for j in range(m):
        members[fill[home[j]]] = j
        fill[home[j]] += 1
    for i in range(n):  # blobs in index order: each detection's ties go to the lower blob
        if not valid[i]:
            continue
        x = state[i, 0]
        y = state[i, 1]
        if not (math.isfinite(x) and math.isfinite(y)):
            continue  # nearest to nothing, as every comparison with NaN is false
        cx = math.floor((x - x0) / reach)
        cy = math.floor((y - y0) / reach)
        for r in range(max(cy - 1, 0), min(cy + 1, rows - 1) + 1):
            for c in range(max(cx - 1, 0), min(cx + 1, cols - 1) + 1):
                cell = int(r) * cols + int(c)
                for k in range(start[cell], start[cell + 1]):
                    j = members[k]
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
