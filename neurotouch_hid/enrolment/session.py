"""The guided enrolment: prompts while the camera records, then the labelled dataset.

The session runs on the driver's one road (:class:`~neurotouch_hid.engine.engine.Engine`): the
source's stream, written to the recording as it passes (AEDAT4, through a temporary name renamed
at the end: :func:`~neurotouch_hid.sources.recording_writer.recorded`), goes through the gesture
pipeline, and each window's record is published to the session's subscribers: the
:class:`Judge` and the views (:class:`~neurotouch_hid.enrolment.prompt_view.PromptView`). They
share the session's :class:`~neurotouch_hid.enrolment.plan.Script`: the plan's prompts and
those asked again, cued in the stream's own time (s from its first event or frame), and the
notes. The simulated hand, when it is the source, performs each prompt as its stream reaches
the cue; a person at the camera reads it on the view.

The judge keeps the gel's motion from each record's markers
(:func:`~neurotouch_hid.enrolment.label.motion_mm`); when a prompt's search span has passed
(:data:`~neurotouch_hid.enrolment.label.SEARCH_S` after its cue) it judges it as ``enrol --from``
would (:func:`~neurotouch_hid.enrolment.label.find_gestures`); a prompt with no gesture is asked
again once, after the plan's last prompt, when that still ends within
:data:`~neurotouch_hid.enrolment.plan.MAX_SESSION_S`. At the end the recording is labelled from
the prompts asked as ``enrol --from`` labels it
(:func:`~neurotouch_hid.enrolment.label.label_recording`): the same recording and prompts give
the same labels.

Where the stream comes from is an :class:`EnrolSource`: the live camera (:class:`CameraSource`,
a person reads the prompts) or the simulated hand (:class:`SimulatedHandSource`).
"""

from __future__ import annotations

import contextlib
import dataclasses
import os
import threading
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol

import numpy as np

from neurotouch_hid.core.dataset_out import DatasetOut
from neurotouch_hid.core.errors import DatasetError, RecordingError
from neurotouch_hid.core.sensor import SensorGeometry
from neurotouch_hid.core.stages import Subscriber, WindowRecord
from neurotouch_hid.engine.queue import item_end_us, item_start_us
from neurotouch_hid.enrolment.label import (
    ONSET_MM,
    SEARCH_S,
    GelMotion,
    Labelled,
    NoGestureError,
    find_gestures,
    label_recording,
)
from neurotouch_hid.enrolment.plan import MAX_SESSION_S, Plan, Prompt, Script, rest_after_s, temp_beside
from neurotouch_hid.enrolment.prompt_view import clock, seen_in
from neurotouch_hid.sources import StreamItem

#: The sequence name of an enrolment's recording in its dataset folder.
SEQUENCE = "enrolment"
#: A prompt asked again is cued at least this long after it was judged missed (s).
AGAIN_AFTER_S = 3.0
#: Items the source may read ahead of the pipeline when the run is not paced: a prompt asked
#: again (cued :data:`AGAIN_AFTER_S` ahead of the judge) is never in the source's past.
QUEUE_ITEMS = 64


class EnrolSource(Protocol):
    """Where an enrolment's stream comes from."""

    #: True when a person performs the prompts.
    by_hand: bool
    #: The camera name written into the recording.
    camera_name: str

    def stream(self, script: Script) -> Iterator[StreamItem]:
        """Frames and event batches, time-ordered, endless; ``script``'s prompts performed as
        the stream reaches their cues, when the source performs them."""


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

    def stream(self, script: Script) -> Iterator[StreamItem]:
        """The simulated gel's frames and event batches (1000 events at most); once an item has
        been taken, each prompt of ``script`` cued by its end (:attr:`Script.start_us`, set as
        the first event batch passes, plus the cue) is performed, as a person starts on a cue."""
        from neurotouch_hid.sources.batches import split_batches

        cued = 0
        for chunk in self.hand.simulator.run():
            for item in (chunk.frame, *split_batches(chunk.events, 1000)):
                yield item
                t_us = item_end_us(item)
                prompts = script.prompts()
                while t_us is not None and cued < len(prompts) and script.cue_us(prompts[cued]) <= t_us:
                    cued += 1
                    missed = True if cued in self._misses else None
                    self.hand.perform(prompts[cued - 1], script.cue_us(prompts[cued - 1]), missed=missed)


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

    def stream(self, script: Script) -> Iterator[StreamItem]:
        """The camera's stream; ``script`` is for the person, who reads it on the view."""
        return iter(self._items)


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


