"""Where the creeping gels' wrong windows are, and what the creep filter's release rule and its
calibrated creep can do about them (docs/accuracy.md, "A second simulator's sessions and
multi-finger starts"; docs/method.md, "Creep").

    python3 docs/lab/creep_release.py --out DIR [--families viscoelastic,compound,compound2]
        [--margins 0,0.1,0.2]

``DIR`` is a ``benchmarks/family_eval.py --sessions`` folder (each family's sessions and its
sensor.yaml with the creep calibrated on ``DIR/presses/FAMILY``). Each sequence is run once through
the product's pipeline, recording per window what its episode vote is given, the gesture step's
answer before the creep filter, and every step of the filter (the gel's amplitude in px it is
given, time, the intensity's share of it, and whether it read the fingers gone). Printed per family:

* **where the wrong windows are**: the product's windows scored for type (outside the 40 ms
  collar, under the 0.3 mm rule: ``benchmarks/felt_rules.py``) whose answer is not the label's,
  by where in the labelled gesture (its first 300 ms, its last 200 ms, after it) and why (the gel
  read still or at rest, the creep filter reading the fingers gone, the vote, a gesture answered
  where the label says ``none``);
* **release rules replayed**: the filter's steps run again with each load margin (``--margins``,
  ``creep.LOAD_MARGIN`` the product's) and with the gel's own creep (the family's q and tau,
  ``sources/physics.py``) in place of the calibrated one; a window the replayed filter no longer
  reads gone answers the gesture step's own answer, one it newly reads gone ``none`` (the tail
  watch, ``creep.TailWatch``, is not replayed); then the episode vote and the scores: gesture under
  the 0.3 mm rule, felt wrong, dead-zone latency p90, false activations;
* **the calibration**: ``fit_creep`` on the family's press (``DIR/presses/FAMILY/u5_push``) from the
  tracked amplitude (what ``calibrate --press`` does), from the simulator's true marker positions
  (``u5_push.markers.npz``), and from the tracked amplitude of the hold alone (no released part).
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

import numpy as np
import typer

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))  # felt_rules.py, workdir.py
from felt_rules import family_figures  # noqa: E402
from workdir import families_in, numbers  # noqa: E402

from neurotouch_hid.calibration.measure import PRESS_MARKERS, press_amplitude  # noqa: E402
from neurotouch_hid.core.dataset import (  # noqa: E402
    labels_at,
    list_sequences,
    read_labels,
    read_pressed,
    write_predictions,
)
from neurotouch_hid.core.estimate import GestureEstimate, GestureType  # noqa: E402
from neurotouch_hid.core.sensor import SensorGeometry  # noqa: E402
from neurotouch_hid.evaluation.felt import FRAME_PERIOD_US, gesture_spans, pressed_at  # noqa: E402
from neurotouch_hid.evaluation.metrics import TYPE_COLLAR_US, Observations, align, evaluate, outside_collar  # noqa: E402
from neurotouch_hid.pipeline import creep  # noqa: E402
from neurotouch_hid.pipeline.episode import EpisodeVote  # noqa: E402
from neurotouch_hid.pipeline.pipeline import GesturePipeline  # noqa: E402
from neurotouch_hid.sources.physics import PHYSICS  # noqa: E402
from neurotouch_hid.sources.recording import RecordingReader  # noqa: E402
from neurotouch_hid.views.console import command_app  # noqa: E402

app = command_app()
NONE = GestureType.NONE


class Recorded(GesturePipeline):
    """The product's pipeline, keeping per window the gesture step's answer before the creep
    filter, the filter's steps and what the episode vote is given."""

    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self.windows: list[dict] = []
        self._window: dict = {"steps": []}
        if self._creep is not None:
            inner, outer = self._creep, self

            class Watched(type(inner)):
                def update(self, deformation: float, t_us: int) -> float:
                    outer._window["steps"].append((float(deformation), int(t_us), self.floor))
                    return super().update(deformation, t_us)

                def released(self, load: float, scale: float = 1.0) -> bool:
                    gone = super().released(load, scale)
                    outer._window["gone"] = bool(gone)
                    outer._window["scale"] = float(scale)
                    return gone

            inner.__class__ = Watched

    def _contacts_and_gesture(self, rest_px, current, valid):
        contacts, result = super()._contacts_and_gesture(rest_px, current, valid)
        self._window.setdefault("fit", (result.gesture, float(result.intensity_mm), len(contacts.points_px)))
        return contacts, result

    def _vote(self, gesture: GestureType, intensity_mm: float, n_contacts: int, t_us: int) -> GestureType:
        self._window["vote"] = (gesture, float(intensity_mm), int(n_contacts), int(t_us))
        self.windows.append(self._window)
        self._window = {"steps": []}
        return super()._vote(gesture, intensity_mm, n_contacts, t_us)


