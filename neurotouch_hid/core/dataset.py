"""The labelled dataset format of docs/dataset.md: folders of sequences, labels CSV, predictions.

A dataset is a folder with ``sensor.yaml`` and, per sequence, ``SEQUENCE.aedat4`` and
``SEQUENCE.labels.csv`` (paper, section "Creation of the Gesture Detection Dataset"). A folder
without ``sensor.yaml`` takes the user's calibration (``neurotouch-hid calibrate``) instead.
Predictions are JSON lines, one :meth:`GestureEstimate.to_json_dict` object a line, ordered by
time, written by the shared line writer (:mod:`neurotouch_hid.core.jsonl_writer`: a path or an
open text stream, ``-`` = stdout), so other JSON-lines outputs write the same way. A dataset
folder is written whole by :mod:`neurotouch_hid.core.dataset_out`.

A format module beneath every stage: the simulator writes datasets, ``track`` and ``eval`` write
predictions, ``run`` replays them, evaluation reads all of them.
"""

from __future__ import annotations

import csv
import io
import json
import logging
import math
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any, Sequence

import numpy as np

from neurotouch_hid.core.atomic import AtomicFile
from neurotouch_hid.core.errors import DatasetError
from neurotouch_hid.core.estimate import GestureEstimate, GestureType
from neurotouch_hid.core.jsonl_writer import JsonlWriter
from neurotouch_hid.core.limits import MAX_SENSOR_PX, printable, read_outside_lines, read_outside_text, short
from neurotouch_hid.core.sensor import user_sensor_path

log = logging.getLogger(__name__)

#: Largest predictions file read (bytes; read line by line): an hour of 10 ms windows is ~80 MB.
MAX_PREDICTIONS_BYTES = 1 << 30
#: Longest line of a predictions file (bytes): a window's line is 180-400 bytes, ~20 bytes more a
#: contact point.
MAX_PREDICTION_LINE_BYTES = 64 << 10

#: The columns of ``SEQUENCE.labels.csv``, in docs/dataset.md's order.
LABEL_COLUMNS: tuple[str, ...] = (
    "t_us",
    "gesture",
    "resting",
    "intensity_mm",
    "n_contacts",
    "x1_px",
    "y1_px",
    "x2_px",
    "y2_px",
    "x3_px",
    "y3_px",
)
MAX_CONTACTS = 3
#: Largest labels file read (bytes) and most rows in it: a row per APS frame, 25 a second, is
#: 40-80 bytes of text and ~0.7 KB once read; 250 000 rows are 2.8 hours of frames, ~180 MB read.
MAX_LABELS_BYTES = 32 << 20
MAX_LABEL_ROWS = 250_000
#: Largest labelled intensity (mm): the dome is 60 mm across; a displacement larger than that is
#: no gel's (``eval`` sizes its intensity histograms by it).
MAX_LABEL_INTENSITY_MM = 60.0


@dataclass(frozen=True)
class LabelRow:
    """One labelled APS frame (docs/dataset.md).

    Attributes:
        t_us: the frame's timestamp, int microseconds, recording clock.
        gesture: the labelled gesture type.
        resting: True when the gel is undeformed.
        intensity_mm: mean displacement of the labelled contact points since the gesture's
            start (mm); 0 for ``none``.
        contacts_px: (K, 2) float64 contact points, image frame px, K in 0..3.
    """

    t_us: int
    gesture: GestureType
    resting: bool
    intensity_mm: float
    contacts_px: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))

    @property
    def n_contacts(self) -> int:
        return int(len(self.contacts_px))


def write_labels(path: str | Path, rows: list[LabelRow]) -> None:
    """Write ``SEQUENCE.labels.csv`` exactly as docs/dataset.md defines it (rows ordered by time).

    The file is written beside its name and renamed into place when complete.

    Raises ValueError when rows are not time-ordered or have more than 3 contacts.
    """
    last = -math.inf
    with AtomicFile(path, what="labels file", newline="") as fh:
        writer = csv.writer(fh)
        writer.writerow(LABEL_COLUMNS)
        for row in rows:
            if row.t_us < last:
                raise ValueError(f"labels are not ordered by time at t_us={row.t_us}")
            last = row.t_us
            if row.n_contacts > MAX_CONTACTS:
                raise ValueError(f"at most {MAX_CONTACTS} contacts per label, got {row.n_contacts}")
            cells: list[str] = [
                str(int(row.t_us)),
                row.gesture.value,
                "1" if row.resting else "0",
                f"{row.intensity_mm:.4f}",
                str(row.n_contacts),
            ]
            for k in range(MAX_CONTACTS):
                if k < row.n_contacts:
                    cells += [f"{row.contacts_px[k, 0]:.3f}", f"{row.contacts_px[k, 1]:.3f}"]
                else:
                    cells += ["", ""]
            writer.writerow(cells)


