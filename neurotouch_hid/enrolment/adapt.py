"""``neurotouch-hid adapt``: the recogniser fitted to one gel and hand from enrolment datasets
(docs/method.md, "Adaptation"; not in the paper).

1. **Record.** The shipped pipeline runs once over every sequence of the enrolment datasets
   (docs/dataset.md folders). Each window's type before the episode vote, intensity, contact count
   and the learned type's nine features (``pipeline/learned.py``) are kept, and each APS frame's
   resting distance (``pipeline/resting.py``). The episode vote only reads each window's type,
   intensity, contact count and time, in order, so what the pipeline would answer with other
   values of what is fitted is replayed from these records without running it again
   (:func:`replay`; the vote is ``pipeline/episode.py``'s own).
2. **Hold out by prompt.** The labelled gestures of each type are numbered in time; every third,
   from the second on (:data:`HOLD_EVERY`), is held out, with the rest before it: the fit never
   sees a window of a held-out gesture.
3. **Fit** on the other gestures, each fitted value with the shipped one as its prior:

   - the learned type: the multinomial logistic regression refitted from the shipped weights,
     L2-regularised toward them (:func:`fit_classifier`; the strength picked by a 3-fold
     cross-validation by gesture within the fitted part);
   - the minimum intensity (the contact threshold, ``gesture.min_intensity_mm``), from the shipped
     value up (:data:`MIN_INTENSITY_STEPS`), scored on the windows outside a collar about each
     change of the labelled type (:data:`THRESHOLD_COLLAR_US`);
   - how long one contact alone keeps an episode undecided (``episode.first_finger_us``, the hand's
     lag between its first and second finger), from the shipped value down
     (:data:`FIRST_FINGER_STEPS_US`), the fitted part's best accuracy among the values that show no
     more windows of another type above the dead zone (:data:`DEADZONE_MM`) than the shipped one;
   - the resting threshold (``resting.centroid_threshold_mm2``), the frames' best resting F1;
   - the intensity scale (``gesture.intensity_gain``), least squares against the labels.

4. **Check** on the held-out gestures: each fitted value is kept only where it beats the shipped
   one there by more than :data:`MIN_GAIN` of the windows' gesture type accuracy (the type, the
   contact threshold (outside the collar) and the first finger's wait: replayed, the wait with no
   more windows of another type above the dead zone either; the resting threshold: the pipeline
   run again with it, and its frames' resting F1 higher too; the scale: an intensity MAE lower by
   more than :data:`MIN_MAE_GAIN` of it, and no accuracy lost);
   otherwise the shipped value stays. The model (``model.py``) holds only what was kept.
"""

from __future__ import annotations

import math
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Sequence

import numpy as np

from neurotouch_hid.core.errors import DatasetError, NeurotouchError
from neurotouch_hid.core.estimate import GestureType
from neurotouch_hid.evaluation.felt import DEFAULT_DEADZONE_MM
from neurotouch_hid.evaluation.metrics import outside_collar
from neurotouch_hid.pipeline.episode import FIRST_FINGER_US
from neurotouch_hid.pipeline.learned import CLASSES, FEATURES, Classifier

#: Every HOLD_EVERY-th labelled gesture of each type, from the second on, is held out.
HOLD_EVERY = 3
#: Regularisation strengths toward the shipped weights tried by the cross-validation (per window,
#: on the standardised features; larger: closer to the shipped model).
PRIOR_STRENGTHS = (0.001, 0.003, 0.01, 0.03, 0.1, 0.3, 1.0)
#: Minimum intensities tried (multiples of the shipped one; only up: a lower one would need the
#: windows the shipped threshold skipped).
MIN_INTENSITY_STEPS = (1.0, 1.25, 1.5, 2.0, 2.5)
#: How long one contact alone keeps an episode undecided, tried (us; only down from the shipped
#: FIRST_FINGER_US: a longer wait only delays every answer). A hand whose fingers land together
#: needs no wait; one whose second finger lags needs the shipped one.
FIRST_FINGER_STEPS_US = (0, 30_000, 45_000, 60_000, 75_000, FIRST_FINGER_US)
#: A window of another type (not ``none``) at or above this intensity (mm) is felt wrong: the
#: ``default`` profile's dead zone (docs/dataset.md, "Per-gesture metrics").
DEADZONE_MM = DEFAULT_DEADZONE_MM
#: Resting thresholds tried (multiples of the shipped one), at most the near-rest threshold.
RESTING_STEPS = (0.5, 0.75, 1.0, 1.5, 2.0, 3.0, 5.0)
#: Fewest held-out gestures (all types together) for a check; fewer: the shipped model is kept.
MIN_HELD_OUT = 3
#: A fitted value is kept only when it beats the shipped one on the held-out gestures' windows by
#: more than this (gesture type accuracy, 0..1): 0.2 points is ~7 windows of a 3-minute enrolment's
#: ~3400 held-out ones, less than one tap: a smaller gain is within what another hold-out moves.
MIN_GAIN = 0.002
#: The contact threshold is fitted and checked on the windows more than this from every change of
#: the labelled type (us; one APS frame, the collar docs/dataset.md puts about the resting flag). A
#: higher threshold moves only a gesture's weakest windows, its attack's first and its release's
#: last, and there the enrolment's labels, which take a gesture's moments from the gel's motion
#: (``label.py``: from the last window near the level before the cue to a tenth of the peak), are
#: unsure by a window or more. Scored on every window, a threshold was kept for answering ``none``
#: in the 10-40 ms after a labelled end (intensity 0.15-0.24 mm), where a game's labels, which end
#: a gesture when its fingers have left, still call it the gesture (docs/method.md, "Adaptation").
THRESHOLD_COLLAR_US = 40_000
#: The intensity scale is kept only when it lowers the held-out intensity MAE by more than this share
#: of it: a scale within a few thousandths of 1 changes nothing a profile can feel.
MIN_MAE_GAIN = 0.05