def record(dataset: Path) -> dict[str, tuple[list[dict], list[GestureEstimate]]]:
    """Per sequence of ``dataset``: its :class:`Recorded` windows and the pipeline's estimates."""
    sensor = SensorGeometry.load(dataset / "sensor.yaml")
    out = {}
    for name in list_sequences(dataset):
        pipeline = Recorded(sensor)
        with RecordingReader(dataset / f"{name}.aedat4") as reader:
            estimates = list(pipeline.run(reader.stream()))
        if len(pipeline.windows) != len(estimates):
            raise RuntimeError(f"{dataset / name}: {len(pipeline.windows)} votes for {len(estimates)} windows")
        out[name] = (pipeline.windows, estimates)
    return out


def scored(dataset: Path, name: str, estimates: list[GestureEstimate]) -> np.ndarray:
    """(W,) bool: the windows scored for type (outside the collar, under the 0.3 mm rule)."""
    labels = read_labels(dataset / f"{name}.labels.csv")
    pressed = read_pressed(dataset / f"{name}.pressed.csv")
    t = np.array([e.t_us for e in estimates], dtype=np.int64)
    label_t = np.array([row.t_us for row in labels], dtype=np.int64)
    kinds = np.array([list(GestureType).index(row.gesture) for row in labels], dtype=np.int64)
    keep = outside_collar(label_t, kinds, t, TYPE_COLLAR_US)
    for _kind, t0, t1 in gesture_spans(labels):
        at = pressed_at(pressed, t0, t1)
        if at is not None:
            keep &= ~((t >= t0) & (t < min(at, t1 + FRAME_PERIOD_US)))
    return keep & np.array([truth is not None for truth in labels_at(labels, t)])


def where_wrong(dataset: Path, recorded: dict) -> dict[tuple[str, str], int]:
    """The product's wrong scored windows counted by (where, why) (module docstring)."""
    counts: dict[tuple[str, str], int] = {}
    for name, (windows, estimates) in recorded.items():
        labels = read_labels(dataset / f"{name}.labels.csv")
        spans = gesture_spans(labels)
        t = np.array([e.t_us for e in estimates], dtype=np.int64)
        truth = labels_at(labels, t)
        for k in np.flatnonzero(scored(dataset, name, estimates)):
            label = truth[k].gesture
            if estimates[k].gesture is label:
                continue
            inside = [(t0, t1) for _g, t0, t1 in spans if t0 <= t[k] <= t1]
            if not inside:
                where = "outside a labelled gesture"
            elif t[k] - inside[0][0] <= 300_000 and inside[0][1] - t[k] > 200_000:
                where = "first 300 ms"
            elif inside[0][1] - t[k] <= 200_000:
                where = "last 200 ms"
            else:
                where = "held"
            w = windows[k]
            if label is NONE:
                why = "a gesture where the label says none"
            elif w["vote"][0] is not NONE:
                why = "the vote"
            elif w.get("gone"):
                why = "the creep filter read the fingers gone"
            else:
                why = "read still or at rest"
            counts[where, why] = counts.get((where, why), 0) + 1
    return counts


def replayed(dataset: Path, recorded: dict, share: float, time_s: float, margin: float) -> dict:
    """The filter's steps with (``share``, ``time_s``, ``margin``), then the vote, scored."""
    sensor = SensorGeometry.load(dataset / "sensor.yaml")
    tmp = Path(tempfile.mkdtemp(prefix="creep_release_"))
    parts = []
    for name, (windows, estimates) in recorded.items():
        model, vote, answers = None, EpisodeVote(), []
        for w, e in zip(windows, estimates):
            gesture, intensity, n, t = w["vote"]
            load = None
            for deformation, t_us, floor in w["steps"]:
                if model is None:
                    model = creep.CreepFilter(share, time_s, floor=floor, margin=margin)
                model.floor = floor
                load = model.update(deformation, t_us)
            if "gone" in w and load is not None:
                scale = w.get("scale", 1.0)
                gone = model.released(load * scale, scale)
                if gone and not w["gone"]:
                    gesture, intensity, n = NONE, 0.0, 0
                elif w["gone"] and not gone:
                    gesture, intensity, n = w["fit"]
            answers.append(
                GestureEstimate(
                    t_us=e.t_us,
                    gesture=vote.update(gesture, intensity, n, t),
                    resting=e.resting,
                    intensity_mm=e.intensity_mm,
                    contacts_px=e.contacts_px,
                    contacts_mm=e.contacts_mm,
                )
            )
        write_predictions(tmp / f"{name}.jsonl", answers)
        labels = read_labels(dataset / f"{name}.labels.csv")
        parts.append(align(labels, answers, sensor, 0.8, pressed=read_pressed(dataset / f"{name}.pressed.csv")))
    felt = evaluate(Observations.concatenate(parts)).to_dict()["felt"]
    rule = family_figures(dataset, tmp, 0.8)["gesture_rule"]
    return {"rule": rule, **felt}


