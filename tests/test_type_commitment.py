"""The type commitment of a gesture (docs/method.md, "Episode vote"): the first felt window
carries the gesture's type, and a short tap is recognised with it."""

from __future__ import annotations

import math

import numpy as np
import pytest
from pipeline_helpers import SENSOR, _WindowByWindow, events_at, gel_image

from neurotouch_hid.core.estimate import GestureEstimate, GestureType
from neurotouch_hid.evaluation.felt import DEFAULT_DEADZONE_MM
from neurotouch_hid.mapping.profile import available_profiles, load_profile
from neurotouch_hid.pipeline.episode import FIRM_MM, PROVISIONAL_MM, QUIET_LEAD_US, EpisodeVote
from neurotouch_hid.pipeline.pipeline import GesturePipeline, PipelineConfig
from neurotouch_hid.sources import Frame

P, Q, N = GestureType.PUSH, GestureType.PINCH, GestureType.NONE
NEVER_RESTING = PipelineConfig(resting={"centroid_threshold_mm2": -1.0})  # only the events decide


@pytest.fixture(scope="module")
def rest_image() -> np.ndarray:
    return gel_image()


def _run(frames_of, n_windows: int, cls: type = GesturePipeline, wait: bool = True) -> list[GestureEstimate]:
    """Each 10 ms window's estimate when the markers sit at ``frames_of(k, rest)`` in window k
    (``wait``: :meth:`GesturePipeline.set_type_wait`)."""
    pipeline = cls(SENSOR, NEVER_RESTING)
    pipeline.set_type_wait(wait)
    pipeline.process(Frame(0, gel_image()))
    pipeline.process(events_at(1))
    rest = pipeline.rest_px
    out = []
    for k in range(n_windows):
        pipeline.tracker.reset(frames_of(k, rest))
        (estimate,) = pipeline.process(events_at(15000 + 10000 * k))
        out.append(estimate)
    return out


def _bump(rest: np.ndarray, at_px) -> np.ndarray:
    """(N, 1) weight of a finger's bump of displacement centred at ``at_px`` (12 px sigma)."""
    return np.exp(-np.sum((rest - np.asarray(at_px)) ** 2, axis=1) / (2 * 12.0**2))[:, None]


def _pinch(lag_windows: int, n_windows: int, peak_px: float = 8.0, ramp_windows: int = 4):
    """A two-finger pinch along x whose second finger lands ``lag_windows`` windows after the first;
    each finger's displacement ramps up over ``ramp_windows`` windows and holds."""
    c = np.asarray(SENSOR.gel_center_px)

    def frames_of(k: int, rest: np.ndarray) -> np.ndarray:
        first = peak_px * min(1.0, (k + 1) / ramp_windows)
        second = peak_px * min(1.0, max(0, k + 1 - lag_windows) / ramp_windows)
        return rest + _bump(rest, c + [-15.0, 0.0]) * [first, 0.0] - _bump(rest, c + [15.0, 0.0]) * [second, 0.0]

    return frames_of


def test_a_second_finger_60_ms_late_shows_no_push_above_the_dead_zone(rest_image):
    """The first finger alone for 60 ms: the window-by-window rule (which the earlier vote
    followed at onset) answers push above the default profile's dead zone before the pinch; the
    commitment waits, and the first window it answers is the pinch."""
    plain = _run(_pinch(6, 14), 14, _WindowByWindow)
    felt_push = [e for e in plain if e.gesture is P and e.intensity_mm >= DEFAULT_DEADZONE_MM]
    assert felt_push, "the hand-made case must show the failure of the window-by-window rule"
    first_pinch = next(k for k, e in enumerate(plain) if e.gesture is Q)
    assert first_pinch >= 5 and plain[first_pinch].n_contacts == 2

    committed = _run(_pinch(6, 14), 14)
    assert not [e for e in committed if e.gesture not in (N, Q) and e.intensity_mm >= PROVISIONAL_MM]
    assert [e.gesture for e in committed[:first_pinch] if e.intensity_mm >= PROVISIONAL_MM] == [N] * len(
        [e for e in committed[:first_pinch] if e.intensity_mm >= PROVISIONAL_MM]
    )
    assert committed[first_pinch].gesture is Q  # no latency added once the second finger is seen
    assert max(e.intensity_mm for e in committed[:first_pinch]) >= DEFAULT_DEADZONE_MM  # pending, not still


