"""How long a one-contact gesture stays undecided, and below which intensity an undecided window
answers its own type: onset latency against felt wrong types (docs/method.md, "Episode vote";
docs/lab/type-commitment.md).

    python3 docs/lab/type_commitment.py --out DIR [--families default,fingers,strong]
        [--first-finger-ms 0,40,70,90,110] [--provisional-mm 0,0.4] [--counted-mm inf,0.8]
        [--commit-mm inf,1,3] [--deadzone-mm 0.8]

``DIR`` is a ``benchmarks/family_eval.py --sessions`` folder (``DIR/FAMILY`` datasets, their
sensor.yaml with the family's creep). Each sequence is run once through the product's pipeline
with its episode vote taken out (each window's own type), into ``DIR/predictions/FAMILY/raw``;
those per-window answers are then replayed through :class:`EpisodeVote` with each undecided time,
provisional limit (0: an undecided window always answers ``none``) and limit from which a
committed window of several contacts votes twice (inf: every window once; the vote reads only each
window's type, intensity, contact count and time, so the replay is what the pipeline answers),
and depth from which one contact ends the wait at once (inf: never, the product's vote; a candidate
tried and not kept, docs/lab/type-commitment.md) and scored: the per-gesture metrics
(docs/dataset.md, the dead-zone latency among them) and the paper's per-window ones, and what the
wait costs a push where it is felt (:func:`push_waits_ms`), one markdown row per family and
candidate, then the mean over the families.
"""

from __future__ import annotations

import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import typer

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))  # workdir.py, a benchmark's helper
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
from neurotouch_hid.evaluation.felt import DEFAULT_DEADZONE_MM, gesture_spans  # noqa: E402
from neurotouch_hid.evaluation.metrics import Observations, align, evaluate  # noqa: E402
from neurotouch_hid.pipeline.episode import COUNTED_MM, EpisodeVote  # noqa: E402
from neurotouch_hid.pipeline.pipeline import GesturePipeline  # noqa: E402
from neurotouch_hid.sources.recording import RecordingReader  # noqa: E402
from neurotouch_hid.views.console import command_app  # noqa: E402

app = command_app()

#: Columns: label, key in the result (felt keys under "felt"), format.
COLUMNS = (
    ("gesture %", "gesture_accuracy", lambda v: f"{100 * v:.2f}"),
    ("count %", "contact_count_accuracy", lambda v: f"{100 * v:.2f}"),
    ("onset median ms", "onset_median_ms", lambda v: f"{v:.0f}"),
    ("onset p90 ms", "onset_p90_ms", lambda v: f"{v:.0f}"),
    ("never", "never_recognised", lambda v: f"{v:.2f}" if isinstance(v, float) else f"{v}"),
    ("changes", "type_changes_per_gesture", lambda v: f"{v:.2f}"),
    ("felt changes", "felt_type_changes_per_gesture", lambda v: f"{v:.2f}"),
    ("felt wrong %", "felt_wrong_share", lambda v: f"{100 * v:.1f}"),
    ("push wait median ms", "push_wait_median_ms", lambda v: f"{v:.0f}"),
    ("push wait max ms", "push_wait_max_ms", lambda v: f"{v:.0f}"),
    ("dead-zone latency median ms", "deadzone_latency_median_ms", lambda v: f"{v:.0f}"),
    ("dead-zone latency p90 ms", "deadzone_latency_p90_ms", lambda v: f"{v:.0f}"),
)


class WindowByWindow(GesturePipeline):
    """The product's pipeline without its episode vote: each window answers its own type."""

    def _vote(self, gesture: GestureType, intensity_mm: float, n_contacts: int, t_us: int) -> GestureType:
        return gesture


