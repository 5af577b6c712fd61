"""The type wait follows the profile (neurotouch_hid/mapping/commitment.py; docs/method.md,
"Episode vote"): a profile that reads no difference between push and the multi-finger types does
not make the pipeline wait for the fingers; a profile switch while running changes it."""

from __future__ import annotations

import pytest

from neurotouch_hid.core.sensor import SensorGeometry
from neurotouch_hid.engine.engine import Engine, RunParts
from neurotouch_hid.engine.mode import RunMode, RunOptions
from neurotouch_hid.mapping.commitment import waits_for_type
from neurotouch_hid.mapping.profile import Profile, available_profiles, load_profile
from neurotouch_hid.pipeline.pipeline import GesturePipeline

A = {"output": "BTN_SOUTH", "press_mm": 1.0, "release_mm": 0.5}
#: every type the wait tells apart on one button (a one-switch user's "any gesture is the switch")
ONE_OUTPUT = {"mappings": {i: {"input": i, **A} for i in ("push_intensity", "pinch", "zoom", "twist_cw", "twist_ccw")}}
#: any touch, whatever its type: no type's input at all
ANY_TOUCH = {"mappings": {"any": {"input": "intensity", **A}}}
#: push alone: a pinch must press nothing, so the wait stays
PUSH_ONLY = {"mappings": {"push": {"input": "push_intensity", **A}}}
#: both twists on one axis (opposite directions), the rest on one button: the twists differ
TWIST_AXIS = {
    "mappings": {
        **{i: {"input": i, **A} for i in ("push_intensity", "pinch", "zoom")},
        "t": {"input": "twist", "output": "ABS_RX", "deadzone_mm": 0.8, "saturation_mm": 4.0},
    }
}


@pytest.mark.parametrize(
    ("spec", "waits"), [(ONE_OUTPUT, False), (ANY_TOUCH, False), (PUSH_ONLY, True), (TWIST_AXIS, True)]
)
def test_the_wait_stays_where_the_profile_reads_the_type(spec, waits):
    assert waits_for_type(Profile.model_validate(spec)) is waits


def test_every_shipped_profile_tells_the_types_apart_and_waits():
    for name, path in available_profiles().items():
        assert waits_for_type(load_profile(path)), name


def test_a_profile_switch_sets_the_pipelines_wait():
    """The runtime sets the wait from the profile it starts with and from each one switched to."""
    pipeline = GesturePipeline(SensorGeometry())
    waited = pipeline.settings.episode.first_finger_us
    assert waited > 0
    runtime = Engine(
        RunParts(iter(()), pipeline), Profile.model_validate(ONE_OUTPUT), [], RunOptions(mode=RunMode.FAST)
    )
    assert pipeline._episode.first_finger_us == 0
    runtime.switch_profile(load_profile("default"))
    assert pipeline._episode.first_finger_us == waited
    runtime.switch_profile(Profile.model_validate(ANY_TOUCH))
    assert pipeline._episode.first_finger_us == 0
