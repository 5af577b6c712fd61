"""Enrolment: ``enrol`` (a guided session, its plan, or labelling a recording made by following one).

The command parses its options, calls one function of the stage it drives
(enrolment/plan.py, enrolment/label.py, enrolment/session.py) and prints.
"""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from neurotouch_hid.cli.common import console, err_console, long_lived_start_up
from neurotouch_hid.errors import NeurotouchError

app = typer.Typer()


@app.command()
def enrol(
    plan_out: Optional[Path] = typer.Option(
        None, "--plan-out", help="write the session's plan (JSON, docs/dataset.md) here and stop"
    ),
    from_recording: Optional[Path] = typer.Option(
        None, "--from", help="label this AEDAT4 recording, made by following --plan, instead of a session"
    ),
    plan: Optional[Path] = typer.Option(
        None, "--plan", help="the plan to follow or to label with (JSON, docs/dataset.md); default: one from --seed"
    ),
    out: Optional[Path] = typer.Option(
        None, "--out", help="the dataset folder to write (default for a session: the user's data folder)"
    ),
    sensor: Optional[Path] = typer.Option(
        None, "--sensor", help="sensor.yaml (default: beside the recording, or the calibrated one)"
    ),
    seed: int = typer.Option(0, "--seed", min=0, help="the plan's seed (and the simulated hand's)"),
) -> None:
    """Teach the driver your gel and your hand: a guided session of at most 3 minutes.

    --plan-out FILE writes the session's prompts without running it. --from REC.aedat4 --plan FILE
    --out DIR labels a recording made by following that plan elsewhere: the type from each prompt,
    the moments, contacts and intensity from the gel; a prompt with no gesture near its cue is
    left out and said. The folder written is a dataset (docs/dataset.md) that `eval DIR` reads."""
    from neurotouch_hid.enrolment.plan import make_plan, read_plan, write_plan

    chosen = read_plan(plan) if plan is not None else make_plan(seed)
    if plan_out is not None:
        if from_recording is not None:
            raise NeurotouchError("--plan-out writes a plan and stops: give it without --from")
        write_plan(chosen, plan_out)
        console.print(
            f"{len(chosen.prompts)} prompts over {chosen.end_s:.0f} s -> {plan_out}", highlight=False, soft_wrap=True
        )
        return
    if from_recording is not None:
        _label(from_recording, plan, chosen, out, sensor)
        return
    raise NeurotouchError("give --plan-out FILE, or --from REC.aedat4 --plan FILE --out DIR")


def _label(recording: Path, plan_path: Optional[Path], plan, out: Optional[Path], sensor: Optional[Path]) -> None:
    """``enrol --from``: label ``recording`` with ``plan`` into ``out``, say what was left out."""
    if plan_path is None or out is None:
        raise NeurotouchError("--from REC.aedat4 needs the plan it followed (--plan FILE) and --out DIR")
    with long_lived_start_up():
        from neurotouch_hid.enrolment.label import label_recording
        from neurotouch_hid.pipeline.pipeline import GesturePipeline
        from neurotouch_hid.sensor import find_sensor_file
        from neurotouch_hid.track import recording_progress

        geometry = find_sensor_file(recording, sensor)
        GesturePipeline(geometry).compile_kernels()
    beside = recording.with_name("sensor.yaml")
    inputs = [plan_path, sensor if sensor is not None else beside]
    with recording_progress(err_console, "labelling") as report:
        done = label_recording(recording, plan, out, geometry, inputs=inputs, on_progress=report)
    say_labelled(done)


def say_labelled(done) -> None:
    """Print where a labelled enrolment went and each prompt left out (``enrolment.label.Labelled``)."""
    seen = len(done.found) - len(done.missed)
    console.print(
        f"labelled {seen} of {len(done.found)} prompts -> {done.folder} ({done.name}.aedat4, "
        f"{done.name}.labels.csv, sensor.yaml); `neurotouch-hid eval {done.folder}` scores the pipeline on it",
        highlight=False,
        soft_wrap=True,
    )
    for f in done.missed:
        n = done.found.index(f) + 1
        console.print(
            f"prompt {n} ({f.prompt.name} at {f.prompt.cue_s:g} s): no gesture seen near its cue, left out",
            highlight=False,
            soft_wrap=True,
        )
