"""The driver's start-up wiring: the ``run`` and ``demo`` commands put the concrete stages together.

:func:`run_driver` loads the profile (a bad one fails before any device exists), opens the source
(:func:`open_source`: the live camera, the simulated gel, an AEDAT4 recording or a predictions
file), builds the pipeline and its resting detector (:func:`build_pipeline`), opens the output
(:func:`open_output`: the uinput devices, JSON lines or the terminal view) and hands them to the
engine, :class:`~neurotouch_hid.runtime.Runtime`, which owns threads, pacing and shutdown.
The engine knows the stages only through the seams of :mod:`neurotouch_hid.stages`.
"""

from __future__ import annotations

import contextlib
import logging
from pathlib import Path
from typing import TYPE_CHECKING, Callable, ContextManager, Iterator, Protocol

from neurotouch_hid.errors import DeviceError, NeurotouchError, ProfileError
from neurotouch_hid.estimate import GestureEstimate
from neurotouch_hid.kinds import MethodKind, OutputKind, SourceKind
from neurotouch_hid.mapping.profile import Profile, available_profiles, load_profile
from neurotouch_hid.runtime import DEFAULT_BATCH_US, DEFAULT_MAX_LAG_US, Runtime
from neurotouch_hid.sources import Frame
from neurotouch_hid.stages import Output, Pipeline, RestingDetection, SourceStream
from neurotouch_hid.stats import RunStats

if TYPE_CHECKING:
    from rich.console import Console

    from neurotouch_hid.enrolment.model import Model
    from neurotouch_hid.output.live import LiveScene
    from neurotouch_hid.pipeline.pipeline import GesturePipeline
    from neurotouch_hid.pipeline.resting import RestingResult
    from neurotouch_hid.sensor import SensorGeometry
    from neurotouch_hid.sources.davis import DavisConfig
    from neurotouch_hid.warmup import KernelGroup, Warmup

log = logging.getLogger(__name__)


class CameraBackend(Protocol):
    """What the live camera's source asks of dv-processing's camera module (``dv.io.camera``),
    or of a stand-in that replays recordings (tests)."""

    def discover(self) -> list:
        """The cameras plugged in (dv-processing's descriptors)."""

    def open(self, descriptor: object) -> object:
        """The opened camera of one descriptor."""


class EstimateReplay:
    """Stands in for the pipeline when the source is a predictions file: its items already are
    the windows' :class:`GestureEstimate` values (docs/dataset.md "Predictions (JSON lines)"), handed on as they are."""

    def process(self, item: GestureEstimate) -> list[GestureEstimate]:
        return [item]

    def restart(self) -> None:  # pragma: no cover - a predictions file is never interrupted
        pass

    def set_resting(self, result: RestingResult | None, t_us: int) -> None:  # pragma: no cover - no frames
        pass


