"""Per-gesture ("felt") metrics: what a controller's user feels, gesture by gesture.

docs/dataset.md, "Per-gesture metrics", defines them. A *gesture* is a maximal run of labelled
frames with the same type other than ``none``, from its first labelled frame ``t0`` to its last
``t1``; its predictions are those with ``t0 <= t_us < t1 + FRAME_PERIOD_US``. Per gesture:

- onset latency: the first of its predictions with the labelled type, minus ``t0`` (ms);
- never recognised: none of its predictions has the labelled type;
- type changes: in its predictions other than ``none``, in time order, the neighbours whose types
  differ; felt type changes: the same over those whose ``intensity_mm`` is at least the dead zone;
- felt wrong: one of its predictions has another type (not ``none``) at or above the dead zone;
  where the simulation says when the gel under the gesture's last finger to press has moved
  0.3 mm (``SEQUENCE.pressed.csv``, fingers starting apart), only its predictions from then on;
- dead-zone latency: when the labelled intensity reaches the dead zone (linear between the two
  labelled frames around it), the first of its predictions with the labelled type at or above
  the dead zone, minus that instant (ms; negative when the answer comes first): how late the
  output passes the dead zone after the gel has. Only for gestures whose labelled intensity
  reaches the dead zone; one with no such prediction is missed above the dead zone.

False activations: predictions other than ``none`` more than :data:`REST_MARGIN_US` from every
labelled frame of a gesture (counted over such predictions, the windows "at rest").

:func:`gesture_records` computes them for one sequence into :class:`FeltRecords` (one entry per
gesture, concatenable across sequences); :func:`summarise` turns records into the figures
(medians, shares) of :class:`FeltSummary`.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Sequence

import numpy as np

from neurotouch_hid.core.dataset import LabelRow
from neurotouch_hid.core.estimate import GESTURE_ORDER, GestureEstimate, GestureType

#: Default dead zone (mm): the ``default`` profile's stick dead zone (profiles/default.yaml).
DEFAULT_DEADZONE_MM = 0.8
#: A gesture's predictions run until one APS frame period (us) after its last labelled frame.
FRAME_PERIOD_US = 40_000
#: A prediction further than this (us) from every labelled gesture frame is at rest.
REST_MARGIN_US = 300_000

_INDEX = {g: i for i, g in enumerate(GESTURE_ORDER)}


@dataclass
class FeltRecords:
    """Per gesture (G entries, arrays of shape (G,)) of one or more sequences.

    Attributes:
        gesture: int64 labelled type, index into ``GESTURE_ORDER``.
        duration_ms: float64 ``t1 - t0`` (ms).
        onset_ms: float64 onset latency (ms), NaN when never recognised.
        changes, felt_changes: int64 type changes, all and at or above the dead zone.
        felt_wrong: bool, another type at or above the dead zone.
        wrong_as: int64 the first such other type (index into ``GESTURE_ORDER``), -1 if none.
        reaches_deadzone: bool, the labelled intensity reaches the dead zone.
        deadzone_latency_ms: float64 dead-zone latency (ms), NaN when the labelled intensity
            does not reach the dead zone or no prediction of the type does.
        n_rest: predictions at rest (more than REST_MARGIN_US from every gesture frame).
        false_activations: those of them other than ``none``.
        felt_false_activations: those of the false activations whose ``intensity_mm`` is at
            least the dead zone (a profile maps them).
        deadzone_mm: the dead zone the felt figures used (mm).
    """

    gesture: np.ndarray
    duration_ms: np.ndarray
    onset_ms: np.ndarray
    changes: np.ndarray
    felt_changes: np.ndarray
    felt_wrong: np.ndarray
    wrong_as: np.ndarray
    reaches_deadzone: np.ndarray
    deadzone_latency_ms: np.ndarray
    n_rest: int = 0
    false_activations: int = 0
    felt_false_activations: int = 0
    deadzone_mm: float = DEFAULT_DEADZONE_MM

    _ARRAYS = (
        "gesture",
        "duration_ms",
        "onset_ms",
        "changes",
        "felt_changes",
        "felt_wrong",
        "wrong_as",
        "reaches_deadzone",
        "deadzone_latency_ms",
    )

    def __len__(self) -> int:
        return int(len(self.gesture))

    @classmethod
    def concatenate(cls, parts: Sequence["FeltRecords"], deadzone_mm: float = DEFAULT_DEADZONE_MM) -> "FeltRecords":
        """All parts' gestures in one (rest counts add up); raises ValueError when the parts
        used different dead zones."""
        if not parts:
            return gesture_records([], [], deadzone_mm)
        if len({p.deadzone_mm for p in parts}) > 1:
            raise ValueError("felt records with different dead zones cannot be combined")
        return cls(
            **{name: np.concatenate([getattr(p, name) for p in parts]) for name in cls._ARRAYS},
            n_rest=sum(p.n_rest for p in parts),
            false_activations=sum(p.false_activations for p in parts),
            felt_false_activations=sum(p.felt_false_activations for p in parts),
            deadzone_mm=parts[0].deadzone_mm,
        )


def gesture_runs(labels: Sequence[LabelRow]) -> list[tuple[GestureType, int, int]]:
    """The gestures of a sequence as rows: (type, first, last) per maximal run of labelled frames
    of one type other than ``none`` (indices into ``labels``, the last included)."""
    runs: list[tuple[GestureType, int, int]] = []
    prev: GestureType | None = None
    for i, row in enumerate(labels):
        if row.gesture is not GestureType.NONE:
            if row.gesture is prev:
                runs[-1] = (row.gesture, runs[-1][1], i)
            else:
                runs.append((row.gesture, i, i))
        prev = row.gesture
    return runs


def gesture_spans(labels: Sequence[LabelRow]) -> list[tuple[GestureType, int, int]]:
    """The gestures of a sequence: (type, t0, t1) per maximal run of labelled frames of one type
    other than ``none`` (:func:`gesture_runs`; t0, t1: its first and last frame's ``t_us``, us)."""
    return [(kind, labels[first].t_us, labels[last].t_us) for kind, first, last in gesture_runs(labels)]


def at_rest(labels: Sequence[LabelRow], t_us: np.ndarray) -> np.ndarray:
    """Which of the times ``t_us`` ((N,) int64, us) are at rest: more than :data:`REST_MARGIN_US`
    from every labelled frame of a gesture (the false activations' windows); (N,) bool."""
    frames = np.array([r.t_us for r in labels if r.gesture is not GestureType.NONE], dtype=np.int64)
    if not len(frames):
        return np.ones(len(t_us), bool)
    at = np.searchsorted(frames, t_us)  # frames[at - 1] < t <= frames[at]
    before = frames[np.clip(at - 1, 0, len(frames) - 1)]
    after = frames[np.clip(at, 0, len(frames) - 1)]
    return np.minimum(np.abs(t_us - before), np.abs(after - t_us)) > REST_MARGIN_US


def _changes(types: list[GestureType]) -> int:
    return sum(1 for a, b in zip(types, types[1:]) if a is not b)


def deadzone_crossing(t_us: np.ndarray, intensity_mm: np.ndarray, deadzone_mm: float) -> float | None:
    """When a gesture's labelled intensity first reaches ``deadzone_mm`` (us, float), linear
    between the labelled frame before and the first at or above it; the first frame's time when it
    is already there; None when no frame reaches it.

    Args:
        t_us: (F,) int64 the gesture's labelled frames' times (us), increasing.
        intensity_mm: (F,) float64 their labelled intensity (mm).
        deadzone_mm: the dead zone (mm).
    """
    above = np.flatnonzero(intensity_mm >= deadzone_mm)
    if len(above) == 0:
        return None
    k = int(above[0])
    if k == 0:
        return float(t_us[0])
    i0, i1 = float(intensity_mm[k - 1]), float(intensity_mm[k])
    return float(t_us[k - 1]) + (deadzone_mm - i0) / (i1 - i0) * float(t_us[k] - t_us[k - 1])


def pressed_at(pressed: Sequence[tuple[int, int]], t0_us: int, t1_us: int) -> int | None:
    """When the gel under the last finger of the labelled gesture ``t0_us``..``t1_us`` (us) has
    moved 0.3 mm: the ``pressed_us`` of the row of ``pressed`` ((t_start_us, pressed_us) rows,
    :func:`~neurotouch_hid.core.dataset.read_pressed`) whose attack starts within one APS frame period
    before ``t0_us`` or up to ``t1_us`` (the labels' first frame of a gesture is at or after its
    start); None when there is none (fingers pressing together, or not a simulation)."""
    return next((p for start, p in pressed if t0_us - FRAME_PERIOD_US < start <= t1_us), None)


def gesture_records(
    labels: Sequence[LabelRow],
    predictions: Sequence[GestureEstimate],
    deadzone_mm: float = DEFAULT_DEADZONE_MM,
    pressed: Sequence[tuple[int, int]] = (),
) -> FeltRecords:
    """The per-gesture records of one sequence (docs/dataset.md, "Per-gesture metrics").

    Args:
        labels: the sequence's label rows, ordered by time.
        predictions: its predictions (``t_us``, ``gesture``, ``intensity_mm``), ordered by time.
        deadzone_mm: the dead zone of the felt figures (mm, >= 0).
        pressed: (t_start_us, pressed_us) per simulated gesture whose fingers start apart
            (:func:`~neurotouch_hid.core.dataset.read_pressed`): such a gesture is felt wrong only by
            its predictions from ``pressed_us`` on (:func:`pressed_at`).
    Raises:
        ValueError: a negative or non-finite dead zone.
    """
    if not (math.isfinite(deadzone_mm) and deadzone_mm >= 0):
        raise ValueError(f"the dead zone must be a finite number of mm >= 0, got {deadzone_mm}")
    t_pred = np.array([p.t_us for p in predictions], dtype=np.int64)
    runs = gesture_runs(labels)
    g = len(runs)
    rec = FeltRecords(
        gesture=np.empty(g, np.int64),
        duration_ms=np.empty(g, np.float64),
        onset_ms=np.full(g, np.nan),
        changes=np.zeros(g, np.int64),
        felt_changes=np.zeros(g, np.int64),
        felt_wrong=np.zeros(g, bool),
        wrong_as=np.full(g, -1, np.int64),
        reaches_deadzone=np.zeros(g, bool),
        deadzone_latency_ms=np.full(g, np.nan),
        deadzone_mm=float(deadzone_mm),
    )
    t_lab = np.array([r.t_us for r in labels], dtype=np.int64)
    i_lab = np.array([r.intensity_mm for r in labels], dtype=np.float64)
    for k, (kind, first, last) in enumerate(runs):
        t0, t1 = int(t_lab[first]), int(t_lab[last])
        lo, hi = np.searchsorted(t_pred, t0, "left"), np.searchsorted(t_pred, t1 + FRAME_PERIOD_US, "left")
        inside = predictions[lo:hi]
        rec.gesture[k] = _INDEX[kind]
        rec.duration_ms[k] = (t1 - t0) / 1000.0
        hit = next((p for p in inside if p.gesture is kind), None)
        if hit is not None:
            rec.onset_ms[k] = (hit.t_us - t0) / 1000.0
        answered = [p for p in inside if p.gesture is not GestureType.NONE]
        felt = [p for p in answered if p.intensity_mm >= deadzone_mm]
        rec.changes[k] = _changes([p.gesture for p in answered])
        rec.felt_changes[k] = _changes([p.gesture for p in felt])
        felt_from = pressed_at(pressed, t0, t1)
        wrong = next((p for p in felt if p.gesture is not kind and (felt_from is None or p.t_us >= felt_from)), None)
        if wrong is not None:
            rec.felt_wrong[k], rec.wrong_as[k] = True, _INDEX[wrong.gesture]
        crossing = deadzone_crossing(t_lab[first : last + 1], i_lab[first : last + 1], deadzone_mm)  # its own rows
        if crossing is not None:
            rec.reaches_deadzone[k] = True
            out = next((p for p in felt if p.gesture is kind), None)
            if out is not None:
                rec.deadzone_latency_ms[k] = (out.t_us - crossing) / 1000.0
    rest = at_rest(labels, t_pred)
    rec.n_rest = int(rest.sum())
    active = [p for p, r in zip(predictions, rest) if r and p.gesture is not GestureType.NONE]
    rec.false_activations = len(active)
    rec.felt_false_activations = sum(1 for p in active if p.intensity_mm >= deadzone_mm)
    return rec


@dataclass
class FeltSummary:
    """The per-gesture figures over records (docs/dataset.md, "Per-gesture metrics").

    Attributes:
        deadzone_mm: the dead zone (mm).
        n_gestures: gestures.
        onset_median_ms, onset_p90_ms: onset latency over the recognised gestures (ms; p90 by
            ``numpy.percentile``'s linear interpolation); NaN when none is recognised.
        never_recognised: gestures with no prediction of their type.
        type_changes_per_gesture, felt_type_changes_per_gesture: mean type changes, all and at or
            above the dead zone.
        felt_wrong_share: share of gestures felt wrong (0..1).
        false_activations, n_rest: predictions other than ``none`` at rest, and predictions at rest.
        felt_false_activations: the false activations at or above the dead zone.
        reached_deadzone: gestures whose labelled intensity reaches the dead zone.
        deadzone_latency_median_ms, deadzone_latency_p90_ms: dead-zone latency over those with an
            answer of their type at or above it (ms); NaN when there is none.
        missed_above_deadzone: gestures that reach the dead zone without such an answer.
    """

    deadzone_mm: float
    n_gestures: int
    onset_median_ms: float
    onset_p90_ms: float
    never_recognised: int
    type_changes_per_gesture: float
    felt_type_changes_per_gesture: float
    felt_wrong_share: float
    false_activations: int
    n_rest: int
    felt_false_activations: int
    reached_deadzone: int
    deadzone_latency_median_ms: float
    deadzone_latency_p90_ms: float
    missed_above_deadzone: int

    def to_dict(self) -> dict:
        """JSON-able values (NaN -> None)."""
        return {k: (None if isinstance(v, float) and math.isnan(v) else v) for k, v in asdict(self).items()}


def summarise(rec: FeltRecords) -> FeltSummary:
    """The figures of :class:`FeltSummary` from records."""
    onsets = rec.onset_ms[~np.isnan(rec.onset_ms)]
    latencies = rec.deadzone_latency_ms[~np.isnan(rec.deadzone_latency_ms)]
    n = len(rec)
    return FeltSummary(
        deadzone_mm=rec.deadzone_mm,
        n_gestures=n,
        onset_median_ms=float(np.median(onsets)) if len(onsets) else math.nan,
        onset_p90_ms=float(np.percentile(onsets, 90)) if len(onsets) else math.nan,
        never_recognised=int(n - len(onsets)),
        type_changes_per_gesture=float(rec.changes.mean()) if n else math.nan,
        felt_type_changes_per_gesture=float(rec.felt_changes.mean()) if n else math.nan,
        felt_wrong_share=float(rec.felt_wrong.mean()) if n else math.nan,
        false_activations=rec.false_activations,
        n_rest=rec.n_rest,
        felt_false_activations=rec.felt_false_activations,
        reached_deadzone=int(rec.reaches_deadzone.sum()),
        deadzone_latency_median_ms=float(np.median(latencies)) if len(latencies) else math.nan,
        deadzone_latency_p90_ms=float(np.percentile(latencies, 90)) if len(latencies) else math.nan,
        missed_above_deadzone=int(rec.reaches_deadzone.sum() - len(latencies)),
    )
