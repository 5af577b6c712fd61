"""Labels a recording made by following an enrolment's plan (``enrol --from``).

The prompt gives each gesture's type; the gel gives its moments (docs/dataset.md, "Guided session
plan (JSON)"). The recording runs through the gesture pipeline
(:class:`~neurotouch_hid.pipeline.pipeline.GesturePipeline`, public entry points only). At each
window's end, the gel's motion is the :data:`MOTION_RANK`-th largest displacement of the
tracker's markers from their rest positions (mm at the centre's scale; the largest few can be a
lost or mis-tracked marker). For each prompt, in order (:func:`find_gestures`):

- the search runs from its cue (or the previous gesture's end, when later) for
  :data:`SEARCH_S`, and not past the next prompt's cue;
- the gesture is there when the motion rises :data:`ONSET_MM` above the gel's level just before
  the cue; its start is the last window before that at most :data:`REST_MM` above that level (the
  fingers' first move);
- it ends at the first window after that in which the motion is back below
  :data:`END_SHARE` of its peak (and at most :data:`REST_MM` above the level before it);
- a prompt with no such motion is left out (not labelled) and reported.

Every APS frame is labelled (docs/dataset.md, "SEQUENCE.labels.csv"): within a gesture
(start <= t < end), the prompt's type, not resting, the contact points that the pipeline's
contact stage finds in the window holding the frame (when a window has none, or another count
than most of the gesture's windows, the gesture's last ones), and as intensity the displacement
of those contact points since the gesture's start (docs/dataset.md): the pipeline's intensity
stage's measure where the points are that window's own, else the mean displacement of the
tracked marker nearest each (:func:`contact_displacement_mm`), 0 before the gesture's first
contact points; outside, ``none``, resting when the motion is within :data:`REST_MM`.
"""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from neurotouch_hid.core.dataset import MAX_CONTACTS, LabelRow, write_labels
from neurotouch_hid.core.errors import DatasetError
from neurotouch_hid.core.estimate import GestureEstimate, GestureType
from neurotouch_hid.core.sensor import SensorGeometry
from neurotouch_hid.enrolment.plan import Plan, Prompt, temp_beside, write_atomic
from neurotouch_hid.sources import Frame, StreamItem

#: How long after its cue a prompted gesture may start (s): people start a few hundred ms late.
SEARCH_S = 2.0
#: The gel's motion that makes a gesture (mm above the level before the cue).
ONSET_MM = 0.5
#: Motion within this of the level before the cue is the gel at rest (mm): above the tracker's
#: noise at rest, below a gesture's first few ms.
REST_MM = 0.15
#: A gesture ends when its motion is back below this share of its peak.
END_SHARE = 0.1
#: The motion is the k-th largest marker displacement (k = MOTION_RANK).
MOTION_RANK = 3
#: The gel's level before a cue: the median motion over this long before it (s).
LEVEL_S = 0.3


class NoGestureError(DatasetError):
    """No prompt of a plan has a gesture near its cue (:func:`write_dataset`): nothing is labelled."""


class NotFollowedError(DatasetError):
    """A recording does not follow its plan (:func:`write_dataset` with ``strict``): most of its
    gestures are not what their prompts asked, or fewer than half the prompts are labelled."""


@dataclass(frozen=True)
class GelMotion:
    """What the pipeline saw of a recording.

    Attributes:
        t_us: (W,) int64 window ends (us, camera clock).
        moved_mm: (W,) float64 the gel's motion at each window's end (mm; module docstring).
        estimates: the W windows' estimates.
        frames_us: (F,) int64 APS frame timestamps (us).
        start_us: the recording's first event's timestamp (us; with no event, its first frame's):
            plans' cues count from it (docs/dataset.md).
        positions_px: (W, N, 2) float32 the N tracked markers at each window's end (image px,
            NaN rows lost; 1.4 KB a window, 8 MB for a three-minute session); (0, 0, 2) when
            not kept (the session's own judge).
    """

    t_us: np.ndarray
    moved_mm: np.ndarray
    estimates: list[GestureEstimate]
    frames_us: np.ndarray
    start_us: int
    positions_px: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros((0, 0, 2), np.float32))


