"""Recordings and datasets: ``info``, ``record``, ``simulate``, ``track``, ``eval`` and ``view``.

Each command parses its options, calls one function of the stage it drives
(sources/recording.py, sources/recording_writer.py, sources/simulator.py, sources/sim_dataset.py, track.py,
evaluation/, view.py) and prints.
"""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from neurotouch_hid.cli.common import (
    METHOD_HELP,
    MODEL_OPTION,
    PRESET_IS_NOT_A_METHOD,
    chosen_model,
    console,
    davis_config,
    duration,
    err_console,
    finite,
    human_console,
    long_lived_start_up,
    no_stdout,
    say_err,
    to_stdout,
)
from neurotouch_hid.core.errors import NeurotouchError
from neurotouch_hid.core.kinds import SourceKind
from neurotouch_hid.core.limits import printable
from neurotouch_hid.core.tables import print_table

app = typer.Typer()


# --- recordings (sources/recording*.py) -----------------------------------------------------
@app.command()
def info(
    recording: Path = typer.Argument(..., help="AEDAT4 recording"),
    json_out: bool = typer.Option(False, "--json", help="print JSON instead of a table"),
) -> None:
    """Print a recording's camera name, resolution, duration, event count and frame count."""
    import json

    from rich.table import Table

    from neurotouch_hid.sources.recording import read_info

    rec = read_info(recording)
    if json_out:
        print(json.dumps(rec.to_json()))
        return
    table = Table(title=str(rec.path), show_header=False)
    table.add_column("field", style="bold")
    table.add_column("value")
    table.add_row("camera", rec.camera_name)
    table.add_row("resolution", f"{rec.width}x{rec.height} px")
    table.add_row("duration", f"{rec.duration_s:.2f} s ({rec.duration_us:,} us)")
    table.add_row("events", f"{rec.n_events:,}")
    table.add_row("APS frames", f"{rec.n_frames:,}")
    table.add_row("time range", f"{rec.start_us} .. {rec.end_us} us")
    print_table(console, table)


