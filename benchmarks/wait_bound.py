"""What a one-contact wait can do at best on game sessions: felt wrong types against the dead-zone
latency for a detector that sees every finger the instant the gel under it has moved.

    python3 benchmarks/wait_bound.py --out DIR --seed SEED [--families fingers,late]
        [--visible-mm 0.1,0.3] [--wait-ms 40,60,90,120,150,200] [--deadzone-mm 0.8]

DIR is a ``family_eval.py --sessions`` working folder made with ``--seed SEED`` (each family's
game sessions under ``DIR/FAMILY``, ``uUSER_sessionK.*``). Each session's gestures are drawn again
from the simulator with that seed (:class:`GelSimulator`, as ``simulate --preset sessions``), and
each finger's displacement is the simulator's truth at the gel point under its centre, every 1 ms
(``gel.deform``, the labels' own intensity: their mean over the fingers; the script stops
with a usage error when that mean differs from a labelled frame's intensity by more than 0.05 mm
+ 1 %, i.e. when the seed is not the folder's).

The ideal detector (docs/method.md, "Episode vote"): a finger is seen once its displacement has
reached ``--visible-mm`` (its own, plus the others' tails at its centre, so seen no later than
its own press shows); the intensity of one contact is the displacement of the deepest finger.
For each wait W it answers, per gesture:

- *from the first finger* (the product's rule): nothing until the first finger is seen + W; then,
  while it is the only one seen, push. A gesture of two or three fingers whose second finger is
  seen later than that, and whose first finger reaches ``--deadzone-mm`` before the second is
  seen, is felt wrong; a gesture is answered with its type once its second finger is seen (a
  push: at first seen + W; a gesture of several fingers whose second is never seen: missed).
- *from the dead zone*: push answered W after the deepest finger reaches the dead zone (every
  push's dead-zone latency is then W); felt wrong as above.

Dead-zone latency as docs/dataset.md defines it, from the labelled intensity's crossing (1 ms
resolution, no window grid, no tracker lag): the figures are lower bounds on what any detector of
that rule measures on these sessions (docs/lab/type-commitment.md).
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import typer
from workdir import families_in, numbers, usage_error

from neurotouch_hid.core.dataset import list_sequences, read_labels
from neurotouch_hid.core.estimate import GestureType
from neurotouch_hid.core.sensor import SensorGeometry
from neurotouch_hid.evaluation.felt import DEFAULT_DEADZONE_MM
from neurotouch_hid.sources.gel import deform
from neurotouch_hid.sources.hands import SESSION_STREAM, SIM_GESTURES, USERS
from neurotouch_hid.sources.physics import PHYSICS
from neurotouch_hid.sources.simulator import GelSimulator
from neurotouch_hid.views.console import command_app

app = command_app()

#: The labels' intensity and the reconstruction's may differ by rounding (labels.csv: 4 decimals)
#: and by the simulator's float32 steps: by at most MATCH_MM + MATCH_SHARE x the intensity.
MATCH_MM, MATCH_SHARE = 0.05, 0.01
SESSION_NAME = re.compile(r"u(\d+)_session(\d+)")


@dataclass
class Gesture:
    """One drawn gesture, on a 1 ms grid from its start.

    Attributes:
        kind: its type. fingers_mm: (T, K) float64 each finger's displacement (mm).
        label_mm: (T,) float64 the labels' intensity (the mean over the fingers, mm).
    """

    kind: GestureType
    fingers_mm: np.ndarray
    label_mm: np.ndarray


def first_at(values: np.ndarray, at_least: float) -> int | None:
    """The first ms (index) at which ``values`` (T,) float64 reaches ``at_least``, or None."""
    hit = np.flatnonzero(values >= at_least)
    return int(hit[0]) if len(hit) else None


def session_gestures(dataset: Path, name: str, family: str, seed: int) -> list[Gesture]:
    """The gestures of session ``name`` of ``dataset`` (``uUSER_sessionK``), drawn again.

    Raises:
        typer.Exit: (a usage error) the name is not a session's, or the drawn gestures' intensity
            differs from the labels' (not the folder's seed).
    """
    match = SESSION_NAME.fullmatch(name)
    if match is None:
        usage_error(f"{dataset / name}: not a game session (family_eval.py --sessions names them uUSER_sessionK)")
    user, k = int(match[1]), int(match[2])
    sensor = SensorGeometry.load(dataset / "sensor.yaml")
    sim = GelSimulator(
        sensor,
        USERS[user],
        SIM_GESTURES,
        seed=seed,
        stream_seed=(user, SESSION_STREAM + k),
        physics=PHYSICS[family],
        hand="session",
    )
    labels = read_labels(dataset / f"{name}.labels.csv")
    drawn = sim._gestures_between(0, labels[-1].t_us)  # the simulator's own draw, as it performs them
    out = []
    for g in drawn:
        t_us = np.arange(g.t_start_us, g.t_end_us, 1000, dtype=np.int64)
        at = deform(drawn, g.fingers_mm, np.concatenate([[g.t_start_us], t_us]), sensor.gel_radius_mm, sim.physics)[0]
        fingers = np.linalg.norm(at[1:] - at[0], axis=-1)
        out.append(Gesture(g.gesture, fingers, fingers.mean(axis=1)))
        rows = [r for r in labels if r.gesture is g.gesture and g.t_start_us <= r.t_us < g.t_end_us]
        times = np.array([g.t_start_us] + [r.t_us for r in rows], dtype=np.int64)
        at = deform(drawn, g.fingers_mm, times, sensor.gel_radius_mm, sim.physics)[0]
        drawn_mm = np.linalg.norm(at[1:] - at[0], axis=-1).mean(axis=1)
        labelled = np.array([r.intensity_mm for r in rows])
        if not rows or (np.abs(drawn_mm - labelled) > MATCH_MM + MATCH_SHARE * labelled).any():
            usage_error(f"{dataset / name}: the gestures drawn with seed {seed} are not the labels' (--seed)")
    return out


def bound(gestures: list[Gesture], visible_mm: float, wait_ms: int, from_deadzone: bool, deadzone_mm: float) -> dict:
    """The ideal detector's figures over ``gestures`` (module docstring): ``felt_wrong`` (share,
    0..1), ``missed`` (gestures past the dead zone never answered), the dead-zone latency's
    ``median`` and ``p90`` over all gestures and ``push_p90`` over the pushes (ms, 1 ms
    resolution; NaN when there is none). ``visible_mm`` and ``deadzone_mm`` in mm, ``wait_ms`` in ms;
    ``from_deadzone``: the wait counts from the deepest finger's crossing of the dead zone instead
    of from the first finger seen."""
    wrong, missed, latencies, pushes = 0, 0, [], []
    for g in gestures:
        seen = sorted(
            t for t in (first_at(g.fingers_mm[:, k], visible_mm) for k in range(g.fingers_mm.shape[1])) if t is not None
        )
        deepest = g.fingers_mm.max(axis=1)
        if from_deadzone:
            start = first_at(deepest, deadzone_mm)
        else:
            start = seen[0] if seen else None
        second = seen[1] if len(seen) > 1 else None
        if g.kind is GestureType.PUSH:
            answer = start + wait_ms if start is not None else None
        elif second is not None and (start is None or second <= start + wait_ms):
            answer = second
        else:
            end = second if second is not None else len(deepest)
            if start is not None and deepest[start + wait_ms : end].max(initial=0.0) >= deadzone_mm:
                wrong += 1
            answer = second
        crossing = first_at(g.label_mm, deadzone_mm)
        if crossing is not None and answer is None:
            missed += 1
        elif crossing is not None:
            latencies.append(max(answer, crossing) - crossing)
            if g.kind is GestureType.PUSH:
                pushes.append(latencies[-1])
    return {
        "felt_wrong": wrong / len(gestures),
        "missed": missed,
        "median": float(np.median(latencies)) if latencies else float("nan"),
        "p90": float(np.percentile(latencies, 90)) if latencies else float("nan"),
        "push_p90": float(np.percentile(pushes, 90)) if pushes else float("nan"),
    }


@app.command()
def main(
    out: Path = typer.Option(..., "--out", help="a family_eval.py --sessions working folder"),
    seed: int = typer.Option(..., "--seed", help="the seed the folder's sessions were made with"),
    families: str = typer.Option("fingers,late", "--families", help="comma-separated"),
    visible_mm: str = typer.Option("0.1,0.3", "--visible-mm", help="displacements (mm) at which a finger is seen"),
    wait_ms: str = typer.Option("40,60,90,120,150,200", "--wait-ms", help="one-contact waits (ms)"),
    deadzone_mm: float = typer.Option(DEFAULT_DEADZONE_MM, "--deadzone-mm", min=0.0),
) -> None:
    names = families_in(out, families)
    seen_at = numbers(visible_mm, "--visible-mm", finite=True)
    waits = [int(w) for w in numbers(wait_ms, "--wait-ms", finite=True)]
    gestures = {
        fam: [g for s in list_sequences(out / fam) for g in session_gestures(out / fam, s, fam, seed)] for fam in names
    }
    print(
        "| family | gestures | finger seen at mm | wait counted from | wait ms | felt wrong % "
        "| dead-zone latency median / p90 ms | pushes' p90 ms | missed |"
    )
    print("| --- | ---: | ---: | --- | ---: | ---: | ---: | ---: | ---: |")
    for fam in names:
        for v in seen_at:
            for from_deadzone in (False, True):
                for w in waits:
                    r = bound(gestures[fam], v, w, from_deadzone, deadzone_mm)
                    where = "the dead zone" if from_deadzone else "the first finger"
                    print(
                        f"| {fam} | {len(gestures[fam])} | {v:g} | {where} | {w} | {100 * r['felt_wrong']:.1f} | "
                        f"{r['median']:.0f} / {r['p90']:.0f} | {r['push_p90']:.0f} | {r['missed']} |"
                    )


if __name__ == "__main__":
    app()
