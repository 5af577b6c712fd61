"""The per-gesture metrics (docs/dataset.md, "Per-gesture metrics") on hand-made labels and
predictions, every expected value worked out by hand in the comments."""

import dataclasses
import math

import numpy as np
import pytest
from test_recognition_failures import uneven_pinch

from neurotouch_hid.core.dataset import LabelRow
from neurotouch_hid.core.estimate import GestureEstimate, GestureType
from neurotouch_hid.core.sensor import SensorGeometry
from neurotouch_hid.evaluation.felt import FeltRecords, gesture_records, gesture_spans, pressed_at, summarise
from neurotouch_hid.evaluation.metrics import align, evaluate
from neurotouch_hid.evaluation.report import felt_rows

G = GestureType
NO_POINTS = np.zeros((0, 2))


def label(t_us: int, gesture: GestureType) -> LabelRow:
    none = gesture is G.NONE
    return LabelRow(t_us, gesture, none, 0.0 if none else 1.0, NO_POINTS)


def labels() -> list[LabelRow]:
    """Frames every 40 ms from 0 to 1.5 s: push at 80-160 ms, pinch at 640-720 ms, zoom at
    1000-1080 ms, none elsewhere."""
    kinds = {80: G.PUSH, 120: G.PUSH, 160: G.PUSH, 640: G.PINCH, 680: G.PINCH, 720: G.PINCH}
    kinds.update({1000: G.ZOOM, 1040: G.ZOOM, 1080: G.ZOOM})
    return [label(ms * 1000, kinds.get(ms, G.NONE)) for ms in range(0, 1501, 40)]


def pred(ms: int, gesture: GestureType, mm: float = 0.0) -> GestureEstimate:
    return GestureEstimate(ms * 1000, gesture, gesture is G.NONE, mm)


def predictions() -> list[GestureEstimate]:
    return [
        pred(0, G.PUSH, 0.3),  # 80 ms before the push: not at rest
        # push, frames 80..160 ms: its predictions are 80 <= t < 200 ms
        pred(80, G.NONE),
        pred(100, G.PUSH, 0.5),  # onset 100 - 80 = 20 ms
        pred(120, G.PINCH, 1.0),  # another type, exactly at a 1.0 mm dead zone
        pred(140, G.PUSH, 1.2),
        pred(160, G.PUSH, 2.0),
        pred(180, G.NONE, 0.3),
        pred(200, G.TWIST_CW, 3.0),  # t1 + 40 ms: no longer the push's
        pred(400, G.NONE),  # 240 ms from both gestures: not at rest
        # pinch, frames 640..720 ms: never a pinch
        pred(640, G.TWIST_CW, 0.5),
        pred(660, G.PUSH, 0.9),
        pred(680, G.NONE),
        pred(700, G.ZOOM, 0.7),
        pred(720, G.ZOOM, 0.79),
        pred(740, G.NONE),
        # zoom, frames 1000..1080 ms
        pred(1000, G.NONE),
        pred(1020, G.NONE),
        pred(1040, G.ZOOM, 1.5),  # onset 40 ms
        pred(1060, G.ZOOM, 2.0),
        pred(1300, G.PUSH, 0.5),  # 220 ms after the zoom's last frame: not at rest
        pred(1400, G.NONE),  # 320 ms: at rest
        pred(1500, G.TWIST_CCW, 0.2),  # 420 ms: at rest, a false activation
    ]


def test_gestures_are_runs_of_one_type():
    rows = [label(0, G.NONE), label(40, G.PUSH), label(80, G.PUSH), label(120, G.PINCH)]
    rows += [label(160, G.NONE), label(200, G.PINCH), label(240, G.PINCH)]
    # push 40-80, then pinch straight after it (a new gesture), then after a none another pinch
    assert gesture_spans(rows) == [(G.PUSH, 40, 80), (G.PINCH, 120, 120), (G.PINCH, 200, 240)]