@app.command()
def record(
    out: Path = typer.Argument(..., help="AEDAT4 file to write"),
    seconds: Optional[float] = typer.Option(
        None,
        "--seconds",
        help="stop after this many seconds (default: at Ctrl-C)",
        callback=duration,
    ),
    source: str = typer.Option("davis", "--source", help="davis (the live camera) or sim (the simulated gel)"),
    force: bool = typer.Option(False, "--force", help="overwrite OUT if it exists"),
    fast: bool = typer.Option(
        False, "--fast", help="with --source sim: as fast as it is simulated, not in real time (needs --seconds)"
    ),
    seed: int = typer.Option(0, "--seed", min=0, help="with --source sim: the simulation's seed"),
    serial: Optional[str] = typer.Option(None, "--serial", help="with --source davis: the camera's serial number"),
    exposure_us: str = typer.Option(
        "4000", "--exposure-us", help="with --source davis: APS exposure in microseconds, or 'auto'"
    ),
) -> None:
    """Record what the camera sees (events and APS frames) as AEDAT4, readable by DV and `info`.

    Ctrl-C (or SIGTERM, or the terminal closed) ends the recording with a complete, readable file
    (exit 0); a camera that is unplugged ends it too, keeping what was recorded (exit 2). A disk
    that fills up ends it with the file complete up to then (exit 2); with --force, the recording
    there is replaced only by a complete one."""
    import contextlib
    import signal
    import threading

    from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

    from neurotouch_hid.core.errors import DeviceError
    from neurotouch_hid.sources.recording_writer import record_stream

    if source not in tuple(SourceKind):
        raise NeurotouchError(f"--source {source!r}: expected davis or sim (to replay a recording, copy the file)")
    if out.exists() and not force:
        raise NeurotouchError(f"{out} exists: choose another name, or add --force to overwrite it")
    if fast and source != SourceKind.SIM:
        raise NeurotouchError("--fast is for --source sim (a camera cannot go faster than time)")
    if fast and seconds is None:
        raise NeurotouchError("--fast needs --seconds: how much of the simulated gel to record")
    with contextlib.ExitStack() as stack:
        if source == SourceKind.DAVIS:
            from dataclasses import replace

            from neurotouch_hid.sources.davis import REST_COMMIT_INTERVAL_US, DavisSource

            # a recording waits for nobody: the longest commit interval, whose batches fill the
            # driver's queue with the most camera time for a writer that falls behind
            config = replace(davis_config(serial, exposure_us, 1.0), commit_interval_us=REST_COMMIT_INTERVAL_US)
            camera = stack.enter_context(DavisSource(config))
            stream, name = camera.stream(seconds=seconds, batch_us=10_000), camera.camera_name
        else:
            from neurotouch_hid.sources.simulator import SimulatedSource

            stream, name = (
                SimulatedSource(seed=seed).stream(seconds=seconds, batch_us=10_000),
                "NeuroTouch-sim_DAVIS346",
            )
        stop = threading.Event()
        for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):  # SIGHUP: the terminal closed
            stack.callback(signal.signal, sig, signal.signal(sig, lambda *_: stop.set()))
        columns = [
            TextColumn("{task.fields[title]}", markup=False),  # a file name is text (no markup, no format field)
            *([BarColumn()] if seconds else []),
            TextColumn("{task.fields[what]}"),
            TimeElapsedColumn(),
        ]
        done = {"us": 0, "events": 0, "frames": 0}
        with Progress(*columns, console=err_console, transient=True) as progress:
            task = progress.add_task("record", total=seconds, what="", title=f"recording {source} -> {out}")

            def report(duration_us: int, events: int, frames: int) -> None:
                done.update(us=duration_us, events=events, frames=frames)
                progress.update(
                    task,
                    completed=duration_us / 1e6,
                    what=f"{duration_us / 1e6:.1f} s, {events:,} events, {frames} frames",
                )

            try:
                summary = record_stream(
                    stream,
                    out,
                    camera_name=name,
                    pace=source == SourceKind.SIM and not fast,
                    stop=stop,
                    on_progress=report,
                )
            except DeviceError as exc:
                raise DeviceError(
                    f"{exc}; the {done['us'] / 1e6:.1f} s recorded until then ({done['events']:,} "
                    f"events, {done['frames']} frames) are complete in {out}"
                ) from None
    how = " (stopped by Ctrl-C)" if summary.stopped else ""
    console.print(
        f"wrote {out}: {summary.duration_us / 1e6:.2f} s, {summary.events:,} events, {summary.frames} APS frames{how}",
        highlight=False,
        soft_wrap=True,
    )


# --- the simulated gel (sources/sim_dataset.py) --------------------------------------------
@app.command()
def simulate(
    out: Path = typer.Option(..., "--out", help="dataset folder to write (docs/dataset.md)"),
    preset: str = typer.Option(
        "quick",
        "--preset",
        help="quick (small, for tests), paper (5 users x 5 gestures x ~1 min) or sessions (5 users x a 10 s game "
        "session: the type changes from one gesture to the next; taps from 0.25 s, ordinary gestures, holds of "
        "several seconds, rests of a fraction of a second)",
    ),
    seed: int = typer.Option(0, "--seed", min=0, help="random seed: the same seed gives the same files"),
    minutes: Optional[float] = typer.Option(
        None, "--minutes", help="override the total simulated duration (minutes)", callback=finite
    ),
    users: Optional[str] = typer.Option(
        None,
        "--users",
        help="comma-separated user ids 0-9 (default: the preset's; paper: even seed -> test users 0-4, "
        "odd seed -> tuning users 5-9)",
    ),
    noise_hz: float = typer.Option(
        0.1,
        "--noise-hz",
        help="background-activity noise per pixel (Hz): 0.1 a DAVIS-346 in good light, a few Hz in dim light",
        callback=finite,
    ),
    physics: str = typer.Option(
        "default",
        "--physics",
        help="gel and camera family: default, powerlaw, stickslip, indent, camera, drift, fingers, strong, markers, "
        "noise, flicker, viscoelastic, pasternak, exposure, contrast, late, compound, compound2, or mix (one family "
        "per sequence); "
        "see docs/accuracy.md",
    ),
    force: bool = typer.Option(False, "--force", help="replace the dataset OUT holds, whole"),
) -> None:
    """Simulate the NeuroTouch gel and write a labelled dataset (docs/dataset.md).

    OUT is written whole at the end: a dataset there is refused unless --force, then replaced."""
    from neurotouch_hid.sources.sim_dataset import write_dataset

    no_stdout("--out", out, "a dataset is a folder")
    user_ids = None
    if users is not None:
        try:
            user_ids = [int(u) for u in users.split(",") if u.strip()]
        except ValueError:
            raise NeurotouchError(f"--users: expected comma-separated user ids 0-9, got {users!r}") from None
    folder = write_dataset(
        out,
        preset=preset,
        seed=seed,
        minutes=minutes,
        users=user_ids,
        progress=True,
        noise_hz=noise_hz,
        physics=physics,
        force=force,
    )
    console.print(f"wrote {folder}")


