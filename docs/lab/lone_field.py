"""Whether a lone contact's field tells one finger from a first finger with another arriving, and
what ending the one-contact wait sooner on it trades (docs/lab/type-commitment.md, "A lone
contact's field: the gel moving against its drag").

    python3 docs/lab/lone_field.py --out DIR [--families fingers,late,starts]
        [--leads-ms 10,20] [--quiet-mm 0.05,0.1,0.15] [--deadzone-mm 0.8]

``DIR`` is a ``benchmarks/family_eval.py --sessions`` folder with the product's predictions of
method ``ours`` (or ``--method``). Each sequence is run once through the product's pipeline,
keeping per window what its episode vote is given (type, intensity mm, contact count, time) and,
for a window of one contact, how far the gel moves against that contact's drag
(``counter_drag.counter_drag_mm``, mm), into ``DIR/predictions/FAMILY/lone_field/NAME.npz``
(kept: not run again). Those inputs are replayed through :class:`EpisodeVote` with the field
unread and with each lead (``quiet_lead_us``) and threshold (``quiet_mm``); the answers replace
the method's predictions window by window (the replay of the field unread gives the method's own
figures back). Printed per family and candidate: felt wrong, the dead-zone latency p90, false
activations, and the gesture type outside the collar under the 0.3 mm rule
(``benchmarks/felt_rules.py``). Then every window where the shortest lead with no threshold would
commit a lone contact before the wait ends: family, sequence, time, the labelled gesture, when the
gel under its last finger moved 0.3 mm (ms after that window; ``tog``: fingers together),
the intensity and the counter-motion (mm).
"""

from __future__ import annotations

import dataclasses
import math
import sys
from pathlib import Path

import numpy as np
import typer

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))  # workdir.py, felt_rules.py
from felt_rules import family_figures  # noqa: E402
from workdir import families_in, numbers  # noqa: E402

from neurotouch_hid.core.dataset import (  # noqa: E402
    list_sequences,
    read_labels,
    read_predictions,
    read_pressed,
    write_predictions,
)
from neurotouch_hid.core.estimate import GestureType  # noqa: E402
from neurotouch_hid.core.sensor import SensorGeometry  # noqa: E402
from neurotouch_hid.evaluation.felt import DEFAULT_DEADZONE_MM, gesture_records, gesture_spans, pressed_at  # noqa: E402
from neurotouch_hid.pipeline.episode import EpisodeVote  # noqa: E402
from neurotouch_hid.pipeline.pipeline import GesturePipeline  # noqa: E402
from neurotouch_hid.sources.recording import RecordingReader  # noqa: E402
from neurotouch_hid.views.console import command_app  # noqa: E402

app = command_app()
TYPES = list(GestureType)


class Recorded(GesturePipeline):
    """The product's pipeline, keeping its vote's inputs and every lone contact's counter-motion."""

    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self.rows: list[tuple] = []

    def _vote(self, gesture: GestureType, intensity_mm: float, n_contacts: int, t_us: int) -> GestureType:
        counter = self._counter_drag() if n_contacts == 1 and gesture is not GestureType.NONE else math.nan
        self.rows.append((TYPES.index(gesture), float(intensity_mm), int(n_contacts), int(t_us), counter))
        return super()._vote(gesture, intensity_mm, n_contacts, t_us)


def record(dataset: Path, dst: Path) -> None:
    """Each sequence of ``dataset`` through :class:`Recorded` into ``dst/NAME.npz``."""
    sensor = SensorGeometry.load(dataset / "sensor.yaml")
    dst.mkdir(parents=True, exist_ok=True)
    for name in list_sequences(dataset):
        if (dst / f"{name}.npz").exists():
            continue
        pipeline = Recorded(sensor)
        with RecordingReader(dataset / f"{name}.aedat4") as reader:
            n = sum(1 for _ in pipeline.run(reader.stream()))
        a = np.array(pipeline.rows, dtype=np.float64).reshape(-1, 5)
        if len(a) > n:
            raise RuntimeError(f"{dataset / name}: {len(a)} votes for {n} windows")
        np.savez(
            dst / f"{name}.npz",
            kind=a[:, 0].astype(np.int64),
            intensity=a[:, 1],
            contacts=a[:, 2].astype(np.int64),
            t_us=a[:, 3].astype(np.int64),
            counter=a[:, 4],
        )


class Early(EpisodeVote):
    """The vote, noting each window where a lone contact was committed before ``first_finger_us``."""

    def __init__(self, **kwargs) -> None:
        super().__init__(**kwargs)
        self.early: list[int] = []

    def _vote(self, gesture: GestureType, intensity_mm: float, n_contacts: int, t_us: int) -> GestureType:
        before = self._decision
        answer = super()._vote(gesture, intensity_mm, n_contacts, t_us)
        if before is None and self._decision is not None and n_contacts <= 1:
            if t_us - self._trusted_since_us < self.first_finger_us:
                self.early.append(t_us)
        return answer


