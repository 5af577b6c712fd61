"""Running the gesture pipeline over a labelled dataset (docs/dataset.md) and scoring it.

For each sequence: read ``SEQUENCE.labels.csv``, stream ``SEQUENCE.aedat4`` through
:class:`~neurotouch_hid.pipeline.pipeline.GesturePipeline`, keep the predictions (optionally as
JSON lines, docs/dataset.md "Predictions (JSON lines)") and pair them with the labels
(:func:`~neurotouch_hid.evaluation.metrics.align`). Sequences can run in parallel processes;
their observations are concatenated and :func:`~neurotouch_hid.evaluation.metrics.evaluate`
computes the paper's metrics over the whole dataset (paper, section "Results": "The pipeline is
executed on the complete dataset").
"""

from __future__ import annotations

import logging
import multiprocessing
from concurrent.futures import ProcessPoolExecutor, as_completed
from pathlib import Path
from typing import Callable, Sequence

from neurotouch_hid.core.dataset import (
    check_labels_clock,
    dataset_sensor_file,
    list_sequences,
    read_labels,
    read_pressed,
    write_predictions,
)
from neurotouch_hid.core.errors import NeurotouchError, in_plain_words
from neurotouch_hid.core.limits import short
from neurotouch_hid.core.sensor import SensorGeometry
from neurotouch_hid.evaluation.felt import DEFAULT_DEADZONE_MM
from neurotouch_hid.evaluation.metrics import EvaluationResult, Observations, align, evaluate
from neurotouch_hid.evaluation.through_profile import ProfileUnderTest

log = logging.getLogger(__name__)


def pipeline_config(settings: Sequence[str] = (), method: str = "default", **values):
    """The settings of a method (:data:`~neurotouch_hid.pipeline.methods.METHODS`, the CLI's
    ``--method``: a :class:`~neurotouch_hid.pipeline.config.PipelineConfig` or a
    :class:`~neurotouch_hid.pipeline.paper.PaperConfig`) from its defaults, then ``NAME=VALUE``
    strings (the CLI's ``--set``) and keyword values over them, validated by the pydantic model.

    NAME is a field of the method's config, or ``GROUP.FIELD`` for a field of one of its groups
    (PipelineConfig's ``noise``, ``tracker``, ``contacts``, ``gesture``, ``resting``). VALUE is converted by pydantic to
    the field's type (``none`` or ``null`` for an optional field).

    Raises:
        NeurotouchError: an unknown method (the message lists them); naming the setting, when
            it is not ``NAME=VALUE``, NAME is not a field (the message lists the fields), or the
            model rejects the value (the field, the value found and what was expected).
    """
    from pydantic import BaseModel, ValidationError

    from neurotouch_hid.pipeline.methods import METHODS

    if method not in METHODS:
        raise NeurotouchError(f"--method {method!r}: expected one of {', '.join(METHODS)}")
    config_model = METHODS[method][0]
    data: dict = {}
    given: dict[tuple, str] = {}
    for item in settings:
        name, sep, text = item.partition("=")
        name, text = name.strip(), text.strip()
        if not sep or not name:
            raise NeurotouchError(f"--set {short(item)}: expected NAME=VALUE, e.g. --set contacts.r_mm=12")
        model: type[BaseModel] = config_model
        path = name.split(".")
        group = data
        for part in path[:-1]:
            annotation = model.model_fields[part].annotation if part in model.model_fields else None
            if not (isinstance(annotation, type) and issubclass(annotation, BaseModel)):
                raise NeurotouchError(f"--set {short(item)}: {part!r} is not a group of {config_model.__name__}")
            model, group = annotation, group.setdefault(part, {})
        leaves = [
            f
            for f, info in model.model_fields.items()
            if not (isinstance(info.annotation, type) and issubclass(info.annotation, BaseModel))
        ]
        if path[-1] not in leaves:
            groups = [f for f in model.model_fields if f not in leaves]
            raise NeurotouchError(
                f"--set {short(item)}: {model.__name__} has no field {path[-1]!r}; fields: {', '.join(leaves)}"
                + (f"; groups (GROUP.FIELD): {', '.join(groups)}" if groups else "")
            )
        group[path[-1]] = None if text.lower() in ("none", "null") else text
        given[tuple(path)] = item
    data.update(values)
    try:
        return config_model.model_validate(data)
    except ValidationError as exc:
        problems = []
        for err in exc.errors():
            loc = tuple(str(p) for p in err["loc"])
            where = f"--set {short(given[loc])}: " if loc in given else ""
            field = ".".join(loc) or "the hyperparameters"
            message = in_plain_words(err["msg"])
            message = message[:1].lower() + message[1:]
            problems.append(f"{where}{field}: found {short(err['input'])}; {message}" if loc else f"{where}{message}")
        raise NeurotouchError("invalid pipeline hyperparameters: " + "; ".join(problems)) from None


