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
import logging
import multiprocessing
from concurrent.futures import ProcessPoolExecutor, as_completed
from pathlib import Path
from typing import Callable, Sequence

from neurotouch_hid.errors import NeurotouchError
from neurotouch_hid.evaluation.dataset import dataset_sensor_file, list_sequences, read_labels
from neurotouch_hid.evaluation.metrics import EvaluationResult, Observations, align, evaluate
from neurotouch_hid.output.jsonl import write_predictions
from neurotouch_hid.sensor import SensorGeometry

log = logging.getLogger(__name__)

_TRUE = {"1", "true", "yes", "on"}
_FALSE = {"0", "false", "no", "off"}


def _convert(text: str, default, annotation: str):
    """``text`` as the type of a dataclass field whose default is ``default`` (bool, int, float,
    str; ``none`` for an optional field; int/float/str from the annotation when the default is
    None, e.g. ``noise_filter: str | None``)."""
    optional = default is None or "None" in annotation
    if optional and text.lower() in ("none", "null"):
        return None
    if isinstance(default, bool):
        if text.lower() not in _TRUE | _FALSE:
            raise ValueError("expected true or false")
        return text.lower() in _TRUE
    if isinstance(default, (int, float, str)):
        return type(default)(text)
    for kind in (int, float):
        if default is None and kind.__name__ in annotation:
            return kind(text)
    if default is None and "str" in annotation:
        return text
    raise ValueError(f"a field of type {annotation} cannot be set from the command line")


def pipeline_config(settings: Sequence[str] = (), preset: str = "default", **values):
    """A :class:`~neurotouch_hid.pipeline.pipeline.PipelineConfig` from a preset
    (:data:`~neurotouch_hid.pipeline.pipeline.PIPELINE_PRESETS`, the CLI's ``--preset``), then
    ``NAME=VALUE`` strings (the CLI's ``--set``) and keyword values over it.

    NAME is a field of PipelineConfig, or ``tracker.FIELD`` for a field of its nested
    TrackerConfig (any nested dataclass field works the same way). Each value is converted to
    the type of the field's default (bool, int, float, str; ``none`` for optional fields).

    Raises:
        NeurotouchError: an unknown preset (the message lists them); naming the setting, when
            it is not ``NAME=VALUE``, NAME is not a field
            (the message lists the fields), the value does not convert, or PipelineConfig
            rejects it.
    """
    from neurotouch_hid.pipeline.pipeline import PIPELINE_PRESETS, PipelineConfig

    if preset not in PIPELINE_PRESETS:
        raise NeurotouchError(f"--preset {preset!r}: expected one of {', '.join(PIPELINE_PRESETS)}")
    config = PipelineConfig(**PIPELINE_PRESETS[preset])
    nested: dict[str, dict] = {}
    for item in settings:
        name, sep, text = item.partition("=")
        name, text = name.strip(), text.strip()
        if not sep or not name:
            raise NeurotouchError(f"--set {item!r}: expected NAME=VALUE, e.g. --set r_px=30")
        owner, path = config, name.split(".")
        for part in path[:-1]:
            owner = getattr(owner, part, None) if part in {f.name for f in dataclasses.fields(owner)} else None
            if not dataclasses.is_dataclass(owner):
                raise NeurotouchError(f"--set {item!r}: {part!r} is not a group of PipelineConfig")
        fields = {f.name: f for f in dataclasses.fields(owner)}
        if path[-1] not in fields or dataclasses.is_dataclass(getattr(owner, path[-1])):
            names = [f for f in fields if not dataclasses.is_dataclass(getattr(owner, f))]
            raise NeurotouchError(f"--set {item!r}: {type(owner).__name__} has no field {path[-1]!r}; fields: {', '.join(names)}")
        try:
            value = _convert(text, getattr(owner, path[-1]), str(fields[path[-1]].type))
        except ValueError as exc:
            raise NeurotouchError(f"--set {item!r}: {exc}") from None
        nested.setdefault(".".join(path[:-1]), {})[path[-1]] = value
    nested.setdefault("", {}).update(values)
    try:
        return _replace(config, "", nested)
    except (TypeError, ValueError) as exc:
        raise NeurotouchError(f"invalid pipeline hyperparameters {settings or values}: {exc}") from None


def _replace(obj, prefix: str, nested: dict[str, dict]):
    """``obj`` (a dataclass) with the values of ``nested[prefix]`` and of its nested groups."""
    changes = dict(nested.get(prefix, {}))
    for f in dataclasses.fields(obj):
        child = getattr(obj, f.name)
        key = f"{prefix}.{f.name}" if prefix else f.name
        if dataclasses.is_dataclass(child) and any(k == key or k.startswith(key + ".") for k in nested):
            changes[f.name] = _replace(child, key, nested)
    return dataclasses.replace(obj, **changes)


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
        config: PipelineConfig (None: the defaults, tuned; see PipelineConfig).
        predictions_dir: if given, write ``name.jsonl`` there (DATASET.md "Predictions").
        on_time: called now and then with the microseconds processed since the recording's start.
    Raises:
        DatasetError, RecordingError, SensorError: bad labels, recording or geometry.
    """
    from neurotouch_hid.pipeline.pipeline import GesturePipeline
    from neurotouch_hid.sources.recording import RecordingReader

    dataset = Path(dataset)
    sensor = SensorGeometry.load(dataset_sensor_file(dataset))
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
        Path(predictions_dir).mkdir(parents=True, exist_ok=True)
        write_predictions(Path(predictions_dir) / f"{name}.jsonl", predictions)
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

    A dataset folder without sensor.yaml is run with the user's calibration
    (:func:`~neurotouch_hid.evaluation.dataset.dataset_sensor_file`), which a logged warning says.

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
    sensor_file = dataset_sensor_file(dataset)
    if sensor_file.parent != dataset:
        log.warning("note: %s has no sensor.yaml; using your calibration %s", dataset, sensor_file)
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
