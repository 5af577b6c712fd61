"""``neurotouch-hid calibrate``: sensor.yaml measured from rest frames (simulated gel, a real street
recording, frames without a gel), and where run, track and eval then find it."""

from __future__ import annotations

import dataclasses
import logging
import math
import shutil
from pathlib import Path

import numpy as np
import pytest
from helpers import run_cli

from neurotouch_hid.calibration.measure import calibrate, read_rest_frames
from neurotouch_hid.core.dataset import dataset_sensor_file
from neurotouch_hid.core.errors import DatasetError, SensorError
from neurotouch_hid.core.estimate import GestureType
from neurotouch_hid.core.sensor import SensorGeometry, default_sensor, find_sensor_file, user_sensor_path
from neurotouch_hid.sources import Frame
from neurotouch_hid.sources.hands import USERS, gesture_script
from neurotouch_hid.sources.sim_dataset import write_dataset
from neurotouch_hid.sources.simulator import START_US, GelSimulator

#: Not the default geometry: centre ~10 px off, 2.3 px/mm, the 30 mm radius at that scale.
SHIFTED = SensorGeometry(px_per_mm=2.3, gel_center_px=(183.0, 121.0), gel_radius_px=69.0)


def assert_recovers(found: SensorGeometry, truth: SensorGeometry) -> None:
    """The calibration's tolerance: centre within 2 px, px_per_mm within 3 % (and the radius too)."""
    dx, dy = np.subtract(found.gel_center_px, truth.gel_center_px)
    assert math.hypot(dx, dy) <= 2.0, (found, truth)
    assert found.px_per_mm == pytest.approx(truth.px_per_mm, rel=0.03)
    assert found.gel_radius_px == pytest.approx(truth.gel_radius_px, rel=0.03)
    assert (found.width, found.height) == (truth.width, truth.height)


def test_the_shifted_geometry_is_out_of_tolerance_of_the_default():
    """Guards the tests below: a calibrator returning the defaults cannot pass them."""
    default = SensorGeometry()
    with pytest.raises(AssertionError):
        assert_recovers(default, SHIFTED)


@pytest.fixture(scope="module")
def shifted_dataset(tmp_path_factory) -> Path:
    """:func:`sim_rest_dataset` (tests/conftest.py) in the SHIFTED geometry."""
    return write_dataset(
        tmp_path_factory.mktemp("shifted"), users=[0], gestures=["push"], minutes=0.01, progress=False, sensor=SHIFTED
    )


@pytest.fixture(params=["default", "shifted"])
def sim_dataset(request) -> Path:
    return request.getfixturevalue("sim_rest_dataset" if request.param == "default" else "shifted_dataset")


@pytest.fixture(scope="module")
def rest_frames() -> list[Frame]:
    """10 APS frames of the simulated gel at rest, in the SHIFTED geometry."""
    sim = GelSimulator(SHIFTED, USERS[3], seed=5)
    return [sim.step().frame for _ in range(10)]


def test_recovers_the_simulators_sensor_yaml_from_its_recording(sim_dataset):
    truth = SensorGeometry.load(sim_dataset / "sensor.yaml")
    result = calibrate(read_rest_frames(sim_dataset / "u0_push.aedat4"))
    assert_recovers(result.sensor, truth)
    assert result.edge_found and result.notes == ()
    assert result.n_markers == len(np.load(sim_dataset / "u0_push.markers.npz")["rest_px"])
    assert result.spacing_px / 4.0 == pytest.approx(truth.px_per_mm, rel=0.03)  # 4 mm grid at the centre
    assert len(result.frames_t_us) == 10


def test_refuses_a_street_recording(any_street):
    with pytest.raises(SensorError, match="no gel in view") as caught:
        calibrate(read_rest_frames(any_street.path))
    assert "\n" not in str(caught.value)


