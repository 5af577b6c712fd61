"""A lone contact's field (docs/method.md, "Episode vote"; ``pipeline/counter_drag.py``): one
finger's drag moves the gel nowhere against itself, a second finger dragging another way does, and
a lone contact whose field is one finger's is committed a window before the one-contact wait ends."""

from __future__ import annotations

import numpy as np
import pytest
from pipeline_helpers import SENSOR
from test_type_commitment import _bump, _run

from neurotouch_hid.core.estimate import GestureType
from neurotouch_hid.core.sensor import MARKER_SPACING_MM
from neurotouch_hid.pipeline.counter_drag import counter_drag_mm
from neurotouch_hid.pipeline.episode import PROVISIONAL_MM, QUIET_LEAD_US, QUIET_MM, EpisodeVote
from neurotouch_hid.pipeline.pipeline import GesturePipeline

P, Q, N = GestureType.PUSH, GestureType.PINCH, GestureType.NONE
S = SENSOR.px_per_mm
PITCH = MARKER_SPACING_MM * S


def _grid() -> np.ndarray:
    """(N, 2) markers at rest on a square grid of the marker pitch over the gel (px)."""
    c = np.asarray(SENSOR.gel_center_px)
    k = np.arange(-7, 8) * PITCH
    g = np.stack(np.meshgrid(k, k), axis=-1).reshape(-1, 2)
    return c + g[np.hypot(g[:, 0], g[:, 1]) <= SENSOR.gel_radius_px]


def _counter(rest: np.ndarray, moved: np.ndarray, at) -> float:
    contact = int(np.argmin(np.sum((rest - at) ** 2, axis=1)))
    return counter_drag_mm(rest, moved, np.ones(len(rest), bool), contact, PITCH, S)


def test_one_fingers_drag_moves_nothing_against_it_and_a_second_finger_dragging_back_does():
    """A 4 mm drag with the simulator's Gaussian falloff and with Cerruti's point-load field of an
    incompressible gel (nu = 0.5, regularised over a 2 mm fingertip): nothing moves against it, nor
    with a second finger dragging the same way (a two-finger push). The second finger of a pinch,
    dragging back 0.2 mm (below what the contact step tells from the first's tail), does."""
    rest = _grid()
    c = np.asarray(SENSOR.gel_center_px)
    first, second = c + [-8 * S, 0.0], c + [8 * S, 0.0]
    gauss = rest + _bump(rest, first) * [4.0 * S, 0.0]
    assert _counter(rest, gauss, first) < 0.01
    d = rest - first
    rho = np.sqrt(np.sum(d**2, axis=1) + (2.0 * S) ** 2)
    cerruti = np.stack([0.5 / rho + 0.5 * d[:, 0] ** 2 / rho**3, 0.5 * d[:, 0] * d[:, 1] / rho**3], axis=1)
    cerruti *= 4.0 * S / cerruti[:, 0].max()
    assert _counter(rest, rest + cerruti, first) < 0.01
    both = gauss + _bump(rest, second) * [3.0 * S, 0.0]
    assert _counter(rest, both, first) < 0.01
    pinch = gauss - _bump(rest, second) * [0.2 * S, 0.0]
    assert _counter(rest, pinch, first) >= QUIET_MM
    with pytest.raises(ValueError):
        counter_drag_mm(rest, rest[:-1], np.ones(len(rest), bool), 0, PITCH, S)
    with pytest.raises(ValueError):
        counter_drag_mm(rest, rest, np.ones(len(rest), bool), len(rest), PITCH, S)


def test_a_lone_contact_whose_gel_moves_nowhere_against_it_is_committed_a_window_sooner():
    """One contact read push at 1-5 mm: with the field unread (inf) or showing a second finger
    (``QUIET_MM``) it is committed ``first_finger_us`` after its onset, with a quiet field
    ``QUIET_LEAD_US`` sooner; a count that changes still restarts the wait, and without a wait
    (``first_finger_us=0``) nothing changes."""

    def committed(counter_mm: float, first_finger_us: int | None = None) -> int:
        vote = EpisodeVote() if first_finger_us is None else EpisodeVote(first_finger_us=first_finger_us)
        got = [vote.update(P, 1.0 + 0.4 * k, 1, 10_000 * k, counter_mm) for k in range(14)]
        return got.index(P) * 10_000

    wait = EpisodeVote().first_finger_us
    assert committed(float("inf")) == committed(QUIET_MM) == wait
    assert committed(0.0) == committed(QUIET_MM / 2) == wait - QUIET_LEAD_US
    assert committed(0.0, first_finger_us=0) == 0
    vote = EpisodeVote()
    got = [vote.update(P, 2.0, 1 if k < 5 else 2 if k == 5 else 1, 10_000 * k, 0.0) for k in range(16)]
    assert got.index(P) * 10_000 == 60_000 + wait - QUIET_LEAD_US  # restarted at the 2-contact window and back


def test_the_pipeline_answers_a_lone_push_a_window_sooner_but_not_a_pinch_whose_second_finger_drags_back():
    """Through the pipeline: a one-finger push tap is answered push one window sooner than with
    the field unread. A pinch whose second finger drags back 0.08 mm a window from three windows
    before that (0.24 mm then, not yet a contact of its own) is answered as with the field
    unread: the field shows it, where a field read as quiet would have answered push a window
    sooner."""
    c = np.asarray(SENSOR.gel_center_px)

    def push_tap(k: int, rest: np.ndarray) -> np.ndarray:
        return rest + _bump(rest, c + [-8 * S, 0.0]) * [6.0 * min(1.0, (k + 1) / 5, (25 - k) / 5), 0.0]

    class Unread(GesturePipeline):
        def _counter_drag(self) -> float:
            return float("inf")

    class Quiet(GesturePipeline):
        def _counter_drag(self) -> float:
            return 0.0

    quiet = [e.gesture for e in _run(push_tap, 25)]
    unread = [e.gesture for e in _run(push_tap, 25, Unread)]
    assert (unread.index(P) - quiet.index(P)) * 10_000 == QUIET_LEAD_US
    early = quiet.index(P)

    def late_pinch(k: int, rest: np.ndarray) -> np.ndarray:
        back = 0.08 * S * max(0, k - early + 3)
        return push_tap(k, rest) - _bump(rest, c + [8 * S, 0.0]) * [back, 0.0]

    def answers(cls: type) -> list[GestureType]:
        return [e.gesture if e.intensity_mm >= PROVISIONAL_MM else N for e in _run(late_pinch, early + 2, cls)]

    read = answers(GesturePipeline)
    assert read == answers(Unread) and P not in read[: early + 1]
    assert answers(Quiet)[early] is P  # what the field's reading keeps from the pinch
