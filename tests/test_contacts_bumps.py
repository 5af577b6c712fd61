"""Contact point detection with long tails (docs/method.md): the fingers' centres fitted as radial
bumps (bump_fit) against its algorithm in NumPy, weak fingers the homography keeps, a twist, a
pinch with one finger at the apex."""

from __future__ import annotations

import numpy as np
import pytest
from contacts_helpers import NO_SPIKES, SENSOR, assert_one_contact_on_each, bump, grid, three_finger_push

from neurotouch_hid.pipeline.contacts import (
    _maxima,
    detect_contacts,
    outlier_candidates,
)
from neurotouch_hid.pipeline.contacts_bump import maxima_pushed_out
from neurotouch_hid.pipeline.contacts_plateau import _valid_table, rest_neighbours


# --- long tails: the fingers' centres fitted as radial bumps (bump_fit) ----------------------
def long_tailed_pinch(spread: float = 20.0, amount: float = 6.0, tail=lambda r: (1.0 + r**2 / 288.0) ** -0.75):
    """Two fingers ``2 spread`` px apart moving ``amount`` px towards each other, each dragging
    the gel with a long-tailed radial falloff (default ~r^-1.5 past 12 px); their fields add.
    Returns rest, current and the fingers' true points now (image px)."""
    rest = grid()
    c = np.asarray(SENSOR.gel_center_px, dtype=float) + [2.0, 3.0]
    fingers = c + np.array([[-spread, 0.0], [spread, 0.0]])
    moves = np.array([[amount, 0.0], [-amount, 0.0]])
    v = sum(tail(np.linalg.norm(rest - f, axis=1))[:, None] * d for f, d in zip(fingers, moves))
    return rest, rest + v, fingers + moves + [[-tail(2 * spread) * amount, 0.0], [tail(2 * spread) * amount, 0.0]]


def _pinch_without_and_with_the_bump_fit(tail=None):
    """A two-finger pinch (:func:`long_tailed_pinch`) through the contact step: the maxima before
    the bump fit (``peaks_px``) and the fitted points, each one's distance (px) from the fingers'
    true points."""
    rest, cur, truth = long_tailed_pinch() if tail is None else long_tailed_pinch(tail=tail)
    new = detect_contacts(rest, cur, r_px=25.0, n_min=12, spike_fraction=NO_SPIKES, bump_span_px=SENSOR.gel_radius_px)
    assert new.count == 2
    old_error = np.linalg.norm(new.peaks_px[np.argsort(new.peaks_px[:, 0])] - truth, axis=1)
    new_error = np.linalg.norm(new.points_px[np.argsort(new.points_px[:, 0])] - truth, axis=1)
    return new, old_error, new_error


def test_a_long_tailed_pinch_puts_the_maxima_outside_the_fingers_and_the_bump_fit_on_them():
    # the other finger's tail opposes each finger's field on the inner side: the largest
    # displacement lies a pitch or more outside each finger (the paper's contact point), where the
    # fitted bumps' centres, with their profile measured on this field, are the fingers'
    _, old_error, new_error = _pinch_without_and_with_the_bump_fit()
    assert old_error.min() > 3.5  # 1.4-1.8 mm outward
    assert new_error.max() < 2.0  # 0.8 mm, after BUMP_ITERATIONS (3) rounds


def test_maxima_pushed_out_says_whether_every_fitted_finger_lies_inside_its_maximum():
    new, _, _ = _pinch_without_and_with_the_bump_fit()
    assert maxima_pushed_out(new.peaks_px, new.points_px)  # the long-tailed pinch above
    maxima = np.array([[100.0, 100.0], [140.0, 100.0], [120.0, 134.0]])
    inside = maxima + 0.2 * (maxima.mean(axis=0) - maxima)
    assert maxima_pushed_out(maxima, inside)
    one_out = inside.copy()
    one_out[2] = maxima[2] + [3.0, 4.0]  # 4 px further from the others than its maximum
    assert not maxima_pushed_out(maxima, one_out)
    assert not maxima_pushed_out(maxima[:1], inside[:1])  # one finger: nothing pushes it
    assert not maxima_pushed_out(maxima, inside[:2])