@dataclass
class Record:
    """One sequence as the shipped pipeline saw it, with its labels at each window and frame.

    Attributes (W windows, F frames):
        name: the sequence (``DATASET/NAME``).
        t_us: (W,) int64 window ends (us).
        gesture: (W,) int8, the type before the vote: -1 ``none``, else an index into
            :data:`~neurotouch_hid.pipeline.learned.CLASSES`.
        intensity_mm: (W,) float64 intensity before the vote (0 for ``none``).
        n_contacts: (W,) int16.
        features: (W, 9) float64 learned-type features (NaN where ``gesture`` is -1).
        answered: (W,) int8, what the pipeline answered (after the vote; -1 ``none``).
        label: (W,) int8 labelled type (-1 ``none``, -2 no label yet).
        label_intensity_mm: (W,) float64.
        prompt: (W,) int64 the labelled gesture each window belongs to (rest belongs to the
            gesture after it), unique over all records once offset.
        frame_t_us, frame_distance_mm2: (F,) the resting detector's frames and distances (mm^2
            per reference marker).
        frame_resting: (F,) bool, labelled resting; frame_prompt (F,) as ``prompt``.
        prompt_type: prompt id -> labelled type index (CLASSES) of that gesture.
        counter_mm: (W,) float64 how far the gel moves against a lone contact's drag (mm,
            ``pipeline/counter_drag.py``; inf where the window has not one contact), None: not
            recorded (read as inf).
    """

    name: str
    t_us: np.ndarray
    gesture: np.ndarray
    intensity_mm: np.ndarray
    n_contacts: np.ndarray
    features: np.ndarray
    answered: np.ndarray
    label: np.ndarray
    label_intensity_mm: np.ndarray
    prompt: np.ndarray
    frame_t_us: np.ndarray
    frame_distance_mm2: np.ndarray
    frame_resting: np.ndarray
    frame_prompt: np.ndarray
    prompt_type: dict[int, int] = field(default_factory=dict)
    counter_mm: np.ndarray | None = None


def _type_index(gesture: GestureType) -> int:
    return -1 if gesture is GestureType.NONE else CLASSES.index(gesture)


def _recorder(sensor, config):
    """The shipped pipeline, keeping what :class:`Record` needs of every window and frame."""
    from neurotouch_hid.pipeline.learned import gesture_features
    from neurotouch_hid.pipeline.pipeline import GesturePipeline

    class Recorder(GesturePipeline):
        def __init__(self) -> None:
            super().__init__(sensor, config)
            self.rows: list[tuple] = []
            self.frames: list[tuple[int, float]] = []
            self._features: np.ndarray | None = None

        def _learned_type(self, result, contacts, rest_px, current, valid):
            self._features = None
            if result.gesture is not GestureType.NONE:
                c = self.config
                self._features = gesture_features(
                    result,
                    self.type_centres_of(contacts),
                    rest_px,
                    current,
                    valid,
                    self.sensor,
                    c.r_px,
                    c.origin_radius_px,
                )
            return super()._learned_type(result, contacts, rest_px, current, valid)

        def _vote(self, gesture, intensity_mm, n_contacts, t_us):
            one = n_contacts == 1 and gesture is not GestureType.NONE
            counter = self._counter_drag() if one else math.inf  # as the vote reads it, for the replay
            answer = super()._vote(gesture, intensity_mm, n_contacts, t_us)
            feats = self._features if gesture is not GestureType.NONE else None
            self.rows.append((t_us, _type_index(gesture), intensity_mm, n_contacts, feats, counter))
            return answer

        def _apply_resting(self, result, t_us):
            self.frames.append((int(t_us), float(result.distance) / self.sensor.px_per_mm**2))
            super()._apply_resting(result, t_us)

    return Recorder()