def test_the_first_finger_is_answered_at_once_only_while_too_weak_to_be_felt(rest_image):
    """A slow pinch (a 120 ms ramp) whose second finger lands 30 ms late: its first windows, below the
    provisional limit, answer the first finger's own type at once (the onset is not delayed);
    from the limit on the answer waits (``none``) until the second finger commits the pinch, so no
    window a profile could map shows another type."""
    committed = _run(_pinch(3, 20, peak_px=4.0, ramp_windows=12), 20)
    moving = [e for e in committed if e.intensity_mm > 0]
    first_pinch = next(k for k, e in enumerate(committed) if e.gesture is Q)
    early = committed[:first_pinch]
    assert moving[0].gesture is P and moving[0].intensity_mm < PROVISIONAL_MM  # answered at once
    assert [e for e in early if e.intensity_mm >= PROVISIONAL_MM], "the case must cross the limit undecided"
    assert all(e.gesture is N for e in early if e.intensity_mm >= PROVISIONAL_MM)
    assert all(e.gesture is P for e in early if 0 < e.intensity_mm < PROVISIONAL_MM)
    assert all(e.gesture is Q for e in committed[first_pinch:])


def test_no_shipped_profile_maps_a_provisional_answer():
    """Every dead zone and press threshold of the shipped profiles is at or above the limit below
    which an undecided window answers its first finger's type: no built-in profile feels it."""
    for name, path in available_profiles().items():
        for key, mapping in load_profile(path).mappings.items():
            for field in ("deadzone_mm", "press_mm"):
                value = getattr(mapping, field, None)
                assert value is None or value >= PROVISIONAL_MM, f"{name}: {key}.{field} = {value}"


def test_a_quarter_second_tap_is_recognised_with_its_type(rest_image):
    """25 windows (0.25 s): a one-finger push tap is committed push within the tap, after the
    wait for a second finger (a window short of it: its field is one finger's); a two-finger pinch
    tap is pinch from its first window."""
    c = np.asarray(SENSOR.gel_center_px)

    def push_tap(k: int, rest: np.ndarray) -> np.ndarray:
        return rest + _bump(rest, c) * [6.0 * min(1.0, (k + 1) / 5, (25 - k) / 5), 0.0]

    estimates = _run(push_tap, 25)
    push = [e.gesture for e in estimates]
    assert set(push) == {N, P}
    onset = next(k for k, e in enumerate(estimates) if e.intensity_mm > 0)  # the gel moved: undecided
    first = push.index(P)
    assert (first - onset) * 10_000 == EpisodeVote().first_finger_us - QUIET_LEAD_US  # as soon as the wait ends
    end = max(k for k, e in enumerate(estimates) if e.intensity_mm > 0) + 1  # then the gel is still
    assert end >= 20 and push[first:end] == [P] * (end - first)

    pinch = [e.gesture for e in _run(_pinch(0, 25, peak_px=6.0), 25)]
    assert pinch == [Q] * 25


def test_one_contact_stays_undecided_for_the_first_finger_time_and_a_count_change_restarts_it():
    vote = EpisodeVote(first_finger_us=30_000)
    assert [vote.update(P, 1.0, 1, t) for t in (10_000, 20_000, 30_000)] == [N, N, N]
    assert vote.update(P, 1.0, 1, 40_000) is P  # one contact held 30 ms: committed push
    vote.update(N, 0.0, 0, 50_000)
    assert [vote.update(P, 1.0, 0, 60_000), vote.update(P, 1.0, 1, 70_000)] == [N, N]
    assert vote.update(P, 1.0, 1, 90_000) is N  # held 20 ms since the count became 1
    assert vote.update(P, 1.0, 1, 100_000) is P


