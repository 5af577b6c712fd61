"""The per-gesture figures of game sessions pooled over several seeds, and how far one seed's
dead-zone latency p90 can be from the pooled one.

    python3 benchmarks/felt_pooled.py --out DIR --out DIR2 [...] --method NAME
        [--families default,strong,...] [--deadzone-mm 0.8] [--resamples 2000] [--seed 0]

Each DIR is a ``family_eval.py --sessions`` working folder (each family's game sessions under
``DIR/FAMILY``, a method's predictions under ``DIR/predictions/FAMILY/NAME``), typically the same
users with another ``--seed``. Per family present in every folder (or those named), one markdown
row: the gestures, felt wrong, felt type changes per gesture, the dead-zone latency median and
p90 (docs/dataset.md, "Per-gesture metrics"; ``neurotouch_hid.evaluation.felt``), gestures missed
above the dead zone and false activations, all over the pooled gestures; then each folder's own
p90, and the 5-95 % range of the p90 over ``--resamples`` draws of as many sessions as one folder
has, with replacement, from the pooled ones (a session is the unit: its gestures share a user and
a seed). A p90 target read on one folder lies within that range by chance alone.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import typer
from workdir import families_in, usage_error

from neurotouch_hid.core.dataset import list_sequences, read_labels, read_predictions
from neurotouch_hid.evaluation.felt import DEFAULT_DEADZONE_MM, FeltRecords, gesture_records, summarise
from neurotouch_hid.views.console import command_app

app = command_app()


def session_records(out: Path, family: str, method: str, deadzone_mm: float) -> list[FeltRecords]:
    """One :class:`FeltRecords` per sequence of ``out/family`` with ``method``'s predictions."""
    folder = out / "predictions" / family / method
    return [
        gesture_records(
            read_labels(out / family / f"{name}.labels.csv"), read_predictions(folder / f"{name}.jsonl"), deadzone_mm
        )
        for name in list_sequences(out / family)
    ]


def p90_range(sessions: list[FeltRecords], draw: int, resamples: int, rng: np.random.Generator) -> tuple[float, float]:
    """The 5th and 95th percentiles (ms) of the dead-zone latency p90 over ``resamples`` sets of
    ``draw`` sessions drawn with replacement from ``sessions``; NaN when no draw has a latency."""
    p90s = []
    for _ in range(resamples):
        picked = FeltRecords.concatenate([sessions[i] for i in rng.integers(len(sessions), size=draw)])
        p90 = summarise(picked).deadzone_latency_p90_ms
        if not np.isnan(p90):
            p90s.append(p90)
    if not p90s:
        return float("nan"), float("nan")
    return float(np.percentile(p90s, 5)), float(np.percentile(p90s, 95))


def family_row(family: str, per_folder: list[list[FeltRecords]], resamples: int, rng: np.random.Generator) -> str:
    """The markdown row of one family (see the module docstring)."""
    pooled = summarise(FeltRecords.concatenate([r for folder in per_folder for r in folder]))
    own = " / ".join(
        f"{summarise(FeltRecords.concatenate(folder)).deadzone_latency_p90_ms:.0f}" for folder in per_folder
    )
    sessions = [r for folder in per_folder for r in folder]
    low, high = p90_range(sessions, max(len(f) for f in per_folder), resamples, rng)
    return (
        f"| {family} | {pooled.n_gestures} | {100 * pooled.felt_wrong_share:.1f} % "
        f"| {pooled.felt_type_changes_per_gesture:.2f} "
        f"| {pooled.deadzone_latency_median_ms:.0f} / {pooled.deadzone_latency_p90_ms:.0f} | {own} "
        f"| {low:.0f}-{high:.0f} | {pooled.missed_above_deadzone} "
        f"| {pooled.false_activations} of {pooled.n_rest} |"
    )


@app.command()
def main(
    out: list[Path] = typer.Option(..., help="family_eval.py --sessions folders, one per seed (repeatable)"),
    method: str = typer.Option(..., help="the method's name in those folders"),
    families: str = typer.Option("", help="comma-separated families (default: those of every folder)"),
    deadzone_mm: float = typer.Option(DEFAULT_DEADZONE_MM, min=0.0, help="dead zone of the felt figures (mm)"),
    resamples: int = typer.Option(2000, min=1, max=100_000, help="draws for the p90's range"),
    seed: int = typer.Option(0, min=0, help="seed of the draws"),
) -> None:
    chosen = [families_in(folder, families, method) for folder in out]
    common = [f for f in chosen[0] if all(f in c for c in chosen[1:])]
    if not common:
        usage_error("the folders have no family in common with predictions of method " + repr(method))
    rng = np.random.default_rng(seed)
    print(
        "| family | gestures | felt wrong | felt changes | dead-zone latency median / p90 ms "
        "| p90 per folder ms | p90 of one folder's size, 5-95 % | missed | false activations |"
    )
    print("| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |")
    for family in common:
        per_folder = [session_records(folder, family, method, deadzone_mm) for folder in out]
        print(family_row(family, per_folder, resamples, rng), flush=True)


if __name__ == "__main__":
    app()
