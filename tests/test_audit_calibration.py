"""``neurotouch-hid calibrate`` as a person uses it: a broken sensor.yaml in the config folder is
replaced, nothing is asked on a terminal, and a gesture the person cannot do does not keep a
right calibration from being written (docs/calibration.md)."""

from __future__ import annotations

import dataclasses
import sys

from helpers import run_main

from neurotouch_hid.calibration import guide as calibration_guide
from neurotouch_hid.core.estimate import GestureType
from neurotouch_hid.core.sensor import SensorGeometry, user_sensor_path

#: Mirror and rotation given, no check: the rest frames only (no gesture pipeline).
REST_ONLY = ("calibrate", "--source", "sim", "--mirror", "--rotation", "0", "--no-check")


def broken_user_sensor_file() -> None:
    """The config folder's sensor.yaml, edited by hand into invalid YAML (doctor: "fix: calibrate")."""
    path = user_sensor_path()
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("width: 346\nheight: [260\npx_per_mm: 2.5\n")


def test_a_broken_sensor_yaml_in_the_config_folder_is_replaced_by_calibrate(monkeypatch, capsys):
    broken_user_sensor_file()
    done = run_main(monkeypatch, capsys, [*REST_ONLY, "--out", str(user_sensor_path())])
    assert done.returncode == 0, done.stdout + done.stderr
    assert "not a sensor.yaml" not in done.stderr
    assert f"wrote {user_sensor_path()}" in done.stdout
    assert SensorGeometry.load(user_sensor_path()).mirror is True


def test_a_simulated_calibration_is_not_refused_for_the_users_broken_sensor_yaml(monkeypatch, capsys):
    """--source sim without --out never writes the config folder's file: its state is no reason to refuse."""
    broken_user_sensor_file()
    done = run_main(monkeypatch, capsys, list(REST_ONLY))
    assert done.returncode == 0, done.stdout + done.stderr
    assert "nothing written: a simulated camera's calibration" in done.stdout


class _Terminal:
    """A terminal nobody types on: a question asked on it reads end of input."""

    def isatty(self) -> bool:
        return True

    def readline(self, *args) -> str:
        return ""

    def read(self, *args) -> str:
        return ""

    def fileno(self) -> int:
        return 0


def test_replacing_a_sensor_yaml_on_a_terminal_asks_nothing(tmp_path, monkeypatch, capsys):
    """docs/calibration.md: nothing is typed and each wait is bounded, on a terminal too."""
    out = tmp_path / "sensor.yaml"
    first = run_main(monkeypatch, capsys, [*REST_ONLY, "--out", str(out)])
    assert first.returncode == 0, first.stdout + first.stderr
    monkeypatch.setattr(sys, "stdin", _Terminal())
    again = run_main(
        monkeypatch,
        capsys,
        ["calibrate", "--source", "sim", "--mirror", "--rotation", "10", "--no-check", "--out", str(out)],
    )
    assert again.returncode == 0, again.stdout + again.stderr
    assert "?" not in again.stdout + again.stderr
    assert f"replacing {out}: rotation_deg: 0.0 -> 10.0" in again.stdout
    assert SensorGeometry.load(out).rotation_deg == 10.0


class _OneFingerHand(calibration_guide.SimulatedHand):
    """A person who pushes with one finger but cannot do two-finger gestures (pinch, zoom, twists)."""

    def perform(self, step: calibration_guide.Step) -> None:
        if step.gesture is GestureType.PUSH:
            super().perform(step)


def test_gestures_a_person_cannot_do_do_not_keep_a_right_calibration_from_being_written(tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(calibration_guide, "SimulatedHand", _OneFingerHand)
    out = tmp_path / "sensor.yaml"
    done = run_main(monkeypatch, capsys, ["calibrate", "--source", "sim", "--sim-rotation", "40", "--out", str(out)])
    assert done.returncode == 0, done.stdout + done.stderr
    assert "nothing written" not in done.stdout
    written = SensorGeometry.load(out)
    assert written.mirror is True and abs(written.rotation_deg - 40.0) < 3.0
    lines = done.stdout.splitlines()
    assert "guided check: 4 of 8 gestures right; not done as asked: pinch, zoom, twist clockwise, " in "\n".join(lines)
    assert not any("gestures may come out turned" in line for line in lines)


def test_a_gesture_read_the_wrong_way_still_keeps_the_calibration_from_being_written(tmp_path, monkeypatch, capsys):
    """The camera mirrored, the calibration told it is not: the twists read the other way round."""
    out = tmp_path / "sensor.yaml"
    done = run_main(
        monkeypatch,
        capsys,
        ["calibrate", "--source", "sim", "--no-mirror", "--rotation", "0", "--out", str(out)],
    )
    assert done.returncode == 1, done.stdout + done.stderr
    assert "nothing written: the guided check read gestures wrong" in done.stdout
    assert not out.exists()


def test_a_push_started_late_is_watched_to_its_end_not_cut_into_the_next_step(monkeypatch):
    """A slow person starts each push 11 s after being asked (within the 12 s watched) and holds
    it 1.5 s: it is read whole, and its end is not taken for the next push asked."""
    from neurotouch_hid.calibration import measure as calibration

    monkeypatch.setattr(calibration_guide, "SIM_REACTION_US", 11_200_000)
    source = calibration_guide.SimulatedHand(SensorGeometry(mirror=True, rotation_deg=30.0))
    rest = calibration.calibrate(source.rest_frames(calibration.REST_FRAMES)).sensor
    said: list[str] = []
    mirror, rotation = calibration_guide.measure_orientation(source, source.stream(), rest, said.append)
    assert mirror is True and abs(rotation - 30.0) < 3.0, said
    assert not any("not used" in line for line in said), said


def test_what_looks_off_at_rest_is_said_before_the_guided_pushes(tmp_path, monkeypatch, capsys):
    """A note on the rest frames (markers missing, the gel off-centre) is said as soon as they are
    read, so that the person can fix the camera before doing every push, not after them all."""
    from neurotouch_hid.calibration import measure as calibration

    real = calibration.calibrate

    def with_a_note(*args, **kwargs):
        result = real(*args, **kwargs)
        return dataclasses.replace(result, notes=(*result.notes, "152 markers found, 177 expected"))

    monkeypatch.setattr(calibration, "calibrate", with_a_note)
    out = tmp_path / "sensor.yaml"
    done = run_main(monkeypatch, capsys, ["calibrate", "--source", "sim", "--no-check", "--out", str(out)])
    assert done.returncode == 0, done.stdout + done.stderr
    said = done.stdout
    assert said.count("note: 152 markers found") == 1, said
    assert said.index("note: 152 markers found") < said.index("which way you look at the gel"), said