# --- the pipeline (pipeline/) ---------------------------------------------------------------
@app.command()
def track(
    recording: Path = typer.Argument(..., help="AEDAT4 recording"),
    out: Path = typer.Option(..., "--out", help="predictions, JSON lines (docs/dataset.md; - : standard output)"),
    sensor: Optional[Path] = typer.Option(None, "--sensor", help="sensor.yaml (default: the one beside the recording)"),
    window_us: int = typer.Option(10_000, "--window-us", help="window length in microseconds (>= 1000)"),
    markers: Optional[Path] = typer.Option(None, "--markers", help="also write tracked marker positions (.npz)"),
    method: str = typer.Option("default", "--method", help=METHOD_HELP),
    model: Optional[str] = MODEL_OPTION,
    preset: Optional[str] = PRESET_IS_NOT_A_METHOD,
) -> None:
    """Run the gesture pipeline on a recording and write one prediction per window."""
    from neurotouch_hid.core.atomic import check_output

    no_stdout("--markers", markers, "the markers are an .npz file")
    check_output(out, (recording, sensor), "predictions file")  # before the pipeline's start-up
    if markers is not None:
        check_output(markers, (recording, sensor, out), "markers file", (("predictions file", out),))
    with long_lived_start_up():
        from neurotouch_hid.core.sensor import chosen_sensor_file, find_sensor_file
        from neurotouch_hid.enrolment.model import apply_model
        from neurotouch_hid.evaluation.runner import pipeline_config
        from neurotouch_hid.pipeline.methods import pipeline_for
        from neurotouch_hid.pipeline.track import recording_progress, sensor_label, track_recording
        from neurotouch_hid.service.warmup import compile_before

        config = apply_model(pipeline_config(method=method, window_us=window_us), chosen_model(model))
        sensor_file = chosen_sensor_file(recording, sensor)
        geometry = find_sensor_file(recording, sensor)
        compile_before(say_err, method)  # a first run: compiled in child processes, said
        pipeline_for(geometry, config).compile_kernels()  # numba's cached code, loaded now
    with recording_progress(err_console, "tracking") as report:
        summary = track_recording(
            recording, out, geometry, config, markers_out=markers, on_progress=report, sensor_file=sensor_file
        )
    if summary.refused_frames:
        err_console.print(
            f"note: the first {summary.refused_frames} APS frames did not match the gel at rest in "
            f"{sensor_label(sensor_file)} (the gel pressed, or a sensor.yaml of another camera pose), so the "
            f"windows start {summary.first_window_us * 1e-6:.2f} s into the recording; a sensor.yaml of this "
            "camera (--sensor FILE) starts them at once",
            highlight=False,
            markup=False,
            soft_wrap=True,
        )
    human_console(out).print(  # on stderr when the predictions go to standard output
        f"{summary.windows} windows of {config.window_us} us over {summary.duration_us * 1e-6:.2f} s "
        f"({summary.events} events, {summary.frames} frames) in {summary.elapsed_s:.2f} s, "
        f"{summary.realtime_factor:.1f}x real time -> {out}"
        + (f", markers -> {markers}" if markers else "")
        + f" (geometry: {sensor_label(sensor_file)})",
        highlight=False,
        soft_wrap=True,
    )