class Judge:
    """A subscriber that keeps the gel's motion of each record (it needs the record's markers
    and geometry) and judges each prompt of ``script`` once its search span has passed (module
    docstring), asks a prompt not seen again, says so in the script's notes, and finishes the
    script when every prompt is judged and the last one's rest is over.

    Args:
        script: the session's.
    Attributes:
        asked_again: as :attr:`SessionResult.asked_again`.
    """

    wants_markers = True

    def __init__(self, script: Script) -> None:
        self.script = script
        self.asked_again: list[tuple[int, int]] = []
        self._again_of: set[int] = set()  # indices of prompts that are themselves asked again
        self._judged = 0
        self._t_us: list[int] = []
        self._moved: list[float] = []

    def publish(self, record: WindowRecord) -> None:
        """Keep the window's motion; judge the prompts whose search span ended by its end."""
        t_us = int(record.estimate.t_us)
        self._t_us.append(t_us)
        self._moved.append(seen_in(record).moved_mm)
        prompts = self.script.prompts()
        while self._judged < len(prompts) and self.script.cue_us(prompts[self._judged]) + int(SEARCH_S * 1e6) <= t_us:
            self._judge(prompts, self._judged, t_us)
            self._judged += 1
            prompts = self.script.prompts()
        start_us = self.script.start_us
        if self._judged == len(prompts) and start_us is not None and (t_us - start_us) * 1e-6 >= Plan(prompts).end_s:
            self.script.finish()

    def _judge(self, prompts: Sequence[Prompt], i: int, t_us: int) -> None:
        motion = GelMotion(
            np.asarray(self._t_us, dtype=np.int64),
            np.asarray(self._moved, dtype=np.float64),
            [],
            np.zeros(0, dtype=np.int64),
            int(self.script.start_us or 0),
        )
        if find_gestures(Plan(tuple(prompts[: i + 1])), motion)[-1].seen:
            return
        p = prompts[i]
        what = f"prompt {i + 1} ({p.name}): no gesture seen"
        if i in self._again_of:
            self.script.note(f"{what} when asked again: left out")
            return
        last = prompts[-1]
        now_s = (t_us - int(self.script.start_us or 0)) * 1e-6
        cue = round(max(last.end_s + rest_after_s(last.seconds), now_s + AGAIN_AFTER_S), 3)
        if cue + p.seconds + rest_after_s(p.seconds) > MAX_SESSION_S:
            self.script.note(f"{what}: no time left to ask again, left out")
            return
        again = self.script.ask_again(dataclasses.replace(p, cue_s=cue))
        self._again_of.add(again)
        self.asked_again.append((i, again))
        self.script.note(f"{what}: asked again at {clock(cue)}")

    def neutralise(self) -> None:
        """Nothing to release: the judge drives no device."""

    def prepare(self, profile: object) -> None:
        """Nothing to prepare: the judge maps nothing."""


def _until_over(items: Iterable[StreamItem], script: Script, stop: threading.Event) -> Iterator[StreamItem]:
    """``items`` until ``script`` is finished or ``stop`` is set, each one's times given to
    ``script`` as it passes (:meth:`Script.reach`)."""
    for item in items:
        first, last = item_start_us(item), item_end_us(item)
        if first is not None and last is not None:
            script.reach(first, last, events=isinstance(item, np.ndarray))
        yield item
        if script.finished or stop.is_set():
            return


