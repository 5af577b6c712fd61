"""Contact point detection on hand-made displacement fields (paper, "Contact Point Detection"): the
homography's outliers and their local maxima, lost markers, the fallbacks, the refinement between
markers, and the neighbour tables and usable markers against NumPy."""

from __future__ import annotations

import numpy as np
import pytest
from contacts_helpers import NO_SPIKES, SENSOR, bump, grid, three_finger_push

from neurotouch_hid.pipeline.contacts import (
    detect_contacts,
    local_maxima,
)
from neurotouch_hid.pipeline.contacts_refine import refine_peak
from neurotouch_hid.pipeline.paper import paper_contacts


@pytest.mark.parametrize("method", ["usac_fast", "ransac"])
def test_one_finger_push_gives_one_contact_at_the_peak(method):
    rest = grid()
    centre = rest[np.argmin(np.sum((rest - [183.0, 120.0]) ** 2, axis=1))]
    cur = rest + bump(rest, centre, (6.0, -3.0))
    contacts = paper_contacts(rest, cur, method=method)
    assert contacts.count == 1
    np.testing.assert_allclose(contacts.points_px[0], centre + [6.0, -3.0], atol=1e-6)
    assert contacts.candidates.sum() >= 4
    assert contacts.reproj_threshold_px == pytest.approx(0.6 * np.linalg.norm(cur - rest, axis=1).mean())


@pytest.mark.parametrize("method", ["usac_fast", "ransac"])
def test_two_fingers_far_apart_give_two_contacts(method):
    rest = grid()
    c1, c2 = np.array([143.0, 130.0]), np.array([203.0, 130.0])
    cur = rest + bump(rest, c1, (5.0, 0.0)) + bump(rest, c2, (-5.0, 0.0))
    contacts = paper_contacts(rest, cur, method=method)
    assert contacts.count == 2
    found = sorted(contacts.points_px[:, 0])
    assert found[0] == pytest.approx(148.0, abs=1e-3)
    assert found[1] == pytest.approx(198.0, abs=1e-3)


@pytest.mark.parametrize("method", ["usac_fast", "ransac"])
def test_a_global_motion_is_not_a_contact(method):
    """A pure global translation fits the homography: no outlier, no contact."""
    rest = grid()
    contacts = paper_contacts(rest, rest + [4.0, 2.0], method=method)
    assert contacts.count == 0


def test_lost_markers_take_no_part():
    rest = grid()
    centre = np.array([173.0, 130.0])
    cur = rest + bump(rest, centre, (6.0, 0.0))
    valid = np.ones(len(rest), dtype=bool)
    peak = int(np.argmin(np.sum((rest - centre) ** 2, axis=1)))
    valid[peak] = False
    cur[peak] = np.nan  # a lost marker may have any position
    contacts = paper_contacts(rest, cur, valid)
    assert contacts.count >= 1
    assert peak not in contacts.indices
    assert not contacts.candidates[peak]


@pytest.mark.parametrize("n", [0, 1, 3])
def test_fewer_than_four_valid_markers_give_no_contact(n):
    rest = grid()[:n]
    contacts = paper_contacts(rest, rest + 5.0)
    assert contacts.count == 0
    assert contacts.candidates.shape == (n,)


def test_all_zero_displacement_gives_no_contact():
    rest = grid()
    contacts = paper_contacts(rest, rest.copy())
    assert contacts.count == 0 and not contacts.candidates.any()


def test_degenerate_homography_falls_back_to_all_markers():
    """Collinear markers: OpenCV finds no homography; the displacement maxima still count."""
    rest = np.stack([np.arange(10) * 10.0 + 100.0, np.full(10, 130.0)], axis=1)
    disp = np.zeros_like(rest)
    disp[:, 1] = [0, 1, 2, 3, 6, 3, 2, 1, 0, 0]
    contacts = paper_contacts(rest, rest + disp, r_px=30.0, n_min=4)
    assert contacts.candidates.all()
    assert list(contacts.indices) == [4]


def test_local_maxima_need_n_min_neighbours():
    pts = np.array([[0.0, 0.0], [10.0, 0.0], [0.0, 10.0], [100.0, 0.0]])
    mags = np.array([5.0, 1.0, 1.0, 9.0])
    assert list(local_maxima(pts, mags, r_px=30.0, n_min=3)) == [0]
    assert list(local_maxima(pts, mags, r_px=30.0, n_min=1)) == [3, 0]


def test_equal_maxima_keep_one_per_neighbourhood():
    pts = np.array([[0.0, 0.0], [10.0, 0.0], [0.0, 10.0], [10.0, 10.0]])
    mags = np.array([1.0, 5.0, 5.0, 1.0])
    kept = local_maxima(pts, mags, r_px=30.0, n_min=4)
    assert list(kept) == [1]


def test_a_wide_push_the_homography_absorbs_falls_back_to_the_field_peak():
    # a displacement falloff far wider than r (a multi-finger push dragging most of the gel):
    # a homography models it, so no outlier is left to carry a contact
    rest = grid()
    centre = rest[np.argmin(np.sum((rest - [173.0, 130.0]) ** 2, axis=1))]
    cur = rest + bump(rest, centre, (15.0, -5.0), sigma=60.0)
    assert paper_contacts(rest, cur).count == 0
    contacts = detect_contacts(rest, cur, r_px=30.0, n_min=4)  # the product falls back on the rest model
    assert contacts.count >= 1  # the flat top's fingers, all on the field's peak marker
    assert set(contacts.indices.tolist()) == {int(np.argmin(np.linalg.norm(rest - centre, axis=1)))}


