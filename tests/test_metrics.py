"""The evaluation metrics and the label interpolation, on hand-computed cases."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from neurotouch_hid.core.dataset import LabelRow, labels_at
from neurotouch_hid.core.estimate import GESTURE_ORDER, GestureEstimate, GestureType
from neurotouch_hid.core.sensor import SensorGeometry
from neurotouch_hid.evaluation.metrics import (
    Observations,
    accuracy,
    accuracy_by_bin,
    align,
    balanced_confusion_matrix,
    confusion_matrix,
    contact_distances,
    evaluate,
    mean_absolute_error,
    outside_collar,
    outside_resting_collar,
    precision_recall_f1,
)

PUSH, NONE, PINCH = GestureType.PUSH, GestureType.NONE, GestureType.PINCH


def _pts(*xy):
    return np.array(xy, dtype=np.float64).reshape(-1, 2)


# --- labels at prediction times ---------------------------------------------------------
def test_labels_at_interpolates_contacts_and_intensity_between_frames():
    labels = [
        LabelRow(0, PUSH, False, 1.0, _pts((10, 20))),
        LabelRow(100, PUSH, False, 3.0, _pts((20, 40))),
    ]
    before, quarter, at_second, after = labels_at(labels, np.array([-5, 25, 100, 150]))
    assert before is None
    assert quarter.t_us == 25 and quarter.gesture is PUSH and not quarter.resting
    assert quarter.intensity_mm == pytest.approx(1.5)
    np.testing.assert_allclose(quarter.contacts_px, [[12.5, 25.0]])
    assert at_second.intensity_mm == pytest.approx(3.0)
    np.testing.assert_allclose(at_second.contacts_px, [[20, 40]])
    # after the last label: its values as they are
    assert after.intensity_mm == pytest.approx(3.0)
    np.testing.assert_allclose(after.contacts_px, [[20, 40]])


def test_labels_at_takes_type_flag_count_from_most_recent_and_points_only_when_counts_match():
    labels = [
        LabelRow(0, NONE, True, 0.0, _pts()),
        LabelRow(100, PINCH, False, 2.0, _pts((10, 10))),
        LabelRow(200, PINCH, False, 4.0, _pts((10, 10), (50, 50))),
    ]
    (a, b) = labels_at(labels, np.array([60, 150]))
    # none -> pinch: type, flag, count of the earlier frame; intensity still interpolated
    assert a.gesture is NONE and a.resting and a.n_contacts == 0
    assert a.intensity_mm == pytest.approx(1.2)
    # 1 contact -> 2 contacts: the most recent frame's points, not interpolated
    assert b.gesture is PINCH and b.n_contacts == 1
    np.testing.assert_allclose(b.contacts_px, [[10, 10]])
    assert b.intensity_mm == pytest.approx(3.0)


# --- classification -------------------------------------------------------------------------
def test_confusion_precision_recall_f1_by_hand():
    y_true = np.array([0, 0, 0, 1, 1, 2])
    y_pred = np.array([0, 0, 1, 1, 2, 2])
    counts = confusion_matrix(y_true, y_pred, 3)
    np.testing.assert_array_equal(counts, [[2, 1, 0], [0, 1, 1], [0, 0, 1]])
    p, r, f1 = precision_recall_f1(counts)
    np.testing.assert_allclose(p, [1.0, 0.5, 0.5])
    np.testing.assert_allclose(r, [2 / 3, 0.5, 1.0])
    np.testing.assert_allclose(f1, [0.8, 0.5, 2 / 3])
    assert accuracy(y_true, y_pred) == pytest.approx(4 / 6)


def test_precision_undefined_for_never_predicted_class_and_f1_zero_when_all_wrong():
    counts = confusion_matrix(np.array([0, 1]), np.array([1, 0]), 3)
    p, r, f1 = precision_recall_f1(counts)
    np.testing.assert_allclose(p[:2], [0, 0])
    np.testing.assert_allclose(f1[:2], [0, 0])
    assert math.isnan(p[2]) and math.isnan(r[2]) and math.isnan(f1[2])


def test_confusion_matrix_rejects_unknown_class():
    with pytest.raises(ValueError):
        confusion_matrix(np.array([0, 3]), np.array([0, 0]), 3)


def test_balanced_confusion_matrix_by_hand_with_empty_row_and_column():
    counts = np.array([[2, 1, 0, 0], [0, 1, 1, 0], [0, 0, 1, 0], [0, 0, 0, 0]])
    balanced = balanced_confusion_matrix(counts)
    expected = np.array([[5 / 6, 5 / 12, 0, 0], [0, 0.5, 0.5, 0], [0, 0, 0.75, 0], [0, 0, 0, 0]])
    np.testing.assert_allclose(balanced, expected)
    assert np.isfinite(balanced).all()


# --- contact distance, intensity, bins ------------------------------------------------------
def test_contact_distances_drop_the_furthest_surplus_predictions():
    predicted = _pts((0, 0), (10, 0), (0, 3))
    truth = _pts((0, 4), (1, 0))
    # nearest: (0,0)->1, (10,0)->9, (0,3)->1; two ground-truth points keep the two nearest
    np.testing.assert_allclose(contact_distances(predicted, truth), [1.0, 1.0])


def test_contact_distances_fewer_predictions_and_empty_sides():
    np.testing.assert_allclose(contact_distances(_pts((3, 4)), _pts((0, 0), (10, 10))), [5.0])
    assert contact_distances(_pts(), _pts((0, 0))).size == 0
    assert contact_distances(_pts((0, 0)), _pts()).size == 0


def test_mean_absolute_error_and_empty():
    assert mean_absolute_error(np.array([1.0, 2.0]), np.array([2.0, 0.0])) == pytest.approx(1.5)
    assert math.isnan(mean_absolute_error(np.array([]), np.array([])))


def test_accuracy_by_bin_uses_06_mm_bins_and_marks_empty_bins():
    edges, acc, count = accuracy_by_bin(np.array([0.1, 0.5, 0.7, 1.9]), np.array([True, False, True, True]))
    np.testing.assert_allclose(edges, [0, 0.6, 1.2, 1.8, 2.4])
    np.testing.assert_array_equal(count, [2, 1, 0, 1])
    np.testing.assert_allclose(acc[[0, 1, 3]], [0.5, 1.0, 1.0])
    assert math.isnan(acc[2])


# --- align + evaluate -----------------------------------------------------------------------
@pytest.fixture()
def small_case():
    sensor = SensorGeometry(px_per_mm=2.5)
    labels = [
        LabelRow(0, NONE, True, 0.0, _pts()),
        LabelRow(100, PUSH, False, 2.0, _pts((173, 130))),
        LabelRow(200, PUSH, False, 4.0, _pts((183, 130))),
    ]
    predictions = [
        GestureEstimate(t_us=-10),
        GestureEstimate(t_us=50, gesture=NONE, resting=True),
        # truth at 150: push, contact (178, 130), intensity 3.0
        GestureEstimate(
            t_us=150, gesture=PUSH, resting=False, intensity_mm=2.5, contacts_px=_pts((178, 135), (300, 130))
        ),
        # truth at 250: push, contact (183, 130), intensity 4.0
        GestureEstimate(t_us=250, gesture=PINCH, resting=True, intensity_mm=5.0, contacts_px=_pts((183, 137.5))),
    ]
    return sensor, labels, predictions


def test_evaluate_small_sequence_by_hand(small_case):
    result = evaluate(align(small_case[1], small_case[2], small_case[0]))
    assert (result.n_predictions, result.n_skipped, result.n_observations) == (4, 1, 3)
    assert result.n_gesture_observations == 2
    assert result.gesture_accuracy == pytest.approx(2 / 3)
    assert result.contact_count_accuracy == pytest.approx(2 / 3)
    # 5 px = 2 mm and 7.5 px = 3 mm; the 122 px surplus prediction is dropped
    assert result.n_contact_pairs == 2
    assert result.contact_distance_mm == pytest.approx(2.5)
    assert result.intensity_mae_mm == pytest.approx(0.75)
    # resting truth [T, F, F], predicted [T, F, T]
    assert result.resting_precision == pytest.approx(0.5)
    assert result.resting_recall == pytest.approx(1.0)
    assert result.resting_f1 == pytest.approx(2 / 3)
    push = GESTURE_ORDER.index(PUSH)
    none = GESTURE_ORDER.index(NONE)
    assert result.contact_distance_by_gesture_mm[push] == pytest.approx(2.5)
    assert result.intensity_mae_by_gesture_mm[push] == pytest.approx(0.75)
    assert math.isnan(result.intensity_mae_by_gesture_mm[none])
    assert result.confusion[push, GESTURE_ORDER.index(PINCH)] == 1
    # intensities 3.0 (type right, count wrong) and 4.0 (type wrong, count right)
    assert result.n_by_intensity.sum() == 2
    assert result.gesture_accuracy_by_intensity[5] == 1.0 and result.gesture_accuracy_by_intensity[6] == 0.0
    assert result.contact_count_accuracy_by_intensity[5] == 0.0 and result.contact_count_accuracy_by_intensity[6] == 1.0


def test_observations_concatenate_and_result_is_json(small_case):
    sensor, labels, predictions = small_case
    one = align(labels, predictions, sensor)
    both = Observations.concatenate([one, one])
    assert len(both) == 6 and both.n_skipped == 2 and both.n_sequences == 2
    result = evaluate(both)
    assert result.gesture_accuracy == pytest.approx(2 / 3)
    data = json.loads(json.dumps(result.to_dict(), allow_nan=False))
    assert data["classes"] == [g.value for g in GESTURE_ORDER]
    assert data["intensity_mae_by_gesture_mm"][0] is None
    assert len(data["balanced_confusion"]) == len(GESTURE_ORDER)
    assert Observations.concatenate([]).n_sequences == 0


# --- resting outside the collar -------------------------------------------------------------
def test_resting_collar_leaves_out_predictions_within_40_ms_of_each_flag_change():
    # frames every 40 ms: rest, rest, pressed from 80 ms, rest again from 200 ms
    label_t = np.array([0, 40_000, 80_000, 120_000, 160_000, 200_000, 240_000, 280_000])
    label_rest = np.array([1, 1, 0, 0, 0, 1, 1, 1], dtype=bool)
    t = np.arange(0, 300_001, 10_000)
    kept = outside_resting_collar(label_t, label_rest, t)
    left_out = set(t[~kept].tolist())
    # [80 - 40, 80 + 40] and [200 - 40, 200 + 40] ms, ends included
    assert left_out == set(range(40_000, 120_001, 10_000)) | set(range(160_000, 240_001, 10_000))
    # a flag that never changes has no collar; a wider collar takes more
    assert outside_resting_collar(label_t, np.ones(8, dtype=bool), t).all()
    assert not outside_resting_collar(label_t, label_rest, t, collar_us=200_000).any()
    with pytest.raises(ValueError):
        outside_resting_collar(label_t, label_rest[:3], t)


def test_a_collar_about_a_labelled_type_counts_a_change_from_one_type_to_another():
    # none, push from 100 ms, pinch from 200 ms (no rest between), none from 300 ms
    label_t = np.array([0, 100_000, 200_000, 300_000, 400_000])
    label_type = np.array([-1, 0, 1, 1, -1])
    t = np.arange(0, 400_001, 10_000)
    left_out = set(t[~outside_collar(label_t, label_type, t, 40_000)].tolist())
    expected = {u for c in (100_000, 200_000, 400_000) for u in range(c - 40_000, c + 40_001, 10_000)}
    assert left_out == expected & set(t.tolist())


def test_collared_resting_f1_scores_only_predictions_outside_the_collar():
    sensor = SensorGeometry(px_per_mm=2.5)
    labels = [
        LabelRow(0, NONE, True, 0.0, _pts()),
        LabelRow(100_000, PUSH, False, 1.0, _pts((173, 130))),
        LabelRow(200_000, PUSH, False, 2.0, _pts((173, 130))),
        LabelRow(300_000, NONE, True, 0.0, _pts()),
    ]
    # the pipeline sees the press 30 ms late and its end 20 ms late: wrong only inside the collar
    predictions = [
        GestureEstimate(t_us=t, gesture=NONE, resting=not (130_000 <= t < 320_000)) for t in range(0, 400_001, 10_000)
    ]
    result = evaluate(align(labels, predictions, sensor))
    # raw: truth resting at 0-90 and 300-400 ms (21 windows), predicted resting at 0-120 and
    # 320-400 ms (22 windows), 19 of them right
    assert result.resting_precision == pytest.approx(19 / 22)
    assert result.resting_recall == pytest.approx(19 / 21)
    # outside the collar (60-140 and 260-340 ms left out) every answer is right
    assert result.resting_collared_precision == pytest.approx(1.0)
    assert result.resting_collared_recall == pytest.approx(1.0)
    assert result.resting_collared_f1 == pytest.approx(1.0)
    # a miss outside the collar counts
    predictions[20] = GestureEstimate(t_us=200_000, gesture=NONE, resting=True)
    missed = evaluate(align(labels, predictions, sensor))
    assert missed.resting_collared_precision < 1.0


# --- gesture type and contact count outside their collars -----------------------------------
def test_gesture_and_count_accuracy_outside_their_collars_leave_out_40_ms_about_each_labelled_change():
    sensor = SensorGeometry(px_per_mm=2.5)
    # none; push on one contact from 100 ms; pinch on two contacts from 200 ms (no rest between);
    # at 260 ms the pinch's labels count three contacts; none from 300 ms
    labels = [
        LabelRow(0, NONE, True, 0.0, _pts()),
        LabelRow(100_000, PUSH, False, 1.0, _pts((173, 130))),
        LabelRow(200_000, PINCH, False, 1.0, _pts((160, 130), (186, 130))),
        LabelRow(260_000, PINCH, False, 1.5, _pts((160, 130), (186, 130), (173, 140))),
        LabelRow(300_000, NONE, True, 0.0, _pts()),
    ]

    def answer(t: int) -> GestureEstimate:
        # each type answered 30 ms late; the count two contacts from 230 ms on
        kind = NONE if t < 130_000 else PUSH if t < 230_000 else PINCH if t < 330_000 else NONE
        n = 0 if kind is NONE else 1 if t < 230_000 else 2
        return GestureEstimate(t_us=t, gesture=kind, resting=kind is NONE, contacts_px=_pts(*[(173, 130)] * n))

    result = evaluate(align(labels, [answer(t) for t in range(0, 400_001, 10_000)], sensor))
    # 41 windows; the type is wrong at 100-120, 200-220 and 300-320 ms: 9 windows
    assert result.gesture_accuracy == pytest.approx(32 / 41)
    # outside 60-140, 160-240, 260-340 ms (the type's changes at 100, 200, 300 ms) all right:
    # 41 - 27 = 14 windows scored
    assert result.gesture_collared_accuracy == pytest.approx(1.0)
    # the count is wrong at 100-120 (0 for 1), 200-220 (1 for 2), 260-290 (2 for 3) and
    # 300-320 (2 for 0) ms: 13 windows
    assert result.contact_count_accuracy == pytest.approx(28 / 41)
    # the count's changes at 100, 200, 260, 300 ms leave out 60-340 ms but 150 ms: of the
    # windows scored (0-50, 150, 350-400 ms: 13) all right
    assert result.contact_count_collared_accuracy == pytest.approx(1.0)
    push = GESTURE_ORDER.index(PUSH)
    assert result.contact_count_collared_accuracy_by_gesture[push] == pytest.approx(1.0)  # the 150 ms window
    assert math.isnan(result.contact_count_collared_accuracy_by_gesture[GESTURE_ORDER.index(PINCH)])