def record_sequence(dataset: str | Path, name: str, config=None) -> Record:
    """Run the pipeline (``config``, a PipelineConfig; None: the shipped one) over one labelled
    sequence (docs/dataset.md) and keep its :class:`Record` (prompt ids local to the sequence, from 0).

    Raises:
        DatasetError, RecordingError, SensorError: bad labels, recording or geometry.
    """
    from neurotouch_hid.core.dataset import dataset_sensor_file, labels_at, read_labels
    from neurotouch_hid.core.sensor import SensorGeometry
    from neurotouch_hid.pipeline.config import PipelineConfig
    from neurotouch_hid.sources.recording import RecordingReader

    dataset = Path(dataset)
    sensor = SensorGeometry.load(dataset_sensor_file(dataset))
    labels = read_labels(dataset / f"{name}.labels.csv")
    pipeline = _recorder(sensor, config or PipelineConfig())
    answered = []
    with RecordingReader(dataset / f"{name}.aedat4") as reader:
        for estimate in pipeline.run(reader.stream()):
            answered.append(_type_index(estimate.gesture))
    rows = pipeline.rows
    if len(rows) != len(answered):  # every window votes once: a recorder out of step is a bug
        raise RuntimeError(f"{name}: {len(rows)} votes for {len(answered)} windows")
    t_us = np.array([r[0] for r in rows], dtype=np.int64)
    features = np.full((len(rows), len(FEATURES)), np.nan)
    for i, r in enumerate(rows):
        if r[4] is not None:
            features[i] = r[4]
    # the labelled gestures in time: a new one where the type changes from the row before
    label_t = np.array([row.t_us for row in labels], dtype=np.int64)
    row_prompt = np.zeros(len(labels), dtype=np.int64)
    prompt_type: dict[int, int] = {}
    current, previous = -1, None
    for i, row in enumerate(labels):
        if row.gesture is not GestureType.NONE and row.gesture is not previous:
            current += 1
            prompt_type[current] = _type_index(row.gesture)
        previous = row.gesture if row.gesture is not GestureType.NONE else None
        row_prompt[i] = current if row.gesture is not GestureType.NONE else current + 1  # rest: the next one

    def prompts_at(times: np.ndarray) -> np.ndarray:
        at = np.searchsorted(label_t, times, side="right") - 1
        return np.where(at >= 0, row_prompt[np.clip(at, 0, None)], 0)

    at = labels_at(labels, t_us)
    frames = np.array(pipeline.frames, dtype=np.float64).reshape(-1, 2)
    frame_t = frames[:, 0].astype(np.int64)
    frame_labels = labels_at(labels, frame_t)
    keep = np.array([lab is not None for lab in frame_labels], dtype=bool)
    return Record(
        name=f"{dataset}/{name}",
        t_us=t_us,
        gesture=np.array([r[1] for r in rows], dtype=np.int8),
        intensity_mm=np.array([r[2] for r in rows], dtype=np.float64),
        n_contacts=np.array([r[3] for r in rows], dtype=np.int16),
        counter_mm=np.array([r[5] for r in rows], dtype=np.float64),
        features=features,
        answered=np.array(answered, dtype=np.int8),
        label=np.array([-2 if lab is None else _type_index(lab.gesture) for lab in at], dtype=np.int8),
        label_intensity_mm=np.array([0.0 if lab is None else lab.intensity_mm for lab in at]),
        prompt=prompts_at(t_us),
        frame_t_us=frame_t[keep],
        frame_distance_mm2=frames[keep, 1],
        frame_resting=np.array([lab.resting for lab in frame_labels if lab is not None], dtype=bool),
        frame_prompt=prompts_at(frame_t[keep]),
        prompt_type=prompt_type,
    )


def record_datasets(
    datasets: Sequence[str | Path],
    jobs: int = 1,
    on_sequence: Callable[[str], None] | None = None,
    config=None,
) -> list[Record]:
    """:func:`record_sequence` over every sequence of the datasets (``jobs`` processes; ``config``
    as there), prompt ids made unique over all of them (the same ids for the same datasets).
    Raises what :func:`record_sequence` and ``dataset.list_sequences`` raise."""
    import multiprocessing

    from neurotouch_hid.core.dataset import list_sequences

    work = [(Path(d), n) for d in datasets for n in list_sequences(d)]
    if jobs <= 1 or len(work) == 1:
        records = []
        for d, n in work:
            records.append(record_sequence(d, n, config))
            if on_sequence is not None:
                on_sequence(f"{d}/{n}")
    else:
        with ProcessPoolExecutor(max_workers=jobs, mp_context=multiprocessing.get_context("spawn")) as pool:
            futures = [pool.submit(record_sequence, d, n, config) for d, n in work]
            records = []
            for f, (d, n) in zip(futures, work):
                records.append(f.result())
                if on_sequence is not None:
                    on_sequence(f"{d}/{n}")
    offset = 0
    for r in records:
        r.prompt = r.prompt + offset
        r.frame_prompt = r.frame_prompt + offset
        r.prompt_type = {k + offset: v for k, v in r.prompt_type.items()}
        offset = max(r.prompt.max(initial=offset), r.frame_prompt.max(initial=offset)) + 1
    return records


#: ``adapt`` refuses labels when the shipped recogniser reads more than this share of the
#: labelled gestures it reads at all as one other type each (:func:`contradiction`).
CONTRADICTED_SHARE = 0.5
#: ... and at least this many gestures (fewer tell nothing).
MIN_CONTRADICTED = 3


def read_as(records: Sequence[Record]) -> list[tuple[int, int]]:
    """(labelled type, the type the shipped pipeline answered most over that gesture's labelled
    windows) for each labelled gesture it answered a gesture for at all (CLASSES indices)."""
    pairs: list[tuple[int, int]] = []
    for r in records:
        for prompt, kind in sorted(r.prompt_type.items()):
            answers = r.answered[(r.prompt == prompt) & (r.label == kind) & (r.answered >= 0)]
            if len(answers):
                pairs.append((kind, int(np.bincount(answers.astype(np.int64)).argmax())))
    return pairs


