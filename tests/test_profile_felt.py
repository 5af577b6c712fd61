"""benchmarks/profile_felt.py on hand-made labels and predictions, through the shipped profiles:
which outputs are a type's, a wrong output during a gesture, a gesture missed, outputs at rest."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
from helpers import BENCHMARKS, load_benchmark

from neurotouch_hid.dataset import LabelRow, write_labels
from neurotouch_hid.estimate import GestureEstimate, GestureType
from neurotouch_hid.mapping.profile import load_profile
from neurotouch_hid.sensor import SensorGeometry

G = GestureType
GEOMETRY = SensorGeometry()
#: Two contacts 20 px apart at the gel's centre (image px), as labelled.
TWO_PX = np.array([[163.0, 130.0], [183.0, 130.0]])


@pytest.fixture(scope="module")
def profile_felt():
    return load_benchmark("profile_felt")


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


def test_each_type_owns_the_outputs_its_profile_maps(profile_felt):
    # default.yaml: push -> left stick, pinch -> left trigger (ABS_Z), zoom -> right trigger
    # (ABS_RZ), both twists -> the right stick's x (ABS_RX)
    own = profile_felt.outputs_by_type(load_profile("default"))
    assert own[G.PUSH] == {"ABS_X", "ABS_Y"}
    assert own[G.PINCH] == {"ABS_Z"} and own[G.ZOOM] == {"ABS_RZ"}
    assert own[G.TWIST_CW] == own[G.TWIST_CCW] == {"ABS_RX"}
    # switch-access.yaml: one key each, Shift+Tab for the counter-clockwise twist
    keys = profile_felt.outputs_by_type(load_profile("switch-access"))
    assert keys[G.PINCH] == {"KEY_ENTER"} and keys[G.TWIST_CCW] == {"KEY_LEFTSHIFT", "KEY_TAB"}


def test_a_pinch_answered_push_past_the_dead_zone_is_a_wrong_move(profile_felt):
    default = load_profile("default")
    own = profile_felt.outputs_by_type(default)
    first_push = answers({range(400, 500): (G.PUSH, 3.0), range(500, 1000): (G.PINCH, 4.0)})
    t = profile_felt.tally(default, own, labelled_pinch(), first_push, GEOMETRY)
    assert (t["gestures"], t["wrong"], t["ideal"], t["missed"]) == (1, 1, 1, 0)
    # the same first finger below the stick's 0.8 mm dead zone moves nothing
    weak_push = answers({range(400, 500): (G.PUSH, 0.5), range(500, 1000): (G.PINCH, 4.0)})
    assert profile_felt.tally(default, own, labelled_pinch(), weak_push, GEOMETRY)["wrong"] == 0


def test_a_gesture_never_answered_is_missed_unless_the_profile_could_not_fire(profile_felt):
    nothing = answers({})
    default = load_profile("default")
    t = profile_felt.tally(default, profile_felt.outputs_by_type(default), labelled_pinch(), nothing, GEOMETRY)
    assert (t["ideal"], t["missed"], t["wrong"]) == (1, 1, 0)
    # a sequence without a single answer is judged against its labels all the same
    t = profile_felt.tally(default, profile_felt.outputs_by_type(default), labelled_pinch(), [], GEOMETRY)
    assert (t["gestures"], t["ideal"], t["missed"]) == (1, 1, 1)
    # switch-access presses Enter only past 2.5 mm: a 1 mm pinch fires nothing even when read right
    switch = load_profile("switch-access")
    right = answers({range(400, 1000): (G.PINCH, 1.0)})
    t = profile_felt.tally(switch, profile_felt.outputs_by_type(switch), labelled_pinch(1.0), right, GEOMETRY)
    assert (t["ideal"], t["missed"]) == (0, 0)


def test_an_output_going_active_at_rest_is_counted_a_toggle_left_on_is_not(profile_felt):
    default = load_profile("default")
    stray = answers({range(400, 1000): (G.PINCH, 4.0), range(2000, 2100): (G.PUSH, 3.0)})
    t = profile_felt.tally(default, profile_felt.outputs_by_type(default), labelled_pinch(), stray, GEOMETRY)
    # rest windows: more than 300 ms from the pinch's labelled frames (before 100 ms, after 1 300 ms)
    assert t["rest"] == len([ms for ms in range(10, 3000, 10) if ms < 100 or ms > 1300])
    assert t["rest_active"] == 1  # the stick leaves its centre once
    # accessibility.yaml: a counter-clockwise twist toggles A on; it stays on through the rest
    # that follows and a later push, which it does not make wrong
    access = load_profile("accessibility")
    own = profile_felt.outputs_by_type(access)
    assert own[G.TWIST_CCW] == {"BTN_SOUTH"}
    rows = [LabelRow(ms * 1000, G.NONE, True, 0.0) for ms in range(0, 3000, 40)]
    for k, ms in enumerate(range(0, 3000, 40)):
        if 200 <= ms <= 600:
            rows[k] = LabelRow(ms * 1000, G.TWIST_CCW, False, 5.0, TWO_PX)
        elif 1600 <= ms <= 2400:
            rows[k] = LabelRow(ms * 1000, G.PUSH, False, 5.0, TWO_PX[:1])
    toggled = answers({range(200, 600): (G.TWIST_CCW, 5.0), range(1600, 2400): (G.PUSH, 5.0)})
    t = profile_felt.tally(access, own, rows, toggled, GEOMETRY)
    assert t["gestures"] == 2 and t["wrong"] == 0 and t["rest_active"] == 0


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