class DeepOneContact(EpisodeVote):
    """A candidate: one contact at ``commit_mm`` or more ends the wait at once (a fast push is
    deep long before the wait runs out; a lagging second finger lands whatever the first's depth)."""

    def __init__(self, commit_mm: float, **kwargs) -> None:
        self.commit_mm = commit_mm
        super().__init__(**kwargs)

    def update(self, gesture: GestureType, intensity_mm: float, n_contacts: int, t_us: int) -> GestureType:
        if (
            self._decision is None
            and gesture is not GestureType.NONE
            and n_contacts <= 1
            and n_contacts == self._count
            and intensity_mm >= self.commit_mm
        ):
            self._count_since_us = min(self._count_since_us, t_us - self.first_finger_us)
        return super().update(gesture, intensity_mm, n_contacts, t_us)


class WaitFromIntensity(DeepOneContact):
    """A candidate: one contact's wait counts from its first window at ``wait_from_mm`` or more
    instead of from its first window (a slow attack's first finger is long below any dead zone,
    which is when a lagging finger lands; 0: the product's vote)."""

    def __init__(self, commit_mm: float, wait_from_mm: float, **kwargs) -> None:
        self.wait_from_mm = wait_from_mm
        self._reached = False
        super().__init__(commit_mm, **kwargs)

    def update(self, gesture: GestureType, intensity_mm: float, n_contacts: int, t_us: int) -> GestureType:
        if gesture is GestureType.NONE or n_contacts != self._count:
            self._reached = False
        if self._decision is None and gesture is not GestureType.NONE and not self._reached:
            self._reached = intensity_mm >= self.wait_from_mm
            answer = super().update(gesture, intensity_mm, n_contacts, t_us)
            self._count_since_us = t_us  # the wait starts at the first window at wait_from_mm
            return answer
        return super().update(gesture, intensity_mm, n_contacts, t_us)


def raw_predictions(dataset: Path, dst: Path) -> None:
    """Each sequence of ``dataset`` through :class:`WindowByWindow`, into ``dst/NAME.jsonl``
    (kept: a sequence already there is not run again)."""
    sensor = SensorGeometry.load(dataset / "sensor.yaml")
    dst.mkdir(parents=True, exist_ok=True)
    for name in list_sequences(dataset):
        if (dst / f"{name}.jsonl").exists():
            continue
        with RecordingReader(dataset / f"{name}.aedat4") as reader:
            predictions = list(WindowByWindow(sensor).run(reader.stream()))
        write_predictions(dst / f"{name}.jsonl", predictions)


def push_waits_ms(labels: list, raw: list, voted: list, deadzone_mm: float) -> list[float]:
    """What the vote costs a push where it is felt: per labelled push gesture (docs/dataset.md's
    spans), ms from its first window answered with any type at ``deadzone_mm`` or more without
    the vote (``raw``) to its first window answered push at ``deadzone_mm`` or more with it
    (``voted``); pushes that reach the dead zone in neither are left out."""
    waits = []
    for gesture, t0, t1 in gesture_spans(labels):
        if gesture is not GestureType.PUSH:
            continue
        span = [(r, v) for r, v in zip(raw, voted) if t0 <= r.t_us < t1 + 40_000 and r.intensity_mm >= deadzone_mm]
        first_raw = next((r.t_us for r, _ in span if r.gesture is not GestureType.NONE), None)
        first_push = next((v.t_us for _, v in span if v.gesture is GestureType.PUSH), None)
        if first_raw is not None and first_push is not None:
            waits.append((first_push - first_raw) / 1000)
    return waits


