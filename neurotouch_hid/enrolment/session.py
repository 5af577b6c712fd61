"""The guided enrolment: prompts while the camera records, then the labelled dataset.

The session follows a plan (:mod:`~neurotouch_hid.enrolment.plan`) in the stream's own time
(s from its first event or frame): at each cue the prompt is shown (and the simulated hand, when
it is the source, performs it), every item is written to the recording (AEDAT4, through a
temporary name renamed at the end) and fed to the pipeline, whose tracked markers give the gel's
motion (:class:`~neurotouch_hid.enrolment.label.MotionMeter`). When a prompt's search span has
passed (:data:`~neurotouch_hid.enrolment.label.SEARCH_S` after its cue) it is judged as
``enrol --from`` would (:func:`~neurotouch_hid.enrolment.label.find_gestures`); a prompt with no
gesture is asked again once, after the plan's last prompt, when that still ends within
:data:`~neurotouch_hid.enrolment.plan.MAX_SESSION_S`. At the end the recording is labelled from
the prompts asked (the plan's and those asked again) and written as a dataset
(:func:`~neurotouch_hid.enrolment.label.write_dataset`).

Where the stream comes from is an :class:`EnrolSource`: the live camera (:class:`CameraSource`,
a person reads the prompts) or the simulated hand (:class:`SimulatedHandSource`). What is shown
is the caller's view (:class:`~neurotouch_hid.enrolment.prompt_view.PromptView`).
"""

from __future__ import annotations

import contextlib
import dataclasses
import os
import threading
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol

from neurotouch_hid.enrolment.label import SEARCH_S, Labelled, MotionMeter, find_gestures, write_dataset
from neurotouch_hid.enrolment.plan import MAX_SESSION_S, Plan, Prompt, rest_after_s, temp_beside
from neurotouch_hid.enrolment.prompt_view import Seen, clock
from neurotouch_hid.errors import RecordingError
from neurotouch_hid.sensor import SensorGeometry
from neurotouch_hid.sources import Frame, Pacer, StreamItem

#: The sequence name of an enrolment's recording in its dataset folder.
SEQUENCE = "enrolment"
#: A prompt asked again is cued at least this long after it was judged missed (s).
AGAIN_AFTER_S = 3.0


class EnrolSource(Protocol):
    """Where an enrolment's stream comes from."""

    #: True when a person performs the prompts.
    by_hand: bool
    #: The camera name written into the recording.
    camera_name: str

    def stream(self) -> Iterator[StreamItem]:
        """Frames and event batches, time-ordered, endless."""

    def perform(self, number: int, prompt: Prompt, cue_us: int) -> None:
        """Called when prompt ``number`` (1-based, in the order asked) is cued at ``cue_us``."""


class SimulatedHandSource:
    """The simulated gel with the enrolment's simulated hand (:class:`~neurotouch_hid.enrolment.hand.SimulatedHand`).

    Args:
        seed, physics, miss_rate: the hand's (:class:`SimulatedHand`).
        misses: prompt numbers (1-based, in the order asked) the hand misses whatever the rate.
    """

    by_hand = False
    camera_name = "NeuroTouch-sim_DAVIS346"

    def __init__(
        self, seed: int = 0, *, physics: str = "default", miss_rate: float = 1 / 20, misses: Sequence[int] = ()
    ) -> None:
        from neurotouch_hid.enrolment.hand import SimulatedHand

        self.hand = SimulatedHand(seed, physics=physics, miss_rate=miss_rate)
        self.sensor = self.hand.sensor
        self._misses = set(misses)

    def stream(self) -> Iterator[StreamItem]:
        from neurotouch_hid.sources.recording import split_batches

        for chunk in self.hand.simulator.run():
            yield chunk.frame
            yield from split_batches(chunk.events, 1000)

    def perform(self, number: int, prompt: Prompt, cue_us: int) -> None:
        self.hand.perform(prompt, cue_us, missed=True if number in self._misses else None)


