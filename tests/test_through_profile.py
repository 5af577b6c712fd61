"""evaluation/through_profile.py on hand-made labels and predictions, through the shipped profiles:
which outputs are a type's, a wrong output during a gesture, a gesture missed, outputs at rest; and
the same counts from ``eval --profile`` and from benchmarks/profile_felt.py."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest
from helpers import BENCHMARKS, run_cli

from neurotouch_hid.core.dataset import LabelRow, list_sequences, read_labels, read_predictions, write_labels
from neurotouch_hid.core.estimate import GestureEstimate, GestureType
from neurotouch_hid.core.sensor import SensorGeometry
from neurotouch_hid.evaluation.through_profile import ProfileTally, ProfileUnderTest, outputs_by_type, tally
from neurotouch_hid.mapping.profile import load_profile

G = GestureType
GEOMETRY = SensorGeometry()
#: Two contacts 20 px apart at the gel's centre (image px), as labelled.
TWO_PX = np.array([[163.0, 130.0], [183.0, 130.0]])


def probed(name: str) -> ProfileUnderTest:
    return ProfileUnderTest.probe(name, load_profile(name))


def labelled_pinch(mm: float = 4.0) -> list[LabelRow]:
    """Rest to 400 ms, a pinch at ``mm`` from 400 to 1 000 ms (frames every 40 ms), rest to 3 s."""
    rows = []
    for ms in range(0, 3000, 40):
        pinch = 400 <= ms <= 1000
        rows.append(LabelRow(ms * 1000, G.PINCH if pinch else G.NONE, not pinch, mm if pinch else 0.0,
                             TWO_PX if pinch else np.zeros((0, 2))))  # fmt: skip
    return rows


def answers(kinds: dict[range, tuple[GestureType, float]]) -> list[GestureEstimate]:
    """10 ms windows over 3 s: ``none`` at rest, else the (type, mm) of the range (ms) they fall in;
    a push towards +x of the user frame."""
    out = []
    for ms in range(10, 3000, 10):
        kind, mm = next(((k, v) for r, (k, v) in kinds.items() if ms in r), (G.NONE, 0.0))
        moving = kind is not G.NONE
        out.append(
            GestureEstimate(
                t_us=ms * 1000,
                gesture=kind,
                resting=not moving,
                intensity_mm=mm,
                contacts_px=TWO_PX if moving else np.zeros((0, 2)),
                contacts_mm=GEOMETRY.image_to_user(TWO_PX) if moving else np.zeros((0, 2)),
                translation_mm=np.array([mm, 0.0]) if kind is G.PUSH else np.zeros(2),
            )
        )
    return out


def test_each_type_owns_the_outputs_its_profile_maps():
    # default.yaml: push -> left stick, pinch -> left trigger (ABS_Z), zoom -> right trigger
    # (ABS_RZ), both twists -> the right stick's x (ABS_RX)
    own = outputs_by_type(load_profile("default"))
    assert own[G.PUSH] == {"ABS_X", "ABS_Y"}
    assert own[G.PINCH] == {"ABS_Z"} and own[G.ZOOM] == {"ABS_RZ"}
    assert own[G.TWIST_CW] == own[G.TWIST_CCW] == {"ABS_RX"}
    # switch-access.yaml: one key each, Shift+Tab for the counter-clockwise twist
    keys = outputs_by_type(load_profile("switch-access"))
    assert keys[G.PINCH] == {"KEY_ENTER"} and keys[G.TWIST_CCW] == {"KEY_LEFTSHIFT", "KEY_TAB"}


def test_a_pinch_answered_push_past_the_dead_zone_is_a_wrong_move():
    default = probed("default")
    first_push = answers({range(400, 500): (G.PUSH, 3.0), range(500, 1000): (G.PINCH, 4.0)})
    t = tally(default, labelled_pinch(), first_push, GEOMETRY)
    assert (t.gestures, t.wrong, t.ideal, t.missed) == (1, 1, 1, 0)
    # the same first finger below the stick's 0.8 mm dead zone moves nothing
    weak_push = answers({range(400, 500): (G.PUSH, 0.5), range(500, 1000): (G.PINCH, 4.0)})
    assert tally(default, labelled_pinch(), weak_push, GEOMETRY).wrong == 0


def test_a_gesture_never_answered_is_missed_unless_the_profile_could_not_fire():
    default = probed("default")
    t = tally(default, labelled_pinch(), answers({}), GEOMETRY)
    assert (t.ideal, t.missed, t.wrong) == (1, 1, 0)
    # a sequence without a single answer is judged against its labels all the same
    t = tally(default, labelled_pinch(), [], GEOMETRY)
    assert (t.gestures, t.ideal, t.missed) == (1, 1, 1)
    # switch-access presses Enter only past 2.5 mm: a 1 mm pinch fires nothing even when read right
    right = answers({range(400, 1000): (G.PINCH, 1.0)})
    t = tally(probed("switch-access"), labelled_pinch(1.0), right, GEOMETRY)
    assert (t.ideal, t.missed) == (0, 0)


def test_an_output_going_active_at_rest_is_counted_a_toggle_left_on_is_not():
    stray = answers({range(400, 1000): (G.PINCH, 4.0), range(2000, 2100): (G.PUSH, 3.0)})
    t = tally(probed("default"), labelled_pinch(), stray, GEOMETRY)
    # rest windows: more than 300 ms from the pinch's labelled frames (before 100 ms, after 1 300 ms)
    assert t.rest == len([ms for ms in range(10, 3000, 10) if ms < 100 or ms > 1300])
    assert t.rest_active == 1  # the stick leaves its centre once
    # accessibility.yaml: a counter-clockwise twist toggles A on; it stays on through the rest
    # that follows and a later push, which it does not make wrong
    access = probed("accessibility")
    assert access.outputs[G.TWIST_CCW] == {"BTN_SOUTH"}
    rows = [LabelRow(ms * 1000, G.NONE, True, 0.0) for ms in range(0, 3000, 40)]
    for k, ms in enumerate(range(0, 3000, 40)):
        if 200 <= ms <= 600:
            rows[k] = LabelRow(ms * 1000, G.TWIST_CCW, False, 5.0, TWO_PX)
        elif 1600 <= ms <= 2400:
            rows[k] = LabelRow(ms * 1000, G.PUSH, False, 5.0, TWO_PX[:1])
    toggled = answers({range(200, 600): (G.TWIST_CCW, 5.0), range(1600, 2400): (G.PUSH, 5.0)})
    t = tally(access, rows, toggled, GEOMETRY)
    assert t.gestures == 2 and t.wrong == 0 and t.rest_active == 0


def family_folder(out, sequences: bool) -> None:
    """A family_eval.py folder: family ``default`` (with one sequence, ``u0``, when ``sequences``)
    and an empty predictions folder of method ``ours``."""
    (out / "default").mkdir()
    (out / "default" / "sensor.yaml").write_text("{}\n")
    if sequences:
        (out / "default" / "u0.aedat4").write_bytes(b"")
        write_labels(out / "default" / "u0.labels.csv", labelled_pinch())
    (out / "predictions" / "default" / "ours").mkdir(parents=True)


def run_script(out, profiles: str) -> subprocess.CompletedProcess:
    argv = [str(BENCHMARKS / "profile_felt.py"), "--out", str(out), "--method", "ours", "--profiles", profiles]
    return subprocess.run([sys.executable, *argv], capture_output=True, text=True, timeout=120)


def test_an_unknown_profile_is_one_line_naming_those_there_are(tmp_path):
    family_folder(tmp_path, sequences=False)
    done = run_script(tmp_path, "default,no-such-profile")
    assert done.returncode == 2 and done.stdout == "", done.stderr
    (line,) = done.stderr.splitlines()
    assert "no-such-profile" in line and "switch-access" in line


def test_a_sequence_without_predictions_is_one_line_naming_the_file(tmp_path):
    family_folder(tmp_path, sequences=True)
    done = run_script(tmp_path, "default")
    assert done.returncode == 2, done.stderr
    (line,) = done.stderr.splitlines()
    assert "u0.jsonl" in line and "Traceback" not in done.stderr


# --- `neurotouch-hid eval --profile` and the benchmark, end to end on a tiny simulated dataset ----
@pytest.fixture(scope="module")
def evaluated(sim_quick_dataset, tmp_path_factory):
    """``eval`` of the quick dataset (one user, five gestures of one type each, ~3 s apiece) through
    ``default`` and ``switch-access``, in two processes: its JSON and its predictions folder (its
    printed tables and report checked here)."""
    out = tmp_path_factory.mktemp("through")
    done = run_cli(
        "eval", str(sim_quick_dataset), "--jobs", "2", "--profile", "default", "--profile", "switch-access",
        "--json", str(out / "metrics.json"), "--predictions", str(out / "pred"), "--report", str(out / "report"),
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    assert "Through the profiles" in done.stdout and "switch-access" in done.stdout
    summary = (out / "report" / "summary.md").read_text()
    assert "## Through the profiles" in summary and "| switch-access | 5 |" in summary
    return json.loads((out / "metrics.json").read_text()), out / "pred"


def test_eval_counts_what_the_answers_do_through_each_profile_named(evaluated, sim_quick_dataset):
    data, predictions = evaluated
    assert list(data["through_profiles"]) == ["default", "switch-access"]
    assert "--profile=default" in data["command"] and "--profile=switch-access" in data["command"]
    default, switch = data["through_profiles"]["default"], data["through_profiles"]["switch-access"]
    # five labelled gestures; on a steady user's gestures the default profile moves every one's own
    # stick or trigger and nothing of another type, and nothing leaves its centre at rest
    assert default == {**default, "gestures": 5, "ideal": 5, "missed": 0, "wrong": 0, "rest_active": 0}
    assert default["rest"] > 0 and switch["rest"] == default["rest"]
    # switch-access presses a key only past 2.5 mm after a 300 ms dwell: fewer gestures can fire it
    assert switch["gestures"] == 5 and switch["ideal"] <= 5 and switch["wrong"] == 0
    # the two processes' counts are those of the written predictions, replayed here in one
    geometry = SensorGeometry.load(sim_quick_dataset / "sensor.yaml")
    for name in ("default", "switch-access"):
        total = ProfileTally()
        for seq in list_sequences(sim_quick_dataset):
            labels = read_labels(sim_quick_dataset / f"{seq}.labels.csv")
            total += tally(probed(name), labels, read_predictions(predictions / f"{seq}.jsonl"), geometry)
        assert total.to_dict() == data["through_profiles"][name]


def test_the_benchmark_replays_the_written_predictions_to_the_same_counts(evaluated, sim_quick_dataset, tmp_path):
    data, predictions = evaluated
    family = tmp_path / "default"
    family.mkdir()
    for path in sim_quick_dataset.iterdir():
        (family / path.name).symlink_to(path)
    (tmp_path / "predictions" / "default").mkdir(parents=True)
    (tmp_path / "predictions" / "default" / "ours").symlink_to(predictions)
    done = run_script(tmp_path, "default,switch-access")
    assert done.returncode == 0, done.stderr
    for name in ("default", "switch-access"):
        (row,) = [line for line in done.stdout.splitlines() if line.startswith(f"| {name} | **all")]
        t = data["through_profiles"][name]
        assert row.endswith(f"| {t['gestures']} | {t['wrong']} | {t['missed']} of {t['ideal']} | "
                            f"{t['rest_active']} of {t['rest']} |")  # fmt: skip


def test_eval_with_an_unknown_or_broken_profile_is_one_line_before_any_run(sim_quick_dataset, tmp_path):
    done = run_cli("eval", str(sim_quick_dataset), "--profile", "no-such-profile", "--json", str(tmp_path / "m.json"))
    assert done.returncode == 2 and "Traceback" not in done.stderr, done.stderr
    assert "no-such-profile" in done.stderr and "switch-access" in done.stderr
    assert not (tmp_path / "m.json").exists()
    broken = tmp_path / "broken.yaml"
    broken.write_text("mappings:\n  push:\n    deadzone_mm: lots\n")
    done = run_cli("eval", str(sim_quick_dataset), "--profile", str(broken))
    assert done.returncode == 2 and "Traceback" not in done.stderr, done.stderr
    assert f"{broken}:3" in done.stderr and "deadzone_mm" in done.stderr