@dataclass(frozen=True)
class Found:
    """One prompt and the gesture found for it.

    Attributes:
        prompt: the prompt; start_us, end_us: the gesture's start and end (us, camera clock),
        None when missed; peak_mm: its largest motion (mm; 0 when missed); disagrees: why what
        the gel did there is not what the prompt asked (:func:`check_gestures`), None when it
        agrees or was not checked.
    """

    prompt: Prompt
    start_us: int | None
    end_us: int | None
    peak_mm: float = 0.0
    disagrees: str | None = None

    @property
    def seen(self) -> bool:
        """A gesture was found near the prompt's cue."""
        return self.start_us is not None

    @property
    def labelled(self) -> bool:
        """Found, and what the gel did agrees with the prompt (:mod:`neurotouch_hid.enrolment.agree`)."""
        return self.seen and self.disagrees is None


class MotionMeter:
    """Keeps what a pipeline sees of a stream: the gel's motion at each window's end, the
    windows' estimates, the APS frames' times and the stream's first timestamp.

    Feed each stream item to :attr:`pipeline` (its ``process``, or
    :func:`neurotouch_hid.pipeline.track.pipeline_over`), then hand the item and the estimates it closed to
    :meth:`note`; :meth:`motion` is what was seen so far.

    Args:
        sensor: the pipeline's geometry.
    """

    def __init__(self, sensor: SensorGeometry) -> None:
        from neurotouch_hid.pipeline.pipeline import GesturePipeline

        self.sensor = sensor
        self.pipeline = GesturePipeline(sensor, on_window=self._keep)
        self._moved: list[float] = []
        self._positions: list[np.ndarray] = []
        self.estimates: list[GestureEstimate] = []
        self._frames: list[int] = []
        self.start_us: int | None = None

    def _keep(self, estimate: GestureEstimate) -> None:
        positions = self.pipeline.marker_positions()
        self._moved.append(motion_mm(positions, self.pipeline.rest_px, self.sensor.px_per_mm))
        self._positions.append(np.asarray(positions, dtype=np.float32))

    @property
    def moved_mm(self) -> float:
        """The gel's motion at the last window's end (mm; 0 before the first window)."""
        return self._moved[-1] if self._moved else 0.0

    def note(self, item: StreamItem, closed: Sequence[GestureEstimate]) -> None:
        """Keep ``item``'s time (a frame's timestamp, an event batch's first: the first event is
        where a plan's cues count from) and the estimates it closed."""
        if isinstance(item, Frame):
            self._frames.append(item.t_us)
        elif len(item):
            first = int(item["timestamp"][0])
            self.start_us = first if self.start_us is None else min(self.start_us, first)
        self.estimates.extend(closed)

    def motion(self) -> GelMotion:
        """What was seen so far."""
        n = len(self.estimates)
        return GelMotion(
            np.asarray([e.t_us for e in self.estimates], dtype=np.int64),
            np.asarray(self._moved[:n], dtype=np.float64),
            list(self.estimates),
            np.asarray(self._frames, dtype=np.int64),
            int(self.start_us if self.start_us is not None else (self._frames[0] if self._frames else 0)),
            np.stack(self._positions[:n]) if n else np.zeros((0, 0, 2), np.float32),
        )


def measure_motion(
    recording: str | Path, sensor: SensorGeometry, on_progress: Callable[[int, int], None] | None = None
) -> GelMotion:
    """Run the pipeline over ``recording`` and keep what it sees (:class:`MotionMeter`).

    Raises:
        RecordingError, SensorError: as :func:`neurotouch_hid.pipeline.track.pipeline_over`.
    """
    from neurotouch_hid.pipeline.track import pipeline_over

    meter = MotionMeter(sensor)
    for item, closed in pipeline_over(recording, meter.pipeline, on_progress=on_progress):
        meter.note(item, closed)
    return meter.motion()


def motion_mm(positions_px: np.ndarray, rest_px: np.ndarray, px_per_mm: float) -> float:
    """The gel's motion (mm): the :data:`MOTION_RANK`-th largest distance of the tracked
    markers (N, 2) px (NaN rows lost) from their rest positions (N, 2) px; 0 with fewer markers."""
    d = np.linalg.norm(np.asarray(positions_px, dtype=np.float64) - rest_px, axis=1)
    d = d[np.isfinite(d)]
    if len(d) < MOTION_RANK:
        return 0.0
    return float(np.partition(d, len(d) - MOTION_RANK)[len(d) - MOTION_RANK]) / px_per_mm


