"""The evaluation report (tables, figures, summary.md) and the `eval` command end to end."""

from __future__ import annotations

import json

import numpy as np
import pytest
from rich.console import Console

from neurotouch_hid.core.dataset import LabelRow
from neurotouch_hid.core.estimate import GestureEstimate, GestureType
from neurotouch_hid.core.sensor import SensorGeometry
from neurotouch_hid.evaluation.metrics import align, evaluate
from neurotouch_hid.evaluation.report import FIGURES, print_tables, write_report


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
        GestureEstimate(
            t_us=150, gesture=GestureType.PUSH, resting=False, intensity_mm=1.0, contacts_px=np.array([[171.0, 131.0]])
        ),
        GestureEstimate(
            t_us=210,
            gesture=GestureType.ZOOM,
            resting=False,
            intensity_mm=2.5,
            contacts_px=np.array([[168.0, 131.0], [191.0, 130.0]]),
        ),
    ]
    return evaluate(align(labels, predictions, sensor))


def test_print_tables_shows_headline_metrics_beside_the_paper(result):
    console = Console(record=True, width=200)
    print_tables(result, console)
    text = console.export_text()
    assert "Gesture type accuracy" in text and f"{100 * result.gesture_accuracy:.2f} %" in text
    assert "91.12 %" in text  # the paper's figure beside ours
    assert "Resting F1 outside the 40 ms collar" in text
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


# --- `neurotouch-hid eval` end to end on a tiny simulated dataset ----------------------------
def test_eval_command_writes_report_json_and_predictions(sim_quick_dataset, tmp_path):
    from typer.testing import CliRunner

    from neurotouch_hid.cli import app
    from neurotouch_hid.core.dataset import list_sequences
    from neurotouch_hid.evaluation.metrics import EvaluationResult

    out_json = tmp_path / "metrics.json"
    res = CliRunner().invoke(
        app,
        [
            "eval",
            str(sim_quick_dataset),
            "--report",
            str(tmp_path / "report"),
            "--json",
            str(out_json),
            "--predictions",
            str(tmp_path / "pred"),
            "--set",
            "contacts.a=0.6",
            "--jobs",
            "2",
        ],
    )
    assert res.exit_code == 0, res.output
    assert "Gesture type accuracy" in res.output
    data = json.loads(out_json.read_text())
    for name in EvaluationResult.__dataclass_fields__:
        assert name in data, name
    assert data["config"]["contacts"]["a"] == 0.6
    for name in FIGURES:
        assert (tmp_path / "report" / name).stat().st_size > 0
    assert (tmp_path / "report" / "summary.md").exists()
    for seq in list_sequences(sim_quick_dataset):
        lines = (tmp_path / "pred" / f"{seq}.jsonl").read_text().splitlines()
        assert lines and {"t_us", "gesture", "resting", "intensity_mm", "contacts_px"} <= json.loads(lines[0]).keys()


def test_pipeline_config_rejects_unknown_or_bad_hyperparameter():
    from neurotouch_hid.core.errors import NeurotouchError
    from neurotouch_hid.evaluation.runner import pipeline_config

    with pytest.raises(NeurotouchError, match="no field 'radius'"):
        pipeline_config(["radius=3"])
    with pytest.raises(NeurotouchError, match="r_mm"):
        pipeline_config(["contacts.r_mm=big"])
    with pytest.raises(NeurotouchError, match="TrackerConfig has no field 'nope'"):
        pipeline_config(["tracker.nope=1"])
    config = pipeline_config(
        ["contacts.r_mm=10", "contacts.n_min=3", "noise.kind=none", "tracker.assoc_mm=2"], window_us=5000
    )
    assert (
        config.contacts.r_mm,
        config.contacts.n_min,
        config.noise.kind,
        config.tracker.assoc_mm,
        config.window_us,
    ) == (
        10.0,
        3,
        None,
        2.0,
        5000,
    )


def test_a_bad_set_value_names_the_setting_the_field_and_what_was_expected():
    from neurotouch_hid.core.errors import NeurotouchError
    from neurotouch_hid.evaluation.runner import pipeline_config

    with pytest.raises(NeurotouchError) as info:
        pipeline_config(["tracker.assoc_mm=wide"])
    assert "--set 'tracker.assoc_mm=wide': tracker.assoc_mm: found 'wide'; expected a number" in str(info.value)
    assert pipeline_config(["resting.marker_threshold=none"]).resting.marker_threshold is None