def run_session(
    script: Script,
    source: EnrolSource,
    out_dir: str | Path | DatasetOut,
    sensor: SensorGeometry,
    views: Sequence[Subscriber],
    *,
    pace: bool = False,
    stop: threading.Event | None = None,
    on_progress: Callable[[int, int], None] | None = None,
) -> SessionResult:
    """Run a guided enrolment (module docstring) and write its dataset into ``out_dir`` (created):
    ``enrolment.aedat4``, ``enrolment.labels.csv``, ``enrolment.plan.json`` (the prompts asked)
    and ``sensor.yaml``. The folder is written whole (:class:`~neurotouch_hid.core.dataset_out.DatasetOut`;
    give one to replace a dataset with ``force``): a folder that holds a dataset is refused.

    Args:
        script: the session's prompts (a new :class:`~neurotouch_hid.enrolment.plan.Script` of
            the plan), which the views read; source: the stream and who performs the prompts;
            sensor: the geometry.
        views: subscribers to the run's records (e.g. the prompt view, which draws ``script``).
        pace: keep the stream on wall time (the simulated gel; a camera paces itself).
        stop: set it (Ctrl-C) to end the session early; what was recorded is labelled.
        on_progress: how far the labelling of the recording is, after the session (as
            :func:`~neurotouch_hid.pipeline.track.pipeline_over`'s).
    Returns:
        :class:`SessionResult`.
    Raises:
        DatasetError: ``out_dir`` holds a dataset or other files, or another session wrote
        there meanwhile, or no gesture was seen for any prompt asked (nothing labelled).
        RecordingError: the recording cannot be written; SensorError: no gel in view; the
        source's own errors (e.g. DeviceError). The recording is complete and kept on any of them
        raised after it started.
    """
    from neurotouch_hid.engine.engine import Engine, RunParts
    from neurotouch_hid.engine.mode import RunMode, RunOptions
    from neurotouch_hid.mapping.profile import Profile
    from neurotouch_hid.pipeline.pipeline import GesturePipeline
    from neurotouch_hid.sources.recording_writer import RecordingWriter, recorded

    stop = stop or threading.Event()
    target = out_dir if isinstance(out_dir, DatasetOut) else DatasetOut(out_dir)
    out = target.work
    recording = out / f"{SEQUENCE}.aedat4"
    partial = temp_beside(recording, ".aedat4")
    judge = Judge(script)
    try:
        with RecordingWriter(partial, camera_name=source.camera_name) as writer:
            stream = _until_over(recorded(source.stream(script), writer), script, stop)
            # no profile maps anything here: the judge and the views read the estimates and markers
            options = RunOptions(mode=RunMode.of(pace=pace, waits=pace), queue_items=QUEUE_ITEMS)
            parts = RunParts(stream, GesturePipeline(sensor), sensor=sensor)
            Engine(parts, Profile(), [judge, *views], options).run()
    except RecordingError as exc:  # the disk: said of the folder asked for, what was kept with it
        kept = _keep_recording(target, partial, recording)
        said = str(exc).replace(str(partial), str(target.out / recording.name)).replace(str(out), str(target.out))
        where = f"the session until then is kept in {target.out / recording.name}" if kept else "nothing was kept"
        raise RecordingError(f"{said}; {where}") from None
    except BaseException:  # the writer has closed the file complete: keep what was recorded, however it ended
        _keep_recording(target, partial, recording)
        raise
    _keep_recording(target, partial, recording, commit=False)
    try:
        labelled = label_recording(recording, script.asked(), out, sensor, on_progress=on_progress)
    except NoGestureError:  # the person followed these prompts: say what to do, not another plan
        kept = _keep_recording(target, partial, recording)
        where = f"the recording is kept in {target.out / recording.name}" if kept else "nothing was kept"
        raise DatasetError(
            f"no gesture was seen for any of the {len(script.asked().prompts)} prompts asked: nothing to label, "
            f"no dataset written ({where}). A gesture is seen when the gel moves at least {ONSET_MM:g} mm within "
            f"{SEARCH_S:g} s of its prompt: start as each prompt appears, press until the panel says "
            "'gel: moving', then run `neurotouch-hid enrol` again"
        ) from None
    except BaseException:
        _keep_recording(target, partial, recording)
        raise
    labelled = dataclasses.replace(labelled, folder=target.commit())
    return SessionResult(labelled, judge.asked_again, not script.finished)


def _keep_recording(target: DatasetOut, partial: Path, recording: Path, commit: bool = True) -> bool:
    """The session's recording (complete once its writer is closed) in place in ``target``'s
    folder, and (``commit``) that folder put in place when there is a recording to keep and
    nothing to lose there (True then); otherwise it is removed. A failing commit says nothing
    more: the error that ended the session is the one said."""
    if partial.exists():
        if partial.stat().st_size:
            os.replace(partial, recording)
        else:
            partial.unlink()
    if not commit:
        return False
    if recording.exists() and not target.force:
        with contextlib.suppress(DatasetError):
            target.commit()
            return True
    target.discard()
    return False


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