def _csv_rows(fh: IO[str], path: Path) -> Iterator[list[str]]:
    """The rows of a CSV text (``csv.reader``); a row the reader refuses (a field over its
    128 KiB limit, a NUL) is a DatasetError naming the file and line, not a ``csv.Error``."""
    reader = csv.reader(fh)
    while True:
        try:
            row = next(reader)
        except StopIteration:
            return
        except csv.Error as exc:
            raise DatasetError(f"{path}:{reader.line_num}: not a CSV row ({printable(exc, 200)})") from None
        yield row


def _label_cell(convert, cell: str, expected: str):
    """``convert(cell)``, or a ValueError saying what was ``expected`` and what was found."""
    try:
        return convert(cell)
    except ValueError:
        raise ValueError(f"expected {expected}, found {short(cell)}") from None


def read_labels(path: str | Path) -> list[LabelRow]:
    """Read a ``SEQUENCE.labels.csv``.

    Raises:
        DatasetError: naming the file, the line, the column and what was expected, when the file
            is empty, the header differs from docs/dataset.md's, a value has the wrong type or
            range, a ``none`` row has an intensity other than 0, a contact cell after the first
            ``n_contacts`` points is filled, or rows are not ordered by time.
    """
    path = Path(path)
    rows: list[LabelRow] = []
    # a regular file (a FIFO would hang), at most MAX_LABELS_BYTES
    text = read_outside_text(path, MAX_LABELS_BYTES, "labels file", DatasetError)
    with io.StringIO(text, newline="") as fh:
        reader = _csv_rows(fh, path)
        header = next(reader, None)
        if header is None:
            raise DatasetError(
                f"{path}:1: the file is empty; expected the header {','.join(LABEL_COLUMNS)} (docs/dataset.md)"
            )
        if tuple(h.strip() for h in header) != LABEL_COLUMNS:
            raise DatasetError(
                f"{path}:1: header must be {','.join(LABEL_COLUMNS)} (docs/dataset.md), found {short(header)}"
            )
        last = -math.inf
        for line_no, cells in enumerate(reader, start=2):
            if not cells:
                continue
            if len(cells) != len(LABEL_COLUMNS):
                raise DatasetError(f"{path}:{line_no}: expected {len(LABEL_COLUMNS)} columns, found {len(cells)}")
            col = "t_us"
            if len(rows) >= MAX_LABEL_ROWS:
                raise DatasetError(f"{path}:{line_no}: more than {MAX_LABEL_ROWS:,} rows (docs/limits.md, Labels)")
            try:
                t_us = _label_cell(int, cells[0], "an integer time in microseconds from 0 to 2^62")
                if not 0 <= t_us <= MAX_T_US:
                    raise ValueError(f"expected a time in microseconds from 0 to 2^62, found {short(cells[0])}")
                col = "gesture"
                gesture = _label_cell(GestureType, cells[1], f"one of {', '.join(g.value for g in GestureType)}")
                col = "resting"
                if cells[2] not in ("0", "1"):
                    raise ValueError("expected 0 or 1")
                col = "intensity_mm"
                mm = f"mm from 0 to {MAX_LABEL_INTENSITY_MM:g}"
                intensity = _label_cell(float, cells[3], mm)
                if not 0.0 <= intensity <= MAX_LABEL_INTENSITY_MM:  # NaN fails too
                    raise ValueError(f"expected {mm}, found {short(cells[3])}")
                if gesture is GestureType.NONE and intensity != 0.0:
                    raise ValueError(f"expected 0 for gesture none, found {short(cells[3])}")
                col = "n_contacts"
                n = _label_cell(int, cells[4], f"an integer from 0 to {MAX_CONTACTS}")
                if not 0 <= n <= MAX_CONTACTS:
                    raise ValueError(f"expected 0 to {MAX_CONTACTS}")
                values = []
                for k, cell in enumerate(cells[5:]):
                    col = LABEL_COLUMNS[5 + k]
                    if k < 2 * n:
                        px = f"image pixels from -{MAX_SENSOR_PX} to {MAX_SENSOR_PX}"
                        values.append(_label_cell(float, cell, px))
                        if not abs(values[-1]) <= MAX_SENSOR_PX:  # NaN fails too
                            raise ValueError(f"expected {px}, found {short(cell)}")
                    elif cell.strip():  # the points after the first n_contacts: dropped unsaid else
                        raise ValueError(f"expected empty (n_contacts is {n}), found {short(cell)}")
                contacts = np.array(values, dtype=np.float64).reshape(n, 2)
            except ValueError as exc:
                raise DatasetError(f"{path}:{line_no}: column {col!r}: {printable(exc, 200)}") from None
            if t_us < last:
                raise DatasetError(f"{path}:{line_no}: rows must be ordered by time (t_us {t_us} < {last})")
            last = t_us
            rows.append(LabelRow(t_us, gesture, cells[2] == "1", intensity, contacts))
    if not rows:
        raise DatasetError(f"{path}:2: no labelled frame after the header (docs/dataset.md): nothing to score")
    return rows


