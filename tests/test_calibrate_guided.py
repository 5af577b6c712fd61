"""``calibrate``'s guided pushes and guided check (neurotouch_hid/calibration/guide.py).

Calibration used to ask "Rotation from the mirrored image to your view (counter-clockwise
degrees)" with nothing to find it by, ``--source sim`` answered "sim: no such file", and nothing
checked afterwards that a push up moved the stick up. Here the simulated camera is mounted
turned (and mirrored or not), the simulated hand does what it is asked, and calibration must
find the mounting from two guided pushes; the check must say which gestures come out wrong
when the calibration is wrong, and what to give instead."""

from __future__ import annotations

import dataclasses
import math
import os
import subprocess
import sys

import numpy as np
import pytest

from neurotouch_hid.calibration import measure as calibration
from neurotouch_hid.calibration.guide import (
    CALIBRATION_PUSHES,
    CHECK_STEPS,
    SimulatedHand,
    guided_check,
    measure_orientation,
    orientation,
)
from neurotouch_hid.core.errors import SensorError
from neurotouch_hid.core.estimate import GestureType
from neurotouch_hid.core.sensor import SensorGeometry, user_sensor_path


def run_cli(*args: str) -> subprocess.CompletedProcess:
    """``neurotouch-hid ARGS`` in a fresh process, its input not a terminal (the tmp user config folder)."""
    return subprocess.run(
        [sys.executable, "-m", "neurotouch_hid.cli", *args],
        capture_output=True,
        text=True,
        env=dict(os.environ, COLUMNS="80"),
        stdin=subprocess.DEVNULL,
        timeout=600,
    )


def turn_difference(a: float, b: float) -> float:
    """|a - b| in degrees, the short way round."""
    return abs((a - b + 180.0) % 360.0 - 180.0)


def started(camera: SensorGeometry, **hand) -> tuple[SimulatedHand, SensorGeometry, list[str]]:
    """A simulated hand at a camera mounted as ``camera``, the rest frames' geometry, and where
    the lines said go."""
    source = SimulatedHand(camera, **hand)
    rest = calibration.calibrate(source.rest_frames(calibration.REST_FRAMES)).sensor
    return source, rest, []


@pytest.mark.parametrize("mirror", [True, False])
@pytest.mark.parametrize("rotation", [0.0, 90.0, -135.0, 180.0])
def test_two_pushes_give_the_mirror_and_rotation_the_sensor_convention_makes(mirror, rotation):
    """The pushes as the image shows them are made by the sensor's own image <-> user conversion,
    not by the inverse that ``orientation`` computes."""
    truth = SensorGeometry(mirror=mirror, rotation_deg=rotation)
    neutral = dataclasses.replace(truth, mirror=False, rotation_deg=0.0)
    seen = [
        neutral.vectors_image_to_user(truth.vectors_user_to_image(np.array(step.direction) * 3.0))
        for step in CALIBRATION_PUSHES
    ]
    found_mirror, found_rotation = orientation(CALIBRATION_PUSHES, seen)
    assert found_mirror is mirror
    assert turn_difference(found_rotation, rotation) < 0.1
    assert -180.0 < found_rotation <= 180.0


def test_two_pushes_not_at_a_right_angle_are_refused_saying_so():
    with pytest.raises(SensorError, match="were 20 degrees apart, not 90: push straight"):
        seventy = math.radians(70.0)
        orientation(CALIBRATION_PUSHES, [np.array([0.0, 3.0]), 3.0 * np.array([math.cos(seventy), math.sin(seventy)])])


def test_guided_pushes_find_an_unmirrored_camera_turned_120_degrees():
    source, rest, said = started(SensorGeometry(mirror=False, rotation_deg=120.0))
    mirror, rotation = measure_orientation(source, source.stream(), rest, said.append)
    assert mirror is False
    assert turn_difference(rotation, 120.0) < 3.0
    assert said[0].startswith("push the gel towards the top of your view (away from you)")
    assert any(line.startswith("push the gel towards your right") for line in said)