@pytest.mark.parametrize("tail", [lambda r: np.exp(-(r**2) / 288.0), lambda r: 1.0 / (1.0 + r / 12.0)])
def test_the_bump_fit_measures_the_profile_so_another_falloff_gains_too(tail):
    # no falloff is assumed: a Gaussian (short tails) and a 1/r tail (longer than the profile's
    # span), neither of which the fit's start is, also come nearer the fingers
    _, old_error, new_error = _pinch_without_and_with_the_bump_fit(tail)
    assert new_error.max() < 2.5
    assert new_error.max() < 0.5 * old_error.max()


def test_the_bump_fit_leaves_one_finger_and_a_split_flat_top_alone():
    rest = grid()
    centre = np.asarray(SENSOR.gel_center_px, dtype=float) + [3.0, -3.0]
    cur = rest + bump(rest, centre, (6.0, -3.0))
    one = detect_contacts(rest, cur, r_px=30.0, n_min=4, refine_px=15.0)
    assert one.count == 1
    np.testing.assert_array_equal(one.points_px, one.peaks_px)
    rest, cur, _ = three_finger_push(seed=0)
    flat = detect_contacts(rest, cur, r_px=25.0, n_min=12, refine_px=20.0, plateau_fraction=0.8)
    assert flat.count == 3
    np.testing.assert_array_equal(flat.points_px, flat.peaks_px)


def numpy_bump_fit(rest, v, centres, knot, n_knots, rounds):
    """bump_fit's algorithm written with NumPy: the same rounds, normal equations with the same
    small ridges and curvature penalty, step limit and final guard."""

    def solve(a, b, ridge):
        return np.linalg.solve(a + ridge * np.diag(np.diag(a) + 1e-12), b)

    c = centres.copy()
    g = np.exp(-4.5 * (np.arange(n_knots) / (n_knots - 1.0)) ** 2)
    for _ in range(rounds):
        diff = rest[:, None, :] - c[None]
        r = np.linalg.norm(diff, axis=2)
        t = np.minimum(r / knot, n_knots - 1.0)
        j = np.minimum(np.floor(t).astype(int), n_knots - 2)
        f = t - j
        basis = np.zeros(r.shape + (n_knots,))
        np.put_along_axis(basis, j[..., None], (1 - f)[..., None], axis=2)
        np.put_along_axis(basis, (j + 1)[..., None], f[..., None], axis=2)
        a = basis @ g
        u = solve(a.T @ a, a.T @ v, 1e-9)
        rows = np.einsum("ikl,kd->idl", basis, u).reshape(-1, n_knots)
        normal = rows.T @ rows
        second = np.diff(np.eye(n_knots), n=2, axis=0)  # the faint curvature penalty
        normal = normal + 1e-6 * np.trace(normal) / n_knots * (np.eye(n_knots) + second.T @ second)
        g = np.linalg.solve(normal, rows.T @ v.reshape(-1))
        u, g = u * g[0], g / g[0]
        slope = np.where((r < (n_knots - 1) * knot) & (r > 1e-9), (g[j + 1] - g[j]) / knot, 0.0)
        jac = -(slope / np.maximum(r, 1e-9))[:, :, None, None] * diff[:, :, None, :] * u[None, :, :, None]
        jac = jac.transpose(0, 2, 1, 3).reshape(2 * len(rest), 2 * len(c))  # rows (i, d), columns (k, e)
        step = solve(jac.T @ jac, jac.T @ (v - (basis @ g) @ u).reshape(-1), 1e-6).reshape(-1, 2)
        n = np.linalg.norm(step, axis=1, keepdims=True)
        c = c + step * np.minimum(1.0, 0.5 * knot / np.maximum(n, 1e-300))
    far = np.linalg.norm(c - centres, axis=1) > 2 * knot
    c[far] = centres[far]
    return c


