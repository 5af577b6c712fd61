"""The evaluation report (tables, figures, summary.md) and the `eval` command end to end."""

from __future__ import annotations

import json

import numpy as np
import pytest
from rich.console import Console

from neurotouch_hid.estimate import GestureEstimate, GestureType
from neurotouch_hid.evaluation.dataset import LabelRow
from neurotouch_hid.evaluation.metrics import align, evaluate
from neurotouch_hid.evaluation.report import FIGURES, print_tables, write_report
from neurotouch_hid.sensor import SensorGeometry


@pytest.fixture(scope="module")
def result():
    sensor = SensorGeometry()
    labels = [
        LabelRow(0, GestureType.NONE, True, 0.0, np.zeros((0, 2))),
        LabelRow(100, GestureType.ZOOM, False, 1.0, np.array([[170.0, 130.0], [190.0, 130.0]])),
        LabelRow(200, GestureType.ZOOM, False, 2.0, np.array([[168.0, 130.0], [192.0, 130.0]])),
    ]
    predictions = [
        GestureEstimate(t_us=50),
        GestureEstimate(t_us=150, gesture=GestureType.PUSH, resting=False, intensity_mm=1.0,
                        contacts_px=np.array([[171.0, 131.0]])),
        GestureEstimate(t_us=210, gesture=GestureType.ZOOM, resting=False, intensity_mm=2.5,
                        contacts_px=np.array([[168.0, 131.0], [191.0, 130.0]])),
    ]
    return evaluate(align(labels, predictions, sensor))


def test_print_tables_shows_headline_metrics_beside_the_paper(result):
    console = Console(record=True, width=200)
    print_tables(result, console)
    text = console.export_text()
    assert "Gesture type accuracy" in text and f"{100 * result.gesture_accuracy:.2f} %" in text
    assert "91.12 %" in text  # the paper's figure beside ours
    assert "Balanced confusion matrix" in text and "Zoom" in text
    assert "Accuracy against ground-truth intensity" in text


def test_write_report_writes_figures_and_summary_embedding_them(result, tmp_path):
    summary = write_report(result, tmp_path / "report", command="neurotouch-hid eval X", config={"r_px": 30.0})
    text = summary.read_text()
    for name in FIGURES:
        path = tmp_path / "report" / name
        assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
        assert f"]({name})" in text
    assert "neurotouch-hid eval X" in text and "r_px" in text
    assert "Contact distance error" in text