@pytest.mark.parametrize(
    "image",
    [
        np.zeros((260, 346), np.uint8),  # camera covered / LEDs off
        np.full((260, 346), 255, np.uint8),  # saturated
        np.random.default_rng(0).integers(0, 30, (260, 346)).astype(np.uint8),  # dark noise
    ],
    ids=["black", "white", "noise"],
)
def test_refuses_frames_without_a_gel(image):
    with pytest.raises(SensorError, match="no gel in view"):
        calibrate(Frame(40_000 * k, image) for k in range(10))


def test_refuses_when_the_gel_moves_during_calibration():
    """A push starting 80 ms into the rest frames: the user touched the gel."""
    script = gesture_script(
        np.random.default_rng(1), USERS[0], [GestureType.PUSH], START_US, SHIFTED, first_rest_us=80_000
    )
    sim = GelSimulator(SHIFTED, USERS[0], script=script)
    frames = [sim.step().frame for _ in range(10)]
    with pytest.raises(SensorError, match="keep your hands off the gel"):
        calibrate(frames)


def test_needs_a_few_frames(rest_frames):
    with pytest.raises(SensorError, match="at least 3 APS frames"):
        calibrate(rest_frames[:2])


def test_marker_count_is_checked_against_the_expected_count(rest_frames):
    n = calibrate(rest_frames).n_markers
    assert calibrate(rest_frames, expected_markers=n).notes == ()
    note = calibrate(rest_frames, expected_markers=round(n * 1.3)).notes
    assert len(note) == 1 and f"{n} markers found" in note[0]
    with pytest.raises(SensorError, match="fewer than half"):
        calibrate(rest_frames, expected_markers=2 * n + 1)


def test_without_a_visible_edge_the_circle_comes_from_the_marker_grid(rest_frames):
    """The surroundings as bright as the gel: the disc's edge cannot be seen."""
    lift = np.where(SHIFTED.gel_mask() > 0, 0, 12).astype(np.uint8)
    frames = [Frame(f.t_us, f.image + lift) for f in rest_frames]
    result = calibrate(frames)
    assert not result.edge_found and "edge is not visible" in result.notes[0]
    dx, dy = np.subtract(result.sensor.gel_center_px, SHIFTED.gel_center_px)
    assert math.hypot(dx, dy) <= 2.0
    assert result.sensor.px_per_mm == pytest.approx(SHIFTED.px_per_mm, rel=0.03)
    assert result.sensor.inside_gel(result.markers_px).all()


# --- where the calibration goes and who finds it -------------------------------------------------
def test_user_calibration_comes_between_the_recording_and_the_default(tmp_path):
    recording = tmp_path / "alone" / "rec.aedat4"
    recording.parent.mkdir()
    assert default_sensor() == SensorGeometry() == find_sensor_file(recording)
    user_sensor_path().parent.mkdir(parents=True)
    SHIFTED.save(user_sensor_path())
    assert default_sensor() == SHIFTED == find_sensor_file(recording)
    beside = SensorGeometry(px_per_mm=3.0)
    beside.save(recording.with_name("sensor.yaml"))
    assert find_sensor_file(recording) == beside
    explicit = SensorGeometry(px_per_mm=2.0)
    explicit.save(tmp_path / "explicit.yaml")
    assert find_sensor_file(recording, tmp_path / "explicit.yaml") == explicit


def test_a_dataset_without_sensor_yaml_takes_the_users_calibration(tmp_path):
    dataset = tmp_path / "dataset"
    dataset.mkdir()
    with pytest.raises(DatasetError, match="no sensor.yaml.*neurotouch-hid calibrate"):
        dataset_sensor_file(dataset)
    user_sensor_path().parent.mkdir(parents=True)
    SHIFTED.save(user_sensor_path())
    assert dataset_sensor_file(dataset) == user_sensor_path()
    SensorGeometry().save(dataset / "sensor.yaml")
    assert dataset_sensor_file(dataset) == dataset / "sensor.yaml"


