"""What a gesture does through a profile: wrong outputs per gesture, outputs at rest.

    python3 benchmarks/profile_felt.py --out DIR --method NAME [--families default,late,...]
        [--profiles default,switch-access,...]

DIR is a ``family_eval.py`` working folder (each family's dataset under ``DIR/FAMILY``, a
method's predictions under ``DIR/predictions/FAMILY/NAME``), typically made with ``--sessions``.
docs/dataset.md's per-gesture metrics judge the answer against one dead zone; a user feels it
through a profile, whose dead zones, press thresholds, dwells and smoothing differ per output.
This replays each sequence's predictions through each shipped profile's mapper
(``mapping/replay.py``, as ``profile test`` does) and counts, per profile and family:

* **wrong output**: the gestures during which an output of another type went active (an axis left
  its neutral value; a button, key or mouse button went down; relative motion), from the
  gesture's first labelled frame until 300 ms after its last or the next gesture's first,
  whichever is sooner. An output already active before (a toggle left on) did not go active. An
  output's types are found by probing the profile: each gesture type alone (a push in eight
  directions), its intensity ramped to 6 mm over 200 ms and held 700 ms, one or two contacts at
  the gel's centre; an output that a type's probe sets active is that type's. Outputs of inputs
  that follow every type (``intensity``, ``contact``) are every type's, so never wrong;
* **missed**: among the gestures for which the labels, replayed as answers (:func:`ideal_estimates`),
  change the state of one of the gesture type's own outputs, those for which the predictions
  change none (a profile's press threshold or dwell that the gesture itself never meets is no miss);
* **went active at rest**: windows 300 ms or more from every labelled frame of a gesture (the
  false activations' margin, docs/dataset.md, "Per-gesture metrics") in which an output went active.
"""

from __future__ import annotations

import math
from collections import Counter
from pathlib import Path

import numpy as np
import typer
from workdir import families_in, usage_error

from neurotouch_hid.controller import AXES, ControllerState
from neurotouch_hid.dataset import labels_at, list_sequences, read_labels, read_predictions
from neurotouch_hid.errors import DatasetError, ProfileError
from neurotouch_hid.estimate import GESTURE_ORDER, GestureEstimate, GestureType
from neurotouch_hid.evaluation.felt import REST_MARGIN_US, gesture_spans
from neurotouch_hid.mapping.profile import DPAD, Profile, load_profile, shipped_profiles_dir
from neurotouch_hid.mapping.replay import pressed, replay
from neurotouch_hid.output.console import command_app
from neurotouch_hid.sensor import SensorGeometry

app = command_app()

#: After a gesture's last labelled frame, its outputs are its own this long (us): the answer
#: outlasts the fingers while the gel relaxes, longest on a creeping gel (docs/method.md, "Creep";
#: measured: up to ~240 ms), and the rest margin of the false activations is as long.
TAIL_US = 300_000
#: The windows of the probe and of the labels' replay (us); the probe's intensity is ramped to
#: PROBE_MM over PROBE_RAMP_US, then held.
PROBE_MM = 6.0
PROBE_RAMP_US = 200_000
PROBE_HOLD_US = 700_000
WINDOW_US = 10_000


def active_outputs(state: ControllerState) -> set[str]:
    """The outputs of ``state`` away from neutral: its buttons, d-pad directions and keys down
    (``replay.pressed``), its other axes off centre (evdev names) and its relative motion."""
    hats = {axis for axis, _ in DPAD.values()}
    axes = {name for name, (_, _, neutral) in AXES.items() if name not in hats and state.axes[name] != neutral}
    return set(pressed(state)) | axes | {name for name, count in state.rel.items() if count}


def _probe(gesture: GestureType, direction_rad: float) -> list[GestureEstimate]:
    """One gesture type alone at the gel's centre, ramped to PROBE_MM and held (10 ms windows)."""
    n_contacts = 1 if gesture is GestureType.PUSH else 2
    contacts = np.zeros((n_contacts, 2)) + (np.array([[0.0, 0.0], [8.0, 0.0]])[:n_contacts])
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


def outputs_by_type(profile: Profile) -> dict[GestureType, set[str]]:
    """Each gesture type's outputs through ``profile``: those its probe sets active (module docstring)."""
    found: dict[GestureType, set[str]] = {}
    for gesture in GESTURE_ORDER:
        if gesture is GestureType.NONE:
            continue
        angles = [k * math.pi / 4 for k in range(8)] if gesture is GestureType.PUSH else [0.0]
        found[gesture] = set()
        for angle in angles:
            for state in replay(profile, _probe(gesture, angle)):
                found[gesture] |= active_outputs(state)
    return found