def find_gestures(plan: Plan, motion: GelMotion) -> list[Found]:
    """For each prompt of ``plan``, in order, the gesture the gel shows near its cue (module
    docstring), or a miss."""
    t, m = motion.t_us, motion.moved_mm
    found: list[Found] = []
    cursor = int(motion.start_us)
    prompts = plan.prompts
    for i, prompt in enumerate(prompts):
        cue = motion.start_us + int(round(prompt.cue_s * 1e6))
        next_cue = motion.start_us + int(round(prompts[i + 1].cue_s * 1e6)) if i + 1 < len(prompts) else None
        lo = max(cue, cursor)
        hi = cue + int(SEARCH_S * 1e6)
        hi = hi if next_cue is None else min(hi, next_cue)
        before = m[(t >= max(cursor, cue - int(LEVEL_S * 1e6))) & (t < lo)]
        level = float(np.median(before)) if len(before) else 0.0
        a, b = np.searchsorted(t, lo, side="left"), np.searchsorted(t, hi, side="left")
        above = np.flatnonzero(m[a:b] >= level + ONSET_MM)
        if len(above) == 0:
            found.append(Found(prompt, None, None))
            continue
        j = a + int(above[0])
        k = j
        while k > 0 and t[k - 1] > cursor and m[k - 1] > level + REST_MM:
            k -= 1
        start = int(t[k - 1]) if k > 0 else int(t[k])
        peak, e = m[j], j
        while e < len(m):
            peak = max(peak, m[e])
            if m[e] < max(level + REST_MM, END_SHARE * peak):
                break
            e += 1
        end = int(t[min(e, len(t) - 1)])
        found.append(Found(prompt, start, end, float(peak)))
        cursor = end
    return found


def check_gestures(found: Sequence[Found], motion: GelMotion, sensor: SensorGeometry) -> list[Found]:
    """``found`` with, for each gesture found, whether what the gel did at its peak (its window
    of largest motion) since its start agrees with the prompt
    (:func:`neurotouch_hid.enrolment.agree.disagreement`; the contact count at the peak is the
    contact stage's, else the gesture's most frequent). Without the markers' positions
    (``motion.positions_px`` empty) nothing is checked."""
    from neurotouch_hid.enrolment.agree import disagreement, gel_did
    from neurotouch_hid.enrolment.plan import DIRECTIONS

    if not len(motion.positions_px):
        return list(found)
    checked: list[Found] = []
    for f in found:
        if not f.seen:
            checked.append(f)
            continue
        a, b = np.searchsorted(motion.t_us, [f.start_us, f.end_us], side="left")
        a = min(int(a), len(motion.t_us) - 1)
        b = max(int(b), a + 1)
        peak = a + int(np.argmax(motion.moved_mm[a:b]))
        contacts = motion.estimates[peak].n_contacts or _finger_count(motion, f.start_us, f.end_us)
        did = gel_did(motion.positions_px[peak], motion.positions_px[a], contacts, sensor)
        direction = DIRECTIONS.get(f.prompt.direction or "")
        checked.append(dataclasses.replace(f, disagrees=disagreement(f.prompt.gesture, direction, did)))
    return checked


def label_frames(motion: GelMotion, found: Sequence[Found], px_per_mm: float) -> list[LabelRow]:
    """One label per APS frame of the recording (module docstring); ``px_per_mm``: the sensor's
    scale at the centre, for the intensity (docs/dataset.md: the mean displacement of the
    labelled contact points since the gesture's start, :func:`contact_displacement_mm`)."""
    spans = [(f.start_us, f.end_us, f.prompt.gesture) for f in found if f.labelled]
    starts = np.asarray([s[0] for s in spans], dtype=np.int64)
    counts = [_finger_count(motion, a, b) for a, b, _ in spans]
    rows: list[LabelRow] = []
    last_contacts = np.zeros((0, 2))
    current = start_w = -1
    for f_us in motion.frames_us.tolist():
        w = min(int(np.searchsorted(motion.t_us, f_us, side="right")), len(motion.t_us) - 1)
        moved = float(motion.moved_mm[w]) if w >= 0 else 0.0
        s = int(np.searchsorted(starts, f_us, side="right")) - 1
        if w < 0 or s < 0 or f_us >= spans[s][1]:
            rows.append(LabelRow(int(f_us), GestureType.NONE, moved <= REST_MM, 0.0, np.zeros((0, 2))))
            continue
        if s != current:
            current, last_contacts = s, np.zeros((0, 2))
            start_w = min(int(np.searchsorted(motion.t_us, spans[s][0], side="left")), w)
        estimate = motion.estimates[w]
        own = bool(estimate.n_contacts) and (estimate.n_contacts == counts[s] or len(last_contacts) == 0)
        if own:
            last_contacts = np.asarray(estimate.contacts_px[:MAX_CONTACTS], dtype=np.float64)
        if own and estimate.intensity_mm > 0:  # the contact stage's own measure of these points
            intensity = float(estimate.intensity_mm)
        else:  # points held from an earlier window: measured at their markers
            intensity = contact_displacement_mm(
                motion.positions_px[w], motion.positions_px[start_w], last_contacts, px_per_mm
            )
        rows.append(LabelRow(int(f_us), spans[s][2], False, intensity, last_contacts))
    return rows


