"""What a person with little hand strength meets in ``enrol`` and ``adapt`` when things go badly:
a session in which no gesture was seen, and an enrolment too small to check a fitted value on."""

from __future__ import annotations

from pathlib import Path

import pytest
from helpers import run_cli, run_main

from neurotouch_hid.core.estimate import GestureType
from neurotouch_hid.enrolment.model import Model, load_model, user_model_path
from neurotouch_hid.enrolment.plan import Plan, Prompt, Script, write_plan

PLAN = Plan(
    (
        Prompt(GestureType.PUSH, 2.0, 1.5, "up"),
        Prompt(GestureType.PINCH, 6.5, 0.4),
        Prompt(GestureType.TWIST_CW, 10.0, 1.5),
    )
)


@pytest.fixture(scope="module")
def small(tmp_path_factory) -> Path:
    """A real-looking enrolment of three prompts, one of each of three types: nothing to hold out."""
    from neurotouch_hid.enrolment.session import SimulatedHandSource, run_session

    folder = tmp_path_factory.mktemp("small") / "enrolment"
    source = SimulatedHandSource(3, miss_rate=0.0)
    result = run_session(Script(PLAN), source, folder, source.sensor, [])
    assert not result.not_seen
    return folder


def test_a_session_in_which_no_gesture_was_seen_says_what_to_do_and_where_the_recording_is(tmp_path):
    """Every prompt missed, and missed again when asked again (a hand too weak or too slow for
    the cue): the error names the folder the recording is kept in (not a temporary one), does not
    say the recording follows another plan, and says what to do."""
    plan = write_plan(PLAN, tmp_path / "short.json")
    out = tmp_path / "session"
    misses = [arg for n in range(1, 7) for arg in ("--sim-miss", str(n))]
    result = run_cli("enrol", "--source", "sim", "--plan", str(plan), "--fast", "--out", str(out), *misses)
    assert result.returncode == 2, result.stderr
    err = result.stderr
    assert "Traceback" not in err and ".part" not in err, err
    assert "does not follow this plan" not in err and "--plan" not in err, err
    assert "no gesture was seen for any of the 6 prompts asked" in err, err
    assert str(out / "enrolment.aedat4") in err and (out / "enrolment.aedat4").exists(), err
    assert "neurotouch-hid enrol" in err, err


def test_adapt_on_too_few_gestures_keeps_the_users_model_and_says_so(small, monkeypatch, capsys):
    """An enrolment with too few gestures to hold any out: nothing is fitted, so the user's
    adapted model is not replaced by an empty one, the summary does not claim the shipped
    recogniser reads their hand as well, and the message says what to do."""
    import neurotouch_hid.enrolment.adapt as adapt_module

    monkeypatch.setattr(adapt_module, "simulated_sequences", lambda datasets: [])  # as a camera's enrolment
    path = user_model_path()
    path.parent.mkdir(parents=True, exist_ok=True)
    Model({"gesture.intensity_gain": 1.1}).save(path)
    before = path.read_bytes()
    done = run_main(monkeypatch, capsys, ["adapt", str(small), "--jobs", "1"])
    assert path.read_bytes() == before, done.stdout
    said = done.stdout + done.stderr
    assert "already reads your hand as well" not in said, said
    assert "only 0 gesture(s) could be held out" in said, said
    assert f"no model written to {path} (the one there is left as it was)" in said, said
    assert "more prompts" not in said and "neurotouch-hid enrol" in said, said
    assert done.returncode == 2, said


def test_adapt_on_too_few_gestures_replaces_no_model_where_out_says(small, tmp_path, monkeypatch, capsys):
    """An existing model at --out is left as it was; a new file gets the shipped method (nothing fitted)."""
    out = tmp_path / "m.yaml"
    Model({"gesture.intensity_gain": 1.1}).save(out)
    before = out.read_bytes()
    done = run_main(monkeypatch, capsys, ["adapt", str(small), "--out", str(out), "--jobs", "1"])
    assert done.returncode == 2 and out.read_bytes() == before, done.stdout + done.stderr
    assert f"no model written to {out} (the one there is left as it was)" in done.stderr
    new = tmp_path / "new.yaml"
    done = run_main(monkeypatch, capsys, ["adapt", str(small), "--out", str(new), "--jobs", "1"])
    assert done.returncode == 0 and not load_model(new).changes(), done.stderr
    assert "what changes for you: nothing, too few gestures to check a change on" in done.stdout


def test_adapt_says_which_gesture_types_the_enrolment_lacks(small):
    """A hand that could not perform some gesture types (left out of the enrolment): the summary
    names them, since nothing it changed was checked on them."""
    from neurotouch_hid.enrolment.adapt import adapt, summary
    from neurotouch_hid.enrolment.adapt_record import record_datasets

    adaptation = adapt(record_datasets([small]))
    assert adaptation.missing == ("zoom", "twist_ccw")
    lines = summary(adaptation)
    assert any(line.startswith("your enrolment has no zoom or twist_ccw gesture") for line in lines), lines
