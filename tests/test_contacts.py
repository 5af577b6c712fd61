"""Contact point detection on hand-made displacement fields (paper, "Contact Point Detection")."""

from __future__ import annotations

import numpy as np
import pytest

from neurotouch_hid.core.sensor import SensorGeometry
from neurotouch_hid.pipeline import contacts_held
from neurotouch_hid.pipeline.contacts import (
    _maxima,
    detect_contacts,
    local_maxima,
    outlier_candidates,
)
from neurotouch_hid.pipeline.contacts_bump import maxima_pushed_out
from neurotouch_hid.pipeline.contacts_held import HELD_PEAK_SHARE
from neurotouch_hid.pipeline.contacts_plateau import _valid_table, rest_neighbours
from neurotouch_hid.pipeline.contacts_refine import refine_peak
from neurotouch_hid.pipeline.paper import paper_contacts

SENSOR = SensorGeometry()
#: A lone-marker fraction that takes no marker for a mistracked one (a marker would have to be
#: displaced 100 times its neighbours' median): these narrow hand-made bumps' peak markers stand
#: well above their neighbours, and the lone-marker rule is not what their tests test.
NO_SPIKES = 0.01


def grid(spacing: float = 10.0) -> np.ndarray:
    """Markers on a square grid (4 mm at 2.5 px/mm) inside the gel disc, image px."""
    k = np.arange(-8, 9) * spacing
    pts = np.stack(np.meshgrid(k, k), axis=-1).reshape(-1, 2) + np.asarray(SENSOR.gel_center_px)
    return pts[SENSOR.inside_gel(pts, margin_px=-3.0)]


def bump(rest: np.ndarray, centre, direction, sigma: float = 12.0) -> np.ndarray:
    """A finger's local deformation: a Gaussian displacement centred on ``centre``."""
    w = np.exp(-np.sum((rest - np.asarray(centre)) ** 2, axis=1) / (2 * sigma**2))
    return w[:, None] * np.asarray(direction, dtype=float)


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


def three_finger_push(noise_px: float = 0.15, seed: int = 0):
    """Three fingers on a line, 35 px (14 mm) apart, pushing hard together: their blended
    falloffs carry the gel between them as one flat top (the displacement saturates at the
    fingers'), ~3.3 fingertip footprints pi (25 px)^2 wide, as deep 3-finger flat tops are on the
    simulated gels (1.1 a finger), with tracker noise on it. Returns rest, current, the fingers'
    current positions."""
    rest = grid()
    c = np.asarray(SENSOR.gel_center_px, dtype=float)
    fingers = c + np.array([[-25.0, -25.0], [0.0, 0.0], [25.0, 25.0]])
    reach = 1.5 * sum(np.exp(-np.sum((rest - f) ** 2, axis=1) / (2 * 22.0**2)) for f in fingers)
    direction = np.array([8.0, -6.0])
    rng = np.random.default_rng(seed)
    cur = rest + np.minimum(reach, 1.0)[:, None] * direction + rng.normal(0.0, noise_px, rest.shape)
    return rest, cur, fingers + direction


def test_a_flat_top_of_three_fingers_gives_three_contacts_on_them_not_random_maxima():
    # the paper's rule: any marker of the plateau may be the largest within r
    # in the noise, so the flat top yields maxima at random places, not three contacts on the fingers
    old_counts, old_errors = [], []
    for seed in range(5):
        rest, cur, fingers = three_finger_push(seed=seed)
        old = paper_contacts(rest, cur, r_px=25.0, n_min=12)
        new = detect_contacts(rest, cur, r_px=25.0, n_min=12, refine_px=20.0, plateau_fraction=0.8)
        old_counts.append(old.count)
        if old.count:
            old_errors.append(np.mean([np.min(np.linalg.norm(fingers - p, axis=1)) for p in old.points_px]))
        assert new.count == 3
        error = [np.min(np.linalg.norm(fingers - p, axis=1)) for p in new.points_px]
        assert max(error) < 10.0  # within one marker pitch of a finger
        assert sorted(np.argmin(np.linalg.norm(fingers[None] - new.points_px[:, None], axis=2), axis=1)) == [0, 1, 2]
    assert sum(n != 3 for n in old_counts) >= 3  # the paper's rule miscounts most of them
    assert not old_errors or np.mean(old_errors) > 10.0


