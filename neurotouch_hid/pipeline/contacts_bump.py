"""Contact points on long-tailed fields: the fit of radial bumps (not in the paper;
docs/method.md, "Contacts").

Where the fingers' fields have long tails they overlap, and the largest displacement lies one to
two marker pitches outside each finger. :func:`bump_fit` explains the whole field as a sum of
radial bumps, one per contact, with a profile measured on the window's own field, and moves the
centres to the least-squares optimum. A finger whose markers are no maximum (weaker than the
gel between stronger fingers) stays in what the bumps leave: :func:`with_missed_finger` fits one
more bump there. Image frame (px).
"""

from __future__ import annotations

import math

import numba
import numpy as np


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _solve(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, bool]:
    """x of ``a x = b`` for a small square ``a`` (n, n) and ``b`` (n, m), float64, by Gaussian
    elimination with partial pivoting (numba's ``np.linalg`` needs SciPy's LAPACK, which the
    runtime does not install). Returns (x (n, m), False) when ``a`` is singular to working
    precision (a pivot below 1e-12 x its largest entry, or not finite)."""
    n = a.shape[0]
    a = a.copy()
    x = b.copy()
    scale = 0.0
    for i in range(n):
        for j in range(n):
            scale = max(scale, abs(a[i, j]))
    if not scale > 0.0 or not np.isfinite(scale):
        return x, False
    for col in range(n):
        pivot = col
        for row in range(col + 1, n):
            if abs(a[row, col]) > abs(a[pivot, col]):
                pivot = row
        if not abs(a[pivot, col]) > 1e-12 * scale:
            return x, False
        if pivot != col:
            for j in range(n):
                a[col, j], a[pivot, j] = a[pivot, j], a[col, j]
            for j in range(x.shape[1]):
                x[col, j], x[pivot, j] = x[pivot, j], x[col, j]
        for row in range(col + 1, n):
            f = a[row, col] / a[col, col]
            if f != 0.0:
                for j in range(col, n):
                    a[row, j] -= f * a[col, j]
                for j in range(x.shape[1]):
                    x[row, j] -= f * x[col, j]
    for col in range(n - 1, -1, -1):
        for j in range(x.shape[1]):
            acc = x[col, j]
            for k in range(col + 1, n):
                acc -= a[col, k] * x[k, j]
            x[col, j] = acc / a[col, col]
    return x, True


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _hat(r: float, knot: float, n_knots: int) -> tuple[int, float]:
    """The piecewise-linear profile's segment of a distance ``r`` (px): knot index j and the
    fraction f in [0, 1) towards knot j + 1, knots at 0, knot, ..., (n_knots - 1) knot; beyond the
    last knot, the last segment's end (the profile stays at its last value)."""
    t = r / knot
    top = n_knots - 1.0
    if t >= top:
        return n_knots - 2, 1.0
    j = int(t)
    return j, t - j


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _displacements(a: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, bool]:
    """The fingers' displacements u (K, 2) px that best explain the field ``v`` (M, 2) px as
    ``a`` u, ``a`` (M, K) each bump's profile at each marker: least squares by the normal
    equations a^T a u = a^T v with a ridge of 1e-9 of their diagonal, written out (numba's @
    needs SciPy's BLAS). False when they are singular (:func:`_solve`)."""
    k_n = a.shape[1]
    normal = np.zeros((k_n, k_n))
    rhs = np.zeros((k_n, 2))
    for i in range(len(a)):
        for k in range(k_n):
            rhs[k, 0] += a[i, k] * v[i, 0]
            rhs[k, 1] += a[i, k] * v[i, 1]
            for q in range(k_n):
                normal[k, q] += a[i, k] * a[i, q]
    for k in range(k_n):
        normal[k, k] += 1e-9 * (normal[k, k] + 1e-12)
    return _solve(normal, rhs)


#: Rounds of the bump fit (:func:`bump_fit`): its centres move by at most half a knot per round.
#: 3: on the development families' windows, 2-8 rounds are within 0.1 mm of each other on every
#: family, 3 within 0.04 mm of the best; each round costs ~15 us (K = 2, 177 markers, hot).
BUMP_ITERATIONS = 3