@app.command("eval")
def eval_cmd(
    dataset: Path = typer.Argument(..., help="dataset folder (docs/dataset.md)"),
    report: Optional[Path] = typer.Option(None, "--report", help="write PNG figures and a Markdown summary here"),
    json_out: Optional[Path] = typer.Option(None, "--json", help="write the metrics as JSON (- : standard output)"),
    window_us: Optional[int] = typer.Option(
        None, "--window-us", help="window length in microseconds (default: PipelineConfig's)"
    ),
    settings: list[str] = typer.Option(
        [],
        "--set",
        help="pipeline hyperparameter NAME=VALUE, repeatable: a field of the method's config; default: "
        "window_us (us), noise.kind, noise.time_us (us), tracker.*, contacts.*, gesture.*, resting.* (*_mm in "
        "mm on the gel, *_mm2 in mm^2, *_um2 in um^2, *_us in us), converted with sensor.yaml's px/mm; paper: its "
        "fields in px, tracker.* as the default's",
    ),
    method: str = typer.Option("default", "--method", help=METHOD_HELP + "; --set applies over it"),
    preset: Optional[str] = PRESET_IS_NOT_A_METHOD,
    jobs: int = typer.Option(1, "--jobs", min=1, help="sequences run in parallel processes"),
    predictions: Optional[Path] = typer.Option(
        None, "--predictions", help="keep each sequence's predictions here (JSON lines)"
    ),
    deadzone_mm: float = typer.Option(
        0.8,
        "--deadzone-mm",
        min=0.0,
        help="dead zone of the per-gesture metrics (mm; default: the default profile's), docs/dataset.md",
        callback=finite,
    ),
    profiles: list[str] = typer.Option(
        [],
        "--profile",
        help="profile name or file, repeatable: replay the answers through it and count wrong outputs, missed "
        'gestures and outputs going active at rest (docs/dataset.md, "Through a profile")',
    ),
    model: Optional[str] = MODEL_OPTION,
) -> None:
    """Run the pipeline over a labelled dataset; print the paper's metrics and the per-gesture ones.

    Says when the labels were partly read by this pipeline (an enrolment's) and when the model in
    use was fitted on the dataset: the figures are then not an independent score."""
    import json
    import shlex
    import sys

    from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn

    from neurotouch_hid.evaluation.report import print_tables, write_report
    from neurotouch_hid.evaluation.runner import evaluate_dataset, pipeline_config
    from neurotouch_hid.evaluation.through_profile import ProfileUnderTest
    from neurotouch_hid.mapping.profile import load_profile
    from neurotouch_hid.service.extras import require

    no_stdout("--report", report, "the report is a folder of figures")
    no_stdout("--predictions", predictions, "the predictions are a folder of one file a sequence")
    if report is not None:  # before the evaluation, not after it
        require("plots", "eval --report")
    from neurotouch_hid.core.atomic import check_output

    for flag, folder in (("--report", report), ("--predictions", predictions), ("--json", json_out)):
        if folder is not None:  # outputs checked before the evaluation, not after it
            _no_file_on_the_way(flag, folder.parent if flag == "--json" else folder)
    if json_out is not None and not to_stdout(json_out):
        from neurotouch_hid.core.dataset import list_sequences
        from neurotouch_hid.evaluation.report import FIGURES

        others = [(f"report's {name}", report / name) for name in ("summary.md", *FIGURES) if report is not None]
        if predictions is not None:  # the JSON, written last, would replace one of them
            others += [(f"predictions of {n}", predictions / f"{n}.jsonl") for n in list_sequences(dataset)]
        check_output(json_out, (dataset,), what="JSON summary", others=others)
    from neurotouch_hid.enrolment.model import apply_model

    config = pipeline_config(settings, method, **({} if window_us is None else {"window_us": window_us}))
    given = [item.partition("=")[0].strip() for item in settings]  # --set wins over the model
    chosen = chosen_model(model)
    config = apply_model(config, chosen, keep=given)
    cautions = eval_cautions(dataset, chosen, model)
    tested = [ProfileUnderTest.probe(name, load_profile(name)) for name in dict.fromkeys(profiles)]  # each once
    columns = (
        TextColumn("{task.description}", markup=False),  # a sequence's name is text
        BarColumn(),
        TextColumn("{task.completed:.1f}/{task.total:.1f} s recorded"),
        TimeElapsedColumn(),
        TimeRemainingColumn(),
    )
    with Progress(*columns, console=err_console, transient=True) as progress:
        result = evaluate_dataset(
            dataset,
            config,
            jobs=jobs,
            predictions_dir=predictions,
            progress=progress,
            deadzone_mm=deadzone_mm,
            profiles=tested,
        )
    print_tables(result, human_console(json_out))  # on stderr when the JSON goes to standard output
    for line in cautions:
        say_err(f"caution: {line}")
    argv = (
        ["eval", str(dataset)]
        + ([f"--method={method}"] if method != "default" else [])
        + [f"--set={item}" for item in settings]
        + [f"--profile={t.name}" for t in tested]
        + [
            f"{flag}={value}"
            for flag, value in (
                ("--window-us", window_us),
                ("--jobs", jobs if jobs > 1 else None),
                ("--deadzone-mm", deadzone_mm if deadzone_mm != 0.8 else None),
                ("--model", model),
                ("--report", report),
                ("--json", json_out),
            )
            if value is not None
        ]
    )
    command = "neurotouch-hid " + shlex.join(argv)
    hyper = config.model_dump()
    if json_out is not None:
        data = {"dataset": str(dataset), "command": command, "config": hyper, "cautions": cautions, **result.to_dict()}
        from neurotouch_hid.core.atomic import AtomicFile

        text = json.dumps(data, indent=1, allow_nan=False, default=str) + "\n"
        if to_stdout(json_out):
            sys.stdout.write(text)
            sys.stdout.flush()
        else:
            json_out.parent.mkdir(parents=True, exist_ok=True)
            with AtomicFile(json_out, (dataset,), what="JSON summary") as fh:
                fh.write(text)
    if report is not None:
        summary = write_report(result, report, command=command, config=hyper)
        human_console(json_out).print(f"report: {summary}", highlight=False, soft_wrap=True)