def test_each_gesture_scored_by_hand():
    rec = gesture_records(labels(), predictions(), deadzone_mm=0.8)
    assert list(rec.gesture) == [1, 2, 3]  # push, pinch, zoom in GESTURE_ORDER
    assert list(rec.duration_ms) == [80.0, 80.0, 80.0]
    # onsets: push 100 - 80; pinch never; zoom 1040 - 1000
    assert rec.onset_ms[0] == 20.0 and math.isnan(rec.onset_ms[1]) and rec.onset_ms[2] == 40.0
    # push answered push, pinch, push, push (the twist at 200 ms is outside): 2 changes;
    # pinch answered twist_cw, push, zoom, zoom: 2; zoom: zoom, zoom: 0
    assert list(rec.changes) == [2, 2, 0]
    # at >= 0.8 mm: push sees pinch 1.0, push 1.2, push 2.0: 1 change; pinch sees push 0.9 alone: 0
    assert list(rec.felt_changes) == [1, 0, 0]
    # felt wrong: push (pinch at 1.0 mm) and pinch (push at 0.9 mm), not zoom
    assert list(rec.felt_wrong) == [True, True, False]
    assert list(rec.wrong_as) == [2, 1, -1]  # pinch, push
    # at rest (> 300 ms from every gesture frame): 1400 and 1500 ms; the one at 1500 is a twist
    assert (rec.n_rest, rec.false_activations) == (2, 1)


def test_summary_by_hand():
    s = summarise(gesture_records(labels(), predictions(), deadzone_mm=0.8))
    assert s.n_gestures == 3
    assert s.onset_median_ms == 30.0  # median of 20 and 40
    assert s.onset_p90_ms == pytest.approx(38.0)  # 20 + 0.9 * (40 - 20), linear interpolation
    assert s.never_recognised == 1
    assert s.type_changes_per_gesture == pytest.approx(4 / 3)  # (2 + 2 + 0) / 3
    assert s.felt_type_changes_per_gesture == pytest.approx(1 / 3)  # (1 + 0 + 0) / 3
    assert s.felt_wrong_share == pytest.approx(2 / 3)
    assert (s.false_activations, s.n_rest) == (1, 2)


def test_the_dead_zone_is_inclusive_and_moves_the_felt_figures():
    at = gesture_records(labels(), predictions(), deadzone_mm=1.0)
    # push: pinch 1.0 counts (at least the dead zone): pinch, push, push -> 1 change, felt wrong
    # pinch: push 0.9 falls below: nothing felt
    assert list(at.felt_changes) == [1, 0, 0] and list(at.felt_wrong) == [True, False, False]
    above = gesture_records(labels(), predictions(), deadzone_mm=1.01)
    # push: only push 1.2 and 2.0 remain: no change, nothing wrong
    assert list(above.felt_changes) == [0, 0, 0] and not above.felt_wrong.any()
    zero = gesture_records(labels(), predictions(), deadzone_mm=0.0)
    # every answer counts: the felt figures equal the plain ones; pinch's first wrong is twist_cw
    assert list(zero.felt_changes) == [2, 2, 0] and list(zero.wrong_as) == [2, 4, -1]


def test_dead_zone_latency_by_hand():
    # the fixture's gestures are labelled 1.0 mm from their first frame: each reaches a 0.8 mm
    # dead zone at t0. push: first push >= 0.8 mm at 140 ms -> 140 - 80 = 60 ms; pinch: no pinch,
    # missed; zoom: zoom 1.5 mm at 1040 ms -> 40 ms
    rec = gesture_records(labels(), predictions(), deadzone_mm=0.8)
    assert list(rec.reaches_deadzone) == [True, True, True]
    assert rec.deadzone_latency_ms[0] == 60.0 and math.isnan(rec.deadzone_latency_ms[1])
    assert rec.deadzone_latency_ms[2] == 40.0
    s = summarise(rec)
    assert (s.reached_deadzone, s.missed_above_deadzone) == (3, 1)
    assert s.deadzone_latency_median_ms == 50.0  # median of 60 and 40
    assert s.deadzone_latency_p90_ms == pytest.approx(58.0)  # 40 + 0.9 * (60 - 40)
    # above every labelled intensity, no gesture reaches the dead zone
    none = summarise(gesture_records(labels(), predictions(), deadzone_mm=1.5))
    assert (none.reached_deadzone, none.missed_above_deadzone) == (0, 0)
    assert math.isnan(none.deadzone_latency_median_ms)