def contradiction(records: Sequence[Record]) -> str | None:
    """Why the labels look wrong, or None: the shipped recogniser, which reads most gestures of
    most hands right, reads more than :data:`CONTRADICTED_SHARE` of the labelled gestures it
    answers at all (at least :data:`MIN_CONTRADICTED` of them) as another type: labels made
    from a plan the recording did not follow, not a hand to adapt to. Names the commonest
    confusions."""
    pairs = read_as(records)
    wrong = [(k, a) for k, a in pairs if k != a]
    if len(wrong) < MIN_CONTRADICTED or len(wrong) <= CONTRADICTED_SHARE * len(pairs):
        return None
    counts: dict[tuple[int, int], int] = {}
    for pair in wrong:
        counts[pair] = counts.get(pair, 0) + 1
    common = sorted(counts.items(), key=lambda item: -item[1])[:3]
    named = "; ".join(f"{n} labelled {CLASSES[k].value} read as {CLASSES[a].value}" for (k, a), n in common)
    return (
        f"the shipped recogniser reads {len(wrong)} of the {len(pairs)} labelled gestures it reads at all as "
        f"another type ({named}): the labels, not the hand, look wrong (a recording labelled with a plan it did "
        "not follow?); no model is fitted to them"
    )


def held_out_prompts(records: Sequence[Record]) -> set[int]:
    """The prompt ids held out: per labelled type, in time, every :data:`HOLD_EVERY`-th from
    the second on (the rest before a gesture goes with it)."""
    held, seen = set(), {}
    for r in records:
        for prompt, kind in sorted(r.prompt_type.items()):
            k = seen.get(kind, 0)
            seen[kind] = k + 1
            if k % HOLD_EVERY == 1:
                held.add(prompt)
    return held


# --- the replay ---------------------------------------------------------------------------
def replay(
    record: Record,
    classifier: Classifier | None = None,
    min_intensity_mm: float = 0.0,
    gain: float = 1.0,
    first_finger_us: int = FIRST_FINGER_US,
) -> np.ndarray:
    """(W,) int8 what the pipeline answers (-1 ``none``, else a CLASSES index) with another
    learned type (None: the shipped one), a minimum intensity at least the shipped one (mm), an
    intensity gain, the episode vote's ``first_finger_us`` (us): the recorded windows through the
    episode vote (``pipeline/episode.py``)."""
    from neurotouch_hid.pipeline.episode import EpisodeVote

    classifier = classifier or Classifier.shipped()
    kinds = np.asarray(record.gesture, dtype=np.int64).copy()
    gesture = kinds >= 0
    if gesture.any():
        kinds[gesture] = np.argmax(classifier.logits(record.features[gesture]), axis=1)
    kinds[record.intensity_mm < min_intensity_mm] = -1
    vote = EpisodeVote(first_finger_us=first_finger_us)
    types = (*CLASSES, GestureType.NONE)  # index -1: none
    out = np.empty(len(kinds), dtype=np.int8)
    counter = record.counter_mm if record.counter_mm is not None else np.full(len(kinds), math.inf)
    for i, (t, k, intensity, n, c) in enumerate(
        zip(
            record.t_us.tolist(),
            kinds.tolist(),
            record.intensity_mm.tolist(),
            record.n_contacts.tolist(),
            counter.tolist(),
        )
    ):
        if k < 0:
            answer = vote.update(GestureType.NONE, 0.0, 0, t)
        else:
            answer = vote.update(types[k], intensity * gain, n, t, c)
        out[i] = _type_index(answer)
    return out


def _accuracy(
    records: Sequence[Record], answers: Sequence[np.ndarray], prompts: set[int], collar_us: int = 0
) -> tuple[float, int]:
    """(gesture type accuracy, windows) over the labelled windows of ``prompts``; with ``collar_us``
    > 0, only those more than that (us) from every change of the labelled type
    (:func:`~neurotouch_hid.evaluation.metrics.outside_collar`)."""
    right = total = 0
    for r, a in zip(records, answers):
        m = (r.label >= -1) & np.isin(r.prompt, list(prompts))
        if collar_us > 0:
            m &= outside_collar(r.t_us, r.label, r.t_us, collar_us)
        right += int(np.sum(a[m] == r.label[m]))
        total += int(m.sum())
    return (right / total if total else float("nan")), total


def _felt_wrong(records: Sequence[Record], answers: Sequence[np.ndarray], prompts: set[int]) -> int:
    """Windows of ``prompts`` labelled a gesture and answered another one (not ``none``) at an
    intensity at least :data:`DEADZONE_MM`: what a player would feel as the wrong gesture."""
    wrong = 0
    for r, a in zip(records, answers):
        m = (r.label >= 0) & (a >= 0) & (a != r.label) & (r.intensity_mm >= DEADZONE_MM)
        wrong += int(np.sum(m & np.isin(r.prompt, list(prompts))))
    return wrong


