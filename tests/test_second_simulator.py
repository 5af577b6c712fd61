"""Recognition failures of a second, independent simulator's game sessions, replayed from its
recordings (../shared/data/second-simulator: AEDAT4, labels and sensor.yaml as docs/dataset.md
says; docs/method.md, "Episode vote").

Each gesture of each session is one test: no window of it (from its first labelled frame to one
APS frame period after its last) may answer another type (not ``none``) at or above the default
profile's dead zone, the "felt wrong" of docs/dataset.md. A failure names the recording, the
window (ms after the gesture's first labelled frame), what was read and what was labelled. The
pipeline runs once per session (module-scoped), ~10 s each on an idle core.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from neurotouch_hid.core.dataset import LabelRow, labels_at, read_labels
from neurotouch_hid.core.estimate import GestureEstimate, GestureType
from neurotouch_hid.core.sensor import SensorGeometry
from neurotouch_hid.evaluation.felt import DEFAULT_DEADZONE_MM, FRAME_PERIOD_US
from neurotouch_hid.pipeline.pipeline import GesturePipeline, PipelineConfig
from neurotouch_hid.sources.recording import RecordingReader

#: The sessions: the shared data beside the repository (as tests/helpers.py's STREET), or where
#: NEUROTOUCH_SECOND_SIMULATOR says (a checkout elsewhere).
DATA = Path(
    os.environ.get("NEUROTOUCH_SECOND_SIMULATOR")
    or Path(__file__).resolve().parents[2] / "shared/data/second-simulator"
)
G = GestureType

#: Every gesture of the three sessions: (session, start s from the first label, type), as the
#: folder's README lists them.
GESTURES = [
    ("session_a", 0.88, G.TWIST_CW),
    ("session_a", 1.56, G.PUSH),
    ("session_a", 3.20, G.TWIST_CCW),
    ("session_b", 0.80, G.TWIST_CW),
    ("session_b", 1.32, G.ZOOM),
    ("session_b", 2.76, G.PUSH),
    ("session_c", 0.72, G.TWIST_CW),
    ("session_c", 2.52, G.ZOOM),
    ("session_c", 4.16, G.TWIST_CCW),
    ("session_c", 4.88, G.PUSH),
]


@dataclass
class Session:
    labels: list[LabelRow]
    estimates: list[GestureEstimate]


_RUNS: dict[str, Session] = {}


@pytest.fixture(scope="module")
def sessions():
    """name -> :class:`Session`, the pipeline run once per session for the whole module."""
    if not (DATA / "sensor.yaml").is_file():
        pytest.skip(reason=f"{DATA} (the second simulator's sessions in shared/) is not on this machine")

    def run(name: str) -> Session:
        if name not in _RUNS:
            pipeline = GesturePipeline(SensorGeometry.load(DATA / "sensor.yaml"))
            with RecordingReader(DATA / f"{name}.aedat4") as reader:
                estimates = list(pipeline.run(reader.stream()))
            _RUNS[name] = Session(read_labels(DATA / f"{name}.labels.csv"), estimates)
        return _RUNS[name]

    yield run
    _RUNS.clear()


def _gesture_span(labels: list[LabelRow], start_s: float, kind: GestureType) -> tuple[int, int]:
    """(t0, t1) us of the labelled gesture of type ``kind`` whose first frame is ``start_s`` after
    the first label (to one APS frame period)."""
    first = labels[0].t_us
    runs: list[list] = []
    for row in labels:
        if runs and runs[-1][0] is row.gesture:
            runs[-1][2] = row.t_us
        else:
            runs.append([row.gesture, row.t_us, row.t_us])
    for gesture, t0, t1 in runs:
        if gesture is kind and abs((t0 - first) / 1e6 - start_s) <= 0.04:
            return t0, t1
    raise AssertionError(f"no {kind.value} labelled {start_s} s after the first label")


def _felt_wrong_windows(session: Session, start_s: float, kind: GestureType) -> list[tuple[float, str]]:
    """The gesture's windows answering another type at or above the dead zone: (ms after the
    gesture's first labelled frame, the window described)."""
    t0, t1 = _gesture_span(session.labels, start_s, kind)
    window = [e for e in session.estimates if t0 <= e.t_us < t1 + FRAME_PERIOD_US]
    assert window, "the pipeline answered no window during the gesture"
    truth = labels_at(session.labels, np.array([e.t_us for e in window], dtype=np.int64))
    return [
        (
            (e.t_us - t0) / 1000,
            f"{(e.t_us - t0) / 1000:.0f} ms: read {e.gesture.value} at {e.intensity_mm:.2f} mm on {e.n_contacts} "
            f"contact(s), labelled {t.gesture.value} at {t.intensity_mm:.2f} mm on {t.n_contacts}",
        )
        for e, t in zip(window, truth)
        if e.gesture not in (G.NONE, kind) and e.intensity_mm >= DEFAULT_DEADZONE_MM
    ]