def test_a_weak_push_is_refused_in_one_line_and_asked_again():
    source, rest, said = started(SensorGeometry(mirror=True, rotation_deg=-60.0), push_mm=[0.3])
    mirror, rotation = measure_orientation(source, source.stream(), rest, said.append)
    assert (mirror, turn_difference(rotation, -60.0) < 3.0) == (True, True)
    refused = [line for line in said if "not used" in line]
    assert len(refused) == 1 and "push up: not used:" in refused[0] and "push harder" in refused[0]
    asked = [line for line in said if line.startswith("push the gel towards the top")]
    assert len(asked) == 2  # asked again after the weak one


def test_no_usable_push_gives_up_with_one_line_naming_the_flags():
    source, rest, said = started(SensorGeometry(), push_mm=[0.2, 0.2, 0.2])
    with pytest.raises(SensorError, match=r"no usable push up in 3 tries .*--mirror/--no-mirror and --rotation DEG"):
        measure_orientation(source, source.stream(), rest, said.append)


def test_the_check_reads_twists_the_other_way_round_with_the_wrong_mirror():
    source, rest, said = started(SensorGeometry(mirror=True, rotation_deg=0.0))
    wrong = dataclasses.replace(rest, mirror=False, rotation_deg=0.0)
    twists = [s for s in CHECK_STEPS if s.gesture in (GestureType.TWIST_CW, GestureType.TWIST_CCW)]
    results = guided_check(source, source.stream(), wrong, said.append, twists)
    assert [r.right for r in results] == [False, False]
    assert [r.attempt.gesture for r in results] == [GestureType.TWIST_CCW, GestureType.TWIST_CW]
    assert all("the mirror is wrong" in r.line() for r in results)


def test_calibrate_source_sim_measures_a_turned_mirrored_camera_and_checks_every_gesture(tmp_path):
    out = tmp_path / "sensor.yaml"
    done = run_cli("calibrate", "--source", "sim", "--sim-rotation", "40", "--out", str(out))
    assert done.returncode == 0, done.stdout + done.stderr
    assert "no such file" not in done.stdout + done.stderr
    written = SensorGeometry.load(out)
    assert written.mirror is True and turn_difference(written.rotation_deg, 40.0) < 3.0
    lines = done.stdout.splitlines()
    for step in CHECK_STEPS:
        assert any(line.strip().startswith(f"{step.name}: right: read as") for line in lines), step.name
    assert "guided check: 8 of 8 gestures right" in lines
    assert all(len(line) > 80 for line in lines if line.startswith("push the gel towards the top"))  # not wrapped


def test_a_wrong_calibration_is_caught_by_the_check_with_the_flags_to_give():
    """The camera mirrored and turned 90 degrees, the calibration told neither: every push and
    both twists come out wrong, the exit code says so, the pushes name the right flags, and
    nothing is written."""
    done = run_cli("calibrate", "--source", "sim", "--sim-rotation", "90", "--no-mirror", "--rotation", "0")
    assert done.returncode == 1, done.stdout + done.stderr
    assert "loading the gesture pipeline" in done.stderr  # the check needs it, the orientation given or not
    lines = [line.strip() for line in done.stdout.splitlines()]
    wrong = {line.split(":")[0] for line in lines if ": WRONG: " in line}
    assert wrong == {"push up", "push down", "push left", "push right", "twist clockwise", "twist counter-clockwise"}
    assert any("twist clockwise: WRONG: read as a counter-clockwise twist" in line for line in lines)
    advice = [line for line in lines if line.startswith("what to do:")]
    assert len(advice) == 1 and advice[0].endswith("give, instead of --no-mirror --rotation 0, --mirror --rotation 90")
    assert "push exactly" not in done.stdout  # the orientation was given, not pushed
    assert "nothing written: the guided check read gestures wrong" in done.stdout
    assert not user_sensor_path().exists()


