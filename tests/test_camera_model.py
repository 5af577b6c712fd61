"""The camera model from the marker grid at rest (``camera_model.py``, ``SensorGeometry.radial_k``):
image px -> gel mm over the whole gel, fitted by ``calibrate`` and by the pipeline."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from neurotouch_hid.core.camera_model import DOME_SPHERE_MM, MARKER_SPACING_MM, fit_camera_model, grid_orientation
from neurotouch_hid.core.sensor import SensorGeometry
from neurotouch_hid.pipeline.gesture import estimate_gesture
from neurotouch_hid.sources import gel as simulated_gel
from neurotouch_hid.sources.gel import Gel
from neurotouch_hid.sources.physics import PHYSICS, DomeCamera

SENSOR = SensorGeometry()


def test_the_gel_constants_are_the_simulators_and_the_trackers():
    assert DOME_SPHERE_MM == simulated_gel.DOME_SPHERE_MM
    assert MARKER_SPACING_MM == simulated_gel.MARKER_PITCH_MM


def gel(family: str, sensor: SensorGeometry = SENSOR) -> Gel:
    return Gel(sensor, np.random.default_rng(0), PHYSICS[family])


def test_a_perspective_camera_is_recovered_from_its_rest_grid():
    g = gel("camera")
    model = fit_camera_model(g.rest_px, SENSOR)
    assert model is not None
    assert model.px_per_mm == pytest.approx(2.27, abs=0.01)  # sensor.yaml's nominal scale is 2.5
    np.testing.assert_allclose(model.image_to_user(g.rest_px), g.rest_mm, atol=0.05)
    assert np.abs(SENSOR.image_to_user(g.rest_px) - g.rest_mm).max() > 1.0  # one scale: ~1 mm off
    camera = DomeCamera(SENSOR, PHYSICS["camera"])
    between = np.array([[1.3, -2.1], [11.0, 7.5], [-18.2, 9.9], [3.0, -27.0]])  # not marker positions
    np.testing.assert_allclose(model.image_to_user(camera.project(between)), between, atol=0.05)


def test_the_orthographic_camera_gives_the_linear_model_back_whatever_the_grids_angle():
    model = fit_camera_model(gel("default").rest_px, SENSOR)
    assert model.px_per_mm == pytest.approx(2.5, abs=0.005)
    assert np.abs(model.radial_k).max() < 0.005
    turned = dataclasses.replace(SENSOR, rotation_deg=0.0)
    pts = gel("default").rest_px - SENSOR.gel_center_px
    a = np.radians(20.0)
    rotated = pts @ np.array([[np.cos(a), np.sin(a)], [-np.sin(a), np.cos(a)]]) + SENSOR.gel_center_px
    assert grid_orientation(rotated) == pytest.approx(a, abs=0.01)
    again = fit_camera_model(rotated, turned)
    assert again.px_per_mm == pytest.approx(2.5, abs=0.005)


def test_points_that_are_not_the_grid_give_no_model():
    rng = np.random.default_rng(1)
    scattered = SENSOR.gel_center_px + rng.uniform(-70, 70, (150, 2))
    assert fit_camera_model(scattered, SENSOR) is None
    assert fit_camera_model(gel("default").rest_px[:5], SENSOR) is None


def test_intensity_is_the_gel_displacement_with_the_camera_model_not_with_one_scale():
    """A 5 mm push near the centre of the perspective camera: px / px_per_mm reads it wrong
    (sensor.yaml's 2.5 px/mm is not the centre's 2.27); the model reads 5 mm."""
    g = gel("camera")
    camera = DomeCamera(SENSOR, PHYSICS["camera"])
    finger = g.rest_mm[np.argmin(np.linalg.norm(g.rest_mm - [4.0, 4.0], axis=1))]
    d = np.linalg.norm(g.rest_mm - finger, axis=1)
    w = np.where(d < 6.0, 1.0, np.exp(-((d - 6.0) ** 2) / (2 * 4.0**2)))  # a stuck disc of 6 mm
    moved_mm = g.rest_mm + w[:, None] * [5.0, 0.0]
    current = camera.project(moved_mm)
    contact = camera.project(finger + [5.0, 0.0])[None]
    model = fit_camera_model(g.rest_px, SENSOR)
    options = dict(r_px=25.0, intensity_sigma_px=3.0, min_intensity_px=0.3)
    linear = estimate_gesture(g.rest_px, current, None, contact, SENSOR, **options)
    fitted = estimate_gesture(g.rest_px, current, None, contact, model, **options)
    assert abs(linear.intensity_mm - 5.0) > 0.3
    assert fitted.intensity_mm == pytest.approx(5.0, abs=0.1)
    assert fitted.gesture is linear.gesture  # the type is decided in px, as before


def test_the_pipeline_fits_the_model_to_its_rest_reference_and_its_pixel_settings_follow():
    from neurotouch_hid.pipeline.paper import PaperConfig, PaperPipeline
    from neurotouch_hid.pipeline.pipeline import GesturePipeline
    from neurotouch_hid.sources.simulator import GelSimulator

    frame = GelSimulator(SENSOR, physics=PHYSICS["camera"]).step().frame
    pipeline = GesturePipeline(SENSOR)
    pipeline.process(frame)
    assert pipeline.sensor.radial_k is not None
    assert pipeline.sensor.px_per_mm == pytest.approx(2.27, abs=0.01)
    assert pipeline.config.r_px == pytest.approx(25.0 * pipeline.sensor.px_per_mm / 2.5)
    paper = PaperPipeline(SENSOR)  # the paper's one scale and fixed pixels
    paper.process(frame)
    assert paper.sensor is SENSOR and paper.config.r_px == PaperConfig().r_px
    calibrated = dataclasses.replace(SENSOR, radial_k=(0.0, 0.0))  # sensor.yaml's own model is kept
    kept = GesturePipeline(calibrated)
    kept.process(frame)
    assert kept.sensor is calibrated


def test_contacts_are_found_on_the_gel_not_on_the_magnified_image():
    """Two fingers twisting a wide field (8 mm) under the perspective camera: the rim is
    magnified, so in image px each finger's field peaks outward of it, 0.8-1.2 mm off. The
    pipeline looks for the contacts on the positions undistorted by the camera model and finds
    both fingers within 0.3 mm (docs/method.md, "Contacts")."""
    from neurotouch_hid.pipeline.pipeline import GesturePipeline

    g = gel("camera")
    camera = DomeCamera(SENSOR, PHYSICS["camera"])
    model = fit_camera_model(g.rest_px, SENSOR)
    fingers = np.array([[14.0, -8.0], [-6.0, 10.0]])
    moves = np.array([[-2.0, 1.0], [2.0, -1.0]])
    moved = g.rest_mm.copy()
    for finger, move in zip(fingers, moves):
        moved += np.exp(-np.sum((g.rest_mm - finger) ** 2, axis=1) / (2 * 8.0**2))[:, None] * move
    rest, current = camera.project(g.rest_mm), camera.project(moved)
    valid = np.ones(len(rest), dtype=bool)

    def errors_mm(sensor: SensorGeometry) -> np.ndarray:
        contacts, _ = GesturePipeline(sensor)._fit(rest, current, valid)
        found = model.image_to_user(contacts.points_px)
        assert len(found) == 2
        return np.linalg.norm(found[:, None] - (fingers + moves)[None], axis=2).min(axis=0)

    on_the_image = errors_mm(dataclasses.replace(model, radial_k=None))  # the same scale, no model
    assert on_the_image.min() > 0.6
    assert errors_mm(model).max() < 0.3
