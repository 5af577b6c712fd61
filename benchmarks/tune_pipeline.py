"""Tune the gesture pipeline's hyperparameters on a simulated tuning set (grid search).

The tuning set and the test set never share a simulated user or a seed (docs/accuracy.md):

    python3 benchmarks/tune_pipeline.py --out DIR                 # simulate + grid search
    python3 benchmarks/tune_pipeline.py --out DIR --grid r_px=25,30,35 --grid a=0.4,0.6

For each combination of the grid, every sequence of the tuning set runs through
:class:`~neurotouch_hid.pipeline.pipeline.GesturePipeline` and is scored with the paper's
metrics (:func:`~neurotouch_hid.evaluation.runner.evaluate_dataset`). Combinations are ranked by
:func:`score`, the mean of each headline metric's ratio to its target; the table is printed with
rich and written to ``DIR/tuning.json``. The best combination's ``--set`` options are printed
for ``neurotouch-hid eval`` on the test set.
"""

from __future__ import annotations

import dataclasses
import itertools
import json
from pathlib import Path
from typing import Optional

import typer
from rich.console import Console
from rich.progress import Progress
from rich.table import Table

from neurotouch_hid.evaluation.metrics import EvaluationResult
from neurotouch_hid.evaluation.runner import evaluate_dataset, pipeline_config

#: Seeds of the tuning and test sets. The simulator's ``paper`` preset simulates its tuning
#: users (5-9, ``simulator.TUNING_USERS``) for an odd seed and its test users (0-4,
#: ``simulator.TEST_USERS``) for an even seed, so tuning never sees a test user or seed.
TUNING_SEED = 1
TEST_SEED = 2

#: Targets of docs/accuracy.md: (metric, target, higher is better).
TARGETS = (
    ("gesture_accuracy", 0.95, True),
    ("contact_count_accuracy", 0.90, True),
    ("contact_distance_mm", 2.5, False),
    ("intensity_mae_mm", 0.7, False),
    ("resting_f1", 0.97, True),
)

DEFAULT_GRID = ("r_px=25,30,35", "a=0.4,0.6,0.8", "n_min=3,4")

console = Console()


def score(result: EvaluationResult) -> float:
    """Mean over :data:`TARGETS` of value/target (higher-is-better metrics) or target/value
    (errors), each capped at 1.2 so that one metric far past its target cannot hide another
    missing it. 1.0 means every target just met."""
    ratios = []
    for name, target, higher in TARGETS:
        value = getattr(result, name)
        if value != value:  # NaN: metric undefined, worst
            ratios.append(0.0)
            continue
        ratio = value / target if higher else target / max(value, 1e-9)
        ratios.append(min(ratio, 1.2))
    return sum(ratios) / len(ratios)


def parse_grid(items: list[str]) -> dict[str, list[str]]:
    """``NAME=V1,V2,...`` strings -> {NAME: [V1, V2, ...]} (values validated by pipeline_config)."""
    grid: dict[str, list[str]] = {}
    for item in items:
        name, _, values = item.partition("=")
        grid[name.strip()] = [v.strip() for v in values.split(",") if v.strip()]
        for value in grid[name.strip()]:
            pipeline_config([f"{name}={value}"])  # raises NeurotouchError on a bad name or value
    return grid


def simulate(out: Path, seed: int, minutes: Optional[float]) -> Path:
    """The simulated dataset (paper preset) of a seed, reused when already written."""
    from neurotouch_hid.sources.simulator import write_dataset

    if not (out / "sensor.yaml").exists():
        write_dataset(out, preset="paper", seed=seed, minutes=minutes)
    return out


def main(
    out: Path = typer.Option(..., "--out", help="folder for the tuning set and tuning.json"),
    grid: list[str] = typer.Option(list(DEFAULT_GRID), "--grid", help="NAME=V1,V2,... (a PipelineConfig field)"),
    minutes: Optional[float] = typer.Option(6.0, "--minutes", help="simulated minutes of the tuning set"),
    jobs: int = typer.Option(2, "--jobs", help="sequences in parallel processes"),
) -> None:
    """Simulate the tuning set, grid-search PipelineConfig, print the ranking and the best --set."""
    from neurotouch_hid.sources.simulator import preset_users

    if set(preset_users("paper", TUNING_SEED)) & set(preset_users("paper", TEST_SEED)):
        raise SystemExit("the tuning and test sets must not share users")
    tuning = simulate(out / "tuning", TUNING_SEED, minutes)
    axes = parse_grid(grid)
    rows = []
    combos = list(itertools.product(*axes.values()))
    with Progress(console=console, transient=True) as progress:
        task = progress.add_task(f"{len(combos)} combinations", total=len(combos))
        for combo in combos:
            settings = [f"{k}={v}" for k, v in zip(axes, combo)]
            result = evaluate_dataset(tuning, pipeline_config(settings), jobs=jobs)
            rows.append({"settings": settings, "score": score(result),
                         **{name: getattr(result, name) for name, _, _ in TARGETS}})
            progress.advance(task)
    rows.sort(key=lambda r: -r["score"])
    table = Table(title=f"Grid search on {tuning} (users {preset_users('paper', TUNING_SEED)}, seed {TUNING_SEED})")
    for col in ("settings", "score", *(name for name, _, _ in TARGETS)):
        table.add_column(col, justify="left" if col == "settings" else "right")
    for r in rows:
        table.add_row(" ".join(r["settings"]), f"{r['score']:.3f}",
                      *(f"{r[name]:.4f}" for name, _, _ in TARGETS))
    console.print(table)
    best = rows[0]
    (out / "tuning.json").write_text(json.dumps({
        "tuning_users": preset_users("paper", TUNING_SEED), "tuning_seed": TUNING_SEED, "minutes": minutes,
        "defaults": dataclasses.asdict(pipeline_config()), "rows": rows}, indent=1, default=str))
    console.print("best: " + " ".join(f"--set {s}" for s in best["settings"]))


if __name__ == "__main__":
    typer.run(main)
