"""The ``neurotouch-hid`` command (typer).

Each command is a thin layer: it parses options, calls one function of the stage it belongs to,
and prints. Heavy modules (numba, OpenCV, dv-processing) are imported inside the commands so
``--help`` stays fast. Every :class:`~neurotouch_hid.errors.NeurotouchError` becomes one clear
line on stderr and exit code 2 (see :func:`main`).
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Optional

import typer
from rich.console import Console

from neurotouch_hid.errors import NeurotouchError

app = typer.Typer(
    name="neurotouch-hid",
    help="NeuroTouch soft tactile sensor -> standard game controller.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)
profile_app = typer.Typer(help="List, show, create, edit, validate, test and tune gamepad profiles.", no_args_is_help=True)
app.add_typer(profile_app, name="profile")

console = Console()
err_console = Console(stderr=True)


def _todo(name: str) -> None:
    raise NeurotouchError(f"'{name}' is not built yet")


# --- recordings (sources/recording.py) ------------------------------------------------------
@app.command()
def info(
    recording: Path = typer.Argument(..., help="AEDAT4 recording"),
    json_out: bool = typer.Option(False, "--json", help="print JSON instead of a table"),
) -> None:
    """Print a recording's camera name, resolution, duration, event count and frame count."""
    _todo("info")


# --- the simulated gel (sources/simulator.py) ----------------------------------------------
@app.command()
def simulate(
    out: Path = typer.Option(..., "--out", help="dataset folder to write (DATASET.md)"),
    preset: str = typer.Option("quick", "--preset", help="quick (small, for tests) or paper (5 users x 5 gestures x ~1 min)"),
    seed: int = typer.Option(0, "--seed", help="random seed: the same seed gives the same files"),
    minutes: Optional[float] = typer.Option(None, "--minutes", help="override the total simulated duration (minutes)"),
) -> None:
    """Simulate the NeuroTouch gel and write a labelled dataset (DATASET.md)."""
    _todo("simulate")


# --- the pipeline (pipeline/) ---------------------------------------------------------------
@app.command()
def track(
    recording: Path = typer.Argument(..., help="AEDAT4 recording"),
    out: Path = typer.Option(..., "--out", help="predictions, JSON lines (DATASET.md)"),
    sensor: Optional[Path] = typer.Option(None, "--sensor", help="sensor.yaml (default: the one beside the recording)"),
    window_us: int = typer.Option(10_000, "--window-us", help="window length in microseconds (>= 1000)"),
    markers: Optional[Path] = typer.Option(None, "--markers", help="also write tracked marker positions (.npz)"),
) -> None:
    """Run the gesture pipeline on a recording and write one prediction per window."""
    _todo("track")


@app.command("eval")
def eval_cmd(
    dataset: Path = typer.Argument(..., help="dataset folder (DATASET.md)"),
    report: Optional[Path] = typer.Option(None, "--report", help="write PNG figures and a Markdown summary here"),
    json_out: Optional[Path] = typer.Option(None, "--json", help="write the metrics as JSON"),
    window_us: Optional[int] = typer.Option(None, "--window-us", help="window length in microseconds (default: PipelineConfig's)"),
    settings: list[str] = typer.Option([], "--set", help="pipeline hyperparameter NAME=VALUE (a PipelineConfig field), repeatable"),
    jobs: int = typer.Option(1, "--jobs", min=1, help="sequences run in parallel processes"),
    predictions: Optional[Path] = typer.Option(None, "--predictions", help="keep each sequence's predictions here (JSON lines)"),
) -> None:
    """Run the pipeline over a labelled dataset and print the paper's metrics."""
    import dataclasses
    import json
    import shlex

    from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn

    from neurotouch_hid.evaluation.report import print_tables, write_report
    from neurotouch_hid.evaluation.runner import evaluate_dataset, pipeline_config

    config = pipeline_config(settings, **({} if window_us is None else {"window_us": window_us}))
    columns = (TextColumn("{task.description}"), BarColumn(), TextColumn("{task.completed:.1f}/{task.total:.1f} s recorded"),
               TimeElapsedColumn(), TimeRemainingColumn())
    with Progress(*columns, console=err_console, transient=True) as progress:
        result = evaluate_dataset(dataset, config, jobs=jobs, predictions_dir=predictions, progress=progress)
    print_tables(result, console)
    argv = ["eval", str(dataset)] + [f"--set={item}" for item in settings] + [
        f"{flag}={value}" for flag, value in (("--window-us", window_us), ("--jobs", jobs if jobs > 1 else None),
                                              ("--report", report), ("--json", json_out)) if value is not None]
    command = "neurotouch-hid " + shlex.join(argv)
    hyper = dataclasses.asdict(config)
    if json_out is not None:
        data = {"dataset": str(dataset), "command": command, "config": hyper, **result.to_dict()}
        json_out.parent.mkdir(parents=True, exist_ok=True)
        json_out.write_text(json.dumps(data, indent=1, allow_nan=False, default=str) + "\n")
    if report is not None:
        summary = write_report(result, report, command=command, config=hyper)
        console.print(f"report: {summary}")


@app.command()
def view(
    recording: Path = typer.Argument(..., help="AEDAT4 recording"),
    out: Path = typer.Option(..., "--out", help="FILE.mp4, FILE.gif or FILE.png"),
    sensor: Optional[Path] = typer.Option(None, "--sensor", help="sensor.yaml (default: the one beside the recording)"),
) -> None:
    """Draw what the pipeline sees: APS frame, events, markers, displacements, contacts, gesture."""
    _todo("view")


# --- the controller (runtime.py, mapping/, output/) -----------------------------------------
@app.command()
def run(
    source: str = typer.Option("davis", "--source", help="davis (live camera), sim (simulated gel) or a recording path"),
    profile: str = typer.Option("default", "--profile", help="profile name or path"),
    output: str = typer.Option("gamepad", "--output", help="gamepad, jsonl or term"),
    seconds: Optional[float] = typer.Option(None, "--seconds", help="stop after this many seconds"),
    fast: bool = typer.Option(False, "--fast", help="do not pace recordings in real time"),
) -> None:
    """Run the driver: source -> pipeline -> profile -> virtual gamepad."""
    _todo("run")


@app.command()
def demo(seconds: Optional[float] = typer.Option(30.0, "--seconds", help="how long to run")) -> None:
    """A simulated gel performing every gesture, through the default profile, to the gamepad."""
    _todo("demo")


@app.command()
def doctor() -> None:
    """Check the camera, permissions, /dev/uinput and libraries; print the fix for each failure."""
    _todo("doctor")


def main() -> None:
    """Console-script entry point: user errors become one line on stderr and exit code 2."""
    try:
        app(standalone_mode=False)
    except NeurotouchError as exc:
        err_console.print(f"[bold red]error:[/] {exc}", highlight=False, soft_wrap=True)
        sys.exit(2)
    except KeyboardInterrupt:
        sys.exit(130)
    except typer.Exit as exc:  # pragma: no cover - typer's own exits
        sys.exit(exc.exit_code)
    except SystemExit:
        raise
    except Exception as exc:  # click's usage errors
        import click

        if isinstance(exc, click.ClickException):
            exc.show()
            sys.exit(exc.exit_code)
        raise


if __name__ == "__main__":  # pragma: no cover
    main()