def test_three_deep_fingertips_give_three_contacts_not_a_finger_count_per_footprint():
    # three fingers pinch deep: each presses a flat disc of radius 26 px, wider than a fingertip's
    # footprint pi r^2 (r = 25 px), so the area rule alone reads each as two fingers (six
    # contacts); a gesture has at most three fingers, so each flat top is one contact, on its disc
    rest = grid()
    c = np.asarray(SENSOR.gel_center_px, dtype=float)
    cur, fingers = rest.copy(), []
    for k in range(3):
        toward = -np.array([np.cos(2 * np.pi * k / 3 + 0.3), np.sin(2 * np.pi * k / 3 + 0.3)])
        centre = c - 45.0 * toward
        d = np.linalg.norm(rest - centre, axis=1)
        cur += np.where(d <= 26.0, 1.0, np.exp(-((d - 26.0) ** 2) / (2 * 6.0**2)))[:, None] * (6.0 * toward)
        fingers.append(centre + 6.0 * toward)
    cur += np.random.default_rng(0).normal(0.0, 0.05, cur.shape)
    found = detect_contacts(rest, cur, r_px=25.0, n_min=12, refine_px=20.0, plateau_fraction=0.8)
    assert found.count == 3
    nearest = np.linalg.norm(np.asarray(fingers)[None] - found.points_px[:, None], axis=2)
    assert sorted(np.argmin(nearest, axis=1)) == [0, 1, 2]  # one contact on each finger
    assert nearest.min(axis=1).max() < 26.0  # on its flat disc


def pressed_discs(rest, centres, radii_px, depths_px, falloff_px):
    """Fingertips pressing flat discs (``radii_px``) into the gel, each carrying its disc by its
    depth (px, straight down the image) and falling off as a Gaussian of ``falloff_px`` outside;
    where two overlap the deeper wins. Returns the current positions, with tracker noise."""
    d = np.linalg.norm(rest[:, None] - np.asarray(centres)[None], axis=2)
    radii = np.asarray(radii_px)
    fall = np.where(d <= radii, 1.0, np.exp(-((d - radii) ** 2) / (2 * falloff_px**2)))
    magnitude = (fall * np.asarray(depths_px)).max(axis=1)
    return rest + magnitude[:, None] * [0.0, 1.0] + np.random.default_rng(0).normal(0.0, 0.05, rest.shape)


def assert_one_contact_on_each(found, fingers_px, within_px):
    """As many contacts as fingers, one on each, every one within ``within_px`` of its finger."""
    assert found.count == len(fingers_px)
    nearest = np.linalg.norm(np.asarray(fingers_px)[None] - found.points_px[:, None], axis=2)
    assert sorted(np.argmin(nearest, axis=1)) == list(range(len(fingers_px)))
    assert nearest.min(axis=1).max() < within_px


def test_two_deep_fingertips_pressed_together_give_two_contacts_though_their_flat_top_spans_more():
    # two fingers push deep side by side, 44 px apart: each presses a flat disc of radius 27 px, and
    # their one flat top covers more than two fingertip footprints pi r^2 (r = 25 px), which one
    # finger per footprint would read as three; a deep fingertip's flat top is wider than its
    # footprint, so one finger per 1.25 footprints reads two, one on each disc
    rest = grid()
    fingers = np.asarray(SENSOR.gel_center_px, dtype=float) + np.array([[-22.0, 0.0], [22.0, 0.0]])
    cur = pressed_discs(rest, fingers, radii_px=(27.0, 27.0), depths_px=(6.0, 6.0), falloff_px=4.0)
    flat = np.linalg.norm(cur - rest, axis=1) >= 0.8 * 6.0
    assert 2.0 < flat.sum() * 10.0**2 / (np.pi * 25.0**2) < 2.5  # footprints: three by one per footprint
    found = detect_contacts(rest, cur, r_px=25.0, n_min=12, refine_px=20.0, plateau_fraction=0.8)
    assert_one_contact_on_each(found, fingers + [0.0, 6.0], within_px=12.0)


def test_a_weaker_finger_s_flat_top_does_not_take_in_a_stronger_finger_s():
    # a deep narrow fingertip (6 px, disc of 12 px) and a weaker wide one (4.8 px, disc of 22 px)
    # 40 px apart: at the weaker one's level (0.8 x 4.8 px) the gel joins them, and its flat top
    # took in the stronger one's markers: its area read two fingers, one placed on the stronger
    # finger (two contacts there); a flat top ends where a stronger maximum's begins
    rest = grid()
    fingers = np.asarray(SENSOR.gel_center_px, dtype=float) + np.array([[-20.0, 0.0], [20.0, 0.0]])
    cur = pressed_discs(rest, fingers, radii_px=(12.0, 22.0), depths_px=(6.0, 4.8), falloff_px=8.0)
    found = detect_contacts(rest, cur, r_px=25.0, n_min=12, refine_px=20.0, plateau_fraction=0.8)
    assert_one_contact_on_each(found, fingers + [0.0, 6.0], within_px=10.0)