def test_the_field_fallback_leaves_found_contacts_alone():
    rest = grid()
    centre = rest[np.argmin(np.sum((rest - [183.0, 120.0]) ** 2, axis=1))]
    cur = rest + bump(rest, centre, (6.0, -3.0))
    a, b = paper_contacts(rest, cur), detect_contacts(rest, cur, r_px=30.0, n_min=4)
    np.testing.assert_array_equal(a.indices, b.indices)


def test_refinement_finds_a_finger_between_markers():
    # the finger's centre lies between grid markers (pitch 10 px, one on the gel's centre)
    rest = grid()
    centre = np.asarray(SENSOR.gel_center_px, dtype=float) + [3.0, -3.0]
    direction = np.array([6.0, -3.0])
    cur = rest + bump(rest, centre, direction)
    truth = centre + direction
    paper = paper_contacts(rest, cur)
    refined = detect_contacts(rest, cur, r_px=30.0, n_min=4, refine_px=15.0, spike_fraction=NO_SPIKES)
    assert refined.count == paper.count == 1
    np.testing.assert_array_equal(refined.indices, paper.indices)
    assert np.linalg.norm(paper.points_px[0] - truth) > 2.0
    assert np.linalg.norm(refined.points_px[0] - truth) < 1.0


def test_refinement_keeps_the_marker_without_a_maximum_or_enough_markers():
    rest = grid()
    peak = int(np.argmin(np.sum((rest - SENSOR.gel_center_px) ** 2, axis=1)))
    flat = np.tile([3.0, 0.0], (len(rest), 1))  # a plane: no maximum
    np.testing.assert_allclose(refine_peak(rest, flat, peak, 15.0), rest[peak] + [3.0, 0.0])
    few = bump(rest, rest[peak], (3.0, 0.0))
    np.testing.assert_allclose(refine_peak(rest, few, peak, 9.0), rest[peak] + few[peak])  # 5 markers only


def test_neighbours_given_once_per_reference_match_those_computed_per_window_with_lost_markers():
    from neurotouch_hid.pipeline.contacts_plateau import rest_neighbours

    rest, cur, _ = three_finger_push(seed=3)
    valid = np.ones(len(rest), dtype=bool)
    valid[::7] = False  # lost markers: their rows and entries drop out
    options = dict(r_px=25.0, n_min=12, refine_px=20.0, plateau_fraction=0.8, spike_fraction=0.6)
    table = rest_neighbours(rest, 10.0)
    assert table.shape == (len(rest), 8)  # a square grid's 8 nearest within 1.5 pitches
    given = detect_contacts(rest, cur, valid, **options, neighbours=table)
    computed = detect_contacts(rest, cur, valid, **options)
    np.testing.assert_array_equal(given.points_px, computed.points_px)
    assert given.count >= 2  # the lost markers take part of the plateau's area


def test_the_valid_markers_neighbour_table_matches_one_built_from_the_valid_markers_alone():
    from neurotouch_hid.pipeline.contacts_plateau import _valid_table, rest_neighbours

    rest = grid()
    rng = np.random.default_rng(5)
    for lost_share in (0.0, 0.1, 0.5, 0.95):
        valid = rng.random(len(rest)) >= lost_share
        idx = np.flatnonzero(valid)
        table = _valid_table(rest_neighbours(rest, 10.0), idx, len(rest))
        alone = rest_neighbours(rest[idx], 10.0)  # numbered among the valid markers from the start
        assert table.shape[0] == len(idx)
        for row, reference in zip(table, alone):
            assert list(row[row >= 0]) == list(reference[reference >= 0])


def test_the_usable_markers_and_their_displacements_match_numpy():
    from neurotouch_hid.pipeline.contacts import _usable

    rng = np.random.default_rng(6)
    rest = grid()
    for trial in range(4):
        cur = rest + rng.normal(scale=[0.01, 1.0, 5.0, 30.0][trial], size=rest.shape)
        cur[rng.random(len(rest)) < 0.1, rng.integers(0, 2)] = np.nan  # lost in one coordinate
        valid = rng.random(len(rest)) > 0.2
        idx, rest_ok, cur_ok, v, norms = _usable(rest, cur, valid)
        expected = np.flatnonzero(valid & np.isfinite(cur).all(axis=1))
        np.testing.assert_array_equal(idx, expected)
        np.testing.assert_array_equal(rest_ok, rest[expected])
        np.testing.assert_array_equal(cur_ok, cur[expected])
        np.testing.assert_array_equal(v, cur[expected] - rest[expected])
        np.testing.assert_array_equal(norms, np.hypot(v[:, 0], v[:, 1]))
    idx, *_ = _usable(rest, np.full_like(rest, np.nan), np.ones(len(rest), dtype=bool))
    assert len(idx) == 0


def test_arrays_of_different_marker_counts_are_an_error_not_a_read_past_the_end():
    from neurotouch_hid.pipeline.gel_motion import estimate_gel_motion
    from neurotouch_hid.pipeline.gesture import estimate_gesture

    rest = grid()
    cur = rest + bump(rest, SENSOR.gel_center_px, (4.0, 0.0))
    valid = np.ones(len(rest), dtype=bool)
    rim = np.ones(len(rest), dtype=bool)
    for bad in [(rest, cur[:-1], valid), (rest, cur, valid[:-1]), (rest[:, :1], cur, valid)]:
        with pytest.raises(ValueError, match="same N markers"):
            detect_contacts(*bad)
        with pytest.raises(ValueError, match="same N markers"):
            estimate_gesture(*bad, SENSOR.gel_center_px, SENSOR)
        with pytest.raises(ValueError, match="same N markers"):
            estimate_gel_motion(*bad, rim, SENSOR.gel_center_px)
    with pytest.raises(ValueError, match="rim"):
        estimate_gel_motion(rest, cur, valid, rim[:-1], SENSOR.gel_center_px)