def check_labels_clock(
    labels: Sequence[LabelRow], path: str | Path, recording: str | Path, start_us: int, end_us: int
) -> None:
    """Refuse labels none of whose frames lies within their recording's time range: labels on
    another clock, or in another unit than microseconds (docs/dataset.md: ``t_us`` is on the
    recording's clock), would score every prediction against the last label, or skip them all.

    Args:
        labels: the rows of ``path`` (:func:`read_labels`), ordered by time, at least one.
        path: the labels file, for the message.
        recording: the recording, for the message.
        start_us, end_us: the recording's first and last timestamp (us); nothing is checked when
            ``end_us <= start_us`` (an empty recording, refused by its reader).
    Raises:
        DatasetError: naming both files and both time ranges.
    """
    first, last = labels[0].t_us, labels[-1].t_us
    if end_us > start_us and (last < start_us or first > end_us):
        raise DatasetError(
            f"{path}:2: t_us: the labels run from {first} to {last} us, the recording {recording} from {start_us} "
            f"to {end_us} us: no labelled frame lies within it; expected the recording's clock, in microseconds "
            "(docs/dataset.md)"
        )


#: The columns of ``SEQUENCE.pressed.csv`` (docs/dataset.md, "Per-gesture metrics").
PRESSED_COLUMNS: tuple[str, ...] = ("t_start_us", "pressed_us")


def write_pressed(path: str | Path, rows: Sequence[tuple[int, int]]) -> None:
    """Write ``SEQUENCE.pressed.csv``: per simulated gesture whose fingers start apart, its
    attack's first instant and when the gel under its last finger to press has moved 0.3 mm
    (both int us, recording clock; docs/dataset.md, "Per-gesture metrics"), ordered by time."""
    with AtomicFile(path, what="pressed file", newline="") as fh:
        writer = csv.writer(fh)
        writer.writerow(PRESSED_COLUMNS)
        for start, pressed in rows:
            writer.writerow([str(int(start)), str(int(pressed))])