def test_eval_says_it_uses_the_users_calibration(shifted_dataset, tmp_path, caplog):
    from neurotouch_hid.evaluation.runner import evaluate_dataset

    dataset = tmp_path / "no_sensor"
    dataset.mkdir()
    for name in ("u0_push.aedat4", "u0_push.labels.csv"):
        shutil.copy(shifted_dataset / name, dataset / name)
    user_sensor_path().parent.mkdir(parents=True)
    shutil.copy(shifted_dataset / "sensor.yaml", user_sensor_path())
    with caplog.at_level(logging.WARNING):
        result = evaluate_dataset(dataset)
    assert result.n_sequences == 1
    assert f"using your calibration {user_sensor_path()}" in caplog.text


def test_calibrate_command_writes_sensor_yaml_where_track_finds_it(shifted_dataset, tmp_path):
    truth = SensorGeometry.load(shifted_dataset / "sensor.yaml")
    recording = tmp_path / "elsewhere" / "rest.aedat4"  # no sensor.yaml beside it
    recording.parent.mkdir()
    shutil.copy(shifted_dataset / "u0_push.aedat4", recording)

    out = tmp_path / "out" / "sensor.yaml"
    out.parent.mkdir()  # an --out folder is not made (a typo in it is refused); your config folder is
    done = run_cli(
        "calibrate", "--source", str(recording), "--out", str(out), "--no-mirror", "--rotation", "30", columns=200
    )
    assert done.returncode == 0, done.stderr
    written = SensorGeometry.load(out)
    assert_recovers(written, truth)
    assert (written.mirror, written.rotation_deg) == (False, 30.0)
    assert not user_sensor_path().exists()

    done = run_cli("calibrate", "--source", str(recording), columns=200)  # no terminal: the defaults, said so
    assert done.returncode == 0, done.stderr
    assert "not asked" in done.stdout and str(user_sensor_path()) in done.stdout
    calibrated = find_sensor_file(recording)
    assert calibrated == SensorGeometry.load(user_sensor_path())
    assert_recovers(calibrated, truth)
    assert (calibrated.mirror, calibrated.rotation_deg) == (True, 0.0)

    done = run_cli("calibrate", "--source", str(recording), "--rotation", "90", columns=200)
    assert done.returncode == 0, done.stderr
    assert f"replacing {user_sensor_path()}" in done.stdout and "rotation_deg: 0.0 -> 90.0" in done.stdout
    assert find_sensor_file(recording).rotation_deg == 90.0


def test_calibrate_command_refuses_a_scene_without_gel_in_one_line(any_street):
    done = run_cli("calibrate", "--source", str(any_street.path), columns=200)
    assert done.returncode == 2
    assert "no gel in view" in done.stderr and len(done.stderr.strip().splitlines()) == 1
    assert not user_sensor_path().exists()


def test_calibrate_fits_the_camera_model_that_the_perspective_camera_needs(tmp_path):
    """The ``camera`` physics family (a pinhole under the dome, barrel distortion): one px_per_mm
    misplaces gel points by up to ~1 mm; the camera model fitted to the rest grid puts them
    within 0.1 mm, and sensor.yaml keeps it."""
    from neurotouch_hid.sources.physics import PHYSICS, DomeCamera

    dataset = write_dataset(
        tmp_path / "camera", users=[0], gestures=[GestureType.PUSH], minutes=0.01, progress=False, physics="camera"
    )
    nominal = SensorGeometry.load(dataset / "sensor.yaml")
    result = calibrate(read_rest_frames(dataset / "u0_push.aedat4"))
    camera = DomeCamera(nominal, PHYSICS["camera"])
    gel_mm = np.array([[0.5, 0.0], [0.0, 10.0], [-20.0, 0.0], [15.0, 20.0], [0.0, -28.0]])
    image = camera.project(gel_mm)
    linear = dataclasses.replace(result.sensor, radial_k=None)
    assert np.abs(linear.image_to_user(image) - gel_mm).max() > 0.8
    assert np.abs(result.sensor.image_to_user(image) - gel_mm).max() < 0.1
    np.testing.assert_allclose(result.sensor.user_to_image(result.sensor.image_to_user(image)), image, atol=1e-6)
    result.sensor.save(tmp_path / "sensor.yaml")
    assert SensorGeometry.load(tmp_path / "sensor.yaml").radial_k == result.sensor.radial_k