def test_an_undecided_window_below_the_provisional_limit_answers_its_own_type():
    vote = EpisodeVote(first_finger_us=30_000, provisional_mm=0.4)
    assert vote.update(P, 0.2, 1, 10_000) is P  # too weak for any profile: answered at once
    assert vote.update(P, 0.6, 1, 20_000) is N  # strong enough to be felt: undecided
    assert vote.update(P, 0.3, 1, 30_000) is P
    assert vote.update(Q, 0.5, 2, 40_000) is Q  # the second finger commits its own type
    assert vote.update(P, 0.1, 2, 50_000) is Q  # committed: the limit no longer applies


def test_the_commitment_is_the_vote_since_the_contact_count_last_changed():
    """Votes cast on fewer contacts while undecided do not count: two contacts commit their own
    type even after a long heavy push on one."""
    vote = EpisodeVote()
    assert vote.update(P, 3.0, 1, 10_000) is N
    assert vote.update(Q, 0.2, 2, 20_000) is Q


def test_once_committed_a_window_that_sees_several_fingers_outweighs_one_that_sees_one():
    """A held three-finger twist whose contacts merge into one window after window: the one-contact
    windows read push, deeper than the twist of the three-contact ones. Counted once each, the
    push outweighs the twist after two of them; a window that sees several fingers votes twice
    from ``counted_mm`` on, and the twist stays. Below it each window counts once."""
    T = GestureType.TWIST_CW
    held = [(T, 4.5, 3), (T, 4.5, 3), (P, 7.5, 1), (T, 4.5, 3), (P, 7.5, 1), (T, 4.5, 3), (P, 7.5, 1)]

    def answers(vote: EpisodeVote, windows) -> list[GestureType]:
        return [vote.update(g, mm, n, 10_000 * (k + 1)) for k, (g, mm, n) in enumerate(windows)]

    assert answers(EpisodeVote(), held) == [T] * 7
    assert answers(EpisodeVote(counted_mm=math.inf, firm_mm=1e9), held)[4] is P  # every window once: push felt
    # a push's attack read as a zoom under a flickering light, two contacts below counted_mm
    attack = [(GestureType.ZOOM, 0.5, 2), (GestureType.ZOOM, 0.5, 2), (P, 1.2, 1)]
    assert answers(EpisodeVote(), attack)[2] is P
    assert answers(EpisodeVote(counted_mm=0.0), attack)[2] is GestureType.ZOOM


def test_a_new_press_of_another_type_in_the_last_ones_tail_is_a_new_gesture():
    """A deep twist held long, then released on a creeping gel: its tail is still read as the
    twist (a committed episode with no ``none`` window), and a pinch begins in it. The pinch's
    windows are outvoted by the hold's for as long as the pinch lasts, unless a window of another
    type that sees two contacts and rises ``REPRESS_MM`` above the tail's lowest, once below half
    the peak, begins a new episode. A tail's wobble, the same type pressed again, another type read
    in the hold or on one contact leaves the episode as it is."""
    T = GestureType.TWIST_CW

    def answers(windows) -> list[GestureType]:
        vote = EpisodeVote()
        return [vote.update(g, mm, n, 10_000 * (k + 1)) for k, (g, mm, n) in enumerate(windows)]

    hold = [(T, 0.5, 2), (T, 2.0, 2)] + [(T, 3.7, 2)] * 100
    tail = [(T, 1.2, 2), (T, 0.9, 2), (T, 0.7, 2), (T, 0.6, 2)]  # below half the peak
    pinch = [(Q, 0.81, 2), (Q, 0.94, 2), (Q, 1.2, 2), (Q, 2.0, 2)]
    assert answers(hold + tail + pinch)[-4:] == [T, Q, Q, Q]  # 0.34 mm above the tail's 0.6 mm
    wobble = [(Q, 0.81, 2), (Q, 0.85, 2), (Q, 0.7, 2), (Q, 0.75, 2)]  # at most 0.25 mm above the tail's lowest
    assert answers(hold + tail + wobble)[-4:] == [T] * 4
    assert answers(hold + tail + [(T, 1.2, 2), (T, 2.0, 2)])[-2:] == [T, T]  # the twist pressed again
    assert answers(hold + [(Q, 3.4, 2), (Q, 3.8, 2)])[-2:] == [T, T]  # another type read in the hold
    # one contact: its intensity jumps where fingers merge (a zoom's release read 0.81 mm on three
    # contacts, then 1.13 on one), so it begins nothing
    assert answers(hold + tail + [(P, 0.95, 1), (P, 1.2, 1)])[-2:] == [T, T]