def test_given_orientation_without_the_check_measures_the_rest_without_loading_the_pipeline(tmp_path):
    """Mirror and rotation given, no check: nothing uses the gesture pipeline, so calibrate does
    not spend its start loading it (under emulation, a minute); the rest frame is still measured."""
    out = tmp_path / "sensor.yaml"
    done = run_cli("calibrate", "--source", "sim", "--mirror", "--rotation", "0", "--no-check", "--out", str(out))
    assert done.returncode == 0, done.stderr
    assert "loading the gesture pipeline" not in done.stdout + done.stderr
    assert "markers: 177 found" in done.stdout and out.exists()
    # with the check, the orientation given too, it is loaded (asserted by test_a_wrong_calibration_...)


def test_half_the_orientation_flags_is_one_clear_line():
    done = run_cli("calibrate", "--source", "sim", "--rotation", "30", "--no-check")
    assert done.returncode == 2
    assert done.stderr.strip().count("\n") == 0 and "give both or neither" in done.stderr


def test_sim_camera_options_belong_to_the_simulator(tmp_path):
    done = run_cli("calibrate", "--source", str(tmp_path / "rest.aedat4"), "--sim-rotation", "30")
    assert done.returncode == 2
    assert (
        done.stderr.strip().count("\n") == 0
        and "--sim-rotation and --sim-no-mirror are for --source sim" in done.stderr
    )


def test_steps_ask_for_what_they_check():
    """Every check prompt names its gesture, every push prompt its way."""
    ways = {(0.0, 1.0): "up", (0.0, -1.0): "down", (-1.0, 0.0): "left", (1.0, 0.0): "right"}
    for step in CHECK_STEPS:
        if step.gesture is GestureType.PUSH:
            assert ways[step.direction] in step.prompt
        else:
            assert step.gesture.value.split("_")[0] in step.prompt


def test_a_person_at_the_camera_is_guided_by_prompts_alone(tmp_path):
    """The live camera's path (the real DavisSource, its capture backend replaying a recording in
    wall time, ``tests/camera_replay.py``): a person at a camera mounted unmirrored and turned
    90 degrees pushes up, then right, as asked; nothing is typed and the mounting is found."""
    from camera_replay import ReplayWorld

    from neurotouch_hid.calibration.guide import LiveCamera
    from neurotouch_hid.service.warmup import compile_pipeline
    from neurotouch_hid.sources.hands import guided_gesture
    from neurotouch_hid.sources.recording_writer import RecordingWriter
    from neurotouch_hid.sources.simulator import GelSimulator

    camera = SensorGeometry(mirror=False, rotation_deg=90.0)
    sim = GelSimulator(camera, script=())
    start = sim.t_us + 800_000
    for step in CALIBRATION_PUSHES:  # the person's pushes, each after the previous one settled
        push = guided_gesture(step.gesture, start, step.direction)
        sim.perform(push)
        start = push.t_settled_us + 300_000
    recording = tmp_path / "person.aedat4"
    with RecordingWriter(recording, width=camera.width, height=camera.height) as writer:
        while sim.t_us < start + 500_000:
            chunk = sim.step()
            writer.write_frame(chunk.frame)
            writer.write_events(chunk.events)

    said: list[str] = []
    # as `calibrate --guided` does before the camera opens: the replay runs in wall time, and a
    # kernel compiled mid-stream would stall it
    compile_pipeline()
    with LiveCamera(calibration.CAMERA_WAIT_S, backend=ReplayWorld(recording)) as source:
        rest = calibration.calibrate(source.rest_frames(calibration.REST_FRAMES)).sensor
        mirror, rotation = measure_orientation(source, source.stream(), rest, said.append)
    assert mirror is False and turn_difference(rotation, 90.0) < 3.0
    assert not any("simulated hand" in line for line in said)  # the prompts are for the person