def replay(
    dataset: Path,
    raw: Path,
    first_finger_us: int,
    provisional_mm: float,
    deadzone_mm: float,
    counted_mm: float = COUNTED_MM,
    commit_mm: float = float("inf"),
    wait_from_mm: float = 0.0,
) -> dict:
    """The per-window answers of ``raw`` through ``EpisodeVote(first_finger_us, provisional_mm=...,
    counted_mm=...)``, scored; with the median and longest :func:`push_waits_ms` (NaN without a push)."""
    sensor = SensorGeometry.load(dataset / "sensor.yaml")
    parts, waits = [], []
    for name in list_sequences(dataset):
        vote = WaitFromIntensity(
            commit_mm,
            wait_from_mm,
            first_finger_us=first_finger_us,
            provisional_mm=provisional_mm,
            counted_mm=counted_mm,
        )
        answers = read_predictions(raw / f"{name}.jsonl")
        voted = [replace(p, gesture=vote.update(p.gesture, p.intensity_mm, p.n_contacts, p.t_us)) for p in answers]
        labels = read_labels(dataset / f"{name}.labels.csv")
        pressed = read_pressed(dataset / f"{name}.pressed.csv")  # felt wrong from the last finger's 0.3 mm
        parts.append(align(labels, voted, sensor, deadzone_mm, pressed=pressed))
        waits += push_waits_ms(labels, answers, voted, deadzone_mm)
    result = evaluate(Observations.concatenate(parts)).to_dict()
    nan = float("nan")
    result["push_wait_median_ms"] = float(np.median(waits)) if waits else nan
    result["push_wait_max_ms"] = float(np.max(waits)) if waits else nan
    return {**result, **result["felt"]}


@app.command()
def main(
    out: Path = typer.Option(..., "--out", help="a family_eval --sessions folder"),
    families: str = typer.Option("default,fingers,strong", "--families"),
    first_finger_ms: str = typer.Option("0,40,70,90,110", "--first-finger-ms", help="undecided times to compare"),
    provisional_mm: str = typer.Option(
        "0,0.4", "--provisional-mm", help="provisional limits to compare (mm; 0: undecided is none)"
    ),
    counted_mm: str = typer.Option(
        f"{COUNTED_MM:g}",
        "--counted-mm",
        help="limits from which a committed window of several contacts votes twice (mm; inf: never)",
    ),
    commit_mm: str = typer.Option(
        "inf", "--commit-mm", help="depths from which one contact ends the wait at once (mm; inf: never)"
    ),
    deadzone_mm: float = typer.Option(DEFAULT_DEADZONE_MM, "--deadzone-mm", min=0.0),
    wait_from_mm: str = typer.Option("0", "--wait-from-mm", help="intensities from which the wait counts (mm)"),
) -> None:
    names = families_in(out, families)
    candidates = [
        (int(t * 1000), p, c, d, w)
        for t in numbers(first_finger_ms, "--first-finger-ms", finite=True)
        for p in numbers(provisional_mm, "--provisional-mm", finite=True)
        for c in numbers(counted_mm, "--counted-mm")
        for d in numbers(commit_mm, "--commit-mm")
        for w in numbers(wait_from_mm, "--wait-from-mm", finite=True)
    ]
    head = "| family | undecided ms | provisional mm | counted mm | one contact commits at mm | wait from mm | "
    print(head + " | ".join(c[0] for c in COLUMNS) + " |")
    print("| --- | ---: | ---: | ---: | ---: | ---: |" + " ---: |" * len(COLUMNS))
    rows: dict[tuple, list[dict]] = {c: [] for c in candidates}
    for fam in names:
        raw = out / "predictions" / fam / "raw"
        raw_predictions(out / fam, raw)
        for t, p, c, d, w in candidates:
            row = replay(out / fam, raw, t, p, deadzone_mm, c, d, w)
            rows[t, p, c, d, w].append(row)
            cells = " | ".join(f(row[k]) for _, k, f in COLUMNS)
            print(f"| {fam} | {t // 1000} | {p:g} | {c:g} | {d:g} | {w:g} | {cells} |", flush=True)
    for t, p, c, d, w in candidates:
        mean = {k: float(np.nanmean([r[k] for r in rows[t, p, c, d, w]])) for _, k, _ in COLUMNS}
        cells = " | ".join(f(mean[k]) for _, k, f in COLUMNS)
        print(f"| mean | {t // 1000} | {p:g} | {c:g} | {d:g} | {w:g} | {cells} |")


if __name__ == "__main__":
    app()