def test_the_pipeline_settings_set_the_vote_and_an_override_changes_its_wait(rest_image):
    """The wait is a setting of ``PipelineConfig.episode`` (a per-user model may override it): the
    same one-finger push tap is answered push after the default wait, and after 50 ms with a
    setting that says so."""
    c = np.asarray(SENSOR.gel_center_px)

    def push_tap(k: int, rest: np.ndarray) -> np.ndarray:
        return rest + _bump(rest, c) * [6.0 * min(1.0, (k + 1) / 5, (25 - k) / 5), 0.0]

    def first_push(config: PipelineConfig) -> int:
        pipeline = GesturePipeline(SENSOR, config)
        pipeline.process(Frame(0, gel_image()))
        pipeline.process(events_at(1))
        rest = pipeline.rest_px
        answers = []
        for k in range(25):
            pipeline.tracker.reset(push_tap(k, rest))
            (estimate,) = pipeline.process(events_at(15000 + 10000 * k))
            answers.append(estimate.gesture)
        return answers.index(P)

    default = first_push(NEVER_RESTING)
    shorter = first_push(PipelineConfig(resting=NEVER_RESTING.resting, episode={"first_finger_us": 50_000}))
    assert (default - shorter) * 10_000 == EpisodeVote().first_finger_us - 50_000
    with pytest.raises(ValueError):
        PipelineConfig(episode={"first_finger_us": -1})


def test_a_pinch_with_one_finger_at_the_apex_is_felt_as_a_pinch_not_a_push_after_the_wait(rest_image):
    """Two fingers 15 mm apart pinching, the stronger at the gel's centre, the other at 0.6 of
    its strength: the contact maxima see one finger, a second bump finds the other, so the
    episode commits the pinch on two contacts instead of answering push when the one-contact wait
    runs out, and it stays a pinch through the hold."""
    c = np.asarray(SENSOR.gel_center_px)

    def apex_pinch(k: int, rest: np.ndarray) -> np.ndarray:
        level = 6.0 * min(1.0, (k + 1) / 6)
        return rest + _bump(rest, c) * [level, 0.0] - _bump(rest, c + [37.5, 0.0]) * [0.6 * level, 0.0]

    estimates = _run(apex_pinch, 30)
    felt = [e for e in estimates if e.intensity_mm >= PROVISIONAL_MM]
    assert felt and all(e.gesture in (N, Q) for e in felt)
    assert [e.gesture for e in estimates[10:]] == [Q] * 20
    assert all(e.n_contacts == 2 for e in estimates[10:])


