"""SensorGeometry: docs/dataset.md's image <-> user frame formula, sensor.yaml loading and its errors."""

import math

import numpy as np
import pytest

from neurotouch_hid.errors import SensorError
from neurotouch_hid.sensor import SensorGeometry


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