def contact_displacement_mm(
    positions_px: np.ndarray, start_px: np.ndarray, contacts_px: np.ndarray, px_per_mm: float
) -> float:
    """The mean displacement of contact points since a gesture's start (mm): for each contact
    point, the tracked marker nearest to it now, and how far that marker has moved since the
    start; 0 with no contact point or no marker tracked at both times.

    Args:
        positions_px: (N, 2) the markers now (image px, NaN rows lost).
        start_px: (N, 2) the same markers at the gesture's start.
        contacts_px: (C, 2) the contact points (image px).
        px_per_mm: the sensor's scale at the centre (px/mm).
    """
    if not len(contacts_px):
        return 0.0
    moved = np.linalg.norm(positions_px.astype(np.float64) - start_px, axis=1)
    seen = np.flatnonzero(np.isfinite(moved))
    if not len(seen):
        return 0.0
    gap = np.linalg.norm(positions_px[seen][None, :, :] - contacts_px[:, None, :], axis=2)  # (C, seen)
    return float(moved[seen[np.argmin(gap, axis=1)]].mean()) / px_per_mm


def _finger_count(motion: GelMotion, start_us: int, end_us: int) -> int:
    """The contact count the pipeline reads most often in a gesture's windows (its fingers stay
    the same from start to end; 0 when no window has contacts)."""
    a, b = np.searchsorted(motion.t_us, [start_us, end_us], side="left")
    counts = [min(e.n_contacts, MAX_CONTACTS) for e in motion.estimates[a:b] if e.n_contacts]
    return int(np.bincount(counts).argmax()) if counts else 0


@dataclass(frozen=True)
class Labelled:
    """What :func:`label_recording` wrote: the dataset folder, the sequence's name and, per
    prompt, what was found."""

    folder: Path
    name: str
    found: list[Found]
    past_end: int = 0  # prompts of the plan cued after the recording's end, left out
    kept: str = "in place"  # how the recording is in the folder (:func:`link_atomic`'s word)

    @property
    def missed(self) -> list[Found]:
        """The prompts with no gesture near their cue (left out of the labels)."""
        return [f for f in self.found if not f.seen]

    @property
    def disagreeing(self) -> list[Found]:
        """The prompts whose gesture is not what they asked (left out of the labels)."""
        return [f for f in self.found if f.seen and not f.labelled]

    @property
    def labelled(self) -> int:
        """How many prompts are labelled."""
        return sum(f.labelled for f in self.found)


def label_recording(
    recording: str | Path,
    plan: Plan,
    out_dir: str | Path,
    sensor: SensorGeometry,
    *,
    inputs: Sequence[str | Path] = (),
    on_progress: Callable[[int, int], None] | None = None,
    past_end: bool = False,
    strict: bool = False,
) -> Labelled:
    """Label ``recording`` from ``plan`` (:func:`measure_motion`) and write it as a dataset
    (:func:`write_dataset`).

    With ``past_end``, prompts cued after the recording's end are left out (counted in
    ``Labelled.past_end``): a recording made by following a plan, stopped before its end.
    ``strict``: as :func:`write_dataset`'s (a recording made elsewhere, ``enrol --from``).

    Raises:
        RecordingError, SensorError: the recording cannot be read or shows no gel (nothing written).
        DatasetError: the folder cannot be written, the recording does not follow ``plan``, or every
            prompt is cued after the recording's end.
    """
    motion = measure_motion(recording, sensor, on_progress)
    if not past_end:
        return write_dataset(out_dir, recording, plan, motion, sensor, inputs=inputs, strict=strict)
    end_us = max([int(motion.start_us), *motion.t_us[-1:].tolist(), *motion.frames_us[-1:].tolist()])
    within = tuple(p for p in plan.prompts if motion.start_us + int(round(p.cue_s * 1e6)) < end_us)
    if plan.prompts and not within:
        raise DatasetError(
            f"{recording}: every one of the plan's {len(plan.prompts)} prompts is cued after the recording's end "
            f"({(end_us - motion.start_us) / 1e6:.1f} s): was it made by following this plan? Nothing written"
        )
    labelled = write_dataset(
        out_dir, recording, Plan(within), motion, sensor, inputs=inputs, of=len(plan.prompts), strict=strict
    )
    return dataclasses.replace(labelled, past_end=len(plan.prompts) - len(within))