# --- the fits -----------------------------------------------------------------------------
def _rows(records: Sequence[Record], prompts: set[int]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(features (n, 9), labelled class (n,), prompt (n,)) of the windows of ``prompts`` the rule
    and the labels both call a gesture: what the learned type is fitted on."""
    x, y, p = [], [], []
    for r in records:
        m = (r.gesture >= 0) & (r.label >= 0) & np.isin(r.prompt, list(prompts))
        x.append(r.features[m])
        y.append(r.label[m].astype(np.int64))
        p.append(r.prompt[m])
    return np.concatenate(x), np.concatenate(y), np.concatenate(p)


def fit_classifier(
    x: np.ndarray, y: np.ndarray, strength: float, prior: Classifier | None = None, steps: int = 30
) -> Classifier:
    """The multinomial logistic regression fitted to (n, 9) features and (n,) class indices by
    Newton's method, the shipped model (``prior``) as its prior: it minimises the mean
    cross-entropy plus ``strength`` / 2 times the squared distance of the weights and intercepts
    to the prior's, on the prior's standardisation (kept). NumPy only."""
    prior = prior or Classifier.shipped()
    k, d = len(CLASSES), len(FEATURES)
    z = np.hstack([(x - prior.mean) / prior.scale, np.ones((len(x), 1))])  # (n, d + 1)
    theta0 = np.hstack([prior.weights, prior.intercept[:, None]])  # (k, d + 1)
    theta = theta0.copy()
    onehot = np.eye(k)[y]
    n = max(len(x), 1)

    def loss(th: np.ndarray) -> float:
        logits = z @ th.T
        logits -= logits.max(axis=1, keepdims=True)
        logp = logits - np.log(np.exp(logits).sum(axis=1, keepdims=True))
        return -float(np.sum(onehot * logp)) / n + 0.5 * strength * float(np.sum((th - theta0) ** 2))

    current = loss(theta)
    for _ in range(steps):
        logits = z @ theta.T
        logits -= logits.max(axis=1, keepdims=True)
        p = np.exp(logits)
        p /= p.sum(axis=1, keepdims=True)
        grad = ((p - onehot).T @ z) / n + strength * (theta - theta0)  # (k, d + 1)
        hess = np.empty((k, d + 1, k, d + 1))
        for a in range(k):
            for b in range(a, k):
                w = p[:, a] * ((a == b) - p[:, b])
                block = (z * w[:, None]).T @ z / n
                hess[a, :, b, :] = block
                hess[b, :, a, :] = block.T
        m = k * (d + 1)
        h = hess.reshape(m, m) + strength * np.eye(m)
        step = np.linalg.solve(h, grad.reshape(m)).reshape(k, d + 1)
        t = 1.0
        while t > 1e-4:  # backtracking: Newton's step may overshoot on separable data
            candidate = theta - t * step
            value = loss(candidate)
            if value <= current:
                break
            t *= 0.5
        else:
            break
        done = current - value < 1e-10
        theta, current = candidate, value
        if done:
            break
    return Classifier(prior.mean.copy(), prior.scale.copy(), theta[:, :d].copy(), theta[:, d].copy())


def pick_strength(x: np.ndarray, y: np.ndarray, prompts: np.ndarray) -> float:
    """The prior strength (:data:`PRIOR_STRENGTHS`) with the most right windows over a 3-fold
    cross-validation by gesture, stratified by type (each type's gestures, in time, dealt to the
    folds in turn); ties go to the stronger prior."""
    fold_of: dict[int, int] = {}
    dealt: dict[int, int] = {}
    for prompt in np.unique(prompts).tolist():
        kind = int(np.bincount(y[prompts == prompt]).argmax())
        fold_of[prompt] = dealt.get(kind, 0) % 3
        dealt[kind] = dealt.get(kind, 0) + 1
    folds = np.array([fold_of[p] for p in prompts.tolist()], dtype=np.int64)
    best, best_score = PRIOR_STRENGTHS[-1], -1
    for strength in sorted(PRIOR_STRENGTHS, reverse=True):
        right = 0
        for fold in range(3):
            test = folds == fold
            if test.all() or not test.any():
                continue
            model = fit_classifier(x[~test], y[~test], strength)
            right += int(np.sum(np.argmax(model.logits(x[test]), axis=1) == y[test]))
        if right > best_score:
            best, best_score = strength, right
    return best


def _fit_first_finger(
    records: Sequence[Record], classifier: Classifier | None, min_intensity_mm: float, prompts: set[int]
) -> int:
    """The first finger's wait (us, of :data:`FIRST_FINGER_STEPS_US`) with the best gesture type
    accuracy over the windows of ``prompts`` among those with no more windows felt wrong there
    (:func:`_felt_wrong`) than the shipped wait; ties go to the longer wait."""
    scores = []
    for wait in FIRST_FINGER_STEPS_US:
        answers = [replay(r, classifier, min_intensity_mm, first_finger_us=wait) for r in records]
        scores.append((wait, _accuracy(records, answers, prompts)[0], _felt_wrong(records, answers, prompts)))
    shipped_felt = next(felt for wait, _, felt in scores if wait == FIRST_FINGER_US)
    allowed = [(accuracy, wait) for wait, accuracy, felt in scores if felt <= shipped_felt]
    return max(allowed)[1]


def _resting_f1(records: Sequence[Record], prompts: set[int], threshold: float) -> float:
    tp = fp = fn = 0
    for r in records:
        m = np.isin(r.frame_prompt, list(prompts))
        said = r.frame_distance_mm2[m] <= threshold
        truth = r.frame_resting[m]
        tp += int(np.sum(said & truth))
        fp += int(np.sum(said & ~truth))
        fn += int(np.sum(~said & truth))
    return 2 * tp / (2 * tp + fp + fn) if tp else 0.0


def _mae(records: Sequence[Record], prompts: set[int], gain: float) -> tuple[float, int]:
    """Intensity MAE (mm) over windows of ``prompts`` labelled and read as a gesture, and their count."""
    err, n = 0.0, 0
    for r in records:
        m = (r.label >= 0) & (r.gesture >= 0) & np.isin(r.prompt, list(prompts))
        err += float(np.sum(np.abs(r.intensity_mm[m] * gain - r.label_intensity_mm[m])))
        n += int(m.sum())
    return (err / n if n else float("nan")), n


# --- adapt --------------------------------------------------------------------------------
@dataclass
class Check:
    """One fitted value and its held-out check.

    Attributes:
        what: the setting (``gesture.min_intensity_mm``, ``classifier``, ...).
        metric: what the check compares (e.g. "gesture type accuracy").
        shipped, fitted: the metric on the held-out gestures with the shipped and the fitted value.
        kept: whether the fitted value was kept (it beat the shipped one).
        value: the fitted value (a number, or a phrase for the classifier).
        higher_is_better: the metric's sense.
    """

    what: str
    metric: str
    shipped: float
    fitted: float
    kept: bool
    value: str
    higher_is_better: bool = True


@dataclass
class Adaptation:
    """What :func:`adapt` fitted and checked.

    Attributes:
        model: the model (only the kept values).
        checks: one :class:`Check` per fitted value, in the order they were fitted.
        held_out: held-out gestures; gestures: all labelled gestures.
        windows: held-out labelled windows.
        accuracy_before, accuracy_after: the held-out windows' gesture type accuracy with the
            shipped method and with the model (replayed).
        note: why nothing was fitted, when so (then nothing is worth writing: ``adapt`` writes no model).
        missing: the gesture types (CLASSES values) with no labelled gesture in the enrolments:
            nothing was checked on them.
    """

    model: "Model"  # noqa: F821 (model.py)
    checks: list[Check]
    held_out: int
    gestures: int
    windows: int
    accuracy_before: float
    accuracy_after: float
    note: str = ""
    missing: tuple[str, ...] = ()


def adapt(records: Sequence[Record], rerun: Callable[..., list[Record]] | None = None) -> Adaptation:
    """Fit, check and keep (module docstring, 3-4) from recorded enrolments. ``rerun(config)``
    records the same enrolments with other settings (:func:`record_datasets`); without it the
    resting threshold, which only a new run can check, stays the shipped one.

    Raises:
        NeurotouchError: the enrolments hold no labelled gesture. DatasetError: the labels'
            intensities are out of scale with the gel's (an intensity gain outside
            ``model.SETTING_RANGES``: labels in micrometres).
    """
    from neurotouch_hid.enrolment.model import SETTING_RANGES, Model, out_of_range
    from neurotouch_hid.pipeline.config import GestureConfig, RestingConfig

    held = held_out_prompts(records)
    every = {p for r in records for p in r.prompt_type}
    if not every:
        raise NeurotouchError("the enrolment datasets hold no labelled gesture: nothing to fit (docs/dataset.md)")
    kinds = {k for r in records for k in r.prompt_type.values()}
    missing = tuple(c.value for i, c in enumerate(CLASSES) if i not in kinds)
    fit_part = {p for r in records for p in np.unique(np.concatenate([r.prompt, r.frame_prompt])).tolist()} - held
    shipped_answers = [replay(r) for r in records]
    before, windows = _accuracy(records, shipped_answers, held)
    if len(held) < MIN_HELD_OUT:
        return Adaptation(
            Model(),
            [],
            len(held),
            len(every),
            windows,
            before,
            before,
            f"only {len(held)} gesture(s) could be held out (at least {MIN_HELD_OUT}): no change can be checked, "
            "so nothing is fitted; enrol again (`neurotouch-hid enrol`) and give adapt all your enrolment folders "
            "together",
            missing,
        )
    checks: list[Check] = []
    # the learned type
    x, y, prompts = _rows(records, fit_part)
    classifier = None
    if len(set(y.tolist())) >= 2:
        strength = pick_strength(x, y, prompts)
        candidate = fit_classifier(x, y, strength)
        after, _ = _accuracy(records, [replay(r, candidate) for r in records], held)
        kept = after > before + MIN_GAIN
        checks.append(
            Check("classifier", "gesture type accuracy", before, after, kept, f"refitted, prior strength {strength:g}")
        )
        classifier = candidate if kept else None
    with_type = [replay(r, classifier) for r in records]
    current = _accuracy(records, with_type, held)[0]
    # the contact threshold: the fitted part's best, then checked, outside the collar
    shipped_min = GestureConfig().min_intensity_mm
    collar = THRESHOLD_COLLAR_US
    fit_scores = [
        (_accuracy(records, [replay(r, classifier, shipped_min * s) for r in records], fit_part, collar)[0], -s)
        for s in MIN_INTENSITY_STEPS
    ]
    step = -max(fit_scores)[1]
    min_intensity = None
    if step != 1.0:
        with_step = [replay(r, classifier, shipped_min * step) for r in records]
        shipped_outside = _accuracy(records, with_type, held, collar)[0]
        after_outside = _accuracy(records, with_step, held, collar)[0]
        kept = after_outside > shipped_outside + MIN_GAIN
        checks.append(
            Check(
                "gesture.min_intensity_mm",
                f"gesture type accuracy outside the {collar // 1000} ms collar",
                shipped_outside,
                after_outside,
                kept,
                f"{shipped_min * step:g}",
            )
        )
        if kept:
            min_intensity, current = shipped_min * step, _accuracy(records, with_step, held)[0]
    # the first finger's wait: the fitted part's best among the waits felt wrong no more often
    first_finger = _fit_first_finger(records, classifier, min_intensity or 0.0, fit_part)
    if first_finger != FIRST_FINGER_US:
        wait_answers = [replay(r, classifier, min_intensity or 0.0, first_finger_us=first_finger) for r in records]
        after = _accuracy(records, wait_answers, held)[0]
        felt_before = _felt_wrong(records, [replay(r, classifier, min_intensity or 0.0) for r in records], held)
        felt_after = _felt_wrong(records, wait_answers, held)
        kept = after > current + MIN_GAIN and felt_after <= felt_before
        checks.append(
            Check(
                "episode.first_finger_us",
                f"gesture type accuracy (windows of another type above the dead zone {felt_before} -> {felt_after})",
                current,
                after,
                kept,
                f"{first_finger}",
            )
        )
        if kept:
            current = after
        else:
            first_finger = FIRST_FINGER_US
    # the resting threshold: the frames' best F1 in the fitted part, checked by running the
    # pipeline again with it (the tracker's re-anchoring follows the verdicts: no replay)
    rest = RestingConfig()
    candidates = [
        rest.centroid_threshold_mm2 * s
        for s in RESTING_STEPS
        if rest.centroid_threshold_mm2 * s <= rest.centroid_reset_threshold_mm2
    ]
    best = max(candidates, key=lambda t: (_resting_f1(records, fit_part, t), t == rest.centroid_threshold_mm2))
    resting = None
    if best != rest.centroid_threshold_mm2 and rerun is not None:
        from neurotouch_hid.pipeline.config import PipelineConfig

        again = rerun(PipelineConfig(resting=RestingConfig(centroid_threshold_mm2=best)))
        after = _accuracy(again, [replay(r, classifier, min_intensity or 0.0, 1.0, first_finger) for r in again], held)[
            0
        ]
        f_shipped, f_fitted = _resting_f1(records, held, rest.centroid_threshold_mm2), _resting_f1(records, held, best)
        kept = after > current + MIN_GAIN and f_fitted > f_shipped
        checks.append(
            Check(
                "resting.centroid_threshold_mm2",
                f"gesture type accuracy (resting F1 of the frames {_percent(f_shipped)} -> {_percent(f_fitted)})",
                current,
                after,
                kept,
                f"{best:g}",
            )
        )
        if kept:
            resting, current, records = best, after, again
    # the intensity scale
    num = den = 0.0
    for r in records:
        m = (r.label >= 0) & (r.gesture >= 0) & np.isin(r.prompt, list(fit_part))
        num += float(np.sum(r.intensity_mm[m] * r.label_intensity_mm[m]))
        den += float(np.sum(r.intensity_mm[m] ** 2))
    gain = None
    if den > 0 and math.isfinite(num / den) and num > 0:
        fitted_gain = round(num / den, 4)
        if out_of_range("gesture.intensity_gain", fitted_gain) is not None:
            low, high = SETTING_RANGES["gesture.intensity_gain"]
            raise DatasetError(
                f"the labels' intensities are {fitted_gain:.4g} times what the gel measures, outside the {low:g} to "
                f"{high:g} a gel can be: are they in another unit? intensity_mm is in millimetres (docs/dataset.md)"
            )
        if fitted_gain != 1.0:
            mae_shipped, _ = _mae(records, held, 1.0)
            mae_fitted, _ = _mae(records, held, fitted_gain)
            with_gain = _accuracy(
                records, [replay(r, classifier, min_intensity or 0.0, fitted_gain, first_finger) for r in records], held
            )[0]
            kept = mae_fitted < (1.0 - MIN_MAE_GAIN) * mae_shipped and with_gain >= current
            checks.append(
                Check(
                    "gesture.intensity_gain",
                    "intensity MAE mm",
                    mae_shipped,
                    mae_fitted,
                    kept,
                    f"{fitted_gain:g}",
                    False,
                )
            )
            if kept:
                gain, current = fitted_gain, with_gain
    settings: dict[str, float] = {}
    if min_intensity is not None:
        settings["gesture.min_intensity_mm"] = float(min_intensity)
    if first_finger != FIRST_FINGER_US:
        settings["episode.first_finger_us"] = float(first_finger)
    if resting is not None:
        settings["resting.centroid_threshold_mm2"] = float(resting)
    if gain is not None:
        settings["gesture.intensity_gain"] = float(gain)
    model = Model(
        settings,
        None
        if classifier is None
        else {
            "mean": classifier.mean.tolist(),
            "scale": classifier.scale.tolist(),
            "weights": classifier.weights.tolist(),
            "intercept": classifier.intercept.tolist(),
        },
    )
    return Adaptation(model, checks, len(held), len(every), windows, before, current, missing=missing)


#: What each fitted setting means to the player, and what its value is in their words.
_FOR_PLAYERS: dict[str, tuple[str, Callable[[str], str]]] = {
    "classifier": ("which gesture it reads from how your gel moves", lambda v: "refitted to your hand"),
    "gesture.min_intensity_mm": ("how firm a touch must be to count", lambda v: f"{float(v):g} mm"),
    "episode.first_finger_us": (
        "how long it waits for your second finger before it answers",
        lambda v: f"{float(v) / 1000:g} ms",
    ),
    "resting.centroid_threshold_mm2": (
        "when the gel counts as let go",
        lambda v: f"{float(v):g} mm^2 of marker motion",
    ),
    "gesture.intensity_gain": ("how strong your gestures read (sticks, triggers)", lambda v: f"x{float(v):g}"),
}


def summary(adaptation: Adaptation) -> list[str]:
    """The report for players, one line each: what was tried, in their words, and whether it
    changes anything for them (and why a small held-out gain is not taken); then what changed
    and how many of their held-out gestures are read right before and after. The settings'
    names (docs/method.md, "Adaptation") close each line in brackets."""
    a = adaptation
    lines = [
        f"checked on {a.held_out} of your {a.gestures} gestures ({a.windows} windows) that the fit never saw "
        "(every third of each type): a change is taken only where it reads those better"
    ]
    if a.note:
        lines.append(a.note)
    if a.missing:
        kinds = " or ".join([", ".join(a.missing[:-1]), a.missing[-1]] if len(a.missing) > 1 else a.missing)
        worse = "" if a.note else ", and what changes may read them worse"
        lines.append(f"your enrolment has no {kinds} gesture: nothing is checked on them{worse}")
    for c in a.checks:
        words, value = _FOR_PLAYERS.get(c.what, (c.what, str))
        pct = "%" in c.metric or "accuracy" in c.metric or "F1" in c.metric
        fmt = _percent if pct else (lambda v: f"{v:.3f} mm")
        measured = f"{'read right' if pct else 'strength off by'} {fmt(c.shipped)} -> {fmt(c.fitted)}"
        better = (c.fitted > c.shipped) == c.higher_is_better and c.fitted != c.shipped
        small = c.fitted - c.shipped <= MIN_GAIN if pct else c.fitted >= (1.0 - MIN_MAE_GAIN) * c.shipped
        if c.kept:
            verdict = f"changed to {value(c.value)}: {measured} of your unseen gestures"
        elif better and small:
            limit = f"{100 * MIN_GAIN:g} points" if pct else f"{100 * MIN_MAE_GAIN:g} %"
            verdict = (
                f"left as shipped: {measured} of your unseen gestures with {value(c.value)}, a gain under "
                f"{limit}, which another choice of unseen gestures could undo; not worth changing how it feels"
            )
        elif better:
            verdict = (
                f"left as shipped: with {value(c.value)} {measured} of your unseen gestures, but it did worse "
                "on another thing checked (in brackets)"
            )
        else:
            verdict = f"left as shipped: {value(c.value)} did no better ({measured} of your unseen gestures)"
        lines.append(f"{words}: {verdict} [{c.what}, {c.metric}]")
    changes = a.model.changes()
    if changes:
        lines.append(
            "what changes for you: "
            + "; ".join(_FOR_PLAYERS.get(k, (k,))[0] for k in _changed(a.model))
            + f" [{'; '.join(changes)}]"
        )
    elif a.note:
        lines.append("what changes for you: nothing, too few gestures to check a change on")
    else:
        lines.append("what changes for you: nothing, the shipped recogniser already reads your hand as well")
    before, after = _percent(a.accuracy_before), _percent(a.accuracy_after)
    lines.append(f"your unseen gestures read right: shipped {before} -> adapted {after} of their windows")
    return lines


def _changed(model) -> list[str]:
    """The :data:`_FOR_PLAYERS` keys a model changes, in its order."""
    return [*model.settings, *(["classifier"] if model.classifier is not None else [])]


def _percent(share: float) -> str:
    """A share as ``12.34 %``; ``-`` when there was nothing to count (NaN: no held-out window)."""
    return f"{100 * share:.2f} %" if math.isfinite(share) else "- (no held-out window)"


def fitted_info(adaptation: Adaptation, datasets: Sequence[str | Path]) -> dict:
    """The model file's ``fitted`` mapping: sources and the held-out check (plain values)."""
    return {
        "from": [str(Path(d).resolve()) for d in datasets],
        "held_out_gestures": int(adaptation.held_out),
        "gestures": int(adaptation.gestures),
        "held_out_accuracy_shipped": round(float(adaptation.accuracy_before), 4),
        "held_out_accuracy_adapted": round(float(adaptation.accuracy_after), 4),
    }