def test_bump_fit_matches_its_algorithm_written_with_numpy():
    from neurotouch_hid.pipeline.contacts_bump import BUMP_ITERATIONS, bump_fit

    rest, cur, _ = long_tailed_pinch()
    v = cur - rest
    c = np.asarray(SENSOR.gel_center_px, dtype=float)
    for start in (c + [[-28.0, 0.0], [28.0, 0.0]], c + [[-60.0, 10.0], [28.0, 0.0]]):  # the second: one too far
        np.testing.assert_allclose(
            bump_fit(rest, v, start, 10.0, 9), numpy_bump_fit(rest, v, start, 10.0, 9, BUMP_ITERATIONS), atol=1e-8
        )
    three = c + np.array([[-30.0, -20.0], [30.0, -20.0], [0.0, 30.0]])
    v3 = sum(
        np.exp(-np.sum((rest - f) ** 2, axis=1) / 300.0)[:, None] * d for f, d in zip(three, [[3, 4], [-4, 2], [1, -5]])
    )
    start = three + [[4.0, -3.0], [-2.0, 5.0], [3.0, 3.0]]
    np.testing.assert_allclose(
        bump_fit(rest, v3, start, 10.0, 9), numpy_bump_fit(rest, v3, start, 10.0, 9, BUMP_ITERATIONS), atol=1e-8
    )
    np.testing.assert_allclose(bump_fit(rest, v3, start, 10.0, 9), three, atol=0.5)


def test_bump_fit_keeps_the_start_on_a_field_it_cannot_fit():
    from neurotouch_hid.pipeline.contacts_bump import bump_fit

    rest = grid()
    start = rest[[10, 50]].astype(float)
    np.testing.assert_array_equal(bump_fit(rest, np.zeros_like(rest), start, 10.0, 9), start)  # no field: singular
    # a profile longer than any marker's distance: its far knots follow the near ones, the fit still runs
    rest_small = rest[np.linalg.norm(rest - SENSOR.gel_center_px, axis=1) < 40.0]
    c = np.asarray(SENSOR.gel_center_px, dtype=float)
    two = c + np.array([[-15.0, 0.0], [15.0, 0.0]])
    v = sum(
        np.exp(-np.sum((rest_small - f) ** 2, axis=1) / 200.0)[:, None] * d
        for f, d in zip(two, [[3.0, 0.0], [-3.0, 0.0]])
    )
    np.testing.assert_allclose(bump_fit(rest_small, v, two + [[4.0, 2.0], [-3.0, 2.0]], 10.0, 30, 8), two, atol=0.5)


def test_the_small_solver_matches_numpy():
    from neurotouch_hid.pipeline.contacts_bump import _solve

    rng = np.random.default_rng(4)
    for n in (1, 2, 6, 9):
        a = rng.normal(size=(n, n)) + n * np.eye(n)
        b = rng.normal(size=(n, 2))
        x, ok = _solve(a, b)
        assert ok
        np.testing.assert_allclose(x, np.linalg.solve(a, b), rtol=1e-10, atol=1e-12)
    a = np.array([[0.0, 1.0], [1.0, 0.0]])  # needs a row exchange
    np.testing.assert_allclose(_solve(a, np.eye(2))[0], np.linalg.inv(a))
    assert not _solve(np.ones((3, 3)), np.ones((3, 1)))[1]
    assert not _solve(np.zeros((2, 2)), np.ones((2, 1)))[1]


def test_field_at_and_at_rest_match_numpy():
    from neurotouch_hid.pipeline.contacts_bump import _at_rest, field_at

    rng = np.random.default_rng(5)
    rest = grid()
    v = rng.normal(size=rest.shape)
    points = rest[[3, 40]] + rng.uniform(-5, 5, (2, 2))
    d2 = np.sum((rest[None] - points[:, None]) ** 2, axis=2)
    near = np.argsort(d2, axis=1)[:, :4]
    w = 1.0 / (np.take_along_axis(d2, near, axis=1) + 1e-6)
    expected = points + np.sum(v[near] * w[..., None], axis=1) / w.sum(axis=1)[:, None]
    np.testing.assert_allclose(field_at(rest, v, points), expected, rtol=1e-12)
    np.testing.assert_allclose(field_at(rest, v, rest[[7]]), rest[[7]] + v[[7]], atol=1e-9)  # on a marker: its own
    cur = rest + v
    nearest = np.argmin(np.sum((cur[None] - points[:, None]) ** 2, axis=2), axis=1)
    np.testing.assert_array_equal(_at_rest(cur, v, points), points - v[nearest])