def test_a_firm_type_does_not_flip_for_a_single_window():
    """A twist held at 4-9 mm: one window of push inside it, whether read in the committed episode
    (a correction to more contacts) or after one ``none`` window restarted the episode (two
    contacts commit their own type at once), is answered twist; two windows in a row of another
    type change the answer from the second. Below ``FIRM_MM`` the first window changes it, as before."""
    T = GestureType.TWIST_CW

    def answers(windows, vote=None) -> list[GestureType]:
        vote = vote or EpisodeVote()
        return [vote.update(g, mm, n, 10_000 * (k + 1)) for k, (g, mm, n) in enumerate(windows)]

    start = [(T, 0.5, 2), (T, 2.5, 2), (T, 5.0, 2)]
    # within the correction time: three contacts, push, answered at once before
    corrected = start + [(P, 6.0, 3), (T, 6.0, 2), (T, 6.0, 2)]
    assert answers(corrected) == [T] * 6
    assert answers(corrected, EpisodeVote(firm_mm=1e9))[3] is P  # without it: the flip
    # 790 ms in: one window of nothing restarts the episode, then push on two contacts
    restarted = start + [(T, 8.0, 2)] * 76 + [(N, 0.0, 0), (P, 8.5, 2), (T, 8.0, 2), (T, 8.0, 2)]
    got = answers(restarted)
    assert got[-4:] == [N, T, T, T]
    # without it: push on two contacts not seen the window before waits (undecided), and another
    # type there flips at once
    assert answers(restarted, EpisodeVote(firm_mm=1e9))[-3] is N
    pinched = start + [(T, 8.0, 2)] * 76 + [(N, 0.0, 0), (Q, 8.5, 2), (T, 8.0, 2), (T, 8.0, 2)]
    assert answers(pinched)[-4:] == [N, T, T, T]
    assert answers(pinched, EpisodeVote(firm_mm=1e9))[-3] is Q
    # a real change, two windows in a row: answered from the second, one window later
    changed = start + [(T, 5.0, 2)] * 20 + [(N, 0.0, 0), (P, 5.0, 2), (P, 5.0, 2), (P, 5.0, 2)]
    assert answers(changed)[-3:] == [T, P, P]
    # below FIRM_MM nothing changes: the correction answers push at once
    weak = [(T, 0.5, 2), (T, 1.0, 2), (P, 1.5, 3), (T, 1.5, 2)]
    assert answers(weak)[2] is P and 1.5 < FIRM_MM
    # a type answered only below FIRM_MM is not firm: a fast push tap's attack read pinch on three
    # contacts at 0.6 mm, then push at 2.8 mm, is answered push at once
    tap = [(Q, 0.62, 3), (P, 2.77, 1), (P, 3.3, 1)]
    assert answers(tap) == [Q, P, P]


def test_a_finger_found_late_in_a_slow_attack_nobody_felt_restarts_the_vote():
    """A slow twist whose second finger presses 0.44 s after the first: the first finger alone
    reads push on one contact (committed after the wait, never at a dead zone). When the second
    finger is found, the one-contact votes no longer count, so the twist is answered as soon as
    it outweighs the push read on two contacts, not after it outweighs 0.4 s of push. Once a
    window of the episode has reached ``COUNTED_MM`` (felt), past the correction time, the
    votes stand as before."""
    T = GestureType.TWIST_CCW
    alone = [(P, 0.1 + 0.015 * k, 1) for k in range(44)]  # 0.1 -> 0.75 mm in 0.44 s
    found = [(P, 0.75, 2)] + [(T, 0.76 + 0.002 * k, 2) for k in range(16)]

    def answers(windows) -> list[GestureType]:
        vote = EpisodeVote()
        return [vote.update(g, mm, n, 10_000 * (k + 1)) for k, (g, mm, n) in enumerate(windows)]

    got = answers(alone + found)
    assert got[43] is P and got[44] is P  # the push so far, then the first window on two contacts
    assert got[45:] == [T] * 16  # the twist outweighs the 0.75 mm of push on two contacts at once
    felt = [(P, 0.1 + 0.02 * k, 1) for k in range(44)]  # the same to 0.96 mm: felt
    assert answers(felt + [(P, 0.97, 2)] + [(T, 0.98 + 0.002 * k, 2) for k in range(16)])[45] is P


