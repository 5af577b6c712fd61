"""Open the source a command names: the live camera, the simulated gel, an AEDAT4 recording, or a
predictions file.

A source knows nothing of who reads it: it yields its stream (event batches, APS frames, a live
camera's status changes, the simulated hand's :class:`~neurotouch_hid.sources.Performed` labels
when asked) and says which gel geometry goes with it.
"""

from __future__ import annotations

import contextlib
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Callable, ContextManager, Iterable, Iterator, Protocol, Union

from neurotouch_hid.core.errors import DeviceError
from neurotouch_hid.core.estimate import GestureEstimate
from neurotouch_hid.core.kinds import SourceKind
from neurotouch_hid.sources import Performed, StreamItem

if TYPE_CHECKING:
    from neurotouch_hid.core.sensor import SensorGeometry
    from neurotouch_hid.sources.batches import BatchCut
    from neurotouch_hid.sources.davis import DavisConfig
    from neurotouch_hid.sources.simulator import SimulatedSource

#: What an opened source yields (``stages.SourceStream``).
Items = Iterable[Union[StreamItem, Performed, GestureEstimate]]


class CameraBackend(Protocol):
    """What the live camera's source asks of dv-processing's camera module (``dv.io.camera``),
    or of a stand-in that replays recordings (tests)."""

    def discover(self) -> list:
        """The cameras plugged in (dv-processing's descriptors)."""

    def open(self, descriptor: object) -> object:
        """The opened camera of one descriptor."""


@dataclass(frozen=True)
class OpenedSource:
    """A source ready to be read.

    Attributes:
        stream: its items in time order.
        sensor: the gel's geometry (image px -> user mm); None for a predictions file.
        live: real time by itself (the camera): never paced by the runtime.
        labelled: the stream says what it performs (:class:`~neurotouch_hid.sources.Performed`).
    """

    stream: Items
    sensor: SensorGeometry | None
    live: bool
    labelled: bool = False


def open_source(
    spec: str,
    stack: contextlib.ExitStack,
    *,
    seconds: float | None = None,
    batch_us: int = 1_000,
    sensor: str | Path | None = None,
    seed: int = 0,
    davis: DavisConfig | None = None,
    wait: bool = False,
    capture: CameraBackend | None = None,
    noise_filter: object = None,
    labelled: bool = False,
    guard: Callable[[], ContextManager[None]] | None = None,
    finish: bool = False,
) -> OpenedSource:
    """Open ``davis`` (the live camera), ``sim`` (the simulated gel), an AEDAT4 recording path, or
    a predictions file (``*.jsonl``, docs/dataset.md: the pipeline's estimates, replayed as they are).

    The camera's stream survives unplugs and stalls (it yields
    :class:`~neurotouch_hid.sources.SourceStatus` items); ``davis`` is its
    :class:`~neurotouch_hid.sources.davis.DavisConfig`, ``wait`` waits for a camera instead of
    failing, ``capture`` replaces dv-processing's camera backend (tests replay recordings through
    it), ``noise_filter`` runs on dv-processing's own event stores (no copies). Its geometry is
    ``sensor``, else the user's calibration, else the built-in one.

    The simulated gel also says what its hand performs when ``labelled``
    (:class:`~neurotouch_hid.sources.Performed` before each APS frame), and simulates each chunk
    inside ``guard()`` when given (a first run's compile: :meth:`neurotouch_hid.service.warmup.Warmup.guard`);
    with ``finish``, its hand finishes the gesture it performs at ``seconds`` (:func:`simulated_items`).

    Resources (camera, file) are closed by ``stack``. Raises RecordingError for a missing or
    unreadable recording, DatasetError for a bad predictions file, DeviceError when the camera
    cannot be opened (and ``wait`` is off).
    """
    from neurotouch_hid.core.sensor import SensorGeometry, default_sensor, find_sensor_file

    if spec.endswith(".jsonl"):
        from neurotouch_hid.core.dataset import open_predictions

        return OpenedSource(open_predictions(spec), None, False)
    if spec == SourceKind.DAVIS:
        from neurotouch_hid.sources.davis import DavisSource

        try:
            camera = stack.enter_context(DavisSource(davis, wait=wait, backend=capture, noise_filter=noise_filter))
        except DeviceError as exc:
            raise DeviceError(f"{exc}\nor start with --wait to wait for a camera") from None
        geometry = SensorGeometry.load(sensor) if sensor is not None else default_sensor()
        return OpenedSource(camera.stream(seconds=seconds, batch_us=batch_us, reconnect=True), geometry, True)
    if spec == SourceKind.SIM:
        from neurotouch_hid.sources.simulator import SimulatedSource

        sim = SimulatedSource(seed=seed) if sensor is None else SimulatedSource(SensorGeometry.load(sensor), seed=seed)
        from neurotouch_hid.sources.batches import BatchCut, CuttingStream, read_ahead

        cut = BatchCut(batch_us)
        stream = simulated_items(sim, seconds, cut, labelled=labelled, guard=guard, finish=finish)
        stream = read_ahead(stream, cut)  # at rest, frame periods simulated in bursts
        return OpenedSource(CuttingStream(stream, cut), sim.sensor, False, labelled=labelled)
    from neurotouch_hid.core.errors import RecordingError
    from neurotouch_hid.sources.batches import BatchCut, CuttingStream, read_ahead
    from neurotouch_hid.sources.recording import RecordingReader

    path = Path(spec)
    if not path.is_file():
        raise RecordingError(
            f"{path}: no such recording (--source takes davis, sim, an AEDAT4 file or a predictions .jsonl)"
        )
    reader = stack.enter_context(RecordingReader(path))
    cut = BatchCut(batch_us)
    stream = read_ahead(reader.stream(batch_us=cut), cut)  # at rest, decoded in bursts
    return OpenedSource(CuttingStream(stream, cut), find_sensor_file(path, sensor), False)