def read_pressed(path: str | Path) -> list[tuple[int, int]]:
    """Read a ``SEQUENCE.pressed.csv`` (:func:`write_pressed`): (t_start_us, pressed_us) rows;
    an empty list when the file does not exist (a recording, not a simulation).

    Raises:
        DatasetError: naming the file, the line and the column, when the header differs, a value
            is not an integer, a row's pressed_us is before its t_start_us, or rows are not
            ordered by time.
    """
    path = Path(path)
    if not path.exists():
        return []
    text = read_outside_text(path, MAX_LABELS_BYTES, "pressed file", DatasetError)
    rows: list[tuple[int, int]] = []
    with io.StringIO(text, newline="") as fh:
        reader = _csv_rows(fh, path)
        header = next(reader, None)
        if header is None or tuple(h.strip() for h in header) != PRESSED_COLUMNS:
            raise DatasetError(f"{path}:1: header must be {','.join(PRESSED_COLUMNS)}, found {short(header)}")
        for line_no, cells in enumerate(reader, start=2):
            if not cells:
                continue
            if len(cells) != len(PRESSED_COLUMNS):
                raise DatasetError(f"{path}:{line_no}: expected {len(PRESSED_COLUMNS)} columns, found {len(cells)}")
            values = []
            for col, cell in zip(PRESSED_COLUMNS, cells):
                try:
                    values.append(int(cell))
                except ValueError:
                    raise DatasetError(
                        f"{path}:{line_no}: column {col!r}: expected an integer (us), found {short(cell)}"
                    ) from None
            if values[1] < values[0] or (rows and values[0] < rows[-1][0]):
                raise DatasetError(f"{path}:{line_no}: pressed_us before t_start_us, or rows not ordered by time")
            if len(rows) >= MAX_LABEL_ROWS:
                raise DatasetError(f"{path}:{line_no}: more than {MAX_LABEL_ROWS:,} rows (docs/limits.md, Labels)")
            rows.append((values[0], values[1]))
    return rows


def dataset_sensor_file(dataset: str | Path) -> Path:
    """The sensor.yaml that applies to a dataset folder: its own (docs/dataset.md), else the user's
    calibration (``neurotouch-hid calibrate``; :func:`~neurotouch_hid.core.sensor.user_sensor_path`).

    Raises DatasetError when there is neither.
    """
    own = Path(dataset) / "sensor.yaml"
    if own.exists():
        return own
    calibrated = user_sensor_path()
    if calibrated.exists():
        return calibrated
    raise DatasetError(
        f"{dataset}: no sensor.yaml (docs/dataset.md), and no calibrated sensor at {calibrated}: add the "
        f"sensor.yaml the dataset was recorded with, or calibrate with `neurotouch-hid calibrate`"
    )


def list_sequences(dataset: str | Path) -> list[str]:
    """Names of the sequences in a dataset folder (those with both .aedat4 and .labels.csv), sorted.

    Raises DatasetError when the folder does not exist, has no sequence, or has no sensor.yaml
    while the user has no calibration either (:func:`dataset_sensor_file`).
    """
    dataset = Path(dataset)
    if not dataset.is_dir():
        raise DatasetError(f"{dataset}: not a dataset folder (docs/dataset.md)")
    names = sorted(p.name[: -len(".aedat4")] for p in dataset.glob("*.aedat4"))
    names = [n for n in names if (dataset / f"{n}.labels.csv").exists()]
    if not names:  # said before the sensor: a folder without recordings needs recordings first
        raise DatasetError(
            f"{dataset}: no recording in it: no SEQUENCE.aedat4 with its SEQUENCE.labels.csv (docs/dataset.md; "
            "`neurotouch-hid enrol` or `neurotouch-hid simulate` writes such a folder)"
        )
    dataset_sensor_file(dataset)
    return names


def labels_at(labels: Sequence[LabelRow], t_us: np.ndarray) -> list[LabelRow | None]:
    """The ground truth at each prediction time, as docs/dataset.md's "Predictions (JSON lines)" section defines it.

    Paper, section "Creation of the Gesture Detection Dataset": "we use the most recent labeled
    gesture type and linearly interpolate the contact points localizations and intensities based
    on the preceding and subsequent labeled data". At time t, with the most recent labelled frame
    L0 (t0 <= t) and the next one L1 (t1 > t), w = (t - t0) / (t1 - t0):

    - gesture type, resting flag and contact count: those of L0;
    - intensity (mm): (1 - w) * L0 + w * L1;
    - contact points (px, image frame): interpolated the same way, point k with point k, only
      when L0 and L1 have the same count; otherwise those of L0.

    At or after the last labelled frame there is no L1: the last frame's values are used as they
    are. Prediction times before the first labelled frame get ``None`` (they are skipped).

    Args:
        labels: rows of a ``SEQUENCE.labels.csv`` (:func:`read_labels`), ordered by time.
        t_us: (M,) int64 prediction times, microseconds, the recording's clock.
    Returns:
        M entries: a :class:`LabelRow` whose ``t_us`` is the prediction time, or ``None``.
    """
    times = np.asarray([row.t_us for row in labels], dtype=np.int64)
    t_us = np.asarray(t_us, dtype=np.int64).reshape(-1)
    before = np.searchsorted(times, t_us, side="right") - 1
    out: list[LabelRow | None] = []
    for t, i in zip(t_us.tolist(), before.tolist()):
        if i < 0:
            out.append(None)
            continue
        row = labels[i]
        intensity, contacts = row.intensity_mm, row.contacts_px
        if i + 1 < len(labels):
            nxt = labels[i + 1]
            span = nxt.t_us - row.t_us
            w = (t - row.t_us) / span if span > 0 else 0.0
            intensity = (1.0 - w) * row.intensity_mm + w * nxt.intensity_mm
            if nxt.n_contacts == row.n_contacts:
                contacts = (1.0 - w) * row.contacts_px + w * nxt.contacts_px
        out.append(LabelRow(int(t), row.gesture, row.resting, float(intensity), np.asarray(contacts, dtype=np.float64)))
    return out