def replay(x: dict, vote: EpisodeVote, preds: list) -> list:
    """``preds`` with the recorded vote inputs ``x`` answered by ``vote`` (counter-motion passed)."""
    at = {p.t_us: i for i, p in enumerate(preds)}
    out = list(preds)
    for k, i, n, t, c in zip(x["kind"], x["intensity"], x["contacts"], x["t_us"], x["counter"]):
        answer = vote.update(TYPES[k], float(i), int(n), int(t), float(c) if np.isfinite(c) else math.inf)
        out[at[int(t)]] = dataclasses.replace(out[at[int(t)]], gesture=answer)
    return out


@app.command()
def main(
    out: Path = typer.Option(..., "--out", help="a family_eval --sessions folder"),
    families: str = typer.Option("fingers,late,starts", "--families"),
    method: str = typer.Option("ours", "--method", help="the product's predictions in that folder"),
    leads_ms: str = typer.Option("10,20", "--leads-ms"),
    quiet_mm: str = typer.Option("0.05,0.1,0.15", "--quiet-mm"),
    deadzone_mm: float = typer.Option(DEFAULT_DEADZONE_MM, "--deadzone-mm", min=0.0),
) -> None:
    leads = [int(v * 1000) for v in numbers(leads_ms, "--leads-ms", finite=True)]
    cands = [("unread", dict(quiet_lead_us=0))] + [
        (f"{lead // 1000} ms below {q:g} mm", dict(quiet_lead_us=lead, quiet_mm=q))
        for lead in leads
        for q in numbers(quiet_mm, "--quiet-mm", finite=True)
    ]
    probe = dict(quiet_lead_us=min(leads), quiet_mm=math.inf)
    windows = []
    for fam in families_in(out, families, method):
        src = out / "predictions" / fam / "lone_field"
        record(out / fam, src)
        print(f"{fam}:")
        for label, kwargs in cands:
            felt, lat, false = [], [], 0
            dst = out / "predictions" / fam / "lone_field" / "replayed"
            dst.mkdir(exist_ok=True)
            for name in list_sequences(out / fam):
                x = dict(np.load(src / f"{name}.npz"))
                preds = replay(
                    x, EpisodeVote(**kwargs), read_predictions(out / "predictions" / fam / method / f"{name}.jsonl")
                )
                labels = read_labels(out / fam / f"{name}.labels.csv")
                pressed = read_pressed(out / fam / f"{name}.pressed.csv")
                rec = gesture_records(labels, preds, deadzone_mm, pressed)
                felt.append(rec.felt_wrong)
                lat.append(rec.deadzone_latency_ms)
                false += rec.false_activations
                write_predictions(dst / f"{name}.jsonl", preds)
            f, la = np.concatenate(felt), np.concatenate(lat)
            p90 = np.percentile(la[np.isfinite(la)], 90)
            rule = family_figures(out / fam, dst, deadzone_mm)["gesture_rule"]
            print(
                f"  {label}: felt wrong {f.sum()} of {len(f)}, dead-zone p90 {p90:.1f} ms, "
                f"false activations {false}, gesture (0.3 mm rule) {100 * rule:.2f} %"
            )
        for name in list_sequences(out / fam):
            x = dict(np.load(src / f"{name}.npz"))
            vote = Early(**probe)
            replay(x, vote, read_predictions(out / "predictions" / fam / method / f"{name}.jsonl"))
            labels = read_labels(out / fam / f"{name}.labels.csv")
            pressed = read_pressed(out / fam / f"{name}.pressed.csv")
            row = {int(t): j for j, t in enumerate(x["t_us"])}
            for t in vote.early:
                span = [(g, t0, t1) for g, t0, t1 in gesture_spans(labels) if t0 - 50_000 <= t <= t1]
                g, last = (span[0][0].value, pressed_at(pressed, span[0][1], span[0][2])) if span else ("rest", None)
                when = "tog" if last is None else f"{(last - t) / 1000:+.0f}"
                j = row[t]
                windows.append((fam, name, t / 1e6, g, when, x["intensity"][j], x["counter"][j]))
    print("windows a lone contact would be committed one lead sooner (push first, by counter-motion):")
    for w in sorted(windows, key=lambda w: (w[3] == "push", -w[6])):
        print(f"  {w[0]} {w[1]} {w[2]:.2f} s {w[3]} (last finger {w[4]} ms): {w[5]:.2f} mm, counter {w[6]:.3f} mm")


if __name__ == "__main__":
    app()