class CameraSource:
    """The live DAVIS-346; the person at the gel reads the prompts. A context manager.

    Args:
        config: the camera's settings (:class:`~neurotouch_hid.sources.davis.DavisConfig`).
        backend: the capture backend of :class:`~neurotouch_hid.sources.davis.DavisSource` (None:
            dv-processing's cameras); options: its other keywords (e.g. its clock).
    Raises:
        DeviceError: no camera (on entering).
    """

    by_hand = True
    camera_name = "DAVIS346"

    def __init__(self, config: object = None, backend: object = None, **options: object) -> None:
        self._config = config
        self._backend = backend
        self._options = options
        self._stack = contextlib.ExitStack()
        self._items: Iterator[StreamItem] | None = None

    def __enter__(self) -> "CameraSource":
        from neurotouch_hid.sources.davis import DavisSource

        camera = self._stack.enter_context(DavisSource(self._config, backend=self._backend, **self._options))
        self._items = self._stack.enter_context(contextlib.closing(camera.stream()))
        return self

    def __exit__(self, *exc) -> None:
        self._stack.close()

    def stream(self) -> Iterator[StreamItem]:
        return iter(self._items)

    def perform(self, number: int, prompt: Prompt, cue_us: int) -> None:
        """Nothing: the person reads the prompt."""


@dataclass(frozen=True)
class SessionResult:
    """What an enrolment did.

    Attributes:
        labelled: the dataset written (its folder, sequence name, each prompt asked and what was found).
        asked_again: (index, index) pairs (0-based, into ``labelled.found``, the prompts in the
            order asked): a prompt not seen when first asked, and the prompt that asked it again.
        stopped: True when the session was stopped before its end (what was recorded is labelled).
    """

    labelled: Labelled
    asked_again: list[tuple[int, int]]
    stopped: bool

    @property
    def not_seen(self) -> list[Prompt]:
        """The prompts asked (the plan's and those asked again) with no gesture seen: left out."""
        return [f.prompt for f in self.labelled.missed]


class _Session:
    """One enrolment's state as the stream goes (see :func:`run_session`)."""

    def __init__(self, plan: Plan, source: EnrolSource, sensor: SensorGeometry) -> None:
        self.prompts = list(plan.prompts)
        self.source = source
        self.meter = MotionMeter(sensor)
        self.notes: list[str] = []
        self.asked_again: list[tuple[int, int]] = []
        self.again_of: set[int] = set()  # indices of prompts that are themselves asked again
        self.cued = 0
        self.judged = 0
        self.seen = Seen()

    def cue_us(self, i: int) -> int:
        return int(self.meter.start_us) + int(round(self.prompts[i].cue_s * 1e6))

    def step(self, t_us: int) -> None:
        """Cue the prompts due at ``t_us`` and judge those whose search span has passed."""
        while self.cued < len(self.prompts) and self.cue_us(self.cued) <= t_us:
            self.source.perform(self.cued + 1, self.prompts[self.cued], self.cue_us(self.cued))
            self.cued += 1
        while self.judged < self.cued and self.cue_us(self.judged) + int(SEARCH_S * 1e6) <= t_us:
            self._judge(self.judged, t_us)
            self.judged += 1

    def _judge(self, i: int, t_us: int) -> None:
        found = find_gestures(Plan(tuple(self.prompts[: i + 1])), self.meter.motion())[-1]
        if found.seen:
            return
        p = self.prompts[i]
        what = f"prompt {i + 1} ({p.name}): no gesture seen"
        if i in self.again_of:
            self.notes.append(f"{what} when asked again: left out")
            return
        last = self.prompts[-1]
        now_s = (t_us - self.meter.start_us) * 1e-6
        cue = round(max(last.end_s + rest_after_s(last.seconds), now_s + AGAIN_AFTER_S), 3)
        if cue + p.seconds + rest_after_s(p.seconds) > MAX_SESSION_S:
            self.notes.append(f"{what}: no time left to ask again, left out")
            return
        self.prompts.append(dataclasses.replace(p, cue_s=cue))
        self.again_of.add(len(self.prompts) - 1)
        self.asked_again.append((i, len(self.prompts) - 1))
        self.notes.append(f"{what}: asked again at {clock(cue)}")

    def done(self, t_us: int) -> bool:
        """All prompts cued and judged, the last one's rest over."""
        end_s = Plan(tuple(self.prompts)).end_s
        return self.judged == len(self.prompts) and (t_us - self.meter.start_us) * 1e-6 >= end_s


