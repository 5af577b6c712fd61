"""The paper's evaluation metrics (paper, sections "Metrics" and "Results").

Predictions (:class:`~neurotouch_hid.core.estimate.GestureEstimate`, one per window) are compared
with the ground truth at each prediction's time (:func:`~neurotouch_hid.core.dataset.labels_at`,
docs/dataset.md "Predictions (JSON lines)"). :func:`align` turns one sequence into :class:`Observations`: plain
aligned arrays, one entry per evaluated prediction, that concatenate across sequences and cross
process boundaries. :func:`evaluate` computes every metric into an :class:`EvaluationResult`.

The metric functions themselves are pure functions on numpy arrays:

- :func:`accuracy`, :func:`precision_recall_f1`, :func:`confusion_matrix`,
  :func:`balanced_confusion_matrix` (gesture type, contact count, resting flag);
- :func:`contact_distances` (average Euclidean distance error, surplus predictions dropped);
- :func:`mean_absolute_error` (intensity);
- :func:`accuracy_by_bin` (accuracy against ground-truth intensity, 0.6 mm bins);
- :func:`outside_resting_collar` (which predictions the collared resting F1 scores), through
  :func:`outside_collar` (the times outside a collar about each change of any labelled value),
  which also picks the predictions the collared gesture type and contact count accuracies score
  (outside 40 ms of each change of the labelled type, of the labelled count).

Undefined values (a precision with no prediction of the class, a mean over nothing) are NaN in
arrays and ``None`` in :meth:`EvaluationResult.to_dict`.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field, is_dataclass
from typing import Sequence

import numpy as np

from neurotouch_hid.core.dataset import LabelRow, labels_at
from neurotouch_hid.core.estimate import GESTURE_ORDER, GestureEstimate, GestureType
from neurotouch_hid.core.sensor import SensorGeometry
from neurotouch_hid.evaluation.felt import DEFAULT_DEADZONE_MM, FeltRecords, FeltSummary, gesture_records, summarise
from neurotouch_hid.evaluation.through_profile import ProfileTally, ProfileUnderTest, tally

#: Width of the ground-truth intensity bins of the accuracy-vs-intensity analysis (mm), as the
#: paper's intensity figures (section "Results").
INTENSITY_BIN_MM = 0.6
#: Half-width of the collar about each change of the labelled resting flag whose predictions the
#: collared resting F1 leaves out (us): one APS frame period at 25 Hz (docs/dataset.md).
RESTING_COLLAR_US = 40_000
#: Half-width of the collar about each change of the labelled gesture type (of the labelled
#: contact count) whose predictions the collared gesture type (contact count) accuracy leaves out
#: (us): the same APS frame period (docs/dataset.md, "Predictions (JSON lines)").
TYPE_COLLAR_US = RESTING_COLLAR_US

_GESTURE_INDEX = {g: i for i, g in enumerate(GESTURE_ORDER)}
_NONE = _GESTURE_INDEX[GestureType.NONE]


# --- pure metric functions ------------------------------------------------------------------
def accuracy(y_true: np.ndarray, y_pred: np.ndarray) -> float:
    """Fraction of equal entries.

    Args:
        y_true, y_pred: (M,) arrays of labels (any comparable dtype).
    Returns:
        The accuracy in [0, 1]; NaN when M = 0.
    """
    y_true, y_pred = np.asarray(y_true), np.asarray(y_pred)
    if y_true.shape != y_pred.shape:
        raise ValueError(f"y_true and y_pred differ in shape: {y_true.shape} vs {y_pred.shape}")
    return float(np.mean(y_true == y_pred)) if y_true.size else math.nan


def confusion_matrix(y_true: np.ndarray, y_pred: np.ndarray, n_classes: int) -> np.ndarray:
    """Count matrix C (n_classes, n_classes) int64: C[i, j] = number of samples of true class i
    predicted as class j (rows: ground truth, columns: prediction).

    Args:
        y_true, y_pred: (M,) int class indices in 0..n_classes-1.
    Raises:
        ValueError: on an index outside 0..n_classes-1.
    """
    y_true = np.asarray(y_true, dtype=np.int64).reshape(-1)
    y_pred = np.asarray(y_pred, dtype=np.int64).reshape(-1)
    if y_true.shape != y_pred.shape:
        raise ValueError(f"y_true and y_pred differ in shape: {y_true.shape} vs {y_pred.shape}")
    for name, y in (("y_true", y_true), ("y_pred", y_pred)):
        if y.size and (y.min() < 0 or y.max() >= n_classes):
            raise ValueError(f"{name} has a class index outside 0..{n_classes - 1}")
    counts = np.zeros((n_classes, n_classes), dtype=np.int64)
    np.add.at(counts, (y_true, y_pred), 1)
    return counts


def precision_recall_f1(counts: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per-class precision, recall and F1-score from a confusion matrix (paper, "Metrics").

    precision_k = C[k, k] / sum_i C[i, k] (column), recall_k = C[k, k] / sum_j C[k, j] (row),
    F1_k = 2 P R / (P + R).

    Args:
        counts: (K, K) confusion counts, rows ground truth, columns prediction.
    Returns:
        Three (K,) float64 arrays. Precision is NaN for a class never predicted, recall NaN for a
        class absent from the ground truth, F1 NaN when either is NaN and 0 when P = R = 0.
    """
    counts = np.asarray(counts, dtype=np.float64)
    tp = np.diag(counts)
    predicted = counts.sum(axis=0)
    actual = counts.sum(axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        precision = np.where(predicted > 0, tp / predicted, np.nan)
        recall = np.where(actual > 0, tp / actual, np.nan)
        denom = precision + recall
        f1 = np.where(denom > 0, 2 * precision * recall / denom, np.where(np.isnan(denom), np.nan, 0.0))
    return precision, recall, f1


def balanced_confusion_matrix(counts: np.ndarray) -> np.ndarray:
    """The paper's balanced confusion matrix (its figure "Balanced gesture type confusion
    matrix"): the mean of the row-normalised matrix (each row divided by its sum: recall view)
    and the column-normalised one (each column divided by its sum: precision view).

    An empty row (class absent from the ground truth) or column (class never predicted)
    normalises to zeros, so it contributes 0 to the mean.

    Args:
        counts: (K, K) confusion counts, rows ground truth, columns prediction.
    Returns:
        (K, K) float64 in [0, 1].
    """
    counts = np.asarray(counts, dtype=np.float64)
    rows = counts.sum(axis=1, keepdims=True)
    cols = counts.sum(axis=0, keepdims=True)
    by_row = np.divide(counts, rows, out=np.zeros_like(counts), where=rows > 0)
    by_col = np.divide(counts, cols, out=np.zeros_like(counts), where=cols > 0)
    return (by_row + by_col) / 2.0


def contact_distances(predicted: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """Distance errors of one observation's contact points (paper, "Metrics": "Average Euclidean
    Distance Error").

    Each predicted contact point is paired with its nearest ground-truth contact point. When
    there are more predicted points than ground-truth points, the predicted points furthest from
    any ground-truth point are discarded, keeping as many as there are ground-truth points.

    Args:
        predicted: (P, 2) float predicted contact points, truth: (G, 2) ground-truth points, both
            in the same frame and unit (the evaluation uses the user frame, mm).
    Returns:
        (min(P, G),) float64 distances, ascending when points were discarded; empty when P = 0
        or G = 0 (such observations do not count).
    """
    predicted = np.asarray(predicted, dtype=np.float64).reshape(-1, 2)
    truth = np.asarray(truth, dtype=np.float64).reshape(-1, 2)
    if len(predicted) == 0 or len(truth) == 0:
        return np.zeros(0)
    nearest = np.linalg.norm(predicted[:, None, :] - truth[None, :, :], axis=2).min(axis=1)
    if len(predicted) > len(truth):
        nearest = np.sort(nearest)[: len(truth)]
    return nearest


def mean_absolute_error(y_true: np.ndarray, y_pred: np.ndarray) -> float:
    """mean |y_true - y_pred| over (M,) float arrays (units of the inputs); NaN when M = 0."""
    y_true = np.asarray(y_true, dtype=np.float64)
    y_pred = np.asarray(y_pred, dtype=np.float64)
    return float(np.mean(np.abs(y_true - y_pred))) if y_true.size else math.nan


def accuracy_by_bin(
    values: np.ndarray, correct: np.ndarray, bin_width: float = INTENSITY_BIN_MM
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Accuracy per bin of a value (paper, figure "Gesture type and contact point count accuracy
    as a function of ground truth intensity").

    Bin k holds the values in [k * bin_width, (k + 1) * bin_width); bins run from 0 to the bin of
    the largest value.

    Args:
        values: (M,) float >= 0 (the ground-truth intensity, mm).
        correct: (M,) bool, whether the observation's prediction was right.
        bin_width: bin size (mm), > 0.
    Returns:
        edges (B+1,) float64 bin edges, accuracy (B,) float64 (NaN for an empty bin), count (B,)
        int64 observations per bin.
    """
    values = np.asarray(values, dtype=np.float64).reshape(-1)
    correct = np.asarray(correct, dtype=bool).reshape(-1)
    if values.shape != correct.shape:
        raise ValueError(f"values and correct differ in shape: {values.shape} vs {correct.shape}")
    if bin_width <= 0:
        raise ValueError(f"bin_width must be > 0, got {bin_width}")
    n_bins = int(np.floor(max(values.max(), 0.0) / bin_width)) + 1 if values.size else 0
    index = np.clip(np.floor(np.maximum(values, 0.0) / bin_width).astype(np.int64), 0, max(n_bins - 1, 0))
    count = np.bincount(index, minlength=n_bins).astype(np.int64)
    hits = np.bincount(index, weights=correct.astype(np.float64), minlength=n_bins)
    with np.errstate(invalid="ignore", divide="ignore"):
        acc = np.where(count > 0, hits / np.maximum(count, 1), np.nan)
    edges = np.arange(n_bins + 1, dtype=np.float64) * bin_width
    return edges, acc, count


def outside_collar(
    label_t_us: np.ndarray, label_values: np.ndarray, t_us: np.ndarray, collar_us: int = RESTING_COLLAR_US
) -> np.ndarray:
    """Which of the times ``t_us`` lie more than ``collar_us`` from every change of a labelled value
    (the resting flag, a gesture type). A change is at the labelled time whose value differs from
    the one before it (from there on the label at a prediction's time says the new value,
    :func:`~neurotouch_hid.core.dataset.labels_at`); a time at most ``collar_us`` before or after it is
    left out.

    Args:
        label_t_us: (L,) int64 labelled times (us), increasing.
        label_values: (L,) the labelled values (bool, int: any dtype ``!=`` compares).
        t_us: (M,) int64 prediction times (us).
        collar_us: the collar's half-width (us, >= 0).
    Returns:
        (M,) bool, True where the time is outside every collar.
    Raises:
        ValueError: the label arrays differ in shape.
    """
    label_t_us = np.asarray(label_t_us, dtype=np.int64).reshape(-1)
    label_values = np.asarray(label_values).reshape(-1)
    t_us = np.asarray(t_us, dtype=np.int64).reshape(-1)
    if label_t_us.shape != label_values.shape:
        raise ValueError(f"label times and values differ in shape: {label_t_us.shape} vs {label_values.shape}")
    changes = label_t_us[1:][label_values[1:] != label_values[:-1]]
    if changes.size == 0 or t_us.size == 0:
        return np.ones(t_us.shape, dtype=bool)
    after = np.searchsorted(changes, t_us, side="left")  # the first change at or after each time
    gap_next = np.abs(changes[np.minimum(after, changes.size - 1)] - t_us)
    gap_prev = np.abs(t_us - changes[np.maximum(after - 1, 0)])
    return np.minimum(gap_next, gap_prev) > collar_us


def outside_resting_collar(
    label_t_us: np.ndarray, label_resting: np.ndarray, t_us: np.ndarray, collar_us: int = RESTING_COLLAR_US
) -> np.ndarray:
    """Which predictions the collared resting F1 scores (docs/dataset.md, "Predictions (JSON
    lines)"): those more than ``collar_us`` from every change of the labelled resting flag
    (:func:`outside_collar`).

    Args:
        label_t_us: (L,) int64 labelled frames' times (us), increasing.
        label_resting: (L,) bool their resting flags.
        t_us: (M,) int64 prediction times (us).
        collar_us: the collar's half-width (us, >= 0).
    Returns:
        (M,) bool, True where the prediction is outside every collar.
    Raises:
        ValueError: the label arrays differ in shape.
    """
    return outside_collar(label_t_us, np.asarray(label_resting, dtype=bool), t_us, collar_us)


# --- aligning predictions with labels -------------------------------------------------------
@dataclass
class Observations:
    """Predictions paired with the ground truth at their times; one entry per evaluated
    prediction (M entries), all arrays of shape (M,).

    Attributes:
        gesture_true, gesture_pred: int64 indices into ``GESTURE_ORDER``.
        resting_true, resting_pred: bool.
        resting_scored: bool, outside the collar about every change of the labelled resting flag
            (:func:`outside_resting_collar`): what the collared resting F1 scores.
        gesture_scored, count_scored: bool, outside the 40 ms collar about every change of the
            labelled gesture type, of the labelled contact count (:func:`outside_collar`): what
            the collared gesture type and contact count accuracies score.
        count_true, count_pred: int64 contact counts.
        intensity_true, intensity_pred: float64 intensity (mm).
        distance_sum_mm: float64 sum of the observation's contact distance errors (mm, user frame).
        distance_n: int64 number of contact pairs in that sum (0 when either side has no contact).
        n_skipped: predictions before the sequence's first label (not evaluated).
        n_sequences: sequences these observations come from.
        felt: the per-gesture records of the same predictions (:mod:`.felt`).
        through_profiles: per profile name, the counts of the same predictions through it
            (:mod:`.through_profile`).
    """

    gesture_true: np.ndarray
    gesture_pred: np.ndarray
    resting_true: np.ndarray
    resting_pred: np.ndarray
    resting_scored: np.ndarray
    gesture_scored: np.ndarray
    count_scored: np.ndarray
    count_true: np.ndarray
    count_pred: np.ndarray
    intensity_true: np.ndarray
    intensity_pred: np.ndarray
    distance_sum_mm: np.ndarray
    distance_n: np.ndarray
    n_skipped: int = 0
    n_sequences: int = 1
    felt: FeltRecords | None = None
    through_profiles: dict[str, ProfileTally] = field(default_factory=dict)

    _ARRAYS = (
        "gesture_true",
        "gesture_pred",
        "resting_true",
        "resting_pred",
        "resting_scored",
        "gesture_scored",
        "count_scored",
        "count_true",
        "count_pred",
        "intensity_true",
        "intensity_pred",
        "distance_sum_mm",
        "distance_n",
    )

    def __len__(self) -> int:
        return int(len(self.gesture_true))

    @classmethod
    def concatenate(cls, parts: Sequence["Observations"]) -> "Observations":
        """All parts' observations in one (sequences' counts add up)."""
        if not parts:
            empty = align([], [], SensorGeometry())
            empty.n_sequences = 0
            return empty
        arrays = {name: np.concatenate([getattr(p, name) for p in parts]) for name in cls._ARRAYS}
        return cls(
            **arrays,
            n_skipped=sum(p.n_skipped for p in parts),
            n_sequences=sum(p.n_sequences for p in parts),
            felt=FeltRecords.concatenate([p.felt for p in parts if p.felt is not None]),
            through_profiles={
                name: sum((p.through_profiles.get(name, ProfileTally()) for p in parts), ProfileTally())
                for name in dict.fromkeys(name for p in parts for name in p.through_profiles)
            },
        )


def align(
    labels: Sequence[LabelRow],
    predictions: Sequence[GestureEstimate],
    sensor: SensorGeometry,
    deadzone_mm: float = DEFAULT_DEADZONE_MM,
    profiles: Sequence[ProfileUnderTest] = (),
    pressed: Sequence[tuple[int, int]] = (),
) -> Observations:
    """Pair one sequence's predictions with its labels (docs/dataset.md "Predictions (JSON lines)"),
    score them per gesture (:func:`.felt.gesture_records`, with ``deadzone_mm``, mm), and through
    each of ``profiles`` (:func:`.through_profile.tally`).

    The ground truth at each prediction time comes from
    :func:`~neurotouch_hid.core.dataset.labels_at`; predictions before the first label are
    skipped (counted in ``n_skipped``). Contact points of both sides are converted from the image
    frame (px) to the user frame (mm) with :meth:`SensorGeometry.image_to_user`, so distance
    errors are in mm (with the linear model of sensor.yaml this is the px distance divided by
    ``px_per_mm``; a calibrated geometry would be honoured too).

    Args:
        labels: the sequence's label rows, ordered by time.
        predictions: the pipeline's estimates for the sequence, ordered by time.
        sensor: the dataset's geometry.
        deadzone_mm: the dead zone of the per-gesture figures (mm).
        profiles: the profiles to replay the predictions through.
        pressed: the simulation's (t_start_us, pressed_us) rows of gestures whose fingers start
            apart (:func:`~neurotouch_hid.core.dataset.read_pressed`; :func:`.felt.gesture_records`).
    """
    truth = (
        labels_at(labels, np.array([p.t_us for p in predictions], dtype=np.int64))
        if labels
        else [None] * len(predictions)
    )
    kept = [(p, t) for p, t in zip(predictions, truth) if t is not None]
    m = len(kept)
    label_t = np.array([row.t_us for row in labels], dtype=np.int64)
    kept_t = np.array([p.t_us for p, _ in kept], dtype=np.int64)
    obs = Observations(
        gesture_true=np.empty(m, np.int64),
        gesture_pred=np.empty(m, np.int64),
        resting_true=np.empty(m, bool),
        resting_pred=np.empty(m, bool),
        resting_scored=outside_resting_collar(label_t, np.array([row.resting for row in labels], dtype=bool), kept_t),
        gesture_scored=outside_collar(
            label_t, np.array([_GESTURE_INDEX[row.gesture] for row in labels], dtype=np.int64), kept_t, TYPE_COLLAR_US
        ),
        count_scored=outside_collar(
            label_t, np.array([row.n_contacts for row in labels], dtype=np.int64), kept_t, TYPE_COLLAR_US
        ),
        count_true=np.empty(m, np.int64),
        count_pred=np.empty(m, np.int64),
        intensity_true=np.empty(m, np.float64),
        intensity_pred=np.empty(m, np.float64),
        distance_sum_mm=np.zeros(m, np.float64),
        distance_n=np.zeros(m, np.int64),
        n_skipped=len(predictions) - m,
        felt=gesture_records(labels, predictions, deadzone_mm, pressed),
        through_profiles={tested.name: tally(tested, labels, predictions, sensor) for tested in profiles},
    )
    for k, (pred, true) in enumerate(kept):
        obs.gesture_true[k] = _GESTURE_INDEX[true.gesture]
        obs.gesture_pred[k] = _GESTURE_INDEX[pred.gesture]
        obs.resting_true[k] = true.resting
        obs.resting_pred[k] = pred.resting
        obs.count_true[k] = true.n_contacts
        obs.count_pred[k] = pred.n_contacts
        obs.intensity_true[k] = true.intensity_mm
        obs.intensity_pred[k] = pred.intensity_mm
        if pred.n_contacts and true.n_contacts:
            d = contact_distances(sensor.image_to_user(pred.contacts_px), sensor.image_to_user(true.contacts_px))
            obs.distance_sum_mm[k] = d.sum()
            obs.distance_n[k] = len(d)
    return obs


# --- the result -----------------------------------------------------------------------------
def _clean(value):
    """JSON-able copy: numpy -> Python, NaN -> None, dataclasses -> dicts."""
    if is_dataclass(value):
        return _clean(asdict(value))
    if isinstance(value, dict):
        return {str(k): _clean(v) for k, v in value.items()}
    if isinstance(value, (list, tuple, np.ndarray)):
        return [_clean(v) for v in (value.tolist() if isinstance(value, np.ndarray) else value)]
    if isinstance(value, (np.integer,)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        return None if math.isnan(value) else float(value)
    return value


@dataclass
class EvaluationResult:
    """Every metric of the paper's evaluation, plus the counts behind them.

    Rates are fractions in [0, 1]; distances and intensities mm. Per-class arrays follow
    ``classes`` (``GESTURE_ORDER``'s names). NaN where a value is undefined.

    Attributes:
        classes: gesture type names, the order of every per-class array and the matrices' axes.
        n_sequences, n_predictions, n_observations, n_skipped: sequences evaluated, predictions
            made, predictions evaluated, predictions before the first label (skipped).
        n_gesture_observations: observations labelled with a gesture (not ``none``).
        gesture_accuracy: gesture type accuracy over all observations (the paper's figure).
        gesture_collared_accuracy: the same over the observations outside the 40 ms collar about
            each change of the labelled type.
        precision, recall, f1, support: (K,) per gesture type (support: labelled observations).
        confusion: (K, K) int64 counts, rows ground truth, columns prediction.
        balanced_confusion: (K, K) mean of row- and column-normalised ``confusion``.
        contact_count_accuracy: contact count accuracy over all observations (the paper's figure).
        contact_count_collared_accuracy: the same outside the 40 ms collar about each change of
            the labelled count.
        contact_count_collared_accuracy_by_gesture: (K,) that per labelled gesture type.
        contact_count_accuracy_by_gesture: (K,) the same per labelled gesture type.
        contact_distance_mm: mean Euclidean contact distance error over all contact pairs (mm).
        n_contact_pairs: contact pairs behind it.
        contact_distance_by_gesture_mm: (K,) the same per labelled gesture type.
        intensity_mae_mm: intensity MAE over gesture observations (mm).
        intensity_mae_by_gesture_mm: (K,) the same per labelled gesture type (NaN for ``none``).
        resting_precision, resting_recall, resting_f1: resting detection, positive = resting.
        resting_collared_precision, resting_collared_recall, resting_collared_f1: the same over
            the observations outside the 40 ms collar about each change of the labelled flag.
        intensity_bin_edges_mm: (B+1,) ground-truth intensity bin edges (0.6 mm bins).
        gesture_accuracy_by_intensity, contact_count_accuracy_by_intensity: (B,) per bin, over
            gesture observations.
        n_by_intensity: (B,) observations per bin.
        felt: the per-gesture figures (docs/dataset.md, "Per-gesture metrics").
        through_profiles: per profile name, the counts through it (docs/dataset.md, "Through a profile").
    """

    classes: list[str]
    n_sequences: int
    n_predictions: int
    n_observations: int
    n_skipped: int
    n_gesture_observations: int
    gesture_accuracy: float
    gesture_collared_accuracy: float
    precision: np.ndarray
    recall: np.ndarray
    f1: np.ndarray
    support: np.ndarray
    confusion: np.ndarray
    balanced_confusion: np.ndarray
    contact_count_accuracy: float
    contact_count_accuracy_by_gesture: np.ndarray
    contact_count_collared_accuracy: float
    contact_count_collared_accuracy_by_gesture: np.ndarray
    contact_distance_mm: float
    n_contact_pairs: int
    contact_distance_by_gesture_mm: np.ndarray
    intensity_mae_mm: float
    intensity_mae_by_gesture_mm: np.ndarray
    resting_precision: float
    resting_recall: float
    resting_f1: float
    resting_collared_precision: float
    resting_collared_recall: float
    resting_collared_f1: float
    intensity_bin_edges_mm: np.ndarray
    gesture_accuracy_by_intensity: np.ndarray
    contact_count_accuracy_by_intensity: np.ndarray
    n_by_intensity: np.ndarray
    felt: FeltSummary
    through_profiles: dict[str, ProfileTally] = field(default_factory=dict)

    def to_dict(self) -> dict:
        """All fields as JSON-able values (lists, floats, ints; NaN -> None)."""
        return _clean({name: getattr(self, name) for name in self.__dataclass_fields__})


def _pairs_mean(sums: np.ndarray, n: np.ndarray) -> float:
    total = int(n.sum())
    return float(sums.sum() / total) if total else math.nan


def evaluate(obs: Observations) -> EvaluationResult:
    """Compute every metric of the paper (sections "Metrics" and "Results") on observations.

    - gesture type: accuracy, precision/recall/F1 per class, confusion and balanced confusion;
    - gesture type and contact count accuracy outside the 40 ms collar about each change of the
      labelled type, of the labelled count (``Observations.gesture_scored``, ``count_scored``);
    - contact count accuracy (all observations, and per labelled gesture type);
    - contact distance error: mean over every contact pair of :func:`contact_distances`, over
      observations where both sides have a contact;
    - intensity MAE over gesture observations (label gesture != none);
    - resting precision/recall/F1 with resting as the positive class, over every observation
      and outside the collar (``Observations.resting_scored``);
    - gesture type and contact count accuracy per 0.6 mm bin of ground-truth intensity, over
      gesture observations;
    - the per-gesture figures of the observations' records (:func:`.felt.summarise`).
    """
    k = len(GESTURE_ORDER)
    counts = confusion_matrix(obs.gesture_true, obs.gesture_pred, k)
    precision, recall, f1 = precision_recall_f1(counts)
    resting = confusion_matrix(obs.resting_true.astype(np.int64), obs.resting_pred.astype(np.int64), 2)
    r_precision, r_recall, r_f1 = (float(v[1]) for v in precision_recall_f1(resting))
    scored = obs.resting_scored
    collared = confusion_matrix(obs.resting_true[scored].astype(np.int64), obs.resting_pred[scored].astype(np.int64), 2)
    c_precision, c_recall, c_f1 = (float(v[1]) for v in precision_recall_f1(collared))
    g_in, c_in = obs.gesture_scored, obs.count_scored
    gesture_ok = obs.gesture_true == obs.gesture_pred
    count_ok = obs.count_true == obs.count_pred
    active = obs.gesture_true != _NONE
    edges, g_acc, n_bin = accuracy_by_bin(obs.intensity_true[active], gesture_ok[active])
    _, c_acc, _ = accuracy_by_bin(obs.intensity_true[active], count_ok[active])

    def by_gesture(fn) -> np.ndarray:
        return np.array([fn(obs.gesture_true == g) for g in range(k)], dtype=np.float64)

    return EvaluationResult(
        classes=[g.value for g in GESTURE_ORDER],
        n_sequences=obs.n_sequences,
        n_predictions=len(obs) + obs.n_skipped,
        n_observations=len(obs),
        n_skipped=obs.n_skipped,
        n_gesture_observations=int(active.sum()),
        gesture_accuracy=accuracy(obs.gesture_true, obs.gesture_pred),
        gesture_collared_accuracy=accuracy(obs.gesture_true[g_in], obs.gesture_pred[g_in]),
        precision=precision,
        recall=recall,
        f1=f1,
        support=counts.sum(axis=1),
        confusion=counts,
        balanced_confusion=balanced_confusion_matrix(counts),
        contact_count_accuracy=accuracy(obs.count_true, obs.count_pred),
        contact_count_accuracy_by_gesture=by_gesture(lambda m: accuracy(obs.count_true[m], obs.count_pred[m])),
        contact_count_collared_accuracy=accuracy(obs.count_true[c_in], obs.count_pred[c_in]),
        contact_count_collared_accuracy_by_gesture=by_gesture(
            lambda m: accuracy(obs.count_true[m & c_in], obs.count_pred[m & c_in])
        ),
        contact_distance_mm=_pairs_mean(obs.distance_sum_mm, obs.distance_n),
        n_contact_pairs=int(obs.distance_n.sum()),
        contact_distance_by_gesture_mm=by_gesture(lambda m: _pairs_mean(obs.distance_sum_mm[m], obs.distance_n[m])),
        intensity_mae_mm=mean_absolute_error(obs.intensity_true[active], obs.intensity_pred[active]),
        intensity_mae_by_gesture_mm=by_gesture(
            lambda m: mean_absolute_error(obs.intensity_true[m & active], obs.intensity_pred[m & active])
        ),
        resting_precision=r_precision,
        resting_recall=r_recall,
        resting_f1=r_f1,
        resting_collared_precision=c_precision,
        resting_collared_recall=c_recall,
        resting_collared_f1=c_f1,
        intensity_bin_edges_mm=edges,
        gesture_accuracy_by_intensity=g_acc,
        contact_count_accuracy_by_intensity=c_acc,
        n_by_intensity=n_bin,
        felt=summarise(obs.felt if obs.felt is not None else FeltRecords.concatenate([])),
        through_profiles=dict(obs.through_profiles),
    )