def write_dataset(
    out_dir: str | Path,
    recording: str | Path,
    plan: Plan,
    motion: GelMotion,
    sensor: SensorGeometry,
    *,
    inputs: Sequence[str | Path] = (),
    of: int | None = None,
    strict: bool = False,
) -> Labelled:
    """Label ``recording``, which the pipeline saw as ``motion``, from ``plan`` and write it as a
    dataset (docs/dataset.md) into ``out_dir`` (created): ``NAME.aedat4`` (a link to the
    recording, :func:`link_atomic`, unless it is there already), ``NAME.labels.csv``,
    ``NAME.plan.json`` and ``sensor.yaml`` (``sensor``), each through a temporary file renamed at
    the end. An output that is the recording or one of
    ``inputs`` (the plan and sensor files read) is not written: it already holds what it would.
    ``of``: the prompts of the whole plan when ``plan`` is its part cued within the recording
    (for the messages). A gesture that is not what its prompt asked is left out
    (:func:`check_gestures`). ``strict`` (a recording made elsewhere): the recording must follow
    ``plan``: at least one prompt, most of the gestures found what their prompts asked, and at
    least half the prompts labelled.

    Raises:
        DatasetError: the folder cannot be written; NoGestureError (a DatasetError): no prompt's
            gesture is found near its cue (the recording does not follow ``plan``; nothing
            written); NotFollowedError (a DatasetError): with ``strict``, the recording does not
            follow ``plan`` (nothing written).
    """
    from neurotouch_hid.enrolment.plan import write_plan

    recording = Path(recording)
    out = Path(out_dir)
    found = check_gestures(find_gestures(plan, motion), motion, sensor)
    if strict:
        _require_following(recording, found, of)
    if found and not any(f.seen for f in found):
        raise NoGestureError(
            f"{recording}: no gesture near any of "
            + (
                f"the plan's {len(found)} cues"
                if of is None or of == len(found)
                else f"the {len(found)} cues within it (of the plan's {of} prompts)"
            )
            + ": it does not follow this plan "
            "(record it while this plan's prompts are shown, from their start, or give the plan it followed "
            "with --plan); no dataset written"
        )
    rows = label_frames(motion, found, sensor.px_per_mm)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise DatasetError(f"{out}: cannot create the dataset folder: {exc.strerror}") from None
    name = recording.name.removesuffix(".aedat4")
    given = [recording, *(Path(p) for p in inputs)]

    def is_input(path: Path) -> bool:
        return path.exists() and any(p.exists() and os.path.samefile(path, p) for p in given)

    target = out / f"{name}.aedat4"
    kept = "in place"
    if not is_input(target):
        kept = link_atomic(recording, target)
    labels = out / f"{name}.labels.csv"
    if is_input(labels):
        raise DatasetError(f"{labels}: an input of this run: write the dataset elsewhere (--out)")
    tmp = temp_beside(labels)
    try:
        write_labels(tmp, rows)
        os.replace(tmp, labels)
    finally:
        tmp.unlink(missing_ok=True)
    if not is_input(out / f"{name}.plan.json"):
        write_plan(plan, out / f"{name}.plan.json")
    if not is_input(out / "sensor.yaml"):
        import yaml

        write_atomic(out / "sensor.yaml", yaml.safe_dump(sensor.to_dict(), sort_keys=False).encode())
    return Labelled(out, name, found, kept=kept)