def run_session(
    plan: Plan,
    source: EnrolSource,
    out_dir: str | Path,
    sensor: SensorGeometry,
    show: Callable[[Sequence[Prompt], float, Seen | None, Sequence[str]], None],
    *,
    pace: bool = False,
    stop: threading.Event | None = None,
) -> SessionResult:
    """Run a guided enrolment (module docstring) and write its dataset into ``out_dir`` (created):
    ``enrolment.aedat4``, ``enrolment.labels.csv``, ``enrolment.plan.json`` (the prompts asked)
    and ``sensor.yaml``.

    Args:
        plan: the prompts; source: the stream and who performs them; sensor: the geometry.
        show: the view, called after every APS frame with (the prompts: the plan's and those asked
            again so far; s from the recording's first event; what the pipeline sees; notes).
        pace: keep the stream on wall time (the simulated gel; a camera paces itself).
        stop: set it (Ctrl-C) to end the session early; what was recorded is labelled.
    Returns:
        :class:`SessionResult`.
    Raises:
        RecordingError: the recording cannot be written; SensorError: no gel in view; the
        source's own errors (e.g. DeviceError). The recording is complete and kept on any of them
        raised after it started.
    """
    from neurotouch_hid.sources.recording import RecordingWriter

    stop = stop or threading.Event()
    out = Path(out_dir)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise RecordingError(f"{out}: cannot create the enrolment folder: {exc.strerror}") from None
    recording = out / f"{SEQUENCE}.aedat4"
    partial = temp_beside(recording, ".aedat4")
    session = _Session(plan, source, sensor)
    pacer = Pacer()
    try:
        with RecordingWriter(partial, camera_name=source.camera_name) as writer:
            for item in source.stream():
                if isinstance(item, Frame):
                    writer.write_frame(item)
                    t_us = item.t_us
                elif len(item):
                    writer.write_events(item)
                    t_us = int(item["timestamp"][-1])
                else:
                    continue
                closed = session.meter.pipeline.process(item)
                session.meter.note(item, closed)
                if closed:
                    last = closed[-1]
                    session.seen = Seen(session.meter.moved_mm, last.gesture, last.intensity_mm)
                session.step(t_us)
                if isinstance(item, Frame):
                    show(
                        session.prompts,
                        (t_us - session.meter.start_us) * 1e-6,
                        session.seen,
                        session.notes,
                    )
                if session.done(t_us) or stop.is_set():
                    break
                if pace:
                    pacer.wait(t_us, stop)
    finally:  # the writer has closed the file complete: keep what was recorded, however it ended
        if partial.stat().st_size:
            os.replace(partial, recording)
        else:
            partial.unlink()
    asked = Plan(tuple(session.prompts[: session.cued]))
    labelled = write_dataset(out, recording, asked, session.meter.motion(), sensor)
    return SessionResult(labelled, session.asked_again, stop.is_set())


def enrolment_folder(now: str | None = None) -> Path:
    """A new folder for an enrolment: ``platformdirs.user_data_dir("neurotouch-hid")/enrolments/<time>``
    (the local time, e.g. ``2026-11-25T09-41-07``; ``-2``, ``-3``... when taken)."""
    import time

    import platformdirs

    base = Path(platformdirs.user_data_dir("neurotouch-hid")) / "enrolments"
    stamp = now or time.strftime("%Y-%m-%dT%H-%M-%S")
    folder, n = base / stamp, 1
    while folder.exists():
        n += 1
        folder = base / f"{stamp}-{n}"
    return folder
