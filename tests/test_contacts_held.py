"""Contact point detection over a press (docs/method.md): which maxima the homography's outliers keep,
maxima a window holds for the next, a finger held earlier in the press, and the held peaks' kernels
against NumPy."""

from __future__ import annotations

import numpy as np
import pytest
from contacts_helpers import NO_SPIKES, SENSOR, bump, grid, three_finger_push

from neurotouch_hid.pipeline import contacts_held
from neurotouch_hid.pipeline.contacts import (
    _maxima,
    detect_contacts,
)
from neurotouch_hid.pipeline.contacts_held import HELD_PEAK_SHARE
from neurotouch_hid.pipeline.contacts_plateau import _valid_table, rest_neighbours


def _two_bumps_maxima(outliers_at_weak: str, held_at: float = 0.0, held_share: float = 1.0):
    """The maxima step on two bumps, the weak one's outliers as the homography might leave them:
    ``peak`` only its peak marker and its ring are outliers (fewer than N_min), ``none`` no
    marker of it is one (the homography explains it, as a gel sliding in its mount), ``ring`` its
    ring but not its peak marker (a stuck disc whose centre the homography fits, the slip about it
    not), ``one`` a single marker of its ring. With ``held_share`` > 0, the window before held the
    marker ``held_at`` px from the weak bump's peak at its displacement / ``held_share``. Returns
    the maxima's rest positions, the bumps' centres and the ||v|| (px) each maximum is held at."""
    rest = grid()
    c = np.asarray(SENSOR.gel_center_px, dtype=float)
    strong, weak = c + [-40.0, 0.0], c + [40.0, 0.0]
    v = bump(rest, strong, (8.0, 0.0), sigma=16.0) + bump(rest, weak, (-1.6, 0.0), sigma=16.0)
    magnitudes = np.linalg.norm(v, axis=1)
    outliers = np.linalg.norm(rest - strong, axis=1) <= 30.0
    to_weak = np.linalg.norm(rest - weak, axis=1)
    if outliers_at_weak == "peak":
        outliers |= to_weak <= 10.0
    elif outliers_at_weak == "ring":
        outliers |= (to_weak > 1.0) & (to_weak <= 10.0)
    elif outliers_at_weak == "one":
        outliers[np.argsort(to_weak)[1]] = True
    table = _valid_table(rest_neighbours(rest, 10.0), np.arange(len(rest)), len(rest))
    threshold = 0.6 * magnitudes.mean()
    held = np.zeros(len(rest))
    if held_share > 0.0:
        marker = np.argmin(np.abs(to_weak - held_at))
        held[marker] = magnitudes[np.argmin(to_weak)] / held_share
    peaks, level, _ = _maxima(rest, magnitudes, outliers, table, NO_SPIKES, 25.0**2, 12, threshold, 0.6, held)
    return rest[peaks], strong, weak, level


@pytest.mark.parametrize(
    ("outliers_at_weak", "weak_is_a_finger"),
    [("peak", True), ("none", False), ("ring", True), ("one", False)],
    ids=[
        "a_weak_finger_with_few_outliers_is_found_through_its_moved_neighbours",
        "a_moved_region_the_homography_explains_is_no_contact",
        "a_finger_whose_peak_marker_the_homography_fits_is_found_through_its_outlier_ring",
        "one_outlier_beside_a_maximum_the_homography_fits_is_no_contact",
    ],
)
def test_which_maxima_the_homography_s_outliers_keep(outliers_at_weak, weak_is_a_finger):
    found, strong, weak, _ = _two_bumps_maxima(outliers_at_weak, held_share=0.0)
    np.testing.assert_allclose(found, [strong, weak] if weak_is_a_finger else [strong])


def test_a_flat_top_of_several_fingers_holds_none_of_its_maxima():
    """A 3-finger push's flat top has maxima at random places, its peak wandering over it from one
    window to the next: held, they would stand beside the peak the next window and change how the
    plateau is read. Only one finger's peak is held; the next window counts three again."""
    for seed in range(5):
        rest, cur, _ = three_finger_push(seed=seed)
        options = {"r_px": 25.0, "n_min": 12, "refine_px": 20.0, "plateau_fraction": 0.8}
        first = detect_contacts(rest, cur, **options)
        assert first.count == 3 and len(first.held[0]) == 0
        assert detect_contacts(rest, cur, **options, held=first.held).count == 3
    rest, cur = grid(), grid() + bump(grid(), SENSOR.gel_center_px, (6.0, -3.0))
    one = detect_contacts(rest, cur, **options)
    assert one.count == 1 and one.held[0].tolist() == one.indices.tolist()


