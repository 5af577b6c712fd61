"""``neurotouch-hid adapt``'s records (docs/method.md, "Adaptation", steps 1 and 2): the shipped
pipeline run once over every enrolment sequence (docs/dataset.md folders), keeping each window's
type before the episode vote, intensity, contact count and learned-type features and each APS
frame's resting distance, with the labels at each window and frame (:class:`Record`); which
labelled gestures are held out (:func:`held_out_prompts`); and whether the labels look wrong
(:func:`contradiction`). :mod:`neurotouch_hid.enrolment.adapt` fits and checks on them.
"""

from __future__ import annotations

import math
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Sequence

import numpy as np

from neurotouch_hid.core.estimate import GestureType
from neurotouch_hid.pipeline.learned import CLASSES, FEATURES

#: Every HOLD_EVERY-th labelled gesture of each type, from the second on, is held out.
HOLD_EVERY = 3


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
