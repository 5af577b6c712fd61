"""Running the gesture pipeline over a labelled dataset (DATASET.md) and scoring it.

For each sequence: read ``SEQUENCE.labels.csv``, stream ``SEQUENCE.aedat4`` through
:class:`~neurotouch_hid.pipeline.pipeline.GesturePipeline`, keep the predictions (optionally as
JSON lines, DATASET.md "Predictions") and pair them with the labels
(:func:`~neurotouch_hid.evaluation.metrics.align`). Sequences can run in parallel processes;
their observations are concatenated and :func:`~neurotouch_hid.evaluation.metrics.evaluate`
computes the paper's metrics over the whole dataset (paper, section "Results": "The pipeline is
executed on the complete dataset").
"""

from __future__ import annotations

import dataclasses
import json
import multiprocessing
from concurrent.futures import ProcessPoolExecutor, as_completed
from pathlib import Path
from typing import Callable, Sequence

from neurotouch_hid.errors import NeurotouchError
from neurotouch_hid.evaluation.dataset import list_sequences, read_labels
from neurotouch_hid.evaluation.metrics import EvaluationResult, Observations, align, evaluate
from neurotouch_hid.sensor import SensorGeometry

_TRUE = {"1", "true", "yes", "on"}
_FALSE = {"0", "false", "no", "off"}


def pipeline_config(settings: Sequence[str] = (), **values):
    """A :class:`~neurotouch_hid.pipeline.pipeline.PipelineConfig` from ``NAME=VALUE`` strings
    (the CLI's ``--set``) and keyword values.

    Each value is converted to the type of the field's default (int, float, bool, str).

    Raises:
        NeurotouchError: naming the setting, when it is not ``NAME=VALUE``, NAME is not a field
            of PipelineConfig (the message lists the fields), the value does not convert, or
            PipelineConfig rejects it.
    """
    from neurotouch_hid.pipeline.pipeline import PipelineConfig

    fields = {f.name: f for f in dataclasses.fields(PipelineConfig)}
    defaults = PipelineConfig()
    for item in settings:
        name, sep, text = item.partition("=")
        name, text = name.strip(), text.strip()
        if not sep or not name:
            raise NeurotouchError(f"--set {item!r}: expected NAME=VALUE, e.g. --set r_px=30")
        if name not in fields:
            raise NeurotouchError(f"--set {item!r}: PipelineConfig has no field {name!r}; fields: {', '.join(fields)}")
        kind = type(getattr(defaults, name))
        try:
            if kind is bool:
                if text.lower() not in _TRUE | _FALSE:
                    raise ValueError("expected true or false")
                value = text.lower() in _TRUE
            elif kind in (int, float, str):
                value = kind(text)
            else:
                raise ValueError(f"field of type {kind.__name__} cannot be set from the command line")
        except ValueError as exc:
            raise NeurotouchError(f"--set {item!r}: {exc}") from None
        values[name] = value
    try:
        return dataclasses.replace(defaults, **values)
    except (TypeError, ValueError) as exc:
        raise NeurotouchError(f"invalid pipeline hyperparameters {values}: {exc}") from None


def run_sequence(
    dataset: str | Path,
    name: str,
    config=None,
    predictions_dir: str | Path | None = None,
    on_time: Callable[[int], None] | None = None,
) -> Observations:
    """Run the pipeline over one sequence and pair its predictions with the labels.

    Args:
        dataset: the dataset folder (DATASET.md).
        name: the sequence (``name.aedat4`` and ``name.labels.csv``).
        config: PipelineConfig (None: the defaults, the paper's hyperparameters).
        predictions_dir: if given, write ``name.jsonl`` there (DATASET.md "Predictions").
        on_time: called now and then with the microseconds processed since the recording's start.
    Raises:
        DatasetError, RecordingError, SensorError: bad labels, recording or geometry.
    """
    from neurotouch_hid.pipeline.pipeline import GesturePipeline
    from neurotouch_hid.sources.recording import RecordingReader

    dataset = Path(dataset)
    sensor = SensorGeometry.load(dataset / "sensor.yaml")
    labels = read_labels(dataset / f"{name}.labels.csv")
    pipeline = GesturePipeline(sensor, config)
    predictions = []
    with RecordingReader(dataset / f"{name}.aedat4") as reader:
        start = reader.info.start_us
        for estimate in pipeline.run(reader.stream()):
            predictions.append(estimate)
            if on_time is not None and len(predictions) % 50 == 0:
                on_time(estimate.t_us - start)
    if predictions_dir is not None:
        out = Path(predictions_dir)
        out.mkdir(parents=True, exist_ok=True)
        with open(out / f"{name}.jsonl", "w") as fh:
            for estimate in predictions:
                fh.write(json.dumps(estimate.to_json_dict()) + "\n")
    return align(labels, predictions, sensor)


def evaluate_dataset(
    dataset: str | Path,
    config=None,
    *,
    jobs: int = 1,
    predictions_dir: str | Path | None = None,
    progress=None,
) -> EvaluationResult:
    """Run the pipeline over every sequence of a dataset and compute the paper's metrics.

    Args:
        dataset: the dataset folder (DATASET.md).
        config: PipelineConfig (None: defaults).
        jobs: sequences processed in parallel processes (1: in this process).
        predictions_dir: if given, each sequence's predictions are written there as JSON lines.
        progress: an optional ``rich.progress.Progress``; a task advancing over the recorded
            time (s) is added to it.
    Raises:
        DatasetError: the folder is not a dataset; and what :func:`run_sequence` raises.
    """
    from neurotouch_hid.sources.recording import read_info

    dataset = Path(dataset)
    names = list_sequences(dataset)
    durations = {n: max(read_info(dataset / f"{n}.aedat4").duration_us, 1) for n in names}
    task = None
    if progress is not None:
        task = progress.add_task(f"evaluating {len(names)} sequences", total=sum(durations.values()) / 1e6)
    parts: list[Observations] = []
    if jobs <= 1:
        for n in names:
            done = [0]

            def on_time(t: int, done=done) -> None:
                if task is not None:
                    progress.advance(task, (t - done[0]) / 1e6)
                done[0] = t

            parts.append(run_sequence(dataset, n, config, predictions_dir, on_time))
            if task is not None:
                progress.advance(task, (durations[n] - done[0]) / 1e6)
    else:
        ctx = multiprocessing.get_context("spawn")  # no fork of a process with rich's refresh thread
        with ProcessPoolExecutor(max_workers=jobs, mp_context=ctx) as pool:
            futures = {pool.submit(run_sequence, dataset, n, config, predictions_dir): n for n in names}
            for future in as_completed(futures):
                parts.append(future.result())
                if task is not None:
                    progress.advance(task, durations[futures[future]] / 1e6)
    return evaluate(Observations.concatenate(parts))
