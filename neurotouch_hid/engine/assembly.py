"""What a run opens when it starts, and the run itself: :func:`run_assembled` opens a
:class:`RunAssembly` (the first run's compile, the source, the pipeline and its resting detector)
and runs the engine (:class:`~neurotouch_hid.engine.engine.Engine`) on it; everything opened is
closed on every way out. Also the pipeline as a run builds it (:func:`build_pipeline`), the replay
of a predictions file in the pipeline's place (:class:`EstimateReplay`) and the estimates of a
source without a run (:func:`estimates_from_source`, for ``eval`` and ``adapt``).
"""

from __future__ import annotations

import contextlib
import logging
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Callable, ContextManager, Iterable, Iterator, Protocol

from neurotouch_hid.core.errors import DeviceError
from neurotouch_hid.core.estimate import GestureEstimate
from neurotouch_hid.core.kinds import SourceKind
from neurotouch_hid.core.stages import MarkerPositions, Subscriber
from neurotouch_hid.engine.engine import Engine, RunParts
from neurotouch_hid.engine.mode import DEFAULT_BATCH_US, RunMode, RunOptions
from neurotouch_hid.sources import Frame
from neurotouch_hid.sources.open import CameraBackend, open_source

if TYPE_CHECKING:
    import numpy as np

    from neurotouch_hid.core.sensor import SensorGeometry
    from neurotouch_hid.core.stats import RunStats
    from neurotouch_hid.enrolment.model import Model
    from neurotouch_hid.mapping.profile import Profile
    from neurotouch_hid.pipeline.pipeline import GesturePipeline
    from neurotouch_hid.pipeline.resting import RestingResult
    from neurotouch_hid.service.warmup import Warmup
    from neurotouch_hid.sources.davis import DavisConfig

log = logging.getLogger(__name__)


class EstimateReplay:
    """Stands in for the pipeline when the source is a predictions file: its items already are
    the windows' :class:`GestureEstimate` values (docs/dataset.md "Predictions (JSON lines)"), handed on as they are."""

    def process(self, item: GestureEstimate) -> list[GestureEstimate]:
        return [item]

    def process_newest(self, events: np.ndarray) -> tuple[list[GestureEstimate], list[int]]:  # pragma: no cover
        raise TypeError("a predictions file has no events")  # its items are estimates, never joined

    def restart(self) -> None:  # pragma: no cover - a predictions file is never interrupted
        pass

    def set_type_wait(self, wait: bool) -> None:
        """Nothing: a predictions file's types are decided already."""

    def set_resting(self, result: RestingResult | None, t_us: int) -> None:  # pragma: no cover - no frames
        pass

    def markers(self) -> MarkerPositions | None:
        """None: a predictions file has no markers."""
        return None


class PipelineResting:
    """The pipeline's own resting detector, run from the runtime's resting thread.

    ``GesturePipeline`` creates its :class:`~neurotouch_hid.pipeline.resting.RestingDetector` at
    its reference (first) APS frame; until then :meth:`update` has no verdict (None)."""

    def __init__(self, pipeline: GesturePipeline):
        self._pipeline = pipeline

    def update(self, frame: Frame) -> RestingResult | None:
        """The Chamfer-distance verdict for ``frame`` (``RestingResult``), or None."""
        detector = self._pipeline.resting_detector
        return None if detector is None else detector.update(frame, verdict_only=True)


def build_pipeline(
    geometry: SensorGeometry,
    window_us: int,
    *,
    method: str = "default",
    resting_beside: bool = True,
    filter_noise: bool = True,
    model: Model | None = None,
) -> tuple[GesturePipeline, PipelineResting | None]:
    """The ``method``'s pipeline (``pipeline.methods``) with ``window_us`` windows, and the resting
    detector to run beside it.

    ``filter_noise``: the product's pipeline runs its noise filter (``PipelineConfig.noise``);
    False when the source already did (the live camera, :func:`open_source`).

    ``resting_beside``: the resting detection runs in the runtime's own thread (paper, section
    "Runtime Performance": one core for it, one for the gesture detection) and the pipeline does
    not run it (``detect_resting=False``). False: the pipeline runs it inline on each frame, and
    the run is deterministic (the same input gives the same estimates): what ``--fast`` replays
    use, as nothing there needs to keep up with the camera.

    ``model``: an adapted model's values over the method's (``enrolment/model.py``; None: the
    shipped method).
    """
    import cv2

    from neurotouch_hid.enrolment.model import apply_model
    from neurotouch_hid.evaluation.runner import pipeline_config
    from neurotouch_hid.pipeline.methods import pipeline_for

    quiet = {} if filter_noise or method != "default" else {"noise": {"kind": None}}
    config = apply_model(pipeline_config(method=method, window_us=window_us, **quiet), model)
    pipeline = pipeline_for(geometry, config, detect_resting=not resting_beside)
    # OpenCV's own pool off: the pipeline's calls are on one 346x260 APS frame or a few hundred
    # points, too small to share out, and the pool's thread woke at every call (25 a second at rest)
    cv2.setNumThreads(1)
    return pipeline, (PipelineResting(pipeline) if resting_beside else None)


