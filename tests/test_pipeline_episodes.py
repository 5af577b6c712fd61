"""GesturePipeline over a gesture's windows: the episode vote keeping one type, a lagging finger
waited for, the one correction, and what a press holds from window to window (docs/method.md)."""

from __future__ import annotations

import numpy as np
import pipeline_helpers
from pipeline_helpers import SENSOR, _WindowByWindow, events_at, gel_image

from neurotouch_hid.core.estimate import GestureType
from neurotouch_hid.pipeline.episode import EpisodeVote
from neurotouch_hid.pipeline.pipeline import GesturePipeline, PipelineConfig
from neurotouch_hid.sources import Frame

rest_image = pipeline_helpers.rest_image  # a shared fixture, found by pytest under this name


def _push_then_pinch(config: PipelineConfig, rest_image, cls: type = GesturePipeline) -> list[GestureType]:
    """A two-finger pinch whose first finger leads: two weak windows where only one finger
    moved (a push), then six strong pinch windows, then a last weak window in which one finger
    lingers (a push again). Returns each window's gesture type."""
    pipeline = cls(SENSOR, config)
    pipeline.process(Frame(0, rest_image))
    pipeline.process(events_at(1))
    rest = pipeline.rest_px
    c = np.asarray(SENSOR.gel_center_px)
    f1, f2 = c + [-15.0, 0.0], c + [15.0, 0.0]
    w1 = np.exp(-np.sum((rest - f1) ** 2, axis=1) / (2 * 12.0**2))
    w2 = np.exp(-np.sum((rest - f2) ** 2, axis=1) / (2 * 12.0**2))
    frames = [rest + w1[:, None] * [3.0, 0.0]] * 2 + [rest + w1[:, None] * [8.0, 0.0] - w2[:, None] * [8.0, 0.0]] * 6
    frames += [rest + w1[:, None] * [3.0, 0.0]]
    types = []
    for k, moved in enumerate(frames):
        pipeline.tracker.reset(moved)
        (estimate,) = pipeline.process(events_at(15000 + 10000 * k))
        types.append(estimate.gesture)
    return types


def test_episode_vote_keeps_one_type_over_a_gesture_where_windows_flip(rest_image):
    """The window-by-window rule (paper) reads the lingering finger at the end as push; the
    episode vote answers pinch once the pinch outweighs the push, and keeps it."""
    base = dict(resting={"centroid_threshold_mm2": -1.0})  # never resting: only the events decide
    plain = _push_then_pinch(PipelineConfig(**base), rest_image, _WindowByWindow)
    voted = _push_then_pinch(PipelineConfig(**base), rest_image)
    P, Q = GestureType.PUSH, GestureType.PINCH
    assert plain[:2] == [P, P] and plain[2:8] == [Q] * 6 and plain[8] is P
    assert voted[:2] == [GestureType.NONE] * 2  # one contact for 10 ms: undecided
    assert voted[2:] == [Q] * 7  # committed on two contacts; the weak push at the end does not outweigh


def _lagging_pinch(
    config: PipelineConfig, rest_image: np.ndarray, cls: type = GesturePipeline
) -> list[tuple[GestureType, int]]:
    """A pinch whose first finger leads: six windows of that finger alone (a one-contact push),
    then the second finger moves towards it for five. Returns each window's (type, contacts)."""
    pipeline = cls(SENSOR, config)
    pipeline.process(Frame(0, rest_image))
    pipeline.process(events_at(1))
    rest = pipeline.rest_px
    c = np.asarray(SENSOR.gel_center_px)
    w1 = np.exp(-np.sum((rest - (c + [-15.0, 0.0])) ** 2, axis=1) / (2 * 12.0**2))[:, None]
    w2 = np.exp(-np.sum((rest - (c + [15.0, 0.0])) ** 2, axis=1) / (2 * 12.0**2))[:, None]
    frames = [rest + w1 * [k, 0.0] for k in (2.0, 4.0, 6.0, 8.0, 8.0)]
    frames += [rest + w1 * [8.0, 0.0] - w2 * [m, 0.0] for m in (4.0, 6.0, 8.0, 8.0, 8.0, 8.0)]
    out = []
    for k, moved in enumerate(frames):
        pipeline.tracker.reset(moved)
        (estimate,) = pipeline.process(events_at(15000 + 10000 * k))
        out.append((estimate.gesture, len(estimate.contacts_px)))
    return out


def test_a_lagging_finger_is_waited_for_and_the_pinch_committed_once_its_second_contact_is_seen(rest_image):
    """The first finger alone for 40 ms leaves the episode undecided (``none``); the pinch is
    answered from the window that sees the second contact on, as the window-by-window rule does."""
    base = dict(resting={"centroid_threshold_mm2": -1.0})
    plain = _lagging_pinch(PipelineConfig(**base), rest_image, _WindowByWindow)
    first_pinch = next(k for k, (g, _) in enumerate(plain) if g is GestureType.PINCH)
    assert {g for g, _ in plain[:first_pinch]} == {GestureType.PUSH}
    assert {n for _, n in plain[:first_pinch]} == {1} and plain[first_pinch][1] == 2
    assert {g for g, _ in plain[first_pinch:]} == {GestureType.PINCH}
    voted = _lagging_pinch(PipelineConfig(**base), rest_image)
    assert [g for g, _ in voted] == [GestureType.NONE] * first_pinch + [g for g, _ in plain[first_pinch:]]


