"""Contact point detection on flat tops of the displacement field (paper, "Contact Point Detection";
docs/method.md): several fingers pushing together, deep fingertips pressing discs, the plateau
rule, a pinch within r, and a lone mistracked marker."""

from __future__ import annotations

import numpy as np
import pytest
from contacts_helpers import NO_SPIKES, SENSOR, assert_one_contact_on_each, bump, grid, three_finger_push

from neurotouch_hid.pipeline.contacts import (
    detect_contacts,
)
from neurotouch_hid.pipeline.paper import paper_contacts


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
