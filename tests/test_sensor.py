"""SensorGeometry: docs/dataset.md's image <-> user frame formula, sensor.yaml loading and its errors."""

import math

import numpy as np
import pytest

from neurotouch_hid.core.errors import SensorError
from neurotouch_hid.core.sensor import SensorGeometry


def test_image_to_user_follows_dataset_formula_with_mirror():
    g = SensorGeometry()  # cx=173, cy=130, 2.5 px/mm, mirror
    # 25 px right of the centre in the image is 10 mm to the LEFT for the user (mirror).
    assert np.allclose(g.image_to_user([198.0, 130.0]), [-10.0, 0.0])
    # 25 px down in the image is 10 mm down for the user (y up in the user frame).
    assert np.allclose(g.image_to_user([173.0, 155.0]), [0.0, -10.0])


def test_rotation_is_counter_clockwise_after_the_mirror():
    g = SensorGeometry(rotation_deg=90.0)
    # mirrored image point (-10, 0) mm rotated 90 deg CCW -> (0, -10) mm
    assert np.allclose(g.image_to_user([198.0, 130.0]), [0.0, -10.0], atol=1e-9)


@pytest.mark.parametrize("mirror", [True, False])
@pytest.mark.parametrize("rotation", [0.0, 33.0, -120.0])
def test_user_to_image_inverts_image_to_user(mirror, rotation):
    g = SensorGeometry(mirror=mirror, rotation_deg=rotation)
    pts = np.random.default_rng(0).uniform([0, 0], [346, 260], size=(20, 2))
    assert np.allclose(g.user_to_image(g.image_to_user(pts)), pts)


def test_a_rotation_in_the_image_is_the_opposite_rotation_for_the_user():
    g = SensorGeometry()
    # a point on a circle moving counter-clockwise as displayed (y up) in the image ...
    a0, a1 = 0.0, 0.2
    img = (
        [g.gel_center_px[0] + 20 * math.cos(a) for a in (a0, a1)],
        [g.gel_center_px[1] - 20 * math.sin(a) for a in (a0, a1)],
    )
    user = g.image_to_user(np.stack(img, axis=1))
    cross = user[0, 0] * user[1, 1] - user[0, 1] * user[1, 0]
    assert cross < 0  # ... moves clockwise for the user (negative cross product)
    assert g.rotation_image_to_user(0.2) == pytest.approx(-0.2)


def test_save_load_round_trip_keeps_extra_fields(tmp_path):
    g = SensorGeometry(px_per_mm=2.4, gel_center_px=(170.5, 131.0), extra={"n_markers": 177})
    g.save(tmp_path / "sensor.yaml")
    back = SensorGeometry.load(tmp_path / "sensor.yaml")
    assert back == g and back.extra == {"n_markers": 177}


def test_bad_sensor_files_name_the_file_and_field(tmp_path):
    with pytest.raises(SensorError, match="no such sensor file"):
        SensorGeometry.load(tmp_path / "missing.yaml")
    bad = tmp_path / "bad.yaml"
    bad.write_text("px_per_mm: fast\n")
    with pytest.raises(SensorError, match=r"bad.yaml.*px_per_mm"):
        SensorGeometry.load(bad)
    bad.write_text("- 1\n- 2\n")
    with pytest.raises(SensorError, match="expected a mapping"):
        SensorGeometry.load(bad)


def test_gel_mask_and_inside_gel_agree():
    g = SensorGeometry()
    mask = g.gel_mask()
    assert mask.shape == (260, 346)
    assert mask[130, 173] == 255 and mask[0, 0] == 0
    assert g.inside_gel(np.array([[173.0 + 74, 130.0]]))[0] and not g.inside_gel(np.array([[173.0 + 76, 130.0]]))[0]


def test_every_bad_field_is_named_with_its_line_and_what_was_expected(tmp_path):
    bad = tmp_path / "sensor.yaml"
    bad.write_text("width: 346\npx_per_mm: -2\nmirror: 1\nn_markers: 177\n")
    with pytest.raises(SensorError) as info:
        SensorGeometry.load(bad)
    message = str(info.value)
    assert f"{bad}:2: field 'px_per_mm': found -2; input should be greater than 0" in message
    assert f"{bad}:3: field 'mirror': found 1" in message and "boolean" in message


@pytest.mark.parametrize("value", ["true", "346.5"])
def test_an_image_size_that_is_no_whole_number_is_named_not_blamed_on_the_recording(tmp_path, value):
    """``width: true`` read as 1, and the error then blamed the recording ("346x260 px but 1x260
    is required")."""
    bad = tmp_path / "sensor.yaml"
    bad.write_text(f"height: 260\nwidth: {value}\n")
    with pytest.raises(SensorError, match=rf"{bad}:2: field 'width': found .*valid integer"):
        SensorGeometry.load(bad)


def test_undistorted_px_are_base_plane_mm_at_the_centres_scale_and_distort_inverts_them():
    """``undistort``: the camera model's radial gain taken out of the image, so one px is one
    base-plane mm / px_per_mm near the rim as at the centre; ``distort`` puts it back."""
    sensor = SensorGeometry(radial_k=(-0.105, 0.0115), rotation_deg=30.0)
    rng = np.random.default_rng(3)
    points = np.asarray(sensor.gel_center_px) + rng.uniform(-60.0, 60.0, (40, 2))
    flat = sensor.undistort(points)
    linear = SensorGeometry(rotation_deg=30.0)  # the same geometry without a camera model
    np.testing.assert_allclose(linear.image_to_user(flat), sensor.image_to_user(points), atol=1e-9)
    np.testing.assert_allclose(sensor.distort(flat), points, atol=1e-9)
    rim = np.asarray(sensor.gel_center_px) + [[60.0, 0.0], [61.0, 0.0]]  # 1 px apart near the rim
    assert np.linalg.norm(np.diff(sensor.undistort(rim), axis=0)) < 0.85  # the rim is magnified
    assert np.array_equal(linear.undistort(points), points) and np.array_equal(linear.distort(points), points)
    lost = sensor.undistort(np.array([[np.nan, np.nan], [200.0, 140.0]]))
    assert np.isnan(lost[0]).all() and np.isfinite(sensor.distort(lost)[1]).all()


def test_a_folded_camera_model_is_refused_with_its_file_line_and_field(tmp_path):
    """A camera model must map the image radius one to one over the gel: k1 = -2 folds the rim
    back onto the gel (and ``distort`` could not invert it), so the file is refused."""
    bad = tmp_path / "sensor.yaml"
    bad.write_text("width: 346\nradial_k: [-2.0, 0.1]\n")
    with pytest.raises(SensorError) as info:
        SensorGeometry.load(bad)
    assert f"{bad}:2: field 'radial_k': found [-2.0, 0.1]; expected a camera model" in str(info.value)
    good = tmp_path / "fitted.yaml"
    good.write_text("width: 346\nradial_k: [-0.105, 0.0115]\n")
    assert SensorGeometry.load(good).radial_k == (-0.105, 0.0115)
