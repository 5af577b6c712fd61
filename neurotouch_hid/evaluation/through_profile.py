"""What a sequence's answers do through a profile: wrong outputs, missed gestures, outputs at rest.

docs/dataset.md, "Through a profile", defines the counts. The per-gesture metrics (:mod:`.felt`)
judge the answer against one dead zone; a user feels it through a profile, whose dead zones, press
thresholds, dwells and smoothing differ per output. :func:`tally` replays one sequence's
predictions through a fresh mapper of the profile (:func:`~neurotouch_hid.mapping.replay.replay`,
as ``profile test`` does) and counts, per gesture (:func:`.felt.gesture_spans`):

* **wrong output**: an output of another type went active (an axis left its neutral value; a
  button, d-pad direction, key or mouse button went down; relative motion) from the gesture's
  first labelled frame until :data:`TAIL_US` after its last or the next gesture's first, whichever
  is sooner. An output already active before (a toggle left on) did not go active. Which type owns
  which output is found by probing the profile (:func:`outputs_by_type`); outputs of inputs that
  follow every type (``intensity``, ``contact``) are every type's, so never wrong;
* **missed**: among the gestures for which the labels, replayed as answers
  (:func:`ideal_estimates`), change the state of one of the gesture type's own outputs, those for
  which the predictions change none (a press threshold or dwell that the gesture itself never
  meets is no miss);
* **went active at rest**: predictions at rest (:func:`.felt.at_rest`: the false activations'
  windows) in which an output went active.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields
from typing import Sequence

import numpy as np

from neurotouch_hid.core.controller import AXES, ControllerState
from neurotouch_hid.core.dataset import LabelRow, labels_at
from neurotouch_hid.core.estimate import GESTURE_ORDER, GestureEstimate, GestureType
from neurotouch_hid.core.sensor import SensorGeometry
from neurotouch_hid.evaluation.felt import at_rest, gesture_spans
from neurotouch_hid.mapping.profile import DPAD, Profile
from neurotouch_hid.mapping.replay import pressed, replay

#: After a gesture's last labelled frame its outputs stay its own this long (us): the answer
#: outlasts the fingers while the gel relaxes, longest on a creeping gel (docs/method.md, "Creep";
#: measured: up to ~240 ms), and the rest margin of the false activations is as long.
TAIL_US = 300_000
#: The probe's intensity is ramped to PROBE_MM (mm) over PROBE_RAMP_US (us), then held
#: PROBE_HOLD_US (us), in windows of WINDOW_US (us); the labels' replay uses the same windows.
PROBE_MM = 6.0
PROBE_RAMP_US = 200_000
PROBE_HOLD_US = 700_000
WINDOW_US = 10_000


@dataclass
class ProfileTally:
    """The counts of one profile over one or more sequences (add tallies with ``+``).

    Attributes:
        gestures: labelled gestures.
        wrong: gestures during which an output of another type went active.
        ideal: gestures whose labels, replayed as answers, change an output of their own type.
        missed: those of ``ideal`` whose predictions change none of their type's outputs.
        rest: predictions at rest (:func:`.felt.at_rest`).
        rest_active: those of them in which an output went active.
    """

    gestures: int = 0
    wrong: int = 0
    ideal: int = 0
    missed: int = 0
    rest: int = 0
    rest_active: int = 0

    def __add__(self, other: "ProfileTally") -> "ProfileTally":
        """Both tallies' counts added."""
        return ProfileTally(**{f.name: getattr(self, f.name) + getattr(other, f.name) for f in fields(self)})

    def to_dict(self) -> dict:
        """The counts by name (JSON-able ints)."""
        return asdict(self)


@dataclass(frozen=True)
class ProfileUnderTest:
    """A profile and the outputs each gesture type owns through it (:func:`outputs_by_type`).

    Attributes:
        name: how the user named it (a profile name or a file's path), for the report.
        profile: the loaded profile (:func:`~neurotouch_hid.mapping.profile.load_profile`).
        outputs: per gesture type other than ``none``, the names of its outputs (evdev names).
    """

    name: str
    profile: Profile
    outputs: dict[GestureType, frozenset[str]]

    @classmethod
    def probe(cls, name: str, profile: Profile) -> "ProfileUnderTest":
        """``profile`` under ``name``, its outputs found by :func:`outputs_by_type`."""
        return cls(name, profile, outputs_by_type(profile))


def active_outputs(state: ControllerState) -> set[str]:
    """The outputs of ``state`` away from neutral (evdev names): its buttons, d-pad directions and
    keys down (:func:`~neurotouch_hid.mapping.replay.pressed`), its other axes off centre and its
    relative motion."""
    hats = {axis for axis, _ in DPAD.values()}
    axes = {name for name, (_, _, neutral) in AXES.items() if name not in hats and state.axes[name] != neutral}
    return set(pressed(state)) | axes | {name for name, count in state.rel.items() if count}


def _probe(gesture: GestureType, direction_rad: float) -> list[GestureEstimate]:
    """One gesture type alone at the gel's centre, ramped to PROBE_MM and held (WINDOW_US windows);
    a push towards ``direction_rad`` (user frame), the other types with two contacts 8 mm apart."""
    n_contacts = 1 if gesture is GestureType.PUSH else 2
    contacts = np.array([[0.0, 0.0], [8.0, 0.0]])[:n_contacts]
    direction = np.array([math.cos(direction_rad), math.sin(direction_rad)])
    out = []
    for t in range(WINDOW_US, PROBE_RAMP_US + PROBE_HOLD_US + 1, WINDOW_US):
        mm = PROBE_MM * min(1.0, t / PROBE_RAMP_US)
        out.append(
            GestureEstimate(
                t_us=t,
                gesture=gesture,
                resting=False,
                intensity_mm=mm,
                contacts_px=contacts.copy(),
                contacts_mm=contacts.copy(),
                translation_mm=direction * mm if gesture is GestureType.PUSH else np.zeros(2),
            )
        )
    return out