def test_dead_zone_latency_is_counted_from_where_the_labelled_intensity_crosses_it():
    def row(ms, gesture, mm):
        return LabelRow(ms * 1000, gesture, gesture is G.NONE, mm, NO_POINTS)

    rows = [row(0, G.NONE, 0.0), row(40, G.PUSH, 0.2), row(80, G.PUSH, 0.6), row(120, G.PUSH, 1.0)]
    rows += [row(160, G.PUSH, 1.4), row(200, G.NONE, 0.0)]
    rows += [row(240, G.PINCH, 0.3), row(280, G.PINCH, 0.7), row(320, G.NONE, 0.0)]
    # push: 0.8 mm lies halfway between 0.6 mm at 80 ms and 1.0 mm at 120 ms: crossed at 100 ms;
    # its first push at or above 0.8 mm comes at 110 ms (the pinch at 105 ms is another type)
    # pinch: its labels never reach 0.8 mm, so its 0.9 mm answer is no dead-zone latency
    late = [pred(90, G.PUSH, 0.7), pred(105, G.PINCH, 0.9), pred(110, G.PUSH, 0.9), pred(260, G.PINCH, 0.9)]
    rec = gesture_records(rows, late, deadzone_mm=0.8)
    assert list(rec.reaches_deadzone) == [True, False]
    assert rec.deadzone_latency_ms[0] == pytest.approx(10.0) and math.isnan(rec.deadzone_latency_ms[1])
    # an answer at or above the dead zone before the gel gets there counts as negative latency
    early = gesture_records(rows, [pred(95, G.PUSH, 0.85)], deadzone_mm=0.8)
    assert early.deadzone_latency_ms[0] == pytest.approx(-5.0)


def test_a_gesture_s_dead_zone_is_crossed_in_its_own_frames_even_where_another_s_share_a_time():
    """A run of frames is its rows: a pinch frame and a push frame labelled at the same time made
    the push take the pinch's 3 mm frame and reach the dead zone it never reached."""

    def row(ms, gesture, mm):
        return LabelRow(ms * 1000, gesture, gesture is G.NONE, mm, NO_POINTS)

    rows = [row(0, G.NONE, 0.0), row(40, G.PINCH, 1.0), row(80, G.PINCH, 3.0)]
    rows += [row(80, G.PUSH, 0.3), row(120, G.PUSH, 0.3), row(160, G.NONE, 0.0)]
    rec = gesture_records(rows, [pred(60, G.PINCH, 2.0)], deadzone_mm=0.8)
    assert list(rec.reaches_deadzone) == [True, False]  # the push's 0.3 mm frames never reach 0.8 mm
    assert summarise(rec).missed_above_deadzone == 0


def test_false_activations_past_the_dead_zone_are_counted_apart():
    """At rest (> 300 ms from every gesture frame): 1400 ms none, 1450 ms push 0.9 mm, 1500 ms
    twist_ccw 0.2 mm: two false activations; the push is past a 0.8 mm dead zone (mapped), not
    past 1.0 mm; the twist under both."""
    preds = [*predictions()[:-1], pred(1450, G.PUSH, 0.9), predictions()[-1]]
    at_08 = gesture_records(labels(), preds, deadzone_mm=0.8)
    assert (at_08.n_rest, at_08.false_activations, at_08.felt_false_activations) == (3, 2, 1)
    at_10 = summarise(gesture_records(labels(), preds, deadzone_mm=1.0))
    assert (at_10.false_activations, at_10.felt_false_activations) == (2, 0)
    both = FeltRecords.concatenate([at_08, at_08])
    assert (both.false_activations, both.felt_false_activations) == (4, 2)
    rows = dict(felt_rows(evaluate(align(labels(), preds, SensorGeometry(), deadzone_mm=0.8))))
    assert rows["False activations at rest >= 0.8 mm"] == "1 of 3 windows"


def test_a_negative_dead_zone_is_refused():
    with pytest.raises(ValueError, match="dead zone"):
        gesture_records(labels(), predictions(), deadzone_mm=-0.1)


def test_records_of_sequences_add_up():
    one = gesture_records(labels(), predictions())
    both = FeltRecords.concatenate([one, one])
    assert len(both) == 6 and (both.n_rest, both.false_activations) == (4, 2)
    assert summarise(both).felt_wrong_share == pytest.approx(2 / 3)
    with pytest.raises(ValueError, match="dead zones"):
        FeltRecords.concatenate([one, gesture_records(labels(), predictions(), deadzone_mm=1.0)])


