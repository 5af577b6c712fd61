"""Where a dataset's wrong windows are: each window of the pipeline by the stage that answered it,
placed against the labels (docs/lab/adaptation.md).

    python3 docs/lab/where_wrong.py DATASET [--models DIR] [--users 0,3]

``DATASET`` is a labelled dataset (docs/dataset.md), e.g. ``benchmarks/adapt_eval.py``'s
``$A/FAMILY``; ``--models DIR``: each user's model ``DIR/u{USER}.yaml`` applied (what
``track --model`` runs; ``$A/models/enrol/FAMILY``), else the shipped method. Each window's stage
is the branch of ``GesturePipeline._estimate`` that answered it (mirrored here, so the answers are
the pipeline's own): ``resting`` (the resting verdict held), ``still`` (no marker beyond the
contact threshold), ``rule-none`` (the gesture step's ``none``), ``creep`` (the creep filter read
the fingers gone, docs/method.md "Creep"; unless a new press in the tail is fitted against the gel
the tail left, noted beside the answer), ``undecided`` (the episode vote's ``none``),
``answered``. The windows whose type, or contact count, differs from the labels' are counted by:

- a labelled gesture's window the creep filter answered, in the gesture's first 150 ms (and
  whether the gesture began within 600 ms of the previous one's labelled end: in its tail), its
  last 150 ms, or between;
- a labelled gesture's window below the thresholds (``resting``, ``still``, ``rule-none``,
  ``undecided``), in its first 150 ms, its last 150 ms or between;
- a window labelled ``none`` answered with a gesture or contacts;
- a labelled gesture's window answered with another type or count.
"""

from __future__ import annotations

from collections import Counter
from pathlib import Path

import numpy as np
import typer

from neurotouch_hid.core.dataset import labels_at, list_sequences, read_labels, read_predictions
from neurotouch_hid.core.estimate import GestureType
from neurotouch_hid.evaluation.runner import run_sequence
from neurotouch_hid.pipeline import pipeline as P
from neurotouch_hid.views.console import command_app

#: the stage that answered each window of the sequence being run, in order
STAGES: list[str] = []
EDGE_MS = 150.0
TAIL_MS = 600.0


def _estimate(self, t_us):
    """``GesturePipeline._estimate``, noting the stage that answered."""
    current, valid = self.tracker.positions_px, self.tracker.valid
    if self._resting.resting and not self._moving(current, valid):
        STAGES.append("resting")
        return self._none(t_us, resting=True)
    if self._still(current, valid):
        STAGES.append("still")
        return self._none(t_us, resting=False)
    contacts, result = self._contacts_and_gesture(self.rest_px, current, valid)
    if result.gesture is GestureType.NONE:
        STAGES.append("rule-none")
        return self._none(t_us, resting=False)
    tail = ""
    if self._released(result.intensity_px, t_us):
        tail_rest = self._new_press_in_tail(current, valid)
        if tail_rest is None:
            STAGES.append("creep")
            return self._none(t_us, resting=False, fed=True)
        contacts, result = self._fit(tail_rest, current, valid)
        if result.gesture is GestureType.NONE:
            STAGES.append("creep")
            return self._none(t_us, resting=False, fed=True)
        tail = ", a new press in a tail"
    estimate = P.GestureEstimate(
        t_us=t_us,
        gesture=self._vote(result.gesture, result.intensity_mm, len(contacts.points_px), t_us),
        resting=False,
        intensity_mm=result.intensity_mm,
        contacts_px=contacts.points_px,
        contacts_mm=P.points_to_user(contacts.points_px, self.sensor),
        translation_mm=result.translation_mm,
        rotation_rad=result.rotation_rad,
        scale=result.similarity.scale,
    )
    STAGES.append(("undecided" if estimate.gesture is GestureType.NONE else "answered") + tail)
    return estimate


def _segments(labels) -> list[tuple[GestureType, int, int]]:
    """The labelled runs of one type: (type, start us, end us)."""
    out, start = [], 0
    for i in range(1, len(labels) + 1):
        if i == len(labels) or labels[i].gesture is not labels[start].gesture:
            end = labels[i].t_us if i < len(labels) else labels[-1].t_us + 40_000
            out.append((labels[start].gesture, labels[start].t_us, end))
            start = i
    return out


def place(stage: str, t_us: int, segments: list[tuple[GestureType, int, int]]) -> str:
    """The category of one wrong window (module docstring)."""
    k = max(i for i, s in enumerate(segments) if s[1] <= t_us)
    kind, start, end = segments[k]
    if kind is GestureType.NONE:
        return "labelled none, answered a gesture or contacts"
    since, left = (t_us - start) / 1000, (end - t_us) / 1000
    edge = f"first {EDGE_MS:g} ms" if since <= EDGE_MS else (f"last {EDGE_MS:g} ms" if left <= EDGE_MS else "between")
    if stage == "creep":
        before = [s for s in segments[:k] if s[0] is not GestureType.NONE]
        tail = bool(before) and (start - before[-1][2]) / 1000 <= TAIL_MS
        return f"creep filter: fingers read gone, {edge}" + (", begun in a tail" if since <= EDGE_MS and tail else "")
    if not stage.startswith("answered"):
        return f"below the thresholds or undecided, {edge}"
    return "answered another type or count" + stage[len("answered") :]


def main(
    dataset: Path = typer.Argument(..., help="a labelled dataset"),
    models: Path = typer.Option(None, "--models", help="a folder of u{USER}.yaml models; none: the shipped method"),
    users: str = typer.Option(None, "--users", help="comma-separated users (default: every sequence)"),
) -> None:
    from neurotouch_hid.enrolment.model import apply_model, load_model

    P.GesturePipeline._estimate = _estimate
    wrong: dict[str, Counter] = {"type": Counter(), "count": Counter()}
    n = 0
    for name in list_sequences(dataset):
        user = name.split("_")[0][1:]
        if users and user not in users.split(","):
            continue
        config = apply_model(None, load_model(models / f"u{user}.yaml")) if models else None
        STAGES.clear()
        folder = dataset.parent / f"{dataset.name}-where"
        run_sequence(dataset, name, config, predictions_dir=folder)
        estimates = read_predictions(folder / f"{name}.jsonl")
        labels = read_labels(dataset / f"{name}.labels.csv")
        segments = _segments(labels)
        truth = labels_at(labels, np.array([e.t_us for e in estimates], dtype=np.int64))
        for e, tr, stage in zip(estimates, truth, STAGES, strict=True):
            if tr is None:
                continue
            n += 1
            if e.gesture is not tr.gesture:
                wrong["type"][place(stage, e.t_us, segments)] += 1
            if e.n_contacts != tr.n_contacts:
                wrong["count"][place(stage, e.t_us, segments)] += 1
    for what, counts in wrong.items():
        print(f"| wrong {what}: {sum(counts.values())} of {n} windows | windows |")
        print("| --- | ---: |")
        for key, value in sorted(counts.items(), key=lambda kv: -kv[1]):
            print(f"| {key} | {value} |")
        print()


if __name__ == "__main__":
    app = command_app()
    app.command()(main)
    app()