def open_source(
    spec: str,
    stack: contextlib.ExitStack,
    *,
    seconds: float | None = None,
    batch_us: int = DEFAULT_BATCH_US,
    sensor: str | Path | None = None,
    seed: int = 0,
    davis: DavisConfig | None = None,
    wait: bool = False,
    capture: CameraBackend | None = None,
    filter_noise: bool = True,
    scene: LiveScene | None = None,
    warmup: Warmup | None = None,
) -> tuple[SourceStream, SensorGeometry | None, bool]:
    """Open ``davis`` (the live camera), ``sim`` (the simulated gel), an AEDAT4 recording path, or
    a predictions file (``*.jsonl``, docs/dataset.md: the pipeline's estimates, replayed as they are).

    The camera's stream survives unplugs and stalls (it yields
    :class:`~neurotouch_hid.sources.SourceStatus` items); ``davis`` is its
    :class:`~neurotouch_hid.sources.davis.DavisConfig`, ``wait`` waits for a camera instead of
    failing, ``capture`` replaces dv-processing's camera backend (tests replay recordings through
    it). Its geometry is ``sensor``, else the user's calibration, else the built-in one. The
    pipeline's default noise filter runs in the camera's source, on dv-processing's own event
    stores (no copies; build the pipeline with ``filter_noise=False`` then); ``filter_noise``
    False: none (the paper's method).

    Returns ``(stream, sensor_geometry, live)``; ``live`` is True for the camera (never paced by
    the runtime); the geometry is None for a predictions file. Resources (camera, file) are
    closed by ``stack``. The simulated gel hands its labels to ``scene`` (the live view's
    :class:`~neurotouch_hid.output.live.LiveScene`) and simulates under ``warmup`` 's guard (a
    first run's compile, :mod:`neurotouch_hid.warmup`). Raises RecordingError for a missing or unreadable recording,
    DatasetError for a bad predictions file, DeviceError when the camera cannot be opened (and
    ``wait`` is off).
    """
    from neurotouch_hid.sensor import SensorGeometry, default_sensor, find_sensor_file

    if spec.endswith(".jsonl"):
        from neurotouch_hid.dataset import read_predictions

        return iter(read_predictions(spec)), None, False

    if spec == SourceKind.DAVIS:
        from neurotouch_hid.pipeline.noise import EventNoiseFilter
        from neurotouch_hid.pipeline.pipeline import PipelineConfig
        from neurotouch_hid.sources.davis import DavisSource
        from neurotouch_hid.sources.recording import DAVIS346_RESOLUTION

        noise = PipelineConfig().noise
        camera_filter = (
            EventNoiseFilter(noise.kind, *DAVIS346_RESOLUTION, noise.time_us)
            if filter_noise and noise.kind is not None
            else None
        )
        try:
            camera = stack.enter_context(DavisSource(davis, wait=wait, backend=capture, noise_filter=camera_filter))
        except DeviceError as exc:
            raise DeviceError(f"{exc}\nor start with --wait to wait for a camera") from None
        geometry = SensorGeometry.load(sensor) if sensor is not None else default_sensor()
        return camera.stream(seconds=seconds, batch_us=batch_us, reconnect=True), geometry, True
    if spec == SourceKind.SIM:
        from neurotouch_hid.sources.simulator import SimulatedSource

        sim = SimulatedSource(seed=seed) if sensor is None else SimulatedSource(SensorGeometry.load(sensor), seed=seed)
        if scene is None and warmup is None:
            return sim.stream(seconds=seconds, batch_us=batch_us), sim.sensor, False
        from neurotouch_hid.output.live import labelled_simulation
        from neurotouch_hid.warmup import SIMULATOR

        return labelled_simulation(sim, scene, _guard(warmup, SIMULATOR), seconds, batch_us), sim.sensor, False
    from neurotouch_hid.errors import RecordingError
    from neurotouch_hid.sources.recording import RecordingReader

    path = Path(spec)
    if not path.is_file():
        raise RecordingError(
            f"{path}: no such recording (--source takes davis, sim, an AEDAT4 file or a predictions .jsonl)"
        )
    reader = stack.enter_context(RecordingReader(path))
    return reader.stream(batch_us=batch_us), find_sensor_file(path, sensor), False


def open_output(
    kind: str,
    profile: Profile,
    stack: contextlib.ExitStack,
    *,
    out: str | Path | None = None,
    console: Console | None = None,
    say: Callable[[str], None] | None = None,
    stats: RunStats | None = None,
) -> Output:
    """Create the output: ``gamepad`` (the uinput pad with the profile's name and ids, and the
    keyboard and mouse if the profile uses them), ``jsonl`` (one state line per change to ``out``
    or stdout) or ``term`` (the terminal view, showing ``stats`` under the pad; on a terminal the
    live view of :mod:`neurotouch_hid.output.live`). ``say`` tells the
    user about rumble effects games send to the pad (the gel has no motor; default: the log).
    Closed by ``stack``. Raises DeviceError when /dev/uinput cannot be used."""
    if kind == OutputKind.GAMEPAD:
        from neurotouch_hid.output.desktop import UinputOutputs
        from neurotouch_hid.output.gamepad import GamepadIdentity, VirtualGamepad

        dev = profile.device
        identity = GamepadIdentity(name=dev.name, vendor=dev.vendor, product=dev.product, version=dev.version)
        on_effect = None if say is None else (lambda line: say(f"rumble (the gel has no motor): {line}"))
        pad = VirtualGamepad(identity, on_effect=on_effect)
        return stack.enter_context(UinputOutputs(pad, profile, known=known_profiles()))
    if kind == OutputKind.JSONL:
        from neurotouch_hid.output.jsonl import StateJsonlWriter

        return stack.enter_context(StateJsonlWriter(out))
    from neurotouch_hid.output.live import LiveView

    return stack.enter_context(LiveView(console, stats=stats))