def test_eval_reports_them_beside_the_papers_metrics():
    result = evaluate(align(labels(), predictions(), SensorGeometry(), deadzone_mm=0.8))
    assert result.felt.never_recognised == 1
    assert result.to_dict()["felt"]["onset_median_ms"] == 30.0
    rows = dict(felt_rows(result))
    assert rows["Onset latency, median / p90"] == "30 ms / 38 ms"
    assert rows["Never recognised"] == "1 of 3"
    assert rows["Gestures felt wrong (another type >= 0.8 mm)"] == "66.67 %"
    assert rows["False activations at rest (> 300 ms from a gesture)"] == "1 of 2 windows"
    assert rows["Dead-zone latency, median / p90 (the gel past 0.8 mm to the answer past it)"] == "50 ms / 58 ms"
    assert rows["Missed above 0.8 mm (no answer of the type past it)"] == "1 of 3"
    assert result.to_dict()["felt"]["missed_above_deadzone"] == 1


def test_eval_refuses_a_negative_dead_zone_before_running_anything(tmp_path):
    from typer.testing import CliRunner

    from neurotouch_hid.cli import app

    result = CliRunner().invoke(app, ["eval", str(tmp_path), "--deadzone-mm", "-0.5"])
    assert result.exit_code == 2 and "--deadzone-mm" in result.output


def test_a_gesture_whose_fingers_start_apart_is_felt_wrong_only_once_its_last_finger_has_pressed():
    """The push's (80-160 ms) wrong answer, pinch at 1.0 mm, is at 120 ms. The simulation says its
    last finger's gel moved 0.3 mm at 130 ms (the attack began at 60 ms, before the first labelled
    frame): the pinch at 120 ms no longer makes it felt wrong. The pinch (640-720 ms) has its own
    row at 700 ms: its push at 0.9 mm (660 ms) is before it, not felt; no row for the zoom."""
    pressed = [(60_000, 130_000), (640_000, 700_000)]
    rec = gesture_records(labels(), predictions(), deadzone_mm=0.8, pressed=pressed)
    assert list(rec.felt_wrong) == [False, False, False]
    # one ms earlier the pinch at 120 ms counts again; the other figures never depend on the rows
    early = gesture_records(labels(), predictions(), deadzone_mm=0.8, pressed=[(60_000, 120_000)])
    assert list(early.felt_wrong) == [True, True, False]
    plain = gesture_records(labels(), predictions(), deadzone_mm=0.8)
    assert list(rec.felt_changes) == list(plain.felt_changes)
    assert np.array_equal(rec.deadzone_latency_ms, plain.deadzone_latency_ms, equal_nan=True)
    # a row whose attack starts a frame period or more before the gesture's first frame is another's
    assert pressed_at([(40_000, 130_000)], 80_000, 160_000) is None
    assert pressed_at([(41_000, 130_000)], 80_000, 160_000) == 130_000


def test_the_simulation_writes_and_reads_back_when_each_lagging_gesture_s_last_finger_pressed(tmp_path):
    from neurotouch_hid.core.dataset import read_pressed, write_pressed
    from neurotouch_hid.core.errors import DatasetError

    path = tmp_path / "u0_session0.pressed.csv"
    assert read_pressed(path) == []  # a recording has none
    write_pressed(path, [(1_000_000, 1_120_000), (2_000_000, 2_050_000)])
    assert read_pressed(path) == [(1_000_000, 1_120_000), (2_000_000, 2_050_000)]
    path.write_text("t_start_us,pressed_us\n1000,x\n")
    with pytest.raises(DatasetError, match=r":2: column 'pressed_us'"):
        read_pressed(path)
    path.write_text("t_start_us,pressed_us\n1000,900\n")
    with pytest.raises(DatasetError, match=":2: pressed_us before"):
        read_pressed(path)


def test_the_simulator_says_when_the_gel_under_a_lagging_finger_has_moved_03_mm():
    from neurotouch_hid.sources.gel import deform
    from neurotouch_hid.sources.simulator import PRESSED_MM, GelSimulator

    pinch = dataclasses.replace(uneven_pinch(), lags_us=(0, 150_000))  # the second finger starts 150 ms late
    sim = GelSimulator(script=[pinch])
    sim.step()
    pressed = sim.pressed_us(pinch)
    assert pinch.t_start_us + 150_000 < pressed < pinch.t_start_us + pinch.attack_us
    t = np.array([pinch.t_start_us, pressed - 1000, pressed], dtype=np.int64)
    pts = deform([pinch], pinch.fingers_mm, t, sim.sensor.gel_radius_mm)[0]
    moved = np.linalg.norm(pts - pts[:1], axis=-1)  # (3, 2)
    assert moved[1, 1] < PRESSED_MM <= moved[2, 1]  # the second finger's gel, to the ms
    assert moved[1, 0] > PRESSED_MM  # the first's had moved further before
