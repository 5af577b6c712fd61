"""family_eval.py's report: beside the five metrics, the contact count per labelled gesture type."""

from __future__ import annotations

import pytest
import typer
from helpers import load_benchmark


@pytest.fixture(scope="module")
def family_eval():
    return load_benchmark("family_eval")


def row(count_by_gesture=None):
    out = {
        "gesture_accuracy": 0.95,
        "contact_count_accuracy": 0.93,
        "contact_distance_mm": 1.0,
        "intensity_mae_mm": 0.1,
        "resting_f1": 0.96,
    }
    if count_by_gesture is not None:
        out["count_by_gesture"] = count_by_gesture
    return out


def test_the_report_gives_the_count_per_gesture_type_and_marks_those_below_92(family_eval):
    per_type = {"push": 0.87, "pinch": 0.974, "zoom": 0.925, "twist_cw": None, "twist_ccw": 0.92}
    lines = family_eval.report({"default/ours": row(per_type), "fingers/ours": row()}, ["default", "fingers"], ["ours"])
    head = lines.index("| family | method | push | pinch | zoom | twist_cw | twist_ccw |")
    assert lines[head + 2] == "| default | ours | 87.00 % * | 97.40 % | 92.50 % | - | 92.00 % |"
    assert lines[head + 3] == "| fingers | ours | - | - | - | - | - |"  # cached before the per-type count


def test_count_by_gesture_reads_the_evaluation_result_without_none(family_eval):
    result = {"contact_count_accuracy_by_gesture": [0.99, 0.8, 0.9, None, 0.95, 0.97]}
    assert family_eval.count_by_gesture(result) == {
        "push": 0.8,
        "pinch": 0.9,
        "zoom": None,
        "twist_cw": 0.95,
        "twist_ccw": 0.97,
    }


def test_the_report_marks_the_dead_zone_latency_against_its_target_and_a_missed_gesture(family_eval):
    felt = {
        "onset_median_ms": 40.0,
        "onset_p90_ms": 120.0,
        "n_gestures": 9,
        "never_recognised": 0,
        "type_changes_per_gesture": 0.1,
        "felt_type_changes_per_gesture": 0.0,
        "felt_wrong_share": 0.0,
        "false_activations": 3,
        "felt_false_activations": 1,
        "n_rest": 58,
        "reached_deadzone": 8,
        "deadzone_latency_median_ms": 11.4,
        "deadzone_latency_p90_ms": 17.5,
        "missed_above_deadzone": 1,
        "resting_collared_f1": 0.9875,
    }
    lines = family_eval.report({"default/ours": {**row(), **felt}}, ["default"], ["ours"])
    head, cells = ([c.strip() for c in line.strip("|").split("|")] for line in (lines[0], lines[2]))
    assert cells[head.index("onset p90 ms")] == "120 *"  # the onset's target is 100 ms
    assert cells[head.index("dead-zone latency median ms")] == "11"  # target 20 ms
    assert cells[head.index("dead-zone latency p90 ms")] == "18"  # target 50 ms
    assert cells[head.index("missed above the dead zone")] == "1 of 8 *"
    assert cells[head.index("false activations")] == "3 of 58 *"  # the target is 0
    assert cells[head.index("false activations past the dead zone")] == "1 of 58"  # no target of its own
    targets = [c.strip() for c in next(line for line in lines if line.startswith("| target")).strip("|").split("|")]
    assert targets[head.index("dead-zone latency p90 ms")] == "50"
    assert cells[head.index("resting F1 outside the collar")] == "98.75 % *"  # the target is 99 %
    assert targets[head.index("resting F1 outside the collar")] == "99 %"
    slow = {**felt, "deadzone_latency_median_ms": 24.0, "deadzone_latency_p90_ms": 80.0}
    lines = family_eval.report({"default/ours": {**row(), **slow}}, ["default"], ["ours"])
    cells = [c.strip() for c in lines[2].strip("|").split("|")]
    assert cells[head.index("dead-zone latency median ms")] == "24 *"
    assert cells[head.index("dead-zone latency p90 ms")] == "80 *"


def test_a_mounted_camera_is_turned_and_moved_and_its_gel_stays_in_the_image(family_eval):
    mounted = family_eval.camera(35.0, "203,105")
    assert (mounted.rotation_deg, mounted.gel_center_px) == (35.0, (203.0, 105.0))
    assert family_eval.camera(-20.0, None).gel_center_px == (173.0, 130.0)  # the image's centre
    with pytest.raises(typer.BadParameter, match="leaves the 346 x 260 image"):
        family_eval.camera(0.0, "300,130")  # the disc's 75 px radius would cross the right edge
    with pytest.raises(typer.BadParameter, match="expected X,Y in px"):
        family_eval.camera(0.0, "203")
