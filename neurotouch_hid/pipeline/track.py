"""Running the gesture pipeline over a recording: the ``track`` command's work.

Reads an AEDAT4 recording (``sources/recording.py``), runs :class:`GesturePipeline` on it and
writes one prediction a window (docs/dataset.md, "Predictions (JSON lines)"), optionally the tracked
marker positions at every window's end (``.npz``, the simulator's ``SEQUENCE.markers.npz``
format: ``t_us`` int64 (T,), ``positions_px`` float32 (T, N, 2) with NaN for a lost marker,
``rest_px`` float32 (N, 2)).
"""

from __future__ import annotations

import contextlib
import os
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from neurotouch_hid.core.atomic import check_output, replacing
from neurotouch_hid.core.dataset import PredictionsWriter
from neurotouch_hid.core.errors import RecordingError, SensorError
from neurotouch_hid.core.estimate import GestureEstimate
from neurotouch_hid.core.sensor import SensorGeometry
from neurotouch_hid.pipeline.methods import MethodConfig, pipeline_for
from neurotouch_hid.pipeline.pipeline import GesturePipeline
from neurotouch_hid.sources import Frame, StreamItem


@dataclass(frozen=True)
class TrackSummary:
    """What a ``track`` run did.

    Attributes:
        windows: estimates written.
        events: events read.
        frames: APS frames read.
        duration_us: recording time covered (us).
        elapsed_s: wall-clock time of the whole run, file reading included (s).
        refused_frames: first APS frames refused as the rest reference (their markers off the
            sensor.yaml's rest layout: the gel pressed, or a sensor.yaml of another camera pose).
        first_window_us: the first window's end from the recording's start (us).
    """

    windows: int
    events: int
    frames: int
    duration_us: int
    elapsed_s: float
    refused_frames: int = 0
    first_window_us: int = 0

    @property
    def realtime_factor(self) -> float:
        """Recording time / wall-clock time (> 1: faster than real time)."""
        return self.duration_us * 1e-6 / self.elapsed_s if self.elapsed_s > 0 else float("inf")


@contextlib.contextmanager
def recording_progress(console, label: str) -> Iterator[Callable[[int, int], None] | None]:
    """A rich progress bar over recording time on ``console`` (a ``rich.console.Console``);
    yields the ``on_progress(done_us, total_us)`` callback of :func:`pipeline_over`. The bar
    disappears when done. When ``console`` is not a terminal (a pipe, a file, CI) rich would
    draw nothing of a transient bar, so there is none and None is yielded: no callback, and no
    pass over the file for the bar's total (~5 % of ``track``; docs/performance.md, "track")."""
    if not console.is_terminal:
        yield None
        return
    from rich.progress import BarColumn, Progress, TextColumn, TimeRemainingColumn

    columns = (TextColumn(label), BarColumn(), TextColumn("{task.completed:.1f} s of recording"), TimeRemainingColumn())
    with Progress(*columns, console=console, transient=True) as progress:
        task = progress.add_task(label, total=1.0)

        def report(done_us: int, total_us: int) -> None:
            progress.update(task, completed=done_us * 1e-6, total=max(total_us, done_us) * 1e-6)

        yield report


def sensor_label(sensor_file: str | Path | None) -> str:
    """How messages name the geometry in use: the sensor.yaml's path, or the built-in one."""
    return str(sensor_file) if sensor_file is not None else "the built-in geometry (no sensor.yaml)"


def pipeline_over(
    recording: str | Path,
    pipeline: GesturePipeline,
    *,
    on_progress: Callable[[int, int], None] | None = None,
    sensor_file: str | Path | None = None,
) -> Iterator[tuple[StreamItem, list[GestureEstimate]]]:
    """Feed a recording through ``pipeline``, yielding each stream item with the estimates it
    closed (shared by ``track`` and ``view``).

    Args:
        recording: AEDAT4 file with events and APS frames of the pipeline sensor's resolution.
        pipeline: a fresh :class:`GesturePipeline`.
        on_progress: called every 0.1 s of recording time and at the end with (recording time
            done, total) in us (the total costs one pass over the file's packets with the
            ``aedat`` decoder; 0 when that pass finds the file damaged: what is readable is
            still tracked and written before the error).
        sensor_file: the sensor.yaml the pipeline's geometry came from (None: the built-in
            one), named when no frame matches it.
    Raises:
        RecordingError: the file is missing, not AEDAT4, has no APS frames or the wrong
            resolution, or is truncated (after everything readable was yielded).
        SensorError: no gel found on the first APS frame, or no APS frame matched the gel at
            rest in the sensor.yaml (the messages name the files and what to try).
    """
    from neurotouch_hid.sources.recording import RecordingReader  # dv-processing: imported on use

    recording = Path(recording)
    sensor = pipeline.sensor
    with RecordingReader(recording, require_frames=True, require_resolution=(sensor.width, sensor.height)) as reader:
        total_us = 0
        if on_progress is not None:
            try:
                total_us = int(reader.info.duration_us)
            except RecordingError:  # damaged: track what is readable, the stream raises at its end
                total_us = 0
        first_us = last_us = None
        next_report = 0
        frames = 0
        for item in reader.stream(batch_us=pipeline.config.window_us):
            frames += isinstance(item, Frame)
            last_us = item.t_us if isinstance(item, Frame) else int(item["timestamp"][-1])
            first_us = last_us if first_us is None else first_us
            try:
                estimates = pipeline.process(item)
            except SensorError as exc:
                raise SensorError(f"{recording}: {exc} (geometry: {sensor_label(sensor_file)})") from None
            yield item, estimates
            if on_progress is not None and last_us - first_us >= next_report:
                on_progress(last_us - first_us, total_us)
                next_report = last_us - first_us + 100_000
    if pipeline.rest_px is None and frames > 0:
        raise SensorError(
            f"{recording}: none of its {frames} APS frames matched the gel at rest in {sensor_label(sensor_file)} "
            "(the markers lie off its rest layout, rest_markers_px): the gel was pressed throughout, or that "
            "sensor.yaml is for another camera pose. Try another one with --sensor FILE, or calibrate on a "
            f"recording of this camera that starts at rest: neurotouch-hid calibrate --source REC.aedat4 --out FILE"
        )
    if pipeline.rest_px is None:
        raise RecordingError(f"{recording}: no APS frame found: the pipeline needs one to find the gel's markers")
    if on_progress is not None and first_us is not None:
        on_progress(last_us - first_us, max(total_us, last_us - first_us))