def ideal_estimates(labels, times: np.ndarray, geometry: SensorGeometry) -> list[GestureEstimate]:
    """What a pipeline without error would answer at ``times`` (us): each window the most recent
    labelled frame's type, resting flag, intensity and contact points (``labels_at``), a push's
    direction the labelled contacts' mean shift (user mm) since the gesture's first frame."""
    out = []
    start = None
    for t_us, row in zip(times, labels_at(labels, times)):
        if row is None or row.gesture is GestureType.NONE:
            out.append(GestureEstimate(t_us=int(t_us), resting=row is None or row.resting))
            start = None
            continue
        contacts = geometry.image_to_user(row.contacts_px) if row.n_contacts else np.zeros((0, 2))
        if start is None or start[0] is not row.gesture:
            start = (row.gesture, contacts.mean(axis=0) if len(contacts) else np.zeros(2))
        shift = (contacts.mean(axis=0) if len(contacts) else np.zeros(2)) - start[1]
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


def edges(profile: Profile, estimates: list[GestureEstimate]) -> tuple[list[set[str]], list[set[str]]]:
    """Per window, the outputs that went active and those that changed state (either way) since
    the window before, through a fresh mapper of ``profile``."""
    went, changed, before = [], [], set()
    for state in replay(profile, estimates):
        now = active_outputs(state)
        went.append(now - before)
        changed.append(now ^ before)
        before = now
    return went, changed


def tally(profile: Profile, own: dict[GestureType, set[str]], labels, predictions, geometry) -> Counter:
    """Over one sequence: gestures; wrong (an output of another type went active during the
    gesture); missed (an output of its own type changed state in the ideal replay, none in the
    predictions'); ideal (gestures whose ideal replay changes an output of their own); rest
    windows; rest windows in which an output went active."""
    t = Counter()
    times = np.array([p.t_us for p in predictions], dtype=np.int64)
    went, changed = edges(profile, predictions)
    # the labels' replay on its own 10 ms grid, so that a sequence answered sparsely (or not at
    # all) is still judged against every gesture its labels hold
    grid = np.arange(labels[0].t_us, labels[-1].t_us + TAIL_US, WINDOW_US, dtype=np.int64) if labels else times
    _, ideal_changed = edges(profile, ideal_estimates(labels, grid, geometry))
    spans = gesture_spans(labels)
    for k, (kind, t0, t1) in enumerate(spans):
        end = t1 + TAIL_US if k + 1 == len(spans) else min(t1 + TAIL_US, spans[k + 1][1])
        lo, hi = np.searchsorted(times, t0), np.searchsorted(times, end)
        others = set().union(*(outs for g, outs in own.items() if g is not kind)) - own[kind]
        ideal_span = ideal_changed[np.searchsorted(grid, t0) : np.searchsorted(grid, end)]
        ideal = bool(set().union(*ideal_span) & own[kind])
        t["gestures"] += 1
        t["wrong"] += bool(set().union(*went[lo:hi]) & others)
        t["ideal"] += ideal
        t["missed"] += ideal and not set().union(*changed[lo:hi]) & own[kind]
    for when, outs in zip(times, went):
        if all(when < t0 - REST_MARGIN_US or when > t1 + REST_MARGIN_US for _, t0, t1 in spans):
            t["rest"] += 1
            t["rest_active"] += bool(outs)
    return t


@app.command()
def main(
    out: Path = typer.Option(..., "--out", help="family_eval.py working folder"),
    method: str = typer.Option(..., "--method", help="the method whose predictions to replay"),
    families: str = typer.Option("", "--families", help="comma-separated (default: every family of --out)"),
    profiles: str = typer.Option(
        "", "--profiles", help="comma-separated shipped profile names or profile files (default: every shipped one)"
    ),
) -> None:
    names = [p.strip() for p in profiles.split(",") if p.strip()] or sorted(
        p.stem for p in shipped_profiles_dir().glob("*.yaml")
    )
    loaded = {name: _shipped_or_path(name) for name in names}
    owned = {name: outputs_by_type(profile) for name, profile in loaded.items()}
    chosen = families_in(out, families, method)
    geometry = {family: SensorGeometry.load(out / family / "sensor.yaml") for family in chosen}
    print("| profile | family | gestures | wrong output | missed (of those the labels move) | went active at rest |")
    print("| --- | --- | ---: | ---: | ---: | ---: |")
    for name, profile in loaded.items():
        total = Counter()
        for family in chosen:
            t = Counter()
            for seq in list_sequences(out / family):
                try:
                    labels = read_labels(out / family / f"{seq}.labels.csv")
                    predictions = read_predictions(out / "predictions" / family / method / f"{seq}.jsonl")
                except DatasetError as exc:
                    usage_error(str(exc))
                t += tally(profile, owned[name], labels, predictions, geometry[family])
            total += t
            print(_row(name, family, t))
        print(_row(name, f"**all {len(chosen)}**", total))


def _shipped_or_path(name: str) -> Profile:
    """A shipped profile by name (never the user's copy of it: the figures are the shipped
    file's), else a profile file's path; a usage error when neither loads."""
    shipped = shipped_profiles_dir() / f"{name}.yaml"
    try:
        return load_profile(shipped if shipped.is_file() else name)
    except ProfileError as exc:
        usage_error(str(exc))


def _row(profile: str, family: str, t: Counter) -> str:
    return (
        f"| {profile} | {family} | {t['gestures']} | {t['wrong']} | {t['missed']} of {t['ideal']} | "
        f"{t['rest_active']} of {t['rest']} |"
    )


if __name__ == "__main__":
    app()