#: The camera name the simulated gel writes into its recordings (``enrol --source sim``,
#: ``simulate``, ``record --source sim``): ``NeuroTouch-sim_DAVIS346``.
SIMULATED_CAMERA_PREFIX = "NeuroTouch-sim"


def simulated_sequences(datasets: Sequence[str | Path]) -> list[str]:
    """The sequences (``DATASET/NAME``) of ``datasets`` recorded from the simulated camera (their
    AEDAT4 header's camera name starts with :data:`SIMULATED_CAMERA_PREFIX`). Reads only the
    headers. Raises what ``dataset.list_sequences`` and the recording reader raise."""
    from neurotouch_hid.core.dataset import list_sequences
    from neurotouch_hid.sources.recording import RecordingReader

    found = []
    for d in datasets:
        for name in list_sequences(d):
            with RecordingReader(Path(d) / f"{name}.aedat4") as reader:
                if reader.camera_name.startswith(SIMULATED_CAMERA_PREFIX):
                    found.append(f"{d}/{name}")
    return found


def check_output(out: str | Path, datasets: Sequence[str | Path]) -> Path:
    """``out`` if writing there destroys no input: not a folder, not a file of an enrolment
    dataset. Raises NeurotouchError naming the clash."""
    from neurotouch_hid.core.atomic import check_output as outside_checks

    out = Path(out).expanduser()
    if str(out) == "-":  # standard output
        return out
    # a symbolic link is never written through; a folder, or an existing file of a dataset, never replaced
    return outside_checks(out, datasets, what="model")