def test_a_finger_just_found_and_missed_for_one_window_keeps_its_type():
    """A twist on `fingers` seen by a turned camera (test user 3's session): its first finger
    alone reads push on one contact, committed after the wait; the second finger is found at
    0.50 mm (twist, two contacts: the correction), missed in the next window (push at 1.30 mm on
    one contact) and found again. The missed window does not vote: the twist holds. Later than one
    APS frame period after the correction, fewer contacts vote again as before."""
    T = GestureType.TWIST_CW
    alone = [(P, mm, 1) for mm in (0.23, 0.28, 0.32, 0.33, 0.5, 0.49, 0.5, 0.55, 0.83, 0.81, 0.75, 0.87, 1.17)]
    found = [(T, 0.5, 2), (P, 1.3, 1), (T, 0.46, 2), (T, 0.96, 2), (T, 0.95, 2)]

    def answers(windows) -> list[GestureType]:
        vote = EpisodeVote()
        return [vote.update(g, mm, n, 10_000 * (k + 1)) for k, (g, mm, n) in enumerate(windows)]

    got = answers(alone + found)
    assert got[12] is P  # committed on the first finger alone
    assert got[13:] == [T] * 5  # found, missed for a window, found again: twist throughout
    # one contact again more than 40 ms after the finger was found votes: push outweighs
    later = alone + [(T, 0.5, 2)] + [(T, 0.5, 2)] * 4 + [(P, 1.3, 1)] * 3
    assert answers(later)[-1] is P


def test_a_weak_window_on_several_contacts_commits_nothing():
    """A twist whose attack's first window reads push at 0.19 mm on three contacts (the count of a
    gel that has barely moved, ``PROVISIONAL_MM``), then push on its first finger alone: the weak
    window answers its vote (nothing a profile maps) but commits no type, so the lone finger waits
    and the twist is answered from the window that sees two fingers. Before, the weak window
    committed push at once and the lone finger's push was felt for 30 ms."""
    T = GestureType.TWIST_CCW
    windows = [(P, 0.19, 3), (P, 0.80, 1), (P, 1.39, 1), (P, 1.96, 1), (T, 1.76, 2), (T, 2.12, 2)]
    vote = EpisodeVote()
    got = [vote.update(g, mm, n, 10_000 * (k + 1)) for k, (g, mm, n) in enumerate(windows)]
    assert 0.19 < PROVISIONAL_MM
    assert got == [P, N, N, N, T, T]


def test_once_several_fingers_are_felt_one_contact_of_another_type_casts_no_vote():
    """A twist committed on two contacts at 0.9 mm (felt), then four windows on one contact read
    push, deeper: a multi-finger gesture shows one contact when a finger is missed or fingers merge,
    never the reverse, so they answer the twist and do not vote. Committed on two contacts below
    ``COUNTED_MM`` (a flickering attack's count), one contact votes as before."""
    W = GestureType.TWIST_CW
    windows = [(W, 0.90, 2), (P, 1.61, 1), (P, 1.67, 1), (P, 1.79, 1), (P, 1.71, 1), (W, 1.73, 2)]
    vote = EpisodeVote()
    assert [vote.update(g, mm, n, 10_000 * (k + 1)) for k, (g, mm, n) in enumerate(windows)] == [W] * 6
    weak = [(W, 0.60, 2), (P, 1.61, 1), (P, 1.67, 1)]
    vote = EpisodeVote()
    assert [vote.update(g, mm, n, 10_000 * (k + 1)) for k, (g, mm, n) in enumerate(weak)] == [W, P, P]