def start_warmup(source: str, *, fast: bool, say: Callable[[str], None], method: str = "default") -> Warmup | None:
    """The first run's compile for ``source`` (:class:`~neurotouch_hid.service.warmup.Warmup`), started.

    The simulated gel in real time (``demo``, ``run --source sim``) runs at once: its cold
    kernels are interpreted while child processes compile them, and it waits rather than drop
    data. Other sources (the camera cannot wait; ``--fast`` replays must be deterministic)
    compile the cold kernels here first, saying so. Warm kernels are loaded from the cache now
    (a first call would otherwise stall the run). None for a predictions file (no pipeline)."""
    from neurotouch_hid.service.warmup import PIPELINE_OF, SIMULATOR, Warmup

    if source.endswith(".jsonl"):
        return None
    interpreted = source == SourceKind.SIM and not fast
    pipeline = list(PIPELINE_OF[method])
    groups = [SIMULATOR, *pipeline] if source == SourceKind.SIM else pipeline
    return Warmup(groups, say=say, interpreted=interpreted).start()


@dataclass(frozen=True)
class RunAssembly:
    """What a run opens when it starts (:meth:`open`, called by the engine): the first run's
    compile, the source, and the pipeline with its resting detector.

    Attributes:
        source: ``davis``, ``sim``, an AEDAT4 recording or a predictions ``.jsonl``
            (:func:`~neurotouch_hid.sources.open.open_source`).
        seconds: how much of the source to read (s of camera time), None for all.
        window_us: the pipeline's window (us). method: ``pipeline.methods``' name.
        fast: as fast as possible, resting detection inline (deterministic replays).
        sensor, seed, davis, wait, capture: the source's settings (``open_source``).
        say: one line to the user (the compile's progress, a child's failure).
        model: an adapted model's values over the method's (``enrolment/model.py``; None: the
            shipped method).
        finish_gesture: the simulated hand finishes the gesture it performs at ``seconds`` (the
            demo ends on the gel at rest, :func:`~neurotouch_hid.sources.open.simulated_items`).
    """

    source: str
    seconds: float | None = None
    window_us: int = 10_000
    method: str = "default"
    fast: bool = False
    sensor: str | Path | None = None
    seed: int = 0
    davis: DavisConfig | None = None
    wait: bool = False
    capture: CameraBackend | None = None
    say: Callable[[str], None] = log.warning
    model: Model | None = None
    finish_gesture: bool = False

    def open(self, stack: contextlib.ExitStack) -> RunParts:
        """Start the first run's compile, open the source, build the pipeline (its kernels
        guarded while they are interpreted: a property of how it is built, not of who watches
        it). Everything opened is closed by ``stack``. Raises what
        :func:`~neurotouch_hid.sources.open.open_source` raises."""
        from neurotouch_hid.service.warmup import PIPELINE_OF, SIMULATOR, GuardedPipeline, GuardedResting

        live_camera = self.source == SourceKind.DAVIS
        if live_camera and not self.wait:  # no camera: said now, not after a first run's compile
            from neurotouch_hid.sources.davis import require_camera_listed

            try:
                require_camera_listed(self.davis, self.capture)
            except DeviceError as exc:
                raise DeviceError(f"{exc}\nor start with --wait to wait for a camera") from None
        warmup = start_warmup(self.source, fast=self.fast, say=self.say, method=self.method)
        if warmup is not None:
            stack.callback(warmup.close)
        opened = open_source(
            self.source,
            stack,
            seconds=self.seconds,
            batch_us=min(DEFAULT_BATCH_US, self.window_us),
            sensor=self.sensor,
            seed=self.seed,
            davis=self.davis,
            wait=self.wait,
            capture=self.capture,
            noise_filter=camera_noise_filter() if live_camera and self.method == "default" else None,
            labelled=self.source == SourceKind.SIM,
            guard=None if warmup is None else warmup.guarded(SIMULATOR),
            finish=self.finish_gesture,
        )
        if opened.sensor is None:  # a predictions file: the estimates are already there
            return RunParts(opened.stream, EstimateReplay(), None, None, opened.live, opened.labelled, None)
        pipeline, resting = build_pipeline(
            opened.sensor,
            self.window_us,
            method=self.method,
            resting_beside=opened.live or not self.fast,
            filter_noise=not opened.live,
            model=self.model,
        )
        if warmup is None:
            return RunParts(opened.stream, pipeline, resting, opened.sensor, opened.live, opened.labelled, None)
        guard = warmup.guarded(*PIPELINE_OF[self.method])
        return RunParts(
            opened.stream,
            GuardedPipeline(pipeline, guard),
            None if resting is None else GuardedResting(resting, guard),
            opened.sensor,
            opened.live,
            opened.labelled,
            warmup.progress_now,
        )