# --- predictions (JSON lines) ---------------------------------------------------------------
class PredictionsWriter(JsonlWriter):
    """Writes a predictions file (docs/dataset.md): one :class:`GestureEstimate` a line."""

    def write(self, estimate: GestureEstimate) -> None:
        """Write ``estimate.to_json_dict()`` as one line."""
        self.write_dict(estimate.to_json_dict())


def write_predictions(path: str | Path, estimates: Iterable[GestureEstimate]) -> int:
    """Write a whole predictions file (renamed into place when complete); returns the number of
    lines written."""
    n = 0
    with PredictionsWriter(path) as writer:
        for estimate in estimates:
            writer.write(estimate)
            n += 1
    return n


#: Latest time a predictions line may carry (us, ~146 000 years; the recordings' bound): later
#: times overflow the int64 arithmetic of the replay.
MAX_T_US = 2**62


def _number(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def _points(value: Any, bound: float) -> bool:
    return isinstance(value, list) and all(
        isinstance(p, list) and len(p) == 2 and all(_number(v) and abs(v) <= bound for v in p) for p in value
    )


#: The fields every predictions line has (docs/dataset.md, Predictions): null is no value of them.
REQUIRED_PREDICTION_FIELDS = ("t_us", "gesture", "resting", "intensity_mm")


def _prediction_field_problem(data: dict) -> str | None:
    """``FIELD: expected ..., found ...`` for the first field of a predictions line of the wrong
    type or range (docs/dataset.md, Predictions; the similarity's terms optional, null where
    optional), else None."""
    checks = (
        ("resting", lambda v: isinstance(v, bool) or (type(v) is int and v in (0, 1)), "true or false (or 1 or 0)"),
        (
            "intensity_mm",
            lambda v: _number(v) and 0 <= v <= MAX_LABEL_INTENSITY_MM,
            f"mm from 0 to {MAX_LABEL_INTENSITY_MM:g}",
        ),
        ("contacts_px", lambda v: _points(v, MAX_SENSOR_PX), f"a list of [x, y] image pixels within {MAX_SENSOR_PX}"),
        (
            "contacts_mm",
            lambda v: _points(v, MAX_LABEL_INTENSITY_MM),
            f"a list of [x, y] mm within {MAX_LABEL_INTENSITY_MM:g}",
        ),
        ("translation_mm", lambda v: _points([v], MAX_LABEL_INTENSITY_MM), "[x, y] in mm"),
        ("rotation_rad", _number, "a finite number (rad)"),
        ("scale", _number, "a finite number"),
    )
    for name, fits, expected in checks:
        given = name in data and (data[name] is not None or name in REQUIRED_PREDICTION_FIELDS)
        if given and not fits(data[name]):
            return f"{name}: expected {expected}, found {short(data[name])}"
    return None


def iter_predictions(path: str | Path) -> Iterator[GestureEstimate]:
    """The estimates of a predictions file (docs/dataset.md), read line by line as they are asked
    for: the memory held is one line's, whatever the file's length (at most
    :data:`MAX_PREDICTIONS_BYTES`, a line at most :data:`MAX_PREDICTION_LINE_BYTES`).

    Blank lines are skipped.
    Raises:
        DatasetError: when the line that breaks a rule is reached: the file cannot be read, a line
            is not JSON, lacks a field or has a bad value (the message names the file, the line
            number and the problem), or the lines are not ordered by time.
    """
    path = Path(path)
    previous: int | None = None
    lines = read_outside_lines(path, MAX_PREDICTIONS_BYTES, MAX_PREDICTION_LINE_BYTES, "predictions file", DatasetError)
    for number, line in lines:
        if not line.strip():
            continue
        estimate = _prediction_line(path, number, line)
        if previous is not None and estimate.t_us < previous:
            raise DatasetError(f"{path}:{number}: t_us {estimate.t_us} goes back in time (previous line: {previous})")
        previous = estimate.t_us
        yield estimate


def _prediction_line(path: Path, number: int, line: str) -> GestureEstimate:
    """One line of a predictions file as an estimate, or a DatasetError naming ``path:number``."""
    try:
        # NaN, Infinity and 1e999 read as floats: the fields' checks below refuse them, by name
        data = json.loads(line)
    except json.JSONDecodeError as exc:
        raise DatasetError(f"{path}:{number}: not a JSON object: {exc.msg}") from None
    except (ValueError, RecursionError):  # a number of thousands of digits, nesting too deep
        raise DatasetError(f"{path}:{number}: not a predictions line (a number or nesting out of bounds)") from None
    if not isinstance(data, dict):
        raise DatasetError(f"{path}:{number}: expected a JSON object, found {type(data).__name__}")
    missing = [k for k in REQUIRED_PREDICTION_FIELDS if k not in data]
    if missing:
        raise DatasetError(f"{path}:{number}: missing field(s) {', '.join(missing)} (docs/dataset.md, Predictions)")
    t_us = data["t_us"]
    whole = isinstance(t_us, int) or (isinstance(t_us, float) and t_us.is_integer())  # 1e6 is; 1.25 (s) is not
    if isinstance(t_us, bool) or not whole or not 0 <= t_us <= MAX_T_US:
        raise DatasetError(
            f"{path}:{number}: t_us: expected a whole number of microseconds from 0 to 2^62, found {short(t_us)}"
        )
    names = tuple(g.value for g in GestureType)
    if not (isinstance(data["gesture"], str) and data["gesture"] in names):
        raise DatasetError(
            f"{path}:{number}: bad value: gesture: expected one of {', '.join(names)}, found {short(data['gesture'])}"
        )
    problem = _prediction_field_problem(data)
    if problem is not None:
        raise DatasetError(f"{path}:{number}: {problem} (docs/dataset.md, Predictions)")
    try:
        estimate = GestureEstimate.from_json_dict(data)
    except (TypeError, ValueError, KeyError, OverflowError) as exc:
        raise DatasetError(f"{path}:{number}: bad value: {short(str(exc))}") from None
    if estimate.contacts_px.shape != estimate.contacts_mm.shape:
        raise DatasetError(f"{path}:{number}: contacts_px and contacts_mm have different numbers of points")
    return estimate


def read_predictions(path: str | Path) -> list[GestureEstimate]:
    """Every estimate of a predictions file (:func:`iter_predictions`), in a list.

    Raises:
        DatasetError: as :func:`iter_predictions`.
    """
    return list(iter_predictions(path))


def open_predictions(path: str | Path) -> Iterator[GestureEstimate]:
    """A predictions file checked whole first (every line, as :func:`iter_predictions` reads it,
    nothing kept), then its estimates read again line by line as they are asked for: a replay
    refuses a bad file before it starts and holds one line at a time.

    A push window with an intensity and no ``translation_mm`` (optional in docs/dataset.md) is
    said once, as a warning: its direction, and so the push inputs of a profile, are unknown.

    Raises:
        DatasetError: the file breaks a rule (:func:`iter_predictions`); when it is changed
            between the check and the replay, at the changed line during the replay.
    """
    blind = 0  # push windows with an intensity and no direction
    for estimate in iter_predictions(path):
        if estimate.gesture is GestureType.PUSH and estimate.intensity_mm > 0 and not np.any(estimate.translation_mm):
            blind += 1
    if blind:
        log.warning(
            "%s: %d push windows give no translation_mm (the field is optional): their direction is unknown, "
            "so a profile's push, push_x, push_y and push_up/down/left/right read 0 there (track and "
            "run --output jsonl write it)",
            path,
            blind,
        )
    return iter_predictions(path)