def _require_following(recording: Path, found: Sequence[Found], of: int | None) -> None:
    """Raise NotFollowedError unless ``found`` (the prompts within ``recording``, of the plan's
    ``of``) shows a recording made by following its plan (:func:`write_dataset`)."""
    n = len(found)
    if n == 0:
        raise NotFollowedError(
            f"{recording}: the plan has no prompt"
            + (f" cued within the recording (of its {of})" if of else "")
            + ": nothing to label, no dataset written (give the plan the recording followed with --plan)"
        )
    seen = [f for f in found if f.seen]
    wrong = [f for f in seen if not f.labelled]
    labelled = len(seen) - len(wrong)
    if not seen or (len(wrong) * 2 <= len(seen) and labelled * 2 >= n):
        return  # no gesture at all: NoGestureError says so
    why = (
        f"{len(wrong)} of the {len(seen)} gestures found are not what their prompts asked"
        if len(wrong) * 2 > len(seen)
        else f"only {labelled} of the {n} prompts within it have the gesture asked"
    )
    left = [(i, f) for i, f in enumerate(found) if not f.labelled][:3]
    named = "; ".join(
        f"prompt {i + 1} ({f.prompt.name} at {f.prompt.cue_s:g} s): "
        + ((f.disagrees or "") if f.seen else "no gesture near its cue")
        for i, f in left
    )
    raise NotFollowedError(
        f"{recording}: it does not follow this plan: {why} ({'first ' if len(left) < n - labelled else ''}"
        f"left out: {named}); no dataset written. Record it while this plan's prompts are shown, from "
        "their start, or give the plan it followed with --plan"
    )


def link_atomic(source: Path, target: Path) -> str:
    """Put ``source`` at ``target`` without copying it, through a temporary name beside
    ``target`` renamed over it: a hard link (the same file under a second name: no space taken,
    and it outlives ``source``'s name being removed or replaced; recordings are written whole
    and renamed, never changed in place) where ``source`` is on ``target``'s file system, else a
    symbolic link to ``source``'s absolute path (the dataset then needs ``source`` where it is).

    Returns:
        ``"linked"`` or ``"referred"`` (the symbolic link).
    Raises:
        DatasetError (naming the files) when neither can be made."""
    tmp = temp_beside(target)
    tmp.unlink()  # a free name beside the target, for the link
    try:
        try:
            os.link(source, tmp, follow_symlinks=True)
            how = "linked"
        except OSError:  # another file system, or one without hard links
            os.symlink(Path(source).resolve(), tmp)
            how = "referred"
        os.replace(tmp, target)
        return how
    except OSError as exc:
        raise DatasetError(f"{target}: cannot link {source} there: {exc.strerror}") from None
    finally:
        tmp.unlink(missing_ok=True)


@dataclass(frozen=True)
class Agreement:
    """How far labels agree with reference labels (the simulator's own) on the frames further
    than a collar from every reference gesture's start or end.

    Attributes:
        frames: frames compared; gesture: share with the same type (``none`` included);
        contacts: share of the frames where both are the same gesture (not ``none``) with the
        same contact count; intensity_mae_mm: mean absolute intensity difference there (mm).
    """

    frames: int
    gesture: float
    contacts: float
    intensity_mae_mm: float


def agreement(reference: Sequence[LabelRow], labels: Sequence[LabelRow], collar_us: int = 100_000) -> Agreement:
    """Compare ``labels`` with ``reference`` frame by frame (same ``t_us``), leaving out frames
    within ``collar_us`` of a change of the reference's gesture type (a gesture's start or end).

    Raises ValueError when the two do not label the same frames."""
    ref_t = np.asarray([r.t_us for r in reference], dtype=np.int64)
    if len(ref_t) != len(labels) or np.any(ref_t != [r.t_us for r in labels]):
        raise ValueError("the labels and the reference do not label the same frames")
    kinds = [r.gesture for r in reference]
    changes = ref_t[1:][[a is not b for a, b in zip(kinds[:-1], kinds[1:])]]
    near = np.zeros(len(ref_t), dtype=bool)
    for c in changes.tolist():
        near |= np.abs(ref_t - c) <= collar_us
    same = both = count = 0
    diffs: list[float] = []
    for r, lab, skip in zip(reference, labels, near.tolist()):
        if skip:
            continue
        if r.gesture is lab.gesture:
            same += 1
            if r.gesture is not GestureType.NONE:
                both += 1
                count += r.n_contacts == lab.n_contacts
                diffs.append(abs(r.intensity_mm - lab.intensity_mm))
    n = int((~near).sum())
    return Agreement(n, same / n if n else 0.0, count / both if both else 0.0, float(np.mean(diffs)) if diffs else 0.0)