def camera_noise_filter() -> object:
    """The product pipeline's noise filter (``PipelineConfig.noise``) to run in the live camera's
    source, on dv-processing's own event stores (the pipeline's own then stays off); None when the
    method has none."""
    from neurotouch_hid.pipeline.noise import EventNoiseFilter
    from neurotouch_hid.pipeline.pipeline import PipelineConfig
    from neurotouch_hid.sources.recording import DAVIS346_RESOLUTION

    noise = PipelineConfig().noise
    return None if noise.kind is None else EventNoiseFilter(noise.kind, *DAVIS346_RESOLUTION, noise.time_us)


def estimates_from_source(
    source: str, seconds: float | None = None, model: Model | None = None
) -> Iterator[GestureEstimate]:
    """Estimates from ``PRED.jsonl`` (predictions), ``sim`` (the simulated gel through the
    pipeline: one cycle of the steady hand's gestures unless ``seconds``,
    :meth:`~neurotouch_hid.sources.simulator.SimulatedSource.cycle_seconds`) or an AEDAT4
    recording (through the pipeline, with the sensor.yaml beside it), the pipeline with
    ``model``'s values (None: the shipped method). Only the first ``seconds`` (from the first
    estimate) when given.

    Raises:
        DatasetError, RecordingError, SensorError: unreadable source.
    """
    if source.endswith(".jsonl"):
        from neurotouch_hid.core.dataset import open_predictions

        yield from _first_seconds(open_predictions(source), seconds)
        return
    from neurotouch_hid.enrolment.model import apply_model
    from neurotouch_hid.pipeline.pipeline import GesturePipeline

    if seconds is None and source == SourceKind.SIM:
        from neurotouch_hid.sources.simulator import SimulatedSource

        seconds = SimulatedSource().cycle_seconds()
    with contextlib.ExitStack() as stack:
        opened = open_source(source, stack, seconds=seconds)
        pipeline = GesturePipeline(opened.sensor, apply_model(None, model))
        yield from _first_seconds(pipeline.run(opened.stream), seconds)


def _first_seconds(estimates: Iterator[GestureEstimate], seconds: float | None) -> Iterator[GestureEstimate]:
    start = None
    for e in estimates:
        start = e.t_us if start is None else start
        if seconds is not None and e.t_us - start > seconds * 1e6:
            return
        yield e


class Assembly(Protocol):
    """What a run opens when it starts: the source, the pipeline and its resting detector
    (``driver.RunAssembly``)."""

    def open(self, stack: contextlib.ExitStack) -> RunParts:
        """Open everything, closed by ``stack``."""


def run_assembled(
    assembly: Assembly,
    profile: Profile,
    subscribers: Iterable[Subscriber],
    seconds: float | None = None,
    options: RunOptions = RunOptions(),
    serve: Callable[[Engine], ContextManager[object]] | None = None,
) -> RunStats:
    """Open what ``assembly`` names, then run it (:class:`Engine`, with ``options``; a live source
    in :attr:`RunMode.LIVE`) to the end, publishing to ``subscribers``; everything opened is closed
    on every way out. ``serve``: what answers the user while the engine runs (the control socket,
    the games watcher: ``service/``), entered around the run.

    Returns the run's :class:`RunStats`; raises what the assembly's opening or the run raises."""
    with contextlib.ExitStack() as stack:
        parts = assembly.open(stack)
        if parts.live:
            options = replace(options, mode=RunMode.LIVE)
        engine = Engine(parts, profile, subscribers, options)
        if serve is not None:
            stack.enter_context(serve(engine))
        return engine.run(seconds)