#: How long past its ``seconds`` a labelled simulation may go on for the hand to finish (s).
FINISH_GESTURE_S = 8.0
#: How long the gel must rest before a labelled simulation past its ``seconds`` ends (us): the
#: pipeline's windows say "none" again by then.
FINISHED_REST_US = 500_000


def simulated_items(
    sim: SimulatedSource,
    seconds: float | None,
    batch_us: int | BatchCut,
    *,
    labelled: bool = False,
    guard: Callable[[], ContextManager[None]] | None = None,
    finish: bool = False,
) -> Iterator[StreamItem | Performed]:
    """The simulated gel's stream (as ``SimulatedSource.stream``): per frame period, the label of
    what the hand performs (when ``labelled``), the APS frame, then its events in ``batch_us``
    batches (or as a :class:`~neurotouch_hid.sources.batches.BatchCut` says); each period
    simulated inside ``guard()`` when given.

    ``finish`` (the demo): past ``seconds`` the hand finishes the gesture it is performing, so
    that the last frame shows the gel at rest, not a gesture cut off before it was recognised:
    the stream ends once the gel has rested for :data:`FINISHED_REST_US`, at most
    :data:`FINISH_GESTURE_S` after ``seconds``."""
    from neurotouch_hid.sources.batches import split_batches

    guard = guard or contextlib.nullcontext
    finish = finish and seconds is not None
    chunks = iter(sim.chunks(seconds + FINISH_GESTURE_S if finish else seconds))
    start_us = rest_since_us = None
    while True:
        with guard():
            chunk = next(chunks, None)
        if chunk is None:
            return
        t_us = int(chunk.t_us[0])
        start_us = t_us if start_us is None else start_us
        rest_since_us = (t_us if rest_since_us is None else rest_since_us) if chunk.label.resting else None
        if finish and t_us - start_us >= seconds * 1e6 and rest_since_us is not None:
            if t_us - rest_since_us >= FINISHED_REST_US:
                return
        if labelled:
            yield Performed(chunk.label)
        yield chunk.frame
        yield from split_batches(chunk.events, batch_us)