@pytest.mark.parametrize(("apart_px", "ratio"), [(40.0, 0.4), (35.0, 0.6)])
def test_a_weaker_finger_s_flat_top_does_not_climb_a_stronger_finger_s_slope(apart_px, ratio):
    # a strong finger (15 px) and a weaker one (0.4 / 0.6 of it) 40 / 35 px apart: the weaker
    # maximum's level (0.8 of its own) takes in the ring of the stronger finger's slope outside
    # the stronger's flat top, which is higher than the weaker maximum itself; read as the weaker
    # one's flat top, that ring made two more contacts on the stronger finger, or put both contacts
    # there. A weaker maximum's flat top holds no marker displaced more than the maximum.
    rest = grid()
    c = np.asarray(SENSOR.gel_center_px, dtype=float)
    fingers = c + np.array([[-apart_px / 2, 0.0], [apart_px / 2, 0.0]])
    noise = np.random.default_rng(0).normal(0.0, 0.05, rest.shape)
    cur = rest + bump(rest, fingers[0], (0.0, 15.0)) + bump(rest, fingers[1], (0.0, 15.0 * ratio)) + noise
    found = detect_contacts(rest, cur, r_px=25.0, n_min=12, refine_px=20.0, plateau_fraction=0.8)
    assert_one_contact_on_each(found, fingers + [[0.0, 15.0], [0.0, 15.0 * ratio]], within_px=5.0)


def test_three_fingertips_in_a_row_give_three_contacts_whatever_the_flat_top_s_area():
    # three fingertips side by side, 24 px apart, push down together: one flat top about 60 px
    # long and 12 px wide, whose area is less than one fingertip footprint pi r^2 (r = 25 px), so
    # the area alone reads one finger; a flat top three times as long as wide is three in a row
    rest = grid()
    c = np.asarray(SENSOR.gel_center_px, dtype=float)
    fingers = c + np.array([[-24.0, 6.0], [0.0, 6.0], [24.0, 6.0]])
    along = np.clip(rest[:, 0] - c[0], -24.0, 24.0)  # each marker's nearest point on the row
    d = np.hypot(rest[:, 0] - (c[0] + along), rest[:, 1] - c[1])
    fall = np.where(d <= 6.0, 1.0, np.exp(-((d - 6.0) ** 2) / (2 * 7.0**2)))
    cur = rest + fall[:, None] * [0.0, 6.0] + np.random.default_rng(0).normal(0.0, 0.05, rest.shape)
    found = detect_contacts(rest, cur, r_px=25.0, n_min=12, refine_px=20.0, plateau_fraction=0.8)
    assert found.count == 3
    np.testing.assert_allclose(np.sort(found.points_px[:, 0]), fingers[:, 0], atol=6.0)  # along the row
    np.testing.assert_allclose(found.points_px[:, 1], fingers[:, 1], atol=2.0)


def test_maxima_on_one_stuck_disc_merge_into_its_centre():
    # a stuck contact disc (Cattaneo-Mindlin) carries the gel under it rigidly: a plateau of
    # radius 16 px, falling off outside; two maxima (tracker noise) on its rim, more than r apart,
    # are one contact, at its centre
    rest = grid()
    centre = np.asarray(SENSOR.gel_center_px, dtype=float) + [5.0, 0.0]
    d = np.linalg.norm(rest - centre, axis=1)
    fall = np.where(d <= 16.0, 1.0, np.exp(-((d - 16.0) ** 2) / (2 * 10.0**2)))
    cur = rest + fall[:, None] * [6.0, 0.0]
    on_disc = np.flatnonzero(d <= 16.0)
    far = [on_disc[np.argmin(rest[on_disc, 0])], on_disc[np.argmax(rest[on_disc, 0])]]  # its left and right ends
    assert np.linalg.norm(rest[far[0]] - rest[far[1]]) > 25.0
    cur[far] += [0.2, 0.0]
    old = paper_contacts(rest, cur, r_px=25.0, n_min=4)
    new = detect_contacts(rest, cur, r_px=25.0, n_min=4, refine_px=20.0, plateau_fraction=0.8)
    assert old.count >= 2 or np.linalg.norm(old.points_px[0] - (centre + [6.0, 0.0])) > 5.0
    assert new.count == 1
    assert np.linalg.norm(new.points_px[0] - (centre + [6.0, 0.0])) < 3.0


def flat_top(rest: np.ndarray, radius_px: float, axes=(1.0, 1.0), peak_px: float = 6.0) -> np.ndarray:
    """Current positions of a flat top of the displacement field at the gel's centre: ``peak_px``
    along x (5 % less at its rim), ``radius_px`` across, stretched by ``axes`` (x, y), falling off
    outside as a Gaussian of 10 px."""
    c = np.asarray(SENSOR.gel_center_px, dtype=float)
    d = np.hypot((rest[:, 0] - c[0]) / axes[0], (rest[:, 1] - c[1]) / axes[1])
    fall = np.where(d <= radius_px, 1.0 - 0.05 * d / radius_px, 0.95 * np.exp(-((d - radius_px) ** 2) / 200.0))
    return rest + fall[:, None] * [peak_px, 0.0]