def _felt_wrong(session: Session, start_s: float, kind: GestureType) -> list[str]:
    """The gesture's windows answering another type at or above the dead zone, described."""
    return [text for _, text in _felt_wrong_windows(session, start_s, kind)]


@pytest.mark.parametrize(
    ("name", "start_s", "kind"),
    [
        pytest.param(
            *g,
            id=f"{g[0]}-{g[1]:.2f}s-{g[2].value}",
            marks=[
                pytest.mark.xfail(
                    strict=True,
                    reason="a three-finger twist read zoom in 8 windows 100-320 ms after its start: its "
                    "fitted fingers lie ~3.5 mm ahead of the fingers along the turn (docs/accuracy.md)",
                )
            ]
            if g[:2] == ("session_c", 0.72)
            else [],
        )
        for g in GESTURES
    ],
)
def test_no_gesture_of_the_second_simulators_sessions_is_felt_wrong(sessions, name, start_s, kind):
    """Reported on these sessions: session_a's twist_ccw read push in 4 windows from 10 ms (a first
    window at 0.19 mm on three contacts committed the type before any finger was counted), and
    session_b's twist_cw push in 5 from its first (committed on two contacts, then outvoted by
    windows on one contact); session_c's twist_cw read push or zoom in 138 of 141 felt windows."""
    wrong = _felt_wrong(sessions(name), start_s, kind)
    assert not wrong, f"{DATA / name}.aedat4, {kind.value} from {start_s} s:\n" + "\n".join(wrong)


def test_the_three_finger_twist_of_session_c_reads_zoom_only_at_its_start(sessions):
    """session_c's twist_cw read zoom in 136 of its 141 windows above the dead zone while its type
    was read about the field's maxima, which close fingers push outward (docs/method.md,
    "Gesture"), and push in its first windows, on the one contact found before the others. Read
    about the bump fit's fingers, zoom is left in 8 windows of its first 350 ms (the xfail above),
    no push."""
    wrong = _felt_wrong_windows(sessions("session_c"), 0.72, G.TWIST_CW)
    text = "\n".join(w for _, w in wrong)
    assert wrong, "no window felt wrong: the xfail above is to go"
    assert not [w for _, w in wrong if "read push" in w], text
    assert len(wrong) <= 8 and all(ms <= 350 for ms, _ in wrong), text


@pytest.mark.parametrize(("name", "start_s"), [(n, s) for n, s, k in GESTURES if k is G.PUSH], ids=lambda v: str(v))
def test_a_push_waits_no_longer_than_the_one_contact_wait_from_its_onset(sessions, name, start_s):
    """Each session's push is committed at most ``episode.first_finger_us`` after its first window
    with a gesture: session_a's and session_b's, whose first windows read pinch or twist on 2-3
    contacts below ``PROVISIONAL_MM``, waited 110 and 130 ms (their spurious count restarted the
    wait at the first window on one contact)."""
    session = sessions(name)
    t0, t1 = _gesture_span(session.labels, start_s, G.PUSH)
    window = [e for e in session.estimates if t0 - FRAME_PERIOD_US <= e.t_us < t1 + FRAME_PERIOD_US]
    onset = next(e.t_us for e in window if e.gesture is not G.NONE or e.intensity_mm > 0)
    first_push = next(e.t_us for e in window if e.gesture is G.PUSH)
    wait = PipelineConfig().episode.first_finger_us
    late_ms = (first_push - onset) / 1000
    assert first_push - onset <= wait, f"{DATA / name}.aedat4: push {late_ms:.0f} ms after its onset"
