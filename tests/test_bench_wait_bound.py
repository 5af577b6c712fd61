"""benchmarks/wait_bound.py: the ideal one-contact wait, on hand-made gestures (1 ms grid) whose
felt figures are worked out by hand, and the seed check against a simulated session's labels."""

from __future__ import annotations

import numpy as np
import pytest
import typer
from helpers import load_benchmark

from neurotouch_hid.core.estimate import GestureType


@pytest.fixture(scope="module")
def wb():
    return load_benchmark("wait_bound")


def ramp(start_ms: int, mm_per_ms: float, n: int = 400) -> np.ndarray:
    """A finger still until ``start_ms``, then pressing ``mm_per_ms`` deeper each ms."""
    return np.clip((np.arange(n) - start_ms) * mm_per_ms, 0.0, None)


def gesture(wb, kind, *fingers):
    depth = np.stack(fingers, axis=1)
    return wb.Gesture(kind, depth, depth.mean(axis=1))


def test_a_lagging_second_finger_is_felt_as_push_unless_the_wait_outlasts_it(wb):
    # first finger seen (0.1 mm) at 10 ms, past the 0.8 mm dead zone at 80 ms; the second seen at 210 ms
    zoom = gesture(wb, GestureType.ZOOM, ramp(0, 0.01), ramp(200, 0.01))
    felt = {w: wb.bound([zoom], 0.1, w, False, 0.8) for w in (90, 250)}
    assert felt[90]["felt_wrong"] == 1.0  # push from 100 ms, the first finger 0.9-2.0 mm until 210
    assert felt[250]["felt_wrong"] == 0.0  # the second finger is seen within the wait
    # the labels' mean, the first finger's 0.01 t halved until 200 ms, reaches 0.8 mm at 160 ms;
    # the zoom is answered when its second finger is seen, at 210 ms
    assert felt[90]["p90"] == 50
    # from the dead zone: the wait starts at 80 ms, 150 ms of it outlast the lag, 100 ms do not
    assert wb.bound([zoom], 0.1, 150, True, 0.8)["felt_wrong"] == 0.0
    assert wb.bound([zoom], 0.1, 100, True, 0.8)["felt_wrong"] == 1.0


def test_a_second_finger_seen_after_the_first_has_left_the_dead_zone_is_not_felt_wrong(wb):
    # the first finger never passes the dead zone before the second is seen: no push felt
    pinch = gesture(wb, GestureType.PINCH, ramp(0, 0.002), ramp(150, 0.01))
    assert wb.bound([pinch], 0.1, 40, False, 0.8)["felt_wrong"] == 0.0


def test_a_push_waits_the_wait_from_where_it_is_counted(wb):
    push = gesture(wb, GestureType.PUSH, ramp(0, 0.02))  # seen at 5 ms, past 0.8 mm at 40 ms
    first = wb.bound([push], 0.1, 60, False, 0.8)
    assert first["median"] == first["push_p90"] == 25  # answered at 65 ms
    deadzone = wb.bound([push], 0.1, 60, True, 0.8)
    assert deadzone["median"] == deadzone["push_p90"] == 60


def test_a_second_finger_never_seen_is_missed_above_the_dead_zone(wb):
    twist = gesture(wb, GestureType.TWIST_CW, ramp(0, 0.02), np.zeros(400))
    result = wb.bound([twist], 0.1, 90, False, 0.4)  # its labels' mean reaches 0.4 mm
    assert result["missed"] == 1 and result["felt_wrong"] == 1.0


def test_sessions_drawn_with_another_seed_are_refused(wb, tmp_path, capsys):
    from neurotouch_hid.sources.sim_dataset import write_dataset

    write_dataset(tmp_path / "default", preset="sessions", seed=1, users=[5], progress=False)
    drawn = wb.session_gestures(tmp_path / "default", "u5_session0", "default", 1)
    assert len(drawn) >= 3 and all(g.fingers_mm.shape[0] == g.label_mm.shape[0] for g in drawn)
    with pytest.raises(typer.Exit) as stop:
        wb.session_gestures(tmp_path / "default", "u5_session0", "default", 3)
    assert stop.value.exit_code == 2 and "--seed" in capsys.readouterr().err