def calibrations(press: Path, sensor: SensorGeometry) -> list[tuple[str, float, float, float]]:
    """(source, q, tau s, misfit share of the elastic gel's) of the best creep model on the press."""
    t, tracked = press_amplitude(press.with_suffix(".aedat4"), sensor)
    truth = np.load(press.with_suffix(".markers.npz"))
    moved = np.hypot(*(truth["positions_px"] - truth["rest_px"][None]).transpose(2, 0, 1))
    true_amplitude = np.interp(t, truth["t_us"], np.sort(moved, axis=1)[:, -PRESS_MARKERS:].mean(axis=1))
    rows = []
    for source, amplitude, hold_only in (
        ("tracked (calibrate --press)", tracked, False),
        ("true markers", true_amplitude, False),
        ("tracked, hold alone", tracked, True),
    ):
        cost = creep.creep_misfit(t, amplitude) if not hold_only else _hold_misfit(t, amplitude)
        i, j = np.unravel_index(np.argmin(cost), cost.shape)
        rows.append((source, float(creep.SHARES[i]), float(creep.TIMES_S[j]), float(cost[i, j] / cost[0, 0])))
    return rows


def _hold_misfit(t_us: np.ndarray, amplitude: np.ndarray) -> np.ndarray:
    """:func:`creep.creep_misfit` without its released part: the load's spread over the hold."""
    pressed = amplitude >= creep.PRESS_FRACTION * amplitude.max()
    hold = np.zeros(len(amplitude), dtype=bool)
    bounds = np.concatenate(([0], np.flatnonzero(np.diff(pressed.astype(np.int8))) + 1, [len(amplitude)]))
    for start, stop in zip(bounds[:-1], bounds[1:]):
        if pressed[start]:
            hold |= (t_us >= t_us[start] + creep.HOLD_AFTER_US) & (t_us <= t_us[stop - 1] - creep.HOLD_BEFORE_US)
    q, tau = np.meshgrid(creep.SHARES, creep.TIMES_S, indexing="ij")
    load = creep.load_estimate(amplitude, t_us, q, tau)[hold]
    return ((load - np.median(load, axis=0)) ** 2).sum(axis=0)


@app.command()
def main(
    out: Path = typer.Option(..., "--out", help="a family_eval --sessions folder"),
    families: str = typer.Option("viscoelastic,compound,compound2", "--families"),
    margins: str = typer.Option("0,0.1,0.2", "--margins", help="load margins to replay (share of q y)"),
) -> None:
    for fam in families_in(out, families):
        dataset = out / fam
        sensor = SensorGeometry.load(dataset / "sensor.yaml")
        if sensor.creep is None:
            print(f"{fam}: no creep in {dataset / 'sensor.yaml'}, nothing to replay")
            continue
        recorded = record(dataset)
        counts = where_wrong(dataset, recorded)
        print(f"## {fam} (calibrated creep q {sensor.creep[0]:g}, tau {sensor.creep[1]:.3f} s)\n")
        print(f"Wrong windows scored for type: {sum(counts.values())}")
        for (where, why), n in sorted(counts.items(), key=lambda kv: -kv[1]):
            print(f"- {n}: {where}, {why}")
        physics = PHYSICS[fam]
        print("\n| creep | margin | gesture, 0.3 mm rule | felt wrong | dead-zone p90 ms | false activations |")
        print("| --- | ---: | ---: | ---: | ---: | ---: |")
        models = [("calibrated", *sensor.creep, m) for m in numbers(margins, "--margins", finite=True)]
        models.append(("the gel's own", physics.creep, physics.creep_s, creep.LOAD_MARGIN))
        for label, share, time_s, margin in models:
            r = replayed(dataset, recorded, share, time_s, margin)
            print(
                f"| {label} (q {share:g}, tau {time_s:.3f} s) | {margin:g} | {100 * r['rule']:.2f} % | "
                f"{100 * r['felt_wrong_share']:.1f} % | {r['deadzone_latency_p90_ms']:.0f} | "
                f"{r['false_activations']} |",
                flush=True,
            )
        press = out / "presses" / fam / "u5_push"
        if press.with_suffix(".markers.npz").exists():
            print("\n| press amplitude | q | tau s | misfit / elastic |\n| --- | ---: | ---: | ---: |")
            for source, share, time_s, ratio in calibrations(press, SensorGeometry.load(press.parent / "sensor.yaml")):
                print(f"| {source} | {share:.2f} | {time_s:.3f} | {ratio:.2f} |")
        print(flush=True)


if __name__ == "__main__":
    app()