def test_a_weak_second_finger_whose_markers_the_homography_keeps_is_still_a_contact():
    # a pinch led by one finger: the second pushes at 0.2 of the first's displacement, 80 px
    # away; the homography keeps half of its markers as inliers, too few outliers are left
    # within r of its peak for N_min, but its markers moved beyond the dynamic threshold and the
    # least displacement (docs/method.md, "Contacts", step 3)
    rest = grid()
    c = np.asarray(SENSOR.gel_center_px, dtype=float)
    strong, weak = c + [-40.0, 0.0], c + [40.0, 0.0]
    cur = rest + bump(rest, strong, (8.0, 0.0), sigma=16.0) + bump(rest, weak, (-1.6, 0.0), sigma=16.0)
    contacts = detect_contacts(rest, cur)
    within_r = np.linalg.norm(rest - weak, axis=1) <= 25.0  # the weak finger's peak marker is on it
    assert contacts.candidates[within_r].sum() < 12  # the outliers alone are fewer than N_min
    assert contacts.count == 2
    found = contacts.points_px[np.argsort(contacts.points_px[:, 0])]
    np.testing.assert_allclose(found, [strong + [8.0, 0.0], weak + [-1.6, 0.0]], atol=1.0)


@pytest.mark.parametrize("weak", [0.3, 0.5, 1.0])
def test_a_second_finger_of_any_strength_in_a_twist_is_a_contact(weak):
    rest = grid()
    c = np.asarray(SENSOR.gel_center_px, dtype=float)
    left, right = c + [-40.0, 0.0], c + [40.0, 0.0]
    cur = rest + bump(rest, left, (0.0, 15.0), sigma=10.0) + bump(rest, right, (0.0, -15.0 * weak), sigma=10.0)
    contacts = detect_contacts(rest, cur)
    assert contacts.count == 2
    found = np.sort(contacts.points_px[:, 0])
    np.testing.assert_allclose(found, [left[0], right[0]], atol=3.0)


def twist_of_three(rest, strengths, sigma_px):
    """Three fingers 28 px from the gel's centre, 120 degrees apart, turning it: each drags the gel
    tangentially, 6 px times its strength at its centre, a Gaussian of ``sigma_px`` about it.
    Returns the current positions (with tracker noise) and where the fingers' centres are now."""
    c = np.asarray(SENSOR.gel_center_px, dtype=float)
    cur, fingers = rest.copy(), []
    for k, strength in enumerate(strengths):
        angle = 2 * np.pi * k / 3 + 0.4
        finger = c + 28.0 * np.array([np.cos(angle), np.sin(angle)])
        turn = 6.0 * strength * np.array([-np.sin(angle), np.cos(angle)])
        cur = cur + bump(rest, finger, turn, sigma=sigma_px)
        fingers.append(finger + turn)
    return cur + np.random.default_rng(0).normal(0.0, 0.05, cur.shape), np.asarray(fingers)


def _product_maxima(found, table: np.ndarray) -> np.ndarray:
    """The product's maxima step (r 25 px, N_min 12) on ``outlier_candidates``' ``found``, no
    finger held: (K,) int64 into its markers."""
    args = (found.rest_px, found.magnitudes, found.outliers, table, 0.6, 25.0**2, 12, found.threshold_px, 0.6)
    return _maxima(*args, np.zeros(len(found.idx)))[0]