def run_sequence(
    dataset: str | Path,
    name: str,
    config=None,
    predictions_dir: str | Path | None = None,
    on_time: Callable[[int], None] | None = None,
    deadzone_mm: float = DEFAULT_DEADZONE_MM,
    profiles: Sequence[ProfileUnderTest] = (),
) -> Observations:
    """Run the pipeline over one sequence and pair its predictions with the labels.

    Args:
        dataset: the dataset folder (docs/dataset.md).
        name: the sequence (``name.aedat4`` and ``name.labels.csv``).
        config: the method's settings (:func:`pipeline_config`; None: the product's defaults).
        predictions_dir: if given, write ``name.jsonl`` there (docs/dataset.md "Predictions (JSON lines)").
        on_time: called now and then with the microseconds processed since the recording's start.
        deadzone_mm: the dead zone of the per-gesture figures (mm; :mod:`.felt`).
        profiles: profiles to replay the predictions through (:mod:`.through_profile`).
    Raises:
        DatasetError, RecordingError, SensorError: bad labels (among them labels none of whose
            frames lies within the recording's time range:
            :func:`~neurotouch_hid.core.dataset.check_labels_clock`), recording or geometry.
    """
    from neurotouch_hid.pipeline.methods import pipeline_for
    from neurotouch_hid.sources.recording import RecordingReader

    dataset = Path(dataset)
    sensor = SensorGeometry.load(dataset_sensor_file(dataset))
    labels_path, recording = dataset / f"{name}.labels.csv", dataset / f"{name}.aedat4"
    labels = read_labels(labels_path)
    pipeline = pipeline_for(sensor, config)
    predictions = []
    with RecordingReader(recording) as reader:
        start = reader.info.start_us
        check_labels_clock(labels, labels_path, recording, start, reader.info.end_us)
        for estimate in pipeline.run(reader.stream()):
            predictions.append(estimate)
            if on_time is not None and len(predictions) % 50 == 0:
                on_time(estimate.t_us - start)
    if predictions_dir is not None:
        Path(predictions_dir).mkdir(parents=True, exist_ok=True)
        write_predictions(Path(predictions_dir) / f"{name}.jsonl", predictions)
    return align(labels, predictions, sensor, deadzone_mm, profiles, read_pressed(dataset / f"{name}.pressed.csv"))


def evaluate_dataset(
    dataset: str | Path,
    config=None,
    *,
    jobs: int = 1,
    predictions_dir: str | Path | None = None,
    progress=None,
    deadzone_mm: float = DEFAULT_DEADZONE_MM,
    profiles: Sequence[ProfileUnderTest] = (),
) -> EvaluationResult:
    """Run the pipeline over every sequence of a dataset and compute the paper's metrics.

    A dataset folder without sensor.yaml is run with the user's calibration
    (:func:`~neurotouch_hid.core.dataset.dataset_sensor_file`), which a logged warning says.

    Args:
        dataset: the dataset folder (docs/dataset.md).
        config: the method's settings (None: the product's defaults).
        jobs: sequences processed in parallel processes (1: in this process).
        predictions_dir: if given, each sequence's predictions are written there as JSON lines.
        progress: an optional ``rich.progress.Progress``; a task advancing over the recorded
            time (s) is added to it.
        deadzone_mm: the dead zone of the per-gesture figures (mm; :mod:`.felt`).
        profiles: profiles to replay the predictions through (:mod:`.through_profile`).
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

            parts.append(run_sequence(dataset, n, config, predictions_dir, on_time, deadzone_mm, profiles))
            if task is not None:
                progress.advance(task, (durations[n] - done[0]) / 1e6)
    else:
        ctx = multiprocessing.get_context("spawn")  # no fork of a process with rich's refresh thread
        with ProcessPoolExecutor(max_workers=jobs, mp_context=ctx) as pool:
            futures = {
                pool.submit(run_sequence, dataset, n, config, predictions_dir, None, deadzone_mm, profiles): n
                for n in names
            }
            finished: dict[str, Observations] = {}
            for future in as_completed(futures):
                finished[futures[future]] = future.result()
                if task is not None:
                    progress.advance(task, durations[futures[future]] / 1e6)
            parts = [finished[n] for n in names]  # in the sequences' order: the same sums, to the last bit
    return evaluate(Observations.concatenate(parts))