def track_recording(
    recording: str | Path,
    out: str | Path,
    sensor: SensorGeometry,
    config: MethodConfig | None = None,
    *,
    markers_out: str | Path | None = None,
    on_progress: Callable[[int, int], None] | None = None,
    sensor_file: str | Path | None = None,
) -> TrackSummary:
    """Run the pipeline over ``recording`` and write its predictions to ``out`` (JSON lines).

    Args:
        recording: AEDAT4 file with events and APS frames of ``sensor``'s resolution.
        out: predictions file to write (docs/dataset.md).
        sensor: the geometry (e.g. :func:`neurotouch_hid.core.sensor.find_sensor_file`).
        config: the method's settings (window length included; its type picks the method,
            ``pipeline.methods``); None = the product's defaults (the paper's: ``PaperConfig``).
        markers_out: if given, also write the tracked marker positions at each window's end
            (``.npz``, see the module docstring).
        on_progress, sensor_file: see :func:`pipeline_over`.
    Returns:
        :class:`TrackSummary`.
    Raises:
        RecordingError, SensorError: see :func:`pipeline_over`. ``out`` is written as a
            temporary file beside it, renamed over it at the end: on an error (a damaged or cut
            recording, Ctrl-C too), what was there is left byte-identical and the windows
            computed before it are in ``OUT.partial``; the error says so (in its message or a
            note, :class:`~neurotouch_hid.core.dataset.JsonlWriter`).
        OutputError: ``out`` or ``markers_out`` is a symbolic link, a folder, the recording or
            ``sensor_file``.
    """
    start = time.perf_counter()
    times: list[int] = []
    positions: list[np.ndarray] = []

    def keep_markers(estimate: GestureEstimate) -> None:
        times.append(estimate.t_us)
        positions.append(pipeline.marker_positions())

    pipeline = pipeline_for(sensor, config, on_window=keep_markers if markers_out is not None else None)
    inputs = (recording, sensor_file)
    if markers_out is not None:
        check_output(markers_out, (*inputs, out), "markers file", (("predictions file", out),))
    windows = events = frames = 0
    first_us = last_us = first_window_us = None
    writer = PredictionsWriter(out, inputs=inputs, keep_partial=True)
    try:
        for item, estimates in pipeline_over(recording, pipeline, on_progress=on_progress, sensor_file=sensor_file):
            if isinstance(item, Frame):
                frames += 1
                last_us = item.t_us
            else:
                events += len(item)
                last_us = int(item["timestamp"][-1])
            first_us = last_us if first_us is None else first_us
            for estimate in estimates:
                writer.write(estimate)
                first_window_us = estimate.t_us if first_window_us is None else first_window_us
            windows += len(estimates)
    except BaseException as exc:  # a damaged or cut file, no gel, Ctrl-C, a full disk
        writer.__exit__(type(exc), exc, exc.__traceback__)  # what was at ``out`` is left as it was
        if isinstance(exc, RecordingError) and writer.partial is not None:
            raise RecordingError(
                f"{exc}; the {windows} windows before it are in {writer.partial}"
                + (f" ({out} is left as it was)" if os.path.lexists(out) else "")
            ) from None
        raise
    writer.close()
    if markers_out is not None:
        n = len(pipeline.rest_px)
        with replacing(markers_out, (*inputs, out), "markers file") as tmp, open(tmp, "wb") as fh:
            np.savez_compressed(  # to the open file: numpy would add .npz to a name without it
                fh,
                t_us=np.asarray(times, dtype=np.int64),
                positions_px=np.asarray(positions, dtype=np.float32).reshape(len(times), n, 2),
                rest_px=pipeline.rest_px.astype(np.float32),
            )
    duration = 0 if first_us is None else last_us - first_us
    late = 0 if first_window_us is None or first_us is None else first_window_us - first_us
    return TrackSummary(windows, events, frames, duration, time.perf_counter() - start, pipeline.pressed_frames, late)