def test_a_weak_third_finger_no_marker_of_which_is_a_maximum_is_found_by_the_bumps():
    # a twist of three fingers, the third at 0.35 of the others' strength: with wide bumps the
    # gel between the strong fingers moves more than the third finger's markers, so no maximum
    # lies on it (two contacts); two bumps leave its field as the residual, a third explains it
    rest = grid()
    cur, fingers = twist_of_three(rest, (1.0, 1.0, 0.35), sigma_px=20.0)
    found = outlier_candidates(rest, cur, None, a=0.6)
    table = _valid_table(rest_neighbours(rest, 10.0), found.idx, found.n)
    peaks = _product_maxima(found, table)
    assert len(peaks) == 2 and np.linalg.norm(found.rest_px[peaks] - fingers[2], axis=1).min() > 25.0
    found = detect_contacts(rest, cur, r_px=25.0, n_min=12, refine_px=20.0, plateau_fraction=0.8)
    assert_one_contact_on_each(found, fingers, within_px=3.0)


@pytest.mark.parametrize("weak", [0.4, 0.6, 0.8])
def test_a_pinch_with_one_finger_at_the_apex_gives_two_contacts_where_the_maxima_see_one(weak):
    # two fingers 15 mm (37.5 px) apart pinching, the stronger at the gel's centre: no marker of
    # the weaker is a maximum with N_min around it (one maximum); one bump explains the stronger
    # finger's field and leaves the weaker's as the residual, which a second bump explains
    rest = grid()
    c = np.asarray(SENSOR.gel_center_px, dtype=float)
    apex, other = c, c + [37.5, 0.0]
    cur = rest + bump(rest, apex, (6.0, 0.0)) + bump(rest, other, (-6.0 * weak, 0.0))
    found = outlier_candidates(rest, cur, None, a=0.6)
    table = _valid_table(rest_neighbours(rest, 10.0), found.idx, found.n)
    peaks = _product_maxima(found, table)
    assert len(peaks) == 1
    contacts = detect_contacts(rest, cur)
    assert contacts.count == 2
    points = contacts.points_px[np.argsort(contacts.points_px[:, 0])]
    np.testing.assert_allclose(points, [apex + [6.0, 0.0], other - [6.0 * weak, 0.0]], atol=3.0)


def test_two_fingers_with_long_tails_get_no_third_from_the_bumps():
    # the third finger absent: what two bumps leave of two fingers is no finger (wider bumps
    # join into one flat top, read by its area)
    rest = grid()
    for sigma in (10.0, 20.0, 25.0):
        cur, fingers = twist_of_three(rest, (1.0, 1.0, 0.0), sigma_px=sigma)
        found = detect_contacts(rest, cur, r_px=25.0, n_min=12, refine_px=20.0, plateau_fraction=0.8)
        assert_one_contact_on_each(found, fingers[:2], within_px=3.0)


def test_a_bump_below_the_least_displacement_is_no_finger():
    # a finger 1 px deep and, 80 px away, a ripple of 0.25 px: above the dynamic threshold
    # (0.6 x the mean, ~0.03 px) but below the least displacement that counts as moved
    rest = grid()
    c = np.asarray(SENSOR.gel_center_px, dtype=float)
    left, right = c + [-40.0, 0.0], c + [40.0, 0.0]
    cur = rest + bump(rest, left, (1.0, 0.0), sigma=10.0) + bump(rest, right, (-0.25, 0.0), sigma=10.0)
    assert detect_contacts(rest, cur, min_move_px=0.6).count == 1
    assert detect_contacts(rest, cur, min_move_px=0.3).count == 1
    assert detect_contacts(rest, cur, min_move_px=0.0).count == 2


def test_moved_markers_add_no_contact_to_a_one_finger_push():
    rest = grid()
    c = np.asarray(SENSOR.gel_center_px, dtype=float)
    for amount in (0.5, 2.0, 8.0, 20.0):
        for sigma in (8.0, 12.0, 20.0):
            for offset in ([0.0, 0.0], [30.0, -20.0], [-50.0, 10.0]):
                cur = rest + bump(rest, c + offset, (amount, -amount / 2), sigma=sigma)
                assert detect_contacts(rest, cur).count == 1, (amount, sigma, offset)