def outputs_by_type(profile: Profile) -> dict[GestureType, frozenset[str]]:
    """Each gesture type's outputs through ``profile``: those that its probe sets active, each type
    alone at the gel's centre, ramped to 6 mm over 200 ms and held 700 ms (a push in eight
    directions).

    Returns:
        Per gesture type other than ``none``, the evdev names of its outputs.
    """
    found: dict[GestureType, frozenset[str]] = {}
    for gesture in GESTURE_ORDER:
        if gesture is GestureType.NONE:
            continue
        angles = [k * math.pi / 4 for k in range(8)] if gesture is GestureType.PUSH else [0.0]
        seen: set[str] = set()
        for angle in angles:
            for state in replay(profile, _probe(gesture, angle)):
                seen |= active_outputs(state)
        found[gesture] = frozenset(seen)
    return found


def ideal_estimates(labels: Sequence[LabelRow], times: np.ndarray, geometry: SensorGeometry) -> list[GestureEstimate]:
    """What a pipeline without error would answer at ``times``: each window the label at its time
    (:func:`~neurotouch_hid.core.dataset.labels_at`: the most recent labelled frame's type, resting flag
    and contact count, the intensity and contact points interpolated), a push's direction the
    labelled contacts' mean shift (user frame, mm) since the gesture's first frame.

    Args:
        labels: the sequence's label rows, ordered by time.
        times: (W,) int64 window times (us), increasing.
        geometry: the dataset's sensor geometry (image px -> user mm).
    """
    out = []
    start = None
    for t_us, row in zip(times, labels_at(labels, times)):
        if row is None or row.gesture is GestureType.NONE:
            out.append(GestureEstimate(t_us=int(t_us), resting=row is None or row.resting))
            start = None
            continue
        contacts = geometry.image_to_user(row.contacts_px) if row.n_contacts else np.zeros((0, 2))
        centre = contacts.mean(axis=0) if len(contacts) else np.zeros(2)
        if start is None or start[0] is not row.gesture:
            start = (row.gesture, centre)
        shift = centre - start[1]
        norm = float(np.hypot(*shift))
        out.append(
            GestureEstimate(
                t_us=int(t_us),
                gesture=row.gesture,
                resting=row.resting,
                intensity_mm=row.intensity_mm,
                contacts_px=row.contacts_px,
                contacts_mm=contacts,
                translation_mm=shift / norm * row.intensity_mm if norm > 0 else np.zeros(2),
            )
        )
    return out


def _edges(profile: Profile, estimates: Sequence[GestureEstimate]) -> tuple[list[set[str]], list[set[str]]]:
    """Per window, the outputs that went active and those that changed state (either way) since
    the window before, through a fresh mapper of ``profile``."""
    went, changed, before = [], [], set()
    for state in replay(profile, estimates):
        now = active_outputs(state)
        went.append(now - before)
        changed.append(now ^ before)
        before = now
    return went, changed


def tally(
    tested: ProfileUnderTest,
    labels: Sequence[LabelRow],
    predictions: Sequence[GestureEstimate],
    geometry: SensorGeometry,
) -> ProfileTally:
    """The counts of one sequence through one profile (module docstring; docs/dataset.md,
    "Through a profile").

    Args:
        tested: the profile and its outputs per type.
        labels: the sequence's label rows, ordered by time.
        predictions: its predictions, ordered by time.
        geometry: the dataset's sensor geometry (the labels' contact points, image px -> user mm).
    """
    own = tested.outputs
    t = ProfileTally()
    times = np.array([p.t_us for p in predictions], dtype=np.int64)
    went, changed = _edges(tested.profile, predictions)
    # the labels' replay on its own grid, so that a sequence answered sparsely (or not at all) is
    # still judged against every gesture its labels hold
    grid = np.arange(labels[0].t_us, labels[-1].t_us + TAIL_US, WINDOW_US, dtype=np.int64) if labels else times
    _, ideal_changed = _edges(tested.profile, ideal_estimates(labels, grid, geometry))
    spans = gesture_spans(labels)
    for k, (kind, t0, t1) in enumerate(spans):
        end = t1 + TAIL_US if k + 1 == len(spans) else min(t1 + TAIL_US, spans[k + 1][1])
        lo, hi = np.searchsorted(times, t0), np.searchsorted(times, end)
        others = set().union(*(outs for g, outs in own.items() if g is not kind)) - own[kind]
        ideal = bool(set().union(*ideal_changed[np.searchsorted(grid, t0) : np.searchsorted(grid, end)]) & own[kind])
        t.gestures += 1
        t.wrong += bool(set().union(*went[lo:hi]) & others)
        t.ideal += ideal
        t.missed += ideal and not set().union(*changed[lo:hi]) & own[kind]
    rest = at_rest(labels, times)
    t.rest = int(rest.sum())
    t.rest_active = sum(bool(outs) for outs, r in zip(went, rest) if r)
    return t
