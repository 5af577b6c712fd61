"""docs/dataset.md labels CSV: exact columns, round trip, and errors that name file, line and column."""

import csv

import numpy as np
import pytest

from neurotouch_hid.core.dataset import LabelRow, list_sequences, read_labels, write_labels
from neurotouch_hid.core.errors import DatasetError
from neurotouch_hid.core.estimate import GestureEstimate, GestureType

DATASET_MD_HEADER = "t_us,gesture,resting,intensity_mm,n_contacts,x1_px,y1_px,x2_px,y2_px,x3_px,y3_px"


def _rows():
    return [
        LabelRow(0, GestureType.NONE, True, 0.0),
        LabelRow(40_000, GestureType.PINCH, False, 2.5, np.array([[150.0, 120.5], [190.25, 125.0]])),
        LabelRow(80_000, GestureType.TWIST_CCW, False, 4.0, np.array([[1.0, 2.0], [3.0, 4.0], [5.0, 6.0]])),
    ]


def test_labels_csv_has_dataset_md_columns_and_empty_cells(tmp_path):
    path = tmp_path / "s.labels.csv"
    write_labels(path, _rows())
    lines = path.read_text().splitlines()
    assert lines[0] == DATASET_MD_HEADER
    cells = list(csv.reader(lines))
    assert cells[1][:5] == ["0", "none", "1", "0.0000", "0"] and cells[1][5:] == [""] * 6
    assert cells[2][4:9] == ["2", "150.000", "120.500", "190.250", "125.000"] and cells[2][9:] == ["", ""]


def test_labels_round_trip(tmp_path):
    path = tmp_path / "s.labels.csv"
    write_labels(path, _rows())
    back = read_labels(path)
    for a, b in zip(_rows(), back):
        assert (a.t_us, a.gesture, a.resting, a.intensity_mm) == (b.t_us, b.gesture, b.resting, b.intensity_mm)
        assert np.allclose(a.contacts_px, b.contacts_px)


@pytest.mark.parametrize(
    "row, message",
    [
        ("40000,wave,0,1.0,0,,,,,,", r":3: column 'gesture'"),
        ("40000,push,2,1.0,0,,,,,,", r":3: column 'resting'"),
        ("40000,push,0,1.0,1,,,,,,", r":3: column 'x1_px'"),
        ("10,push,0,1.0,0,,,,,,", r":3: rows must be ordered by time"),
        # a time in seconds: microseconds are integers
        ("0.04,none,1,0,0,,,,,,", r":3: column 't_us': expected an integer time in microseconds.*found '0\.04'"),
        (",none,1,0,0,,,,,,", r":3: column 't_us': expected an integer time in microseconds.*found ''"),
        ("40000,Push,0,1.0,1,10,10,,,,", r":3: column 'gesture': expected one of none, push, pinch.*found 'Push'"),
        ("40000,push,0,abc,1,10,10,,,,", r":3: column 'intensity_mm': expected mm from 0 to 60, found 'abc'"),
        ("40000,push,0,1.0,1.0,10,10,,,,", r":3: column 'n_contacts': expected an integer from 0 to 3, found '1\.0'"),
        # two contacts said, one given: the column that is missing is named
        ("40000,push,0,1.0,2,10,10,,,,", r":3: column 'x2_px': expected image pixels from -4096 to 4096, found ''"),
        # one contact said, two given: the second would be dropped without a word
        ("40000,push,0,1.0,1,10,10,20,20,,", r":3: column 'x2_px': expected empty \(n_contacts is 1\), found '20'"),
        # `none` has no intensity (docs/dataset.md: 0 for none)
        ("40000,none,1,3.0,0,,,,,,", r":3: column 'intensity_mm': expected 0 for gesture none, found '3\.0'"),
    ],
)
def test_bad_label_rows_name_line_and_column(tmp_path, row, message):
    path = tmp_path / "bad.labels.csv"
    path.write_text(f"{DATASET_MD_HEADER}\n20000,none,1,0,0,,,,,,\n{row}\n")
    with pytest.raises(DatasetError, match=r"bad\.labels\.csv" + message):
        read_labels(path)


def test_list_sequences_needs_sensor_yaml_and_pairs(tmp_path):
    with pytest.raises(DatasetError, match="no recording in it"):  # the recordings are said first
        list_sequences(tmp_path)
    (tmp_path / "a.aedat4").write_bytes(b"")
    (tmp_path / "a.labels.csv").write_text(DATASET_MD_HEADER + "\n")
    with pytest.raises(DatasetError, match="no sensor.yaml"):
        list_sequences(tmp_path)
    (tmp_path / "sensor.yaml").write_text("width: 346\n")
    (tmp_path / "b.aedat4").write_bytes(b"")  # no labels: not a sequence
    assert list_sequences(tmp_path) == ["a"]


def test_prediction_json_line_round_trip():
    est = GestureEstimate(
        t_us=1234567,
        gesture=GestureType.PINCH,
        resting=False,
        intensity_mm=2.7,
        contacts_px=np.array([[150.2, 120.4], [190.1, 125.0]]),
        contacts_mm=np.array([[-9.2, 4.0], [6.8, 2.0]]),
    )
    d = est.to_json_dict()
    assert {"t_us", "gesture", "resting", "intensity_mm", "contacts_px", "contacts_mm"} <= d.keys()
    assert d["gesture"] == "pinch" and d["resting"] is False
    back = GestureEstimate.from_json_dict(d)
    assert back.gesture is GestureType.PINCH and np.allclose(back.contacts_px, est.contacts_px) and back.n_contacts == 2
