"""``neurotouch-hid adapt``'s replay and fits (docs/method.md, "Adaptation", step 3): what the
pipeline answers with other fitted values, replayed from the records through the episode vote
without running it again (:func:`replay`; the vote is ``pipeline/episode.py``'s own), the scores
the fits and checks compare (accuracy, windows felt wrong, resting F1, intensity MAE), and the
fits themselves: the learned type's logistic regression refitted toward the shipped weights by
Newton's method (:func:`fit_classifier`, :func:`pick_strength`; NumPy only) and the first
finger's wait. :mod:`neurotouch_hid.enrolment.adapt` decides what is kept.
"""

from __future__ import annotations

import math
from typing import Sequence

import numpy as np

from neurotouch_hid.core.estimate import GestureType
from neurotouch_hid.enrolment.adapt_record import Record, _type_index
from neurotouch_hid.evaluation.felt import DEFAULT_DEADZONE_MM
from neurotouch_hid.evaluation.metrics import outside_collar
from neurotouch_hid.pipeline.episode import FIRST_FINGER_US
from neurotouch_hid.pipeline.learned import CLASSES, FEATURES, Classifier

#: Regularisation strengths toward the shipped weights tried by the cross-validation (per window,
#: on the standardised features; larger: closer to the shipped model).
PRIOR_STRENGTHS = (0.001, 0.003, 0.01, 0.03, 0.1, 0.3, 1.0)
#: How long one contact alone keeps an episode undecided, tried (us; only down from the shipped
#: FIRST_FINGER_US: a longer wait only delays every answer). A hand whose fingers land together
#: needs no wait; one whose second finger lags needs the shipped one.
FIRST_FINGER_STEPS_US = (0, 30_000, 45_000, 60_000, 75_000, FIRST_FINGER_US)
#: A window of another type (not ``none``) at or above this intensity (mm) is felt wrong: the
#: ``default`` profile's dead zone (docs/dataset.md, "Per-gesture metrics").
DEADZONE_MM = DEFAULT_DEADZONE_MM


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