def known_profiles() -> list[Profile]:
    """The shipped and the user's profiles that load (a broken one is left out: ``profile use``
    refuses it anyway); the keyboard and mouse offer what they use from the start."""
    known = []
    for path in available_profiles().values():
        try:
            known.append(load_profile(path))
        except ProfileError:
            continue
    return known


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
    from neurotouch_hid.enrolment.model import apply_model
    from neurotouch_hid.evaluation.runner import pipeline_config
    from neurotouch_hid.pipeline.methods import pipeline_for

    quiet = {} if filter_noise or method != "default" else {"noise": {"kind": None}}
    config = apply_model(pipeline_config(method=method, window_us=window_us, **quiet), model)
    pipeline = pipeline_for(geometry, config, detect_resting=not resting_beside)
    return pipeline, (PipelineResting(pipeline) if resting_beside else None)


def start_warmup(source: str, *, fast: bool, say: Callable[[str], None], method: str = "default") -> Warmup | None:
    """The first run's compile for ``source`` (:class:`~neurotouch_hid.warmup.Warmup`), started.

    The simulated gel in real time (``demo``, ``run --source sim``) runs at once: its cold
    kernels are interpreted while child processes compile them, and it waits rather than drop
    data. Other sources (the camera cannot wait; ``--fast`` replays must be deterministic)
    compile the cold kernels here first, saying so. Warm kernels are loaded from the cache now
    (a first call would otherwise stall the run). None for a predictions file (no pipeline)."""
    from neurotouch_hid.warmup import PIPELINE_OF, SIMULATOR, Warmup

    if source.endswith(".jsonl"):
        return None
    interpreted = source == SourceKind.SIM and not fast
    pipeline = PIPELINE_OF[method]
    groups = [pipeline, SIMULATOR] if source == SourceKind.SIM else [pipeline]
    return Warmup(groups, say=say, interpreted=interpreted).start()


def _guard(warmup: Warmup | None, group: KernelGroup) -> Callable[[], ContextManager[None]] | None:
    """A zero-argument callable giving ``warmup`` 's guard of ``group`` (None without warmup)."""
    return None if warmup is None else (lambda: warmup.guard(group))


def _with_view(
    out: Output, kind: str, scene: LiveScene, console: Console | None, stats: RunStats, stack: contextlib.ExitStack
) -> Output:
    """The output with the live view: a terminal view shows ``scene``; the virtual gamepad gets
    the live view drawn beside it when ``console`` is a terminal."""
    from neurotouch_hid.output.live import LiveView, ShownOutput

    if isinstance(out, LiveView):
        out.scene = scene
        return out
    if kind == OutputKind.GAMEPAD and console is not None and console.is_terminal:
        return ShownOutput(out, stack.enter_context(LiveView(console, scene=scene, stats=stats)))
    return out