@pytest.mark.parametrize(
    ("held_at", "held_share", "weak_is_a_finger"),
    [
        (0.0, 1.0, True),
        (10.0, 0.95, True),
        (0.0, 0.85, False),
        (20.0, 1.0, False),
        (0.0, 0.0, False),
    ],
    ids=[
        "a_finger_the_homography_follows_stays_held_from_the_window_before",
        "held_beside_its_peak_and_displaced_as_much_it_stays",
        "eased_off_below_the_share_it_goes",
        "held_two_pitches_away_is_another_place",
        "held_nowhere_it_is_no_contact",
    ],
)
def test_a_maximum_the_homography_fits_is_kept_where_the_window_before_held_it(held_at, held_share, weak_is_a_finger):
    # the weak finger's region is all inlier (the homography's consensus followed it this frame)
    found, strong, weak, level = _two_bumps_maxima("none", held_at=held_at, held_share=held_share)
    np.testing.assert_allclose(found, [strong, weak] if weak_is_a_finger else [strong])
    assert 0.85 < HELD_PEAK_SHARE < 0.95
    if weak_is_a_finger:  # held at what it was held at, not at today's displacement: easing off adds up
        assert level[1] == pytest.approx(1.6 / held_share, rel=0.01)
    assert level[0] == pytest.approx(8.0, rel=0.01)  # the strong finger, an outlier: held at its own


@pytest.mark.parametrize(
    ("held_share", "valid", "still_held"),
    [(0.95, True, True), (0.85, True, False), (0.95, False, False)],
    ids=[
        "no_maximum_this_window_but_displaced_as_much_the_press_still_holds_it",
        "eased_off_below_the_share_the_press_lets_it_go",
        "its_marker_lost_the_press_lets_it_go",
    ],
)
def test_a_finger_held_earlier_in_the_press_outlasts_a_window_without_its_maximum(held_share, valid, still_held):
    """A weak finger beside a strong one, displaced below the least move that counts: no contact of
    this window. Held by the press before (at its displacement / ``held_share``), it stays held for
    the next window while its marker is valid and displaced at least HELD_PEAK_SHARE of that, at the
    level it was held at: a correction that reshuffles the maxima for one frame does not lose it."""
    rest = grid()
    c = np.asarray(SENSOR.gel_center_px, dtype=float)
    strong, weak_at = c + [-40.0, 0.0], c + [40.0, 0.0]
    cur = rest + bump(rest, strong, (8.0, 0.0), sigma=16.0) + bump(rest, weak_at, (-0.5, 0.0), sigma=16.0)
    weak = int(np.argmin(np.linalg.norm(rest - weak_at, axis=1)))
    level = float(np.linalg.norm(cur[weak] - rest[weak])) / held_share
    ok = np.ones(len(rest), dtype=bool)
    ok[weak] = valid
    found = detect_contacts(rest, cur, ok, held=(np.array([weak]), np.array([level])))
    assert found.count == 1 and weak not in found.indices.tolist()
    assert (weak in found.held[0].tolist()) == still_held
    if still_held:
        assert found.held[1][found.held[0].tolist().index(weak)] == pytest.approx(level)
    assert len(found.held[0]) == len(set(found.held[0].tolist()))  # the strong finger once, not twice


def _held_reference(held, idx, magnitudes, now):
    """The held peaks written with NumPy, as they were before their kernels: (levels, still held)."""
    levels = np.zeros(len(idx))
    at = np.minimum(np.searchsorted(idx, held[0]), len(idx) - 1)
    found = idx[at] == held[0]
    levels[at[found]] = held[1][found]
    again = (held[0][:, None] == now[0][None, :]).any(axis=1)
    still = (idx[at] == held[0]) & (magnitudes[at] >= contacts_held.HELD_PEAK_SHARE * held[1]) & ~again
    return levels, (np.concatenate([now[0], held[0][still]]), np.concatenate([now[1], held[1][still]]))


def test_the_held_peaks_kernels_match_numpy():
    """Lost markers, peaks beyond the last valid marker, held again or easing off, a marker held twice."""
    rng = np.random.default_rng(7)
    for _ in range(500):
        idx = np.flatnonzero(rng.random(40) < rng.uniform(0.3, 1.0))
        if not len(idx):
            continue
        magnitudes = rng.uniform(0.0, 8.0, len(idx))
        held = (rng.integers(0, 42, rng.integers(1, 6)), rng.uniform(0.0, 9.0, 0))
        held = (held[0], rng.uniform(0.0, 9.0, len(held[0])))
        now = (rng.choice(idx, rng.integers(0, min(4, len(idx)) + 1), replace=False), rng.uniform(0, 9, 0))
        now = (now[0].astype(np.int64), rng.uniform(0.0, 9.0, len(now[0])))
        levels, still = _held_reference(held, idx, magnitudes, now)
        got = contacts_held._still_held(held, idx, magnitudes, now)
        np.testing.assert_array_equal(contacts_held._held_levels(held, idx), levels)
        np.testing.assert_array_equal(got[0], still[0])
        np.testing.assert_array_equal(got[1], still[1])
        assert got[0].dtype == np.int64 and got[1].dtype == np.float64