def eval_cautions(dataset: Path, model, option: Optional[str]) -> list[str]:
    """What makes ``eval``'s figures on ``dataset`` not an independent score: labels made by
    ``enrol`` (a sequence with its ``NAME.plan.json``: the prompt gave the type, this pipeline's
    tracker and contact stage the moments, contacts and intensity), and a ``model`` (the
    adapted one in use, ``--model``'s ``option`` or the user's) fitted on ``dataset``."""
    from neurotouch_hid.core.dataset import list_sequences
    from neurotouch_hid.enrolment.model import fitted_on

    said = []
    enrolled = [name for name in list_sequences(dataset) if (dataset / f"{name}.plan.json").is_file()]
    if enrolled:
        said.append(
            f"{', '.join(enrolled[:3])}{' ...' if len(enrolled) > 3 else ''}: labelled by enrol from a plan: the "
            "moments, contacts and intensity of its labels were read by this pipeline's own tracker and contact "
            "stage, so these figures share their source with the labels (onset latency, contacts and intensity "
            "agree by construction) and do not compare with the paper's"
        )
    if fitted_on(model, dataset):
        which = f"--model {option}" if option is not None else f"your model ({model.path})"
        said.append(
            f"{which} was fitted on {dataset}: it has seen most of these gestures (adapt held out every third), so "
            "these figures overstate how it reads gestures it has not seen; score it on another enrolment"
        )
    return said


def _no_file_on_the_way(flag: str, folder: Path) -> None:
    """Raises NeurotouchError when ``folder`` (an output's folder, made when missing) or the
    nearest of its parents that exists is a file: the folder could not be made."""
    for part in (folder, *folder.parents):
        if part.exists():
            if not part.is_dir():
                raise NeurotouchError(f"{flag}: {printable(part, 200)} is a file, not a folder; give another path")
            return


@app.command()
def view(
    recording: Path = typer.Argument(..., help="AEDAT4 recording"),
    out: Path = typer.Option(..., "--out", help="FILE.mp4, FILE.gif or FILE.png"),
    sensor: Optional[Path] = typer.Option(None, "--sensor", help="sensor.yaml (default: the one beside the recording)"),
) -> None:
    """Draw what the pipeline sees: APS frame, events, markers, displacements, contacts, gesture."""
    from neurotouch_hid.core.sensor import find_sensor_file
    from neurotouch_hid.pipeline.track import recording_progress
    from neurotouch_hid.views.pictures import render_view

    geometry = find_sensor_file(recording, sensor)
    with recording_progress(err_console, "drawing") as report:
        drawn = render_view(recording, out, geometry, on_progress=report)
    what = "the most intense of " if out.suffix.lower() == ".png" else ""
    console.print(f"{what}{drawn} pictures -> {out}", highlight=False, soft_wrap=True)