def test_a_round_flat_top_read_as_two_is_one_fingertip_unless_its_press_was_long():
    # one fingertip pressed deep makes a round flat top of 1.25-2.5 footprints, whose area reads
    # two fingers; two fingertips pressed deep together make one as round, but their press made
    # a long one first (docs/method.md, "Contacts")
    rest = grid()
    options = dict(r_px=25.0, n_min=12, refine_px=20.0, plateau_fraction=0.8)
    round_top = flat_top(rest, 26.0)
    by_area = detect_contacts(rest, round_top, **options)  # a window alone: read by its area
    deep = detect_contacts(rest, round_top, **options, long_before=False)
    assert by_area.count == 2 and detect_contacts(rest, round_top, **options, long_before=True).count == 2
    assert deep.count == 1
    np.testing.assert_allclose(deep.points_px[0], np.asarray(SENSOR.gel_center_px) + [6.0, 0.0], atol=3.0)
    assert not by_area.long_flat_top and not deep.long_flat_top
    side_by_side = detect_contacts(rest, flat_top(rest, 24.0, axes=(1.6, 1.0)), **options, long_before=False)
    assert side_by_side.long_flat_top and side_by_side.count == 2
    small = detect_contacts(rest, flat_top(rest, 10.0, axes=(1.6, 1.0)), **options)
    assert not small.long_flat_top  # long, but less than a footprint


def test_a_plateau_rule_leaves_a_finger_peak_and_two_separate_fingers_alone():
    rest = grid()
    centre = np.asarray(SENSOR.gel_center_px, dtype=float) + [3.0, -3.0]
    cur = rest + bump(rest, centre, (6.0, -3.0))
    one = detect_contacts(rest, cur, r_px=30.0, n_min=4, refine_px=15.0, spike_fraction=NO_SPIKES)
    assert one.count == 1 and np.linalg.norm(one.points_px[0] - (centre + [6.0, -3.0])) < 1.0
    c1, c2 = np.array([143.0, 130.0]), np.array([203.0, 130.0])
    cur = rest + bump(rest, c1, (5.0, 0.0)) + bump(rest, c2, (-5.0, 0.0))
    two = detect_contacts(rest, cur, r_px=30.0, n_min=4)
    np.testing.assert_array_equal(np.sort(two.indices), np.sort(paper_contacts(rest, cur).indices))


def test_a_pinch_that_brings_two_fingers_within_r_keeps_two_contacts_with_neighbourhoods_at_rest():
    # two fingers 60 px apart on the gel pinch 20 px each: their contact markers end 20 px apart
    # in the image, closer than r = 25 px, so the paper's N(i) (current positions) holds both and
    # only the stronger is a maximum; on the gel (rest positions) they stay 60 px apart
    rest = grid()
    c = np.asarray(SENSOR.gel_center_px, dtype=float)
    left, right = c + [-30.0, 0.0], c + [30.0, 0.0]
    cur = rest + bump(rest, left, (20.0, 0.0), sigma=10.0) + bump(rest, right, (-19.0, 0.0), sigma=10.0)
    paper = paper_contacts(rest, cur, r_px=25.0, n_min=4)
    on_gel = detect_contacts(rest, cur, r_px=25.0, n_min=4, spike_fraction=NO_SPIKES)
    assert paper.count == 1
    assert on_gel.count == 2
    found = sorted(cur[on_gel.indices, 0])  # the contact markers, each under its finger
    np.testing.assert_allclose(found, [c[0] - 10.0, c[0] + 11.0], atol=1e-6)


def test_a_lone_mistracked_marker_is_no_contact_and_hides_no_finger():
    # one finger (5 px) and, 20 px from it (within r), a marker the tracker pulled 7 px (a hot
    # pixel): the paper's rule takes the lone marker as the contact, which also suppresses the
    # finger's peak; with its neighbours' median instead, the finger is the contact
    rest = grid()
    c = np.asarray(SENSOR.gel_center_px, dtype=float)
    cur = rest + bump(rest, c, (5.0, 0.0))
    lone = int(np.argmin(np.linalg.norm(rest - (c + [20.0, 0.0]), axis=1)))
    cur[lone] += [0.0, 7.0]
    paper = paper_contacts(rest, cur, r_px=25.0, n_min=4)
    despiked = detect_contacts(rest, cur, r_px=25.0, n_min=4, spike_fraction=0.6)
    assert lone in paper.indices.tolist()
    assert np.min(np.linalg.norm(paper.points_px - (c + [5.0, 0.0]), axis=1)) > 5.0
    assert despiked.count == 1
    np.testing.assert_allclose(despiked.points_px[0], c + [5.0, 0.0], atol=1.0)


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