def test_without_the_type_wait_one_finger_is_answered_at_once(rest_image):
    """The same quarter-second push tap under a profile that reads no difference between the types
    the wait tells apart (``GesturePipeline.set_type_wait(False)``): from the provisional limit on
    every window answers a type (committed at once: the vote so far, then push), none undecided;
    the wait set back on waits again."""
    c = np.asarray(SENSOR.gel_center_px)

    def push_tap(k: int, rest: np.ndarray) -> np.ndarray:
        return rest + _bump(rest, c) * [6.0 * min(1.0, (k + 1) / 5, (25 - k) / 5), 0.0]

    at_once = _run(push_tap, 25, wait=False)
    felt = [e.gesture for e in at_once if e.intensity_mm >= PROVISIONAL_MM]
    assert len(felt) >= 15 and N not in felt and felt[-1] is P
    waited = _run(push_tap, 25, wait=True)
    assert N in [e.gesture for e in waited if e.intensity_mm >= PROVISIONAL_MM]


def test_push_on_contacts_the_window_before_did_not_see_waits_a_window():
    """A twist whose fingers slide together for a moment at its start: a window reads push on three
    contacts (the slide), the next ones push on the lone first finger, then the twist on two. The
    push on three contacts not seen the window before commits nothing (before, it committed push
    at 5.4 mm, felt for 110 ms); the twist is answered from its first window. A two-finger push
    seen on two contacts twice in a row is push from the second; after ``first_finger_us`` a
    count that keeps changing no longer holds it back."""
    C = GestureType.TWIST_CCW
    slide = [(P, 2.9, 1), (P, 4.8, 3), (P, 4.7, 1), (P, 5.0, 1), (P, 5.3, 2), (P, 6.5, 1), (P, 7.6, 1), (C, 4.8, 2)]
    vote = EpisodeVote()
    got = [vote.update(g, mm, n, 10_000 * (k + 1)) for k, (g, mm, n) in enumerate(slide + [(C, 5.2, 2)] * 3)]
    assert got == [N] * 7 + [C] * 4
    vote = EpisodeVote()
    assert [vote.update(P, mm, 2, 10_000 * (k + 1)) for k, mm in enumerate((0.9, 1.5, 2.0))] == [N, P, P]
    vote = EpisodeVote()
    flicker = [vote.update(P, 1.5, 1 + k % 2, 10_000 * (k + 1)) for k in range(12)]
    assert flicker[-1] is P and flicker.index(P) * 10_000 <= EpisodeVote().first_finger_us


def test_the_one_contact_wait_runs_from_the_onset_whatever_the_weak_windows_counted():
    """A fast push under a flickering light: its first windows, below ``PROVISIONAL_MM``, read
    pinch on three and two contacts (the spurious count of a gel that has barely moved), then push
    on one contact from 0.98 mm. The weak windows' count is not trusted, so it does not restart the
    one-contact wait: push is committed ``first_finger_us`` after the onset (before, after its
    first window at or above the limit: 20 ms later, and a push whose weak windows lasted 40 ms
    waited 40 ms more). A count change among trusted windows still restarts it."""
    Q = GestureType.PINCH
    windows = [(Q, 0.12, 3), (Q, 0.34, 2)] + [(P, 0.98 + 0.45 * k, 1) for k in range(12)]
    vote = EpisodeVote()
    wait = vote.first_finger_us
    got = [vote.update(g, mm, n, 10_000 * k) for k, (g, mm, n) in enumerate(windows)]
    assert got[:2] == [Q, Q]  # too weak to be felt: the vote so far
    committed = got.index(P, 2)
    assert committed * 10_000 == wait and N not in got[committed:]
    vote = EpisodeVote()
    trusted = [(P, 0.9, 2), (P, 1.2, 1)] + [(P, 1.5, 1)] * 12
    got = [vote.update(g, mm, n, 10_000 * k) for k, (g, mm, n) in enumerate(trusted)]
    assert got[0] is N and got.index(P, 1) * 10_000 == 10_000 + wait
