"""Pipeline presets (``track/eval --preset``): ``paper`` is the paper's method exactly."""

from __future__ import annotations

import pytest

from neurotouch_hid.errors import NeurotouchError
from neurotouch_hid.evaluation.runner import pipeline_config
from neurotouch_hid.pipeline.pipeline import PipelineConfig

# the paper, section "Results" (r, a, N_min, Chamfer threshold) and "Methodology" (nothing else)
PAPER = {
    "r_px": 30.0,
    "a": 0.6,
    "n_min": 4,
    "chamfer_threshold": 2.5,
    "chamfer_per_marker": False,
    "resting_centroids": False,
    "centroid_reset_threshold": None,
    "min_intensity_px": 0.0,
    "intensity_sigma_px": None,
    "field_fallback": False,
    "contact_refine_px": None,
    "plateau_fraction": None,
    "maxima_at_rest": False,
    "spike_fraction": None,
    "bump_fit": False,
    "gesture_classifier": False,
    "origin_radius_px": None,
    "motion_override_px": None,
    "override_smooth": False,
    "gel_motion": False,
    "noise_filter": None,
    "rest_match_pitch": None,
    "follow_px_per_mm": False,
    "camera_model": False,
    "episode_vote": False,
    "vote_restart": False,
    "frame_correction": False,
    "creep_load": False,
}


def test_paper_preset_has_the_papers_hyperparameters_and_no_extra_option():
    config = pipeline_config(preset="paper")
    for name, value in PAPER.items():
        assert getattr(config, name) == value, name
    assert config.gesture_reproj_factor == config.a  # the paper's one RANSAC threshold rule
    # the tuned defaults are not the paper's
    default = pipeline_config()
    assert default == PipelineConfig()
    assert any(getattr(default, name) != value for name, value in PAPER.items())


def test_set_overrides_the_preset_and_window_is_kept():
    config = pipeline_config(["r_px=20"], "paper", window_us=5000)
    assert config.r_px == 20.0 and config.n_min == 4 and config.window_us == 5000
    assert config.model_copy(update={"r_px": 30.0}) == pipeline_config(preset="paper", window_us=5000)


def test_unknown_preset_is_one_clear_error():
    with pytest.raises(NeurotouchError, match="--preset 'papr': expected one of default, paper"):
        pipeline_config(preset="papr")


def test_track_and_eval_take_the_preset(tmp_path, monkeypatch, capsys):
    from neurotouch_hid.cli import main

    monkeypatch.setattr("sys.argv", ["neurotouch-hid", "eval", str(tmp_path), "--preset", "nope"])
    with pytest.raises(SystemExit) as exc:
        main()
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert "--preset 'nope'" in err and "Traceback" not in err
