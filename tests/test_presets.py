"""Pipeline methods (``track/eval/run --method``; ``--preset`` is simulate's): ``paper`` is the paper's
method exactly, its own composition."""

from __future__ import annotations

import pytest

from neurotouch_hid.core.errors import NeurotouchError
from neurotouch_hid.core.sensor import SensorGeometry
from neurotouch_hid.evaluation.runner import pipeline_config
from neurotouch_hid.pipeline.config import PipelineConfig
from neurotouch_hid.pipeline.methods import pipeline_for
from neurotouch_hid.pipeline.paper import PaperConfig, PaperPipeline
from neurotouch_hid.pipeline.pipeline import GesturePipeline

# the paper, section "Results" (r, a, N_min, Chamfer threshold)
PAPER = {"r_px": 30.0, "a": 0.6, "n_min": 4, "chamfer_threshold": 2.5}


def test_paper_method_has_the_papers_hyperparameters():
    config = pipeline_config(method="paper")
    assert isinstance(config, PaperConfig)
    for name, value in PAPER.items():
        assert getattr(config, name) == value, name
    default = pipeline_config()
    assert default == PipelineConfig()
    assert default.contacts.n_min != config.n_min


def test_paper_config_has_no_product_step():
    """The paper's settings name none of the product's own steps (noise filter, override, ...)."""
    product_only = set(PipelineConfig.model_fields) - set(PaperConfig.model_fields)
    assert {"noise", "contacts", "gesture", "resting"} <= product_only


def test_the_config_picks_the_pipeline():
    sensor = SensorGeometry()
    assert type(pipeline_for(sensor, pipeline_config(method="paper"))) is PaperPipeline
    assert type(pipeline_for(sensor, pipeline_config())) is GesturePipeline
    assert type(pipeline_for(sensor)) is GesturePipeline
    paper = PaperPipeline(sensor)
    assert paper.noise_filter is None and paper.config == PaperConfig()


def test_set_overrides_the_method_and_window_is_kept():
    config = pipeline_config(["r_px=20"], "paper", window_us=5000)
    assert config.r_px == 20.0 and config.n_min == 4 and config.window_us == 5000
    assert config.model_copy(update={"r_px": 30.0}) == pipeline_config(method="paper", window_us=5000)


def test_set_names_a_field_of_the_methods_config():
    with pytest.raises(NeurotouchError, match="PaperConfig has no field 'spike_fraction'"):
        pipeline_config(["spike_fraction=0.5"], "paper")


def test_unknown_method_is_one_clear_error():
    with pytest.raises(NeurotouchError, match="--method 'papr': expected one of default, paper"):
        pipeline_config(method="papr")


def test_eval_takes_the_method(tmp_path, monkeypatch, capsys):
    from neurotouch_hid.cli import main

    monkeypatch.setattr("sys.argv", ["neurotouch-hid", "eval", str(tmp_path), "--method", "nope"])
    with pytest.raises(SystemExit) as exc:
        main()
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert "--method 'nope'" in err and "Traceback" not in err


@pytest.mark.parametrize("command", ["eval", "track"])
def test_preset_belongs_to_simulate_and_the_pipeline_commands_say_to_use_method(tmp_path, monkeypatch, capsys, command):
    from neurotouch_hid.cli import main

    out = ["--out", str(tmp_path / "p.jsonl")] if command == "track" else []
    monkeypatch.setattr("sys.argv", ["neurotouch-hid", command, str(tmp_path), *out, "--preset", "paper"])
    with pytest.raises(SystemExit) as exc:
        main()
    err = capsys.readouterr().err
    assert exc.value.code == 2 and "--preset is simulate's dataset size" in err and "--method paper" in err