def test_a_recording_on_a_terminal_is_calibrated_without_a_question_it_cannot_answer(tmp_path):
    """On a terminal, a recording (which cannot be pushed) used to be met with "Rotation from the
    mirrored image to your view"; now it takes the defaults and says how to measure them."""
    from neurotouch_hid.sources.recording_writer import RecordingWriter
    from neurotouch_hid.sources.simulator import GelSimulator

    sim = GelSimulator(SensorGeometry(), script=())
    recording = tmp_path / "rest.aedat4"
    with RecordingWriter(recording) as writer:
        for _ in range(15):
            chunk = sim.step()
            writer.write_frame(chunk.frame)
            writer.write_events(chunk.events)
    terminal, keyboard = os.openpty()  # stdin is a terminal nobody types on
    try:
        done = subprocess.run(
            [sys.executable, "-m", "neurotouch_hid.cli", "calibrate", "--source", str(recording)],
            capture_output=True,
            text=True,
            stdin=keyboard,
            timeout=120,  # a question nobody answers ends here
        )
    finally:
        os.close(terminal)
        os.close(keyboard)
    assert done.returncode == 0, done.stdout + done.stderr
    assert "Rotation from" not in done.stdout and "?" not in done.stdout
    assert "calibrate with the camera to measure them" in done.stdout


def test_a_check_gesture_done_too_weakly_is_asked_again_not_blamed_on_the_calibration():
    source, rest, said = started(SensorGeometry(mirror=True, rotation_deg=0.0), push_mm=[0.3])
    push_up = [s for s in CHECK_STEPS if s.name == "push up"]
    results = guided_check(source, source.stream(), rest, said.append, push_up)
    assert len(results) == 1 and results[0].right
    first, second = [line for line in said if line.strip().startswith("push up:")]
    assert "WRONG" in first and "do it more firmly" in first and first.endswith("again:")
    assert "push up: right" in second


@pytest.mark.parametrize(("mirror", "rotation"), [(True, 90.0), (False, -45.0), (True, 180.0)])
def test_the_checks_pushes_name_the_flags_that_would_make_them_right(mirror, rotation):
    """Pushes as a camera mounted (mirror, rotation) shows them, read with the default calibration
    (mirror, 0 degrees): the advice names that mounting. The reads are made with the sensor's own
    conversions."""
    from neurotouch_hid.calibration.guide import Attempt, check_advice, judge

    truth = SensorGeometry(mirror=mirror, rotation_deg=rotation)
    told = SensorGeometry()
    results = []
    for step in CHECK_STEPS:
        if step.gesture is GestureType.PUSH:
            read = told.vectors_image_to_user(truth.vectors_user_to_image(np.array(step.direction) * 2.5))
            attempt = Attempt(((GestureType.PUSH, 50),), 4.0, read, 2.0, 0.0)
        else:
            attempt = Attempt(((step.gesture, 50),), 2.5, np.zeros(2), 0.0, 0.0)
        results.append(judge(step, attempt))
    advice = check_advice(results, told)
    flag = "--mirror" if mirror else "--no-mirror"
    assert advice is not None and advice.endswith(f"or give {flag} --rotation {rotation:g}"), advice
    assert check_advice([judge(r.step, r.attempt) for r in results if r.right], told) is None


def test_troubleshooting_lists_what_calibrate_says():
    from pathlib import Path

    from neurotouch_hid.calibration.guide import Attempt, push_problem

    text = (Path(__file__).resolve().parents[1] / "docs" / "troubleshooting.md").read_text()
    weak = push_problem(Attempt(((GestureType.PUSH, 40),), 0.4, np.array([0.3, 0.0]), 1.0, 0.0))
    assert weak is not None and weak.split(" 0.4 mm")[0] in text
    assert "no usable push up in 3 tries" in text and "what to do:" in text