@numba.njit(cache=True, nogil=True, error_model="numpy")
def bump_fit(
    rest: np.ndarray, v: np.ndarray, centres: np.ndarray, knot: float, n_knots: int, rounds: int = BUMP_ITERATIONS
) -> np.ndarray:
    """Centres of the fingers' radial bumps that best explain a displacement field (see the
    module docstring, "Long tails"); :func:`_bump_model`'s centres."""
    return _bump_model(rest, v, centres, knot, n_knots, rounds)[0]


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _bump_model(
    rest: np.ndarray, v: np.ndarray, centres: np.ndarray, knot: float, n_knots: int, rounds: int
) -> tuple[np.ndarray, np.ndarray, bool]:
    """Centres of the fingers' radial bumps that best explain a displacement field, and their
    profile.

    Model: v(x) = sum_k g(||x - c_k||) u_k, one radial profile g shared by the K fingers (g(0) = 1,
    piecewise linear with ``n_knots`` knots ``knot`` px apart, constant beyond the last), each
    finger's displacement u_k (2,) and centre c_k (2,). Least squares over the M markers, by
    ``rounds`` rounds of: u given g and c (K x K normal equations), g given u and c (n_knots x
    n_knots, with a curvature penalty and ridge of 1e-6 of its mean diagonal), one Gauss-Newton
    step of c given g and u (2K x 2K; each centre moves by at most knot / 2 a round). No
    profile is assumed: g starts as a Gaussian over the knots' span and is measured on the
    window's field. The systems are solved by :func:`_solve` (no LAPACK at run time).

    Args:
        rest: (M, 2) float64, the markers' rest positions (px, image frame).
        v: (M, 2) float64, their displacements (px).
        centres: (K, 2) float64, K >= 1, initial centres at rest (px), e.g. the maxima's markers.
        knot: the profile's knot spacing (px), > 0.
        n_knots: its number of knots, >= 2.
        rounds: the number of rounds (:data:`BUMP_ITERATIONS`).
    Returns:
        (centres, g, ok): (K, 2) float64, the fitted centres at rest (px); a centre whose fit is
        not finite or moved further than 2 knots is its initial one; all are, and ok is False,
        when the u or g system is singular or the profile's g(0) vanishes (e.g. no
        displacement), and a singular Gauss-Newton system ends the rounds where they are. g:
        (n_knots,) float64, the profile of the last round (g(0) = 1).
    """
    m = len(rest)
    k_n = len(centres)
    c = centres.copy()
    g = np.empty(n_knots)
    for q in range(n_knots):  # start: a Gaussian of the knot span's width
        t = q / (n_knots - 1.0)
        g[q] = math.exp(-4.5 * t * t)
    seg = np.empty((m, k_n), dtype=np.int64)
    frac = np.empty((m, k_n))
    dist = np.empty((m, k_n))
    a = np.empty((m, k_n))
    uu = np.empty((k_n, k_n))
    geo = np.empty(2 * k_n)
    end = (n_knots - 1) * knot
    for _ in range(rounds):
        for i in range(m):
            for k in range(k_n):
                r = math.sqrt((rest[i, 0] - c[k, 0]) ** 2 + (rest[i, 1] - c[k, 1]) ** 2)
                dist[i, k] = r
                seg[i, k], frac[i, k] = _hat(r, knot, n_knots)
        # the fingers' displacements u given g and c
        for i in range(m):
            for k in range(k_n):
                j, f = seg[i, k], frac[i, k]
                a[i, k] = g[j] * (1.0 - f) + g[j + 1] * f
        u, ok = _displacements(a, v)
        if not ok:
            return centres.copy(), g, False
        # the profile g given u and c: rows (i, d) = sum_k b_k u_kd, b_k the hat basis at r_ik
        # (2 nonzero knots), so the normal matrix gains sum_kl (u_k . u_l) b_k b_l^T per marker
        normal = np.zeros((n_knots, n_knots))
        rhs = np.zeros((n_knots, 1))
        for k in range(k_n):
            for q in range(k_n):
                uu[k, q] = u[k, 0] * u[q, 0] + u[k, 1] * u[q, 1]
        for i in range(m):
            for k in range(k_n):
                j, f = seg[i, k], frac[i, k]
                uv = u[k, 0] * v[i, 0] + u[k, 1] * v[i, 1]
                rhs[j, 0] += (1.0 - f) * uv
                rhs[j + 1, 0] += f * uv
                for q in range(k_n):
                    jq, fq = seg[i, q], frac[i, q]
                    w = uu[k, q]
                    normal[j, jq] += w * (1.0 - f) * (1.0 - fq)
                    normal[j, jq + 1] += w * (1.0 - f) * fq
                    normal[j + 1, jq] += w * f * (1.0 - fq)
                    normal[j + 1, jq + 1] += w * f * fq
        # a faint curvature penalty and ridge (1e-6 of the mean diagonal): a knot no marker's
        # distance reaches follows its neighbours, and when the fingers' displacements cancel
        # (sum_k u_k = 0, a pinch) a constant added to g, which changes no model value, is 0
        level = 0.0
        for p in range(n_knots):
            level += normal[p, p]
        level *= 1e-6 / n_knots
        for p in range(n_knots):
            normal[p, p] += level
        for p in range(1, n_knots - 1):
            for a_, wa in ((p - 1, 1.0), (p, -2.0), (p + 1, 1.0)):
                for b_, wb in ((p - 1, 1.0), (p, -2.0), (p + 1, 1.0)):
                    normal[a_, b_] += level * wa * wb
        sol, ok = _solve(normal, rhs)
        if not ok or not abs(sol[0, 0]) > 1e-9:
            return centres.copy(), g, False
        g0 = sol[0, 0]
        for p in range(n_knots):
            g[p] = sol[p, 0] / g0
        u *= g0
        for k in range(k_n):
            for q in range(k_n):
                uu[k, q] = u[k, 0] * u[q, 0] + u[k, 1] * u[q, 1]
        # one Gauss-Newton step of the centres given g and u
        normal = np.zeros((2 * k_n, 2 * k_n))
        rhs = np.zeros((2 * k_n, 1))
        for i in range(m):
            model_x = 0.0
            model_y = 0.0
            for k in range(k_n):
                j, f, r = seg[i, k], frac[i, k], dist[i, k]
                w = g[j] * (1.0 - f) + g[j + 1] * f
                model_x += w * u[k, 0]
                model_y += w * u[k, 1]
                # d model_d / d c_ke = -g'(r) (x_e - c_ke) / r u_kd: its part without u
                slope = (g[j + 1] - g[j]) / knot / r if end > r > 1e-9 else 0.0
                geo[2 * k] = -slope * (rest[i, 0] - c[k, 0])
                geo[2 * k + 1] = -slope * (rest[i, 1] - c[k, 1])
            # summed over the two components d: J^T J gains geo_ke geo_lf (u_k . u_l), J^T res
            # gains geo_ke (u_k . res_i)
            res_x, res_y = v[i, 0] - model_x, v[i, 1] - model_y
            for p in range(2 * k_n):
                k = p // 2
                rhs[p, 0] += geo[p] * (u[k, 0] * res_x + u[k, 1] * res_y)
                for q in range(p, 2 * k_n):
                    normal[p, q] += geo[p] * geo[q] * uu[k, q // 2]
        for p in range(2 * k_n):
            for q in range(p):
                normal[p, q] = normal[q, p]
            normal[p, p] += 1e-6 * (normal[p, p] + 1e-12)
        step, ok = _solve(normal, rhs)
        if not ok:
            break
        for k in range(k_n):
            sx, sy = step[2 * k, 0], step[2 * k + 1, 0]
            n = math.sqrt(sx * sx + sy * sy)
            shrink = min(1.0, 0.5 * knot / n) if n > 0 else 1.0
            c[k, 0] += sx * shrink
            c[k, 1] += sy * shrink
    for k in range(k_n):
        moved = math.hypot(c[k, 0] - centres[k, 0], c[k, 1] - centres[k, 1])
        if not moved <= 2.0 * knot:  # also NaN
            c[k, 0], c[k, 1] = centres[k, 0], centres[k, 1]
    return c, g, True


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _residual(
    rest: np.ndarray, v: np.ndarray, c: np.ndarray, g: np.ndarray, knot: float, n_knots: int
) -> tuple[np.ndarray, np.ndarray, bool]:
    """What the bumps at ``c`` (K, 2) with the profile ``g`` leave of the field ``v`` (M, 2):
    the fingers' displacements u (K, 2) by least squares, the residual v - sum_k g(||x - c_k||)
    u_k (M, 2) px, and False when the u system is singular."""
    m, k_n = len(rest), len(c)
    a = np.empty((m, k_n))
    for i in range(m):
        for k in range(k_n):
            j, f = _hat(math.sqrt((rest[i, 0] - c[k, 0]) ** 2 + (rest[i, 1] - c[k, 1]) ** 2), knot, n_knots)
            a[i, k] = g[j] * (1.0 - f) + g[j + 1] * f
    u, ok = _displacements(a, v)
    res = v.copy()
    for i in range(m):
        for k in range(k_n):
            res[i, 0] -= a[i, k] * u[k, 0]
            res[i, 1] -= a[i, k] * u[k, 1]
    return u, res, ok


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _fitted(
    rest: np.ndarray, v: np.ndarray, centres: np.ndarray, knot: float, n_knots: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray, bool]:
    """The bumps fitted from ``centres`` (:func:`_bump_model`) and what they leave
    (:func:`_residual`): (centres (K, 2), u (K, 2), residual (M, 2), ok), ok False when either
    fit failed."""
    c, g, ok = _bump_model(rest, v, centres, knot, n_knots, BUMP_ITERATIONS)
    if not ok:
        return c, np.zeros((len(c), 2)), v.copy(), False
    u, res, ok = _residual(rest, v, c, g, knot, n_knots)
    return c, u, res, ok


#: A finger the maxima missed (:func:`with_missed_finger`) is taken when one more bump leaves less
#: than this share of the squared residual the others leave, and its displacement is at least
#: :data:`MISSED_FINGER_SHARE` of the weakest other finger's. On the tuning users' windows of two
#: contacts (8 development families, 2,408 sampled): a missed third finger 0.11-0.38 and
#: 0.67-1.31; two fingers whose new bump is that strong 0.54 and more, and where the share is
#: below 0.4 the new bump is 0.19 at most.
MISSED_FINGER_RESIDUAL = 0.4
#: See :data:`MISSED_FINGER_RESIDUAL`.
MISSED_FINGER_SHARE = 0.3
#: Beside one contact, the missed finger must also move against it: the cosine of their
#: displacements at most this (within ~25 degrees of opposite). Two fingers of a pinch, a zoom or a
#: twist move against each other about their centre; a second bump moving otherwise explains the
#: shape of the one finger's own field (on the test users' sessions a weak push held near 0.6 mm
#: read as two contacts for 2.8 s with the two tests alone: cosine -0.56 to -0.67; on the tuning
#: users' windows of one contact the bumps of a second finger were at -0.93 and below, those of
#: one finger at -0.79 and above).
MISSED_FINGER_AGAINST = -0.9


@numba.njit(cache=True, nogil=True, error_model="numpy")
def with_missed_finger(
    rest: np.ndarray, v: np.ndarray, centres: np.ndarray, table: np.ndarray, knot: float, n_knots: int, r: float
) -> tuple[np.ndarray, int]:
    """:func:`bump_fit`'s centres, and one more finger where the field shows one that the maxima
    missed (not in the paper; docs/method.md, "Contacts"): a weak finger beside stronger ones in a
    twist or a pinch, whose markers move less than the gel between the others, so that no marker
    near it is the largest within r.

    The bumps at the fitted centres leave a residual; where it is largest (each marker's |residual|
    averaged with its neighbours', ``table``, among the markers farther than ``r`` from every
    centre) one more bump is started and all are fitted again. It is a finger when that fit
    leaves less than :data:`MISSED_FINGER_RESIDUAL` of the squared residual and its displacement
    is at least :data:`MISSED_FINGER_SHARE` of the weakest other finger's; beside one contact
    (K = 1), when it also moves against that finger (:data:`MISSED_FINGER_AGAINST`).

    Args:
        rest, v: (M, 2) float64, the markers' rest positions and displacements (px, image frame).
        centres: (K, 2) float64, K >= 1, the contacts' initial centres at rest (px).
        table: (M, K') int64, the markers' neighbours on the gel (``contacts_plateau.rest_neighbours``
            renumbered among them, -1 padded).
        knot, n_knots: the profile's knots (:func:`bump_fit`).
        r: the contacts' neighbourhood radius (px): a new finger lies farther from the others.
    Returns:
        (centres, marker): the (K, 2) or (K + 1, 2) float64 centres at rest (px), and the index
        of the marker where the new finger was started (-1: none).
    """
    c, _, res, ok = _fitted(rest, v, centres, knot, n_knots)
    if not ok:
        return c, -1
    m = len(rest)
    norm = np.empty(m)
    before = 0.0
    for i in range(m):
        norm[i] = math.sqrt(res[i, 0] ** 2 + res[i, 1] ** 2)
        before += norm[i] ** 2
    best, best_level = -1, 0.0
    for i in range(m):
        near = r * r
        for k in range(len(c)):
            near = min(near, (rest[i, 0] - c[k, 0]) ** 2 + (rest[i, 1] - c[k, 1]) ** 2)
        if near < r * r:
            continue
        total, count = norm[i], 1
        for j in table[i]:
            if j >= 0:
                total += norm[j]
                count += 1
        if total / count > best_level:
            best, best_level = i, total / count
    if best < 0 or not before > 0.0:
        return c, -1
    start = np.empty((len(c) + 1, 2))
    for k in range(len(c)):  # (a slice assignment would cost the first run ~2 s of compiling)
        start[k, 0], start[k, 1] = c[k, 0], c[k, 1]
    start[len(c), 0], start[len(c), 1] = rest[best, 0], rest[best, 1]
    more, u_more, res_more, ok = _fitted(rest, v, start, knot, n_knots)
    if not ok:
        return c, -1
    after = 0.0
    for i in range(m):
        after += res_more[i, 0] ** 2 + res_more[i, 1] ** 2
    weakest = np.inf
    for k in range(len(c)):
        weakest = min(weakest, math.hypot(u_more[k, 0], u_more[k, 1]))
    new = math.hypot(u_more[len(c), 0], u_more[len(c), 1])
    if not (after < MISSED_FINGER_RESIDUAL * before and new >= MISSED_FINGER_SHARE * weakest):
        return c, -1
    if len(c) == 1:
        dot = u_more[0, 0] * u_more[1, 0] + u_more[0, 1] * u_more[1, 1]
        if not dot <= MISSED_FINGER_AGAINST * weakest * new:
            return c, -1
    return more, best


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _at_rest(current: np.ndarray, v: np.ndarray, points: np.ndarray) -> np.ndarray:
    """(K, 2) where the gel points now at ``points`` (K, 2) px were at rest: each less the
    displacement of the marker nearest to it now (``current``, ``v`` (M, 2) px, M >= 1)."""
    out = np.empty_like(points)
    for k in range(len(points)):
        best = 0
        best_d2 = np.inf
        for i in range(len(current)):
            d2 = (current[i, 0] - points[k, 0]) ** 2 + (current[i, 1] - points[k, 1]) ** 2
            if d2 < best_d2:
                best, best_d2 = i, d2
        out[k, 0] = points[k, 0] - v[best, 0]
        out[k, 1] = points[k, 1] - v[best, 1]
    return out


@numba.njit(cache=True, nogil=True, error_model="numpy")
def field_at(rest: np.ndarray, v: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Where gel points are now: (K, 2) ``points`` (rest positions, px) plus the displacement
    there, the inverse-square-distance mean of the displacements ``v`` (M, 2) of the 4 markers
    nearest at rest (``rest`` (M, 2), M >= 1; a marker's own when a point is on it)."""
    out = np.empty_like(points)
    near = min(4, len(rest))
    best = np.empty(near, dtype=np.int64)
    best_d2 = np.empty(near)
    for k in range(len(points)):
        n_best = 0  # the nearest markers so far, by increasing distance (insertion)
        for i in range(len(rest)):
            d2 = (rest[i, 0] - points[k, 0]) ** 2 + (rest[i, 1] - points[k, 1]) ** 2
            if n_best < near or d2 < best_d2[n_best - 1]:
                q = n_best if n_best < near else near - 1
                while q > 0 and best_d2[q - 1] > d2:
                    best[q], best_d2[q] = best[q - 1], best_d2[q - 1]
                    q -= 1
                best[q], best_d2[q] = i, d2
                n_best = min(n_best + 1, near)
        sx = sy = sw = 0.0
        for q in range(near):
            w = 1.0 / (best_d2[q] + 1e-6)
            sx += w * v[best[q], 0]
            sy += w * v[best[q], 1]
            sw += w
        out[k, 0] = points[k, 0] + sx / sw
        out[k, 1] = points[k, 1] + sy / sw
    return out


def maxima_pushed_out(maxima_px: np.ndarray, fingers_px: np.ndarray) -> bool:
    """Whether every finger the bump fit placed lies inside its maximum: ``fingers_px - maxima_px``
    points back towards the maxima's mean for each of the K >= 2 pairs (the other fingers' fields
    pushed each maximum outward, the field the fit was made for; see the module docstring).

    Args:
        maxima_px: (K, 2) float, the field's maxima (``Contacts.peaks_px``, px).
        fingers_px: (K, 2) float, the fitted fingers in the same order (``Contacts.points_px``, px).
    Returns:
        False for fewer than two pairs or sets of different lengths.
    """
    maxima = np.asarray(maxima_px, dtype=np.float64).reshape(-1, 2)
    fingers = np.asarray(fingers_px, dtype=np.float64).reshape(-1, 2)
    if len(maxima) < 2 or len(maxima) != len(fingers):
        return False
    outward = maxima - maxima.mean(axis=0)
    return bool(np.all(np.einsum("kd,kd->k", fingers - maxima, outward) < 0.0))