def test_the_one_correction_needs_more_contacts_than_before_and_comes_once():
    """Correction rule of ``EpisodeVote``: a push committed on two contacts is kept against a
    pinch window with two; a third contact, within the correction time, is answered at once; a
    second correction is not taken, nor one after the correction time."""
    P, Q, Z, T = GestureType.PUSH, GestureType.PINCH, GestureType.ZOOM, GestureType.TWIST_CW
    vote = EpisodeVote()
    # (push on two contacts commits from the second window that sees them: test_type_commitment.py)
    got = [vote.update(P, 5.0, 2, 10_000), vote.update(P, 5.0, 2, 20_000), vote.update(Q, 1.0, 2, 30_000)]
    assert got == [GestureType.NONE, P, P]
    assert vote.update(Q, 1.0, 3, 40_000) is Q and vote.update(P, 0.5, 3, 50_000) is Q  # the 10 mm of push are gone
    assert vote.update(T, 0.5, 4, 60_000) is Q  # a second correction is not taken
    vote.update(GestureType.NONE, 0.0, 0, 70_000)
    assert vote.update(Z, 5.0, 2, 200_000) is Z
    assert vote.update(T, 1.0, 3, 200_000 + vote.correction_us + 10_000) is Z  # too late to correct


def test_a_press_remembers_a_long_flat_top_until_it_ends(rest_image):
    """Two fingertips side by side make a long flat top, then pressed deep a round one that reads
    as one fingertip alone: the press keeps them two. A window without a gesture ends the press,
    and the next press's round flat top is one fingertip (docs/method.md, "Contacts")."""
    pipeline = _WindowByWindow(SENSOR)
    pipeline.process(Frame(0, rest_image))
    pipeline.process(Frame(40_000, gel_image((4.0, 0.0), region_px=30)))
    pipeline.process(events_at(41_000))  # the windows start
    rest, c = pipeline.rest_px, np.asarray(SENSOR.gel_center_px, dtype=float)

    def flat_top(radius_px: float, long: float = 1.0) -> np.ndarray:
        d = np.hypot((rest[:, 0] - c[0]) / long, rest[:, 1] - c[1])
        fall = np.where(d <= radius_px, 1.0 - 0.05 * d / radius_px, 0.95 * np.exp(-((d - radius_px) ** 2) / 200.0))
        return rest + fall[:, None] * [6.0, 0.0]

    counts = []
    for t_us, current in enumerate((flat_top(24.0, 1.6), flat_top(26.0), rest + 0.1, flat_top(26.0))):
        pipeline.tracker.reset(current)
        (estimate,) = pipeline.process(events_at(51_000 + 10_000 * t_us))
        counts.append((estimate.gesture is GestureType.NONE, len(estimate.contacts_px)))
    assert counts == [(False, 2), (False, 2), (True, 0), (False, 1)]


def test_a_press_hands_each_window_s_held_maxima_to_the_next_until_it_ends(rest_image, monkeypatch):
    """The maxima a window holds (:attr:`Contacts.held`) reach the next window of the same press,
    whether its fit is computed or reused, and no window after the press ends (docs/method.md,
    "Contacts": a finger held where the homography follows it)."""
    from neurotouch_hid.pipeline import fit_path

    heard, said, real = [], [], fit_path.detect_contacts

    def detect(*args, **kwargs):
        heard.append(kwargs["held"])
        contacts = real(*args, **kwargs)
        said.append(contacts.held)
        return contacts

    monkeypatch.setattr(fit_path, "detect_contacts", detect)
    pipeline = _WindowByWindow(SENSOR)
    pipeline.process(Frame(0, rest_image))
    pipeline.process(Frame(40_000, gel_image((4.0, 0.0), region_px=30)))
    pipeline.process(events_at(41_000))  # the windows start
    rest, c = pipeline.rest_px, np.asarray(SENSOR.gel_center_px, dtype=float)
    push = rest + np.exp(-np.sum((rest - c) ** 2, axis=1) / 300.0)[:, None] * [6.0, 0.0]
    for k, current in enumerate((push, push + [0.02, 0.0], rest + 0.1, push)):
        pipeline.tracker.reset(current)
        pipeline.process(events_at(51_000 + 10_000 * k))
    assert len(heard) == 3  # the window at rest is no fit
    assert heard[0] is None and heard[2] is None  # a press's first window holds nothing
    assert len(said[0][0]) == 1 and heard[1] is said[0]