def run_driver(
    source: str = "davis",
    profile: str | Path = "default",
    output: str = "gamepad",
    *,
    seconds: float | None = None,
    fast: bool = False,
    out: str | Path | None = None,
    window_us: int = 10_000,
    sensor: str | Path | None = None,
    seed: int = 0,
    console: Console | None = None,
    output_obj: Output | None = None,
    davis: DavisConfig | None = None,
    wait: bool = False,
    capture: CameraBackend | None = None,
    say: Callable[[str], None] = log.warning,
    stats: RunStats | None = None,
    max_lag_us: int = DEFAULT_MAX_LAG_US,
    method: str = "default",
    model: Model | None = None,
) -> RunStats:
    """``neurotouch-hid run``: load the profile (a bad one raises ProfileError before any device
    exists), open the source, build the pipeline, open the output, run until the end.

    Real time (the camera, or paced replays): the resting detector runs in its own thread, and
    data is dropped, oldest first, if the pipeline falls more than ``max_lag_us`` (us of camera
    time) behind. ``fast`` (recordings and the simulated gel only): as fast as possible, nothing
    dropped, resting detection inline, so the same input always gives the same states.

    ``output_obj`` replaces the output named by ``output`` (the demo's fallback, benchmarks);
    ``stats`` is where the run is counted (the one a given terminal view shows).
    ``davis``, ``wait``, ``capture``: the live camera's settings (:func:`open_source`); ``say``
    tells the user when it is lost and back. ``method``: the gesture pipeline
    (``pipeline.methods``: ``default`` or ``paper``); ``model``: an adapted model's values over
    it (``enrolment/model.py``; None: the shipped method).
    Raises NeurotouchError subclasses for bad input (ProfileError, RecordingError, DeviceError,
    SensorError).
    """
    if output not in tuple(OutputKind):
        raise NeurotouchError(f"unknown output '{output}' (expected one of: {', '.join(OutputKind)})")
    if window_us < 1000:
        raise NeurotouchError(f"--window-us {window_us}: windows must be at least 1000 us")
    if max_lag_us < 1000:
        raise NeurotouchError(f"--max-lag-ms {max_lag_us / 1000:g}: the lag allowed must be at least 1 ms")
    if method not in tuple(MethodKind):
        raise NeurotouchError(f"--method {method!r}: expected one of {', '.join(MethodKind)}")
    loaded = load_profile(profile)
    warmup = start_warmup(source, fast=fast, say=say, method=method)
    stats = stats if stats is not None else RunStats()
    with contextlib.ExitStack() as stack:
        if warmup is not None:
            stack.callback(warmup.close)
        from neurotouch_hid.output.live import LiveScene, ScenePipeline
        from neurotouch_hid.warmup import PIPELINE_OF

        scene = LiveScene(None, str(profile), loaded, warmup=warmup, demo=source == SourceKind.SIM)
        stream, geometry, live = open_source(
            source,
            stack,
            seconds=seconds,
            batch_us=min(DEFAULT_BATCH_US, window_us),
            sensor=sensor,
            seed=seed,
            davis=davis,
            wait=wait,
            capture=capture,
            scene=scene,
            warmup=warmup,
            filter_noise=method == "default",
        )
        scene.sensor = geometry
        pipeline: Pipeline
        resting: RestingDetection | None = None
        if geometry is None:  # a predictions file: the estimates are already there
            pipeline = EstimateReplay()
        else:
            built, resting = build_pipeline(
                geometry,
                window_us,
                method=method,
                resting_beside=live or not fast,
                filter_noise=not live,
                model=model,
            )
            watched = ScenePipeline(built, scene, _guard(warmup, PIPELINE_OF[method]))
            pipeline, resting = watched, watched.resting(resting)
        out_obj = (
            output_obj
            if output_obj is not None
            else open_output(output, loaded, stack, out=out, console=console, say=say, stats=stats)
        )
        out_obj = _with_view(out_obj, output, scene, console, stats, stack)
        runtime = Runtime(
            stream,
            pipeline,
            loaded,
            out_obj,
            resting=resting,
            pace=not fast,
            live=live,
            profile_ref=profile,
            say=say,
            control=True,
            games=not fast,
            stats=stats,
            max_lag_us=max_lag_us,
            waits=source == SourceKind.SIM,
        )
        scene.follow(runtime)
        return runtime.run(seconds)


def gamepad_or_terminal(
    profile: Profile,
    stack: contextlib.ExitStack,
    *,
    console: Console | None = None,
    say: Callable[[str], None] = print,
    stats: RunStats | None = None,
) -> Output:
    """The virtual gamepad where /dev/uinput is writable; else the terminal view (showing
    ``stats``), after saying why in one line (``say``)."""
    try:
        return open_output("gamepad", profile, stack)
    except DeviceError as exc:
        reason = str(exc).splitlines()[0]  # the why; the fix's lines follow (udev.uinput_help)
        say(
            f"no writable /dev/uinput ({reason}): showing the gamepad in the terminal instead; "
            "see `neurotouch-hid doctor`"
        )
        return open_output("term", profile, stack, console=console, stats=stats)


def run_demo(
    seconds: float | None = 30.0, *, console: Console | None = None, say: Callable[[str], None] = print
) -> RunStats:
    """``neurotouch-hid demo``: the simulated gel performing every gesture, paced in real time,
    through the default profile, to the virtual gamepad (or the terminal view, see
    :func:`gamepad_or_terminal`)."""
    profile = load_profile("default")
    stats = RunStats()
    with contextlib.ExitStack() as stack:
        out = gamepad_or_terminal(profile, stack, console=console, say=say, stats=stats)
        return run_driver("sim", "default", "gamepad", seconds=seconds, console=console, output_obj=out, stats=stats)


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
        from neurotouch_hid.dataset import read_predictions

        yield from _first_seconds(iter(read_predictions(source)), seconds)
        return
    from neurotouch_hid.enrolment.model import apply_model
    from neurotouch_hid.pipeline.pipeline import GesturePipeline

    if seconds is None and source == SourceKind.SIM:
        from neurotouch_hid.sources.simulator import SimulatedSource

        seconds = SimulatedSource().cycle_seconds()
    with contextlib.ExitStack() as stack:
        stream, sensor, _ = open_source(source, stack, seconds=seconds)
        yield from _first_seconds(GesturePipeline(sensor, apply_model(None, model)).run(stream), seconds)


def _first_seconds(estimates: Iterator[GestureEstimate], seconds: float | None) -> Iterator[GestureEstimate]:
    start = None
    for e in estimates:
        start = e.t_us if start is None else start
        if seconds is not None and e.t_us - start > seconds * 1e6:
            return
        yield e
