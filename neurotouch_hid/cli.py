"""The ``neurotouch-hid`` command (typer).

Each command is a thin layer: it parses options, calls one function of the stage it belongs to,
and prints. Heavy modules (numba, OpenCV, dv-processing) are imported inside the commands so
``--help`` stays fast. Every :class:`~neurotouch_hid.errors.NeurotouchError` becomes one clear
line on stderr and exit code 2 (see :func:`main`).
"""

from __future__ import annotations

import contextlib
import gc
import math
import os
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Optional

import typer

from neurotouch_hid.errors import NeurotouchError
from neurotouch_hid.kinds import OutputKind, SourceKind
from neurotouch_hid.output.console import command_app, make_console

app = command_app(
    name="neurotouch-hid",
    help="NeuroTouch soft tactile sensor -> standard game controller.",
    no_args_is_help=True,
)
profile_app = typer.Typer(
    help="List, show, create, edit, validate, test, tune, delete, reset and use (switch the running driver to) "
    "profiles.",
    no_args_is_help=True,
    rich_markup_mode=None,
)
app.add_typer(profile_app, name="profile")
auto_app = typer.Typer(
    help="A profile per game: the running driver switches to a game's profile while the game runs "
    "(a Steam app id or an executable's name; the user's games.yaml). Without a command: list.",
    invoke_without_command=True,
)
profile_app.add_typer(auto_app, name="auto")

#: The variable through which shells ask for completions (click's protocol):
#: ``_NEUROTOUCH_HID_COMPLETE=source_bash neurotouch-hid`` prints the bash script (zsh, fish too).
COMPLETE_ENV = "_NEUROTOUCH_HID_COMPLETE"


def _print_version(value: bool) -> None:
    """``--version``: the installed distribution's version (the package's own when run from a
    checkout without an install), then exit 0."""
    if not value:
        return
    import importlib.metadata

    from neurotouch_hid import __version__

    try:
        version = importlib.metadata.version("neurotouch-hid")
    except importlib.metadata.PackageNotFoundError:
        version = __version__
    typer.echo(f"neurotouch-hid {version}")
    raise typer.Exit()


@app.callback()
def _options(
    version: bool = typer.Option(False, "--version", callback=_print_version, is_eager=True, help="print the version"),
) -> None:
    """NeuroTouch soft tactile sensor -> standard game controller."""


console = make_console()
err_console = make_console(stderr=True)


def _finite(value: Optional[float]) -> Optional[float]:
    """Every float option: ``nan`` and ``inf`` are usage errors (exit 2, the option named), not a
    traceback later on."""
    if value is not None and not math.isfinite(value):
        raise typer.BadParameter(f"expected a finite number, got {value}")
    return value


def _duration(value: Optional[float]) -> Optional[float]:
    """``--seconds``: a finite, positive duration (0 or less ran nothing and said nothing)."""
    if value is not None and not (math.isfinite(value) and value > 0):
        raise typer.BadParameter(f"expected a positive duration (seconds), got {value}")
    return value


@contextlib.contextmanager
def long_lived_start_up() -> Iterator[None]:
    """A command's start-up: what is made inside (imports, numba's loaded code: ~130 k objects
    for ``track``) lives as long as the process. The garbage collector is off meanwhile and
    those objects are frozen at the end (``gc.freeze``), so that none of its passes walks them
    again: its full passes over them were ~0.5 s of CPU of a 40 s ``track`` (docs/performance.md,
    "track"). Cyclic garbage made inside is never freed: keep the block to
    imports and set-up."""
    enabled = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        gc.freeze()
        if enabled:
            gc.enable()


# --- recordings (sources/recording.py) ------------------------------------------------------
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
    console.print(table)


@app.command()
def record(
    out: Path = typer.Argument(..., help="AEDAT4 file to write"),
    seconds: Optional[float] = typer.Option(
        None,
        "--seconds",
        help="stop after this many seconds (default: at Ctrl-C)",
        callback=_duration,
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

    Ctrl-C (or SIGTERM) ends the recording with a complete, readable file (exit 0); a camera that
    is unplugged ends it too, keeping what was recorded (exit 2)."""
    import contextlib
    import signal
    import threading

    from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

    from neurotouch_hid.errors import DeviceError
    from neurotouch_hid.sources.recording import record_stream

    if source not in tuple(SourceKind):
        raise NeurotouchError(f"--source {source!r}: expected davis or sim (to replay a recording, copy the file)")
    if out.exists() and not force:
        raise NeurotouchError(f"{out} exists: choose another name, or add --force to overwrite it")
    if fast and (source != SourceKind.SIM or seconds is None):
        raise NeurotouchError("--fast is for --source sim with --seconds (a camera cannot go faster than time)")
    with contextlib.ExitStack() as stack:
        if source == SourceKind.DAVIS:
            from neurotouch_hid.sources.davis import DavisSource

            camera = stack.enter_context(DavisSource(_davis_config(serial, exposure_us, 1.0)))
            stream, name = camera.stream(seconds=seconds, batch_us=10_000), camera.camera_name
        else:
            from neurotouch_hid.sources.simulator import SimulatedSource

            stream, name = (
                SimulatedSource(seed=seed).stream(seconds=seconds, batch_us=10_000),
                "NeuroTouch-sim_DAVIS346",
            )
        stop = threading.Event()
        for sig in (signal.SIGINT, signal.SIGTERM):
            stack.callback(signal.signal, sig, signal.signal(sig, lambda *_: stop.set()))
        columns = [
            TextColumn(f"recording {source} -> {out}"),
            *([BarColumn()] if seconds else []),
            TextColumn("{task.fields[what]}"),
            TimeElapsedColumn(),
        ]
        done = {"us": 0, "events": 0, "frames": 0}
        with Progress(*columns, console=err_console, transient=True) as progress:
            task = progress.add_task("record", total=seconds, what="")

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


# --- the simulated gel (sources/simulator.py) ----------------------------------------------
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
        None, "--minutes", help="override the total simulated duration (minutes)", callback=_finite
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
        callback=_finite,
    ),
    physics: str = typer.Option(
        "default",
        "--physics",
        help="gel and camera family: default, powerlaw, stickslip, indent, camera, drift, fingers, strong, markers, "
        "noise, flicker, viscoelastic, pasternak, exposure, contrast, late, or mix (one family per sequence); "
        "see docs/accuracy.md",
    ),
) -> None:
    """Simulate the NeuroTouch gel and write a labelled dataset (docs/dataset.md)."""
    from neurotouch_hid.sources.simulator import write_dataset

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
    )
    console.print(f"wrote {folder}")


#: ``--method``'s help (track, eval, run).
METHOD_HELP = "the gesture pipeline: default (the product's) or paper (the paper's method exactly)"


# --- the pipeline (pipeline/) ---------------------------------------------------------------
@app.command()
def track(
    recording: Path = typer.Argument(..., help="AEDAT4 recording"),
    out: Path = typer.Option(..., "--out", help="predictions, JSON lines (docs/dataset.md)"),
    sensor: Optional[Path] = typer.Option(None, "--sensor", help="sensor.yaml (default: the one beside the recording)"),
    window_us: int = typer.Option(10_000, "--window-us", help="window length in microseconds (>= 1000)"),
    markers: Optional[Path] = typer.Option(None, "--markers", help="also write tracked marker positions (.npz)"),
    method: str = typer.Option("default", "--method", "--preset", help=METHOD_HELP),
) -> None:
    """Run the gesture pipeline on a recording and write one prediction per window."""
    with long_lived_start_up():
        from neurotouch_hid.evaluation.runner import pipeline_config
        from neurotouch_hid.pipeline.methods import pipeline_for
        from neurotouch_hid.sensor import find_sensor_file
        from neurotouch_hid.track import recording_progress, track_recording

        config = pipeline_config(method=method, window_us=window_us)
        geometry = find_sensor_file(recording, sensor)
        pipeline_for(geometry, config).compile_kernels()  # numba's cached code, loaded now
    with recording_progress(err_console, "tracking") as report:
        summary = track_recording(recording, out, geometry, config, markers_out=markers, on_progress=report)
    console.print(
        f"{summary.windows} windows of {config.window_us} us over {summary.duration_us * 1e-6:.2f} s "
        f"({summary.events} events, {summary.frames} frames) in {summary.elapsed_s:.2f} s, "
        f"{summary.realtime_factor:.1f}x real time -> {out}" + (f", markers -> {markers}" if markers else ""),
        highlight=False,
        soft_wrap=True,
    )


@app.command("eval")
def eval_cmd(
    dataset: Path = typer.Argument(..., help="dataset folder (docs/dataset.md)"),
    report: Optional[Path] = typer.Option(None, "--report", help="write PNG figures and a Markdown summary here"),
    json_out: Optional[Path] = typer.Option(None, "--json", help="write the metrics as JSON"),
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
    method: str = typer.Option("default", "--method", "--preset", help=METHOD_HELP + "; --set applies over it"),
    jobs: int = typer.Option(1, "--jobs", min=1, help="sequences run in parallel processes"),
    predictions: Optional[Path] = typer.Option(
        None, "--predictions", help="keep each sequence's predictions here (JSON lines)"
    ),
    deadzone_mm: float = typer.Option(
        0.8,
        "--deadzone-mm",
        min=0.0,
        help="dead zone of the per-gesture metrics (mm; default: the default profile's), docs/dataset.md",
        callback=_finite,
    ),
    profiles: list[str] = typer.Option(
        [],
        "--profile",
        help="profile name or file, repeatable: replay the answers through it and count wrong outputs, missed "
        'gestures and outputs going active at rest (docs/dataset.md, "Through a profile")',
    ),
) -> None:
    """Run the pipeline over a labelled dataset; print the paper's metrics and the per-gesture ones."""
    import json
    import shlex

    from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn

    from neurotouch_hid.evaluation.report import print_tables, write_report
    from neurotouch_hid.evaluation.runner import evaluate_dataset, pipeline_config
    from neurotouch_hid.evaluation.through_profile import ProfileUnderTest
    from neurotouch_hid.mapping.profile import load_profile

    config = pipeline_config(settings, method, **({} if window_us is None else {"window_us": window_us}))
    tested = [ProfileUnderTest.probe(name, load_profile(name)) for name in dict.fromkeys(profiles)]  # each once
    columns = (
        TextColumn("{task.description}"),
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
    print_tables(result, console)
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
                ("--report", report),
                ("--json", json_out),
            )
            if value is not None
        ]
    )
    command = "neurotouch-hid " + shlex.join(argv)
    hyper = config.model_dump()
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
    from neurotouch_hid.sensor import find_sensor_file
    from neurotouch_hid.track import recording_progress
    from neurotouch_hid.view import render_view

    geometry = find_sensor_file(recording, sensor)
    with recording_progress(err_console, "drawing") as report:
        drawn = render_view(recording, out, geometry, on_progress=report)
    what = "the most intense of " if out.suffix.lower() == ".png" else ""
    console.print(f"{what}{drawn} pictures -> {out}", highlight=False, soft_wrap=True)


# --- the controller (driver.py, runtime.py, mapping/, output/) ------------------------------
def _davis_config(serial: Optional[str], exposure_us: str, stall_timeout: float):
    """The live camera's settings from the command line (sources/davis.py DavisConfig)."""
    from neurotouch_hid.sources.davis import DavisConfig

    if exposure_us != "auto" and not exposure_us.isdigit():
        raise NeurotouchError(f"--exposure-us {exposure_us!r}: expected a whole number of microseconds or 'auto'")
    try:
        return DavisConfig(
            serial=serial,
            exposure_us=None if exposure_us == "auto" else int(exposure_us),
            stall_timeout_s=stall_timeout,
        )
    except ValueError as exc:
        raise NeurotouchError(f"camera settings: {exc}") from None


@app.command()
def run(
    source: str = typer.Option(
        "davis",
        "--source",
        help="davis (live camera), sim (simulated gel), a recording path, or predictions PRED.jsonl "
        "(replayed without the pipeline)",
    ),
    profile: str = typer.Option("default", "--profile", help="profile name or path"),
    output: OutputKind = typer.Option(OutputKind.GAMEPAD, "--output", help="where the states go"),
    seconds: Optional[float] = typer.Option(None, "--seconds", help="stop after this many seconds", callback=_duration),
    fast: bool = typer.Option(False, "--fast", help="do not pace recordings in real time"),
    out: Optional[Path] = typer.Option(
        None, "--out", help="with --output jsonl: write the states here instead of stdout"
    ),
    window_us: int = typer.Option(10_000, "--window-us", help="window length in microseconds (>= 1000)"),
    sensor: Optional[Path] = typer.Option(
        None, "--sensor", help="sensor.yaml (default: beside the recording, or the built-in one)"
    ),
    seed: int = typer.Option(0, "--seed", min=0, help="with --source sim: the simulation's seed"),
    wait: bool = typer.Option(
        False, "--wait", help="with --source davis: wait for a camera to be plugged in instead of failing"
    ),
    serial: Optional[str] = typer.Option(
        None, "--serial", help="with --source davis: the camera's serial number (default: the first DAVIS-346)"
    ),
    exposure_us: str = typer.Option(
        "4000", "--exposure-us", help="with --source davis: APS exposure in microseconds, or 'auto'"
    ),
    stall_timeout: float = typer.Option(
        1.0,
        "--stall-timeout",
        help="with --source davis: seconds without data that count as a lost camera",
        callback=_finite,
    ),
    max_lag_ms: float = typer.Option(
        200.0,
        "--max-lag-ms",
        help="how far the pipeline may fall behind the camera (or a paced replay) before the oldest "
        "data is dropped; more lets a slow machine track every event, later",
        callback=_finite,
    ),
    method: str = typer.Option("default", "--method", help=METHOD_HELP),
) -> None:
    """Run the driver: source -> pipeline -> profile -> virtual gamepad.

    Stops at the end of the source, after --seconds, on Ctrl-C (exit 130) or SIGTERM (a clean
    stop, exit 0), always leaving the gamepad neutral. SIGHUP reloads the profile. A camera that
    is unplugged or stalls centres the gamepad at once; the driver reconnects when it is back."""
    from neurotouch_hid.driver import run_driver

    stats = run_driver(
        source,
        profile,
        output,
        seconds=seconds,
        fast=fast,
        out=out,
        window_us=window_us,
        sensor=sensor,
        seed=seed,
        console=console,
        wait=wait,
        davis=_davis_config(serial, exposure_us, stall_timeout),
        say=lambda line: err_console.print(line, markup=False, highlight=False, soft_wrap=True),
        max_lag_us=round(max_lag_ms * 1000),
        method=method,
    )
    err_console.print(stats.summary(), highlight=False, soft_wrap=True)


@app.command()
def demo(
    seconds: Optional[float] = typer.Option(30.0, "--seconds", help="how long to run", callback=_duration),
) -> None:
    """A simulated gel performing every gesture, through the default profile, to the gamepad.

    Without a writable /dev/uinput the gamepad is shown in the terminal instead (one line says
    why); without a terminal, a line at each button or key change and at most one a second otherwise."""
    from neurotouch_hid.driver import run_demo

    stats = run_demo(
        seconds,
        console=console,
        say=lambda line: err_console.print(line, markup=False, highlight=False, soft_wrap=True),
    )
    err_console.print(stats.summary(), highlight=False, soft_wrap=True)


@app.command()
def devices(json_out: bool = typer.Option(False, "--json", help="print JSON (for scripts) instead of a table")) -> None:
    """List the DAVIS-346 cameras: every USB 152a:841a device (pyusb) and what dv-processing sees.

    For each: where it is, whether this user can open it and, if not, why and what to do (the
    udev rule, another program holding it, firmware). Exit code 0 when a camera is ready to use,
    1 otherwise."""
    import json

    from rich.markup import escape
    from rich.table import Table

    from neurotouch_hid.sources.discovery import discover, explain

    found = discover()
    if json_out:
        typer.echo(json.dumps(found.to_json(), indent=1))
    elif not found.cameras:
        console.print(escape(explain(found)), style="bold red", highlight=False, soft_wrap=True)
    else:
        style = {"ready": "green", "other-camera": "yellow"}
        table = Table(
            "device",
            "serial",
            "USB (pyusb)",
            "dv-processing",
            "status",
            title="DAVIS-346 cameras (USB 152a:841a)",
            show_lines=True,
        )
        for c in found.cameras:
            usb = "not seen"
            if c.usb is not None:
                speed = f", {c.usb.speed_mbps:g} Mb/s" if c.usb.speed_mbps else ""
                usb = f"{c.usb.product or '?'}{speed}\naccess: {c.usb.access}"
            dv = f"{c.dv.model} ({c.dv.device_type}), firmware {c.dv.firmware}" if c.dv else "not listed"
            table.add_row(
                f"bus {c.bus} device {c.address}\n{c.node}",
                c.serial or "?",
                escape(usb),
                escape(dv),
                f"[{style.get(c.status, 'bold red')}]{c.status}[/]",
            )
        console.print(table)
        for c in found.cameras:
            if c.ready:
                console.print(f"[green]ready:[/] {escape(c.label())}", highlight=False, soft_wrap=True)
            else:
                fix = "".join(f"\n  {escape(step)}" for step in c.fix.splitlines())
                console.print(f"[bold red]{escape(c.problem)}[/]{fix}", highlight=False, soft_wrap=True)
    if not json_out:
        for line in found.dv_log:
            console.print(f"[dim]dv-processing said: {escape(line)}[/]", highlight=False, soft_wrap=True)
        for what, error in (("pyusb", found.usb_error), ("dv-processing", found.dv_error)):
            if error:
                console.print(f"[yellow]{what}: {escape(error)}[/]", highlight=False, soft_wrap=True)
    if not found.ready:
        sys.exit(1)


@app.command()
def doctor() -> None:
    """Check the camera, permissions, /dev/uinput and libraries; print the fix for each failure."""
    from neurotouch_hid.doctor import report, run_checks

    code = report(run_checks(), console)
    if code:
        sys.exit(code)


# --- calibration (calibration.py) -------------------------------------------------------------
def _say_rest_geometry(say, source: str, result, markers: int) -> None:
    """``calibrate``'s lines on what the rest frames gave: the frames, the gel circle, the scale,
    the camera model and the marker count."""
    geometry = result.sensor
    span_s = (result.frames_t_us[-1] - result.frames_t_us[0]) / 1e6
    say(f"{len(result.frames_t_us)} rest frames of {source} over {span_s:.2f} s: the gel did not move")
    offset = math.hypot(
        geometry.gel_center_px[0] - result.grid_center_px[0], geometry.gel_center_px[1] - result.grid_center_px[1]
    )
    circle = (
        f"fitted to the gel's edge, {offset:.1f} px from the marker grid's centre"
        if result.edge_found
        else "the marker grid's extent + 4 mm"
    )
    say(
        f"gel circle: centre ({geometry.gel_center_px[0]:.2f}, {geometry.gel_center_px[1]:.2f}) px, "
        f"radius {geometry.gel_radius_px:.2f} px ({circle})"
    )
    say(
        f"scale: {geometry.px_per_mm:.4f} px/mm at the centre "
        f"(neighbouring markers there {result.spacing_px:.2f} px = 4 mm apart)"
    )
    if geometry.radial_k is not None:
        edge = geometry.gel_radius_px
        rim = geometry.image_to_user([[geometry.gel_center_px[0] + edge, geometry.gel_center_px[1]]])[0]
        say(
            f"camera model: radial_k {geometry.radial_k[0]:g}, {geometry.radial_k[1]:g} "
            f"(fitted to the 4 mm grid on the dome; the gel circle's rim at {math.hypot(*rim):.2f} mm "
            f"from the centre, {edge / geometry.px_per_mm:.2f} mm at the centre's scale)"
        )
    say(f"markers: {result.n_markers} found, {markers} expected")


@app.command()
def calibrate(
    source: str = typer.Option(
        "davis",
        "--source",
        help="davis (the live camera: you push the gel when asked), sim (the simulated gel: its hand does) "
        "or an AEDAT4 recording that starts with the gel at rest",
    ),
    out: Optional[Path] = typer.Option(
        None,
        "--out",
        help="sensor.yaml (or folder) to write (default: your config folder, where run, track and eval find it)",
    ),
    markers: int = typer.Option(177, "--markers", min=1, help="the gel's marker count (the paper's gel: 177)"),
    mirror: Optional[bool] = typer.Option(
        None,
        "--mirror/--no-mirror",
        help="the camera sees the gel from inside; with --rotation, instead of the guided pushes "
        "(a recording: default yes)",
    ),
    rotation: Optional[float] = typer.Option(
        None,
        "--rotation",
        help="counter-clockwise degrees from the (mirrored) image to your view; with --mirror/--no-mirror, "
        "instead of the guided pushes (a recording: default 0)",
        callback=_finite,
    ),
    check: bool = typer.Option(
        True,
        "--check/--no-check",
        help="with davis or sim: afterwards, ask for each gesture and say whether it reads right",
    ),
    frames: int = typer.Option(10, "--frames", min=3, help="rest frames to check and average (25 a second)"),
    press: Optional[Path] = typer.Option(
        None,
        "--press",
        help="an AEDAT4 recording of one press (a finger pressed in, held still ~2 s, lifted quickly, "
        "then ~2 s alone): also measure how the gel creeps",
    ),
    sim_rotation: float = typer.Option(
        0.0,
        "--sim-rotation",
        help="with --source sim: the simulated camera's rotation (degrees), for calibrate to find",
        callback=_finite,
    ),
    sim_mirror: bool = typer.Option(
        True,
        "--sim-mirror/--sim-no-mirror",
        help="with --source sim: whether the simulated camera sees the gel mirrored (from inside, as the real one)",
    ),
    seed: int = typer.Option(0, "--seed", min=0, help="with --source sim: the simulation's seed"),
) -> None:
    """Measure the gel's circle and scale on rest frames, and (camera or simulator) which way you
    look at it from two guided pushes, check each gesture, and save sensor.yaml (docs/dataset.md).

    Keep your hands off the gel until asked to push. Nothing is typed: each gesture is watched
    for up to 12 s. With --press, also measure the gel's creep (how slowly it relaxes after a
    release) on a recorded press; without it, a creep already in the sensor.yaml being replaced
    is kept."""
    import dataclasses

    from neurotouch_hid import calibration, calibration_guide
    from neurotouch_hid.errors import SensorError
    from neurotouch_hid.pipeline.creep import at_search_edge
    from neurotouch_hid.sensor import SensorGeometry, user_sensor_path

    def say(line: str) -> None:
        console.print(line, highlight=False, markup=False, soft_wrap=True)

    if source != SourceKind.SIM and (sim_rotation != 0.0 or not sim_mirror):
        raise NeurotouchError("--sim-rotation and --sim-no-mirror are for --source sim (the simulated camera)")
    if source in (SourceKind.DAVIS, SourceKind.SIM) and (mirror is None) != (rotation is None):
        raise NeurotouchError(
            "--mirror/--no-mirror and --rotation go together with the camera or simulator (both instead of the "
            "guided pushes): give both or neither"
        )
    if source in (SourceKind.DAVIS, SourceKind.SIM) and (check or mirror is None):
        from neurotouch_hid.warmup import compile_pipeline  # the guided pushes and the check use it

        err_console.print("loading the gesture pipeline (compiled on the first run only)", highlight=False)
        compile_pipeline()  # before the camera opens: nothing of the guided gestures waits for it
    with contextlib.ExitStack() as stack:
        guide: Optional[calibration_guide.GuidedSource] = None
        if source == SourceKind.SIM:
            guide = calibration_guide.SimulatedHand(
                SensorGeometry(mirror=sim_mirror, rotation_deg=sim_rotation), seed=seed
            )
        elif source == SourceKind.DAVIS:
            err_console.print("reading rest frames from the camera: keep your hands off the gel", highlight=False)
            guide = stack.enter_context(calibration_guide.LiveCamera(calibration.CAMERA_WAIT_S))
        rest = guide.rest_frames(frames) if guide is not None else calibration.read_rest_frames(source, frames)
        result = calibration.calibrate(rest, expected_markers=markers, n_frames=frames)
        geometry = result.sensor
        _say_rest_geometry(say, source, result, markers)
        items = guide.stream() if guide is not None else None
        if guide is None or (mirror is not None and rotation is not None):
            if guide is None and (mirror is None or rotation is None):
                say(
                    "mirror and rotation: not asked (a recording cannot be pushed; calibrate with the camera to "
                    "measure them, or give --mirror/--no-mirror and --rotation DEG): "
                    f"{'given' if mirror is not None else 'true, the default'} mirror, "
                    f"{'given' if rotation is not None else '0 deg, the default'} rotation"
                )
            mirror = True if mirror is None else mirror
            rotation = 0.0 if rotation is None else rotation
        else:
            say("which way you look at the gel: two guided pushes")
            mirror, rotation = calibration_guide.measure_orientation(guide, items, geometry, say)
            say(
                f"measured: mirror {'true' if mirror else 'false'} (the image is "
                f"{'a mirror of' if mirror else 'the same as'} your view), rotation {rotation:g} deg"
            )
        geometry = dataclasses.replace(geometry, mirror=mirror, rotation_deg=float(rotation))
        results = []
        if guide is not None and check:
            say("guided check: each gesture, read with this calibration")
            results = calibration_guide.guided_check(guide, items, geometry, say)
            wrong = [r for r in results if not r.right]
            say(
                f"guided check: {len(results) - len(wrong)} of {len(results)} gestures right"
                + (f"; wrong: {', '.join(r.step.name for r in wrong)}" if wrong else "")
            )
            advice = calibration_guide.check_advice(results, geometry)
            if advice:
                say(f"what to do: {advice}")
    for note in result.notes:
        say(f"note: {note}")
    checked_wrong = any(not r.right for r in results)  # exit 1, after writing

    if source == SourceKind.SIM and out is None:
        say(
            "nothing written: a simulated camera's calibration does not replace your sensor's in your config "
            "folder (--out FILE to keep it)"
        )
        sys.exit(1 if checked_wrong else 0)
    path = user_sensor_path() if out is None else (out / "sensor.yaml" if out.is_dir() else out)
    if press is not None:
        share, time_s = calibration.measure_creep(press, geometry)
        geometry = dataclasses.replace(geometry, creep=(share, time_s))
        say(
            f"creep: q {share:.2f}, tau {time_s:.2f} s (a press in {press}: {share:.0%} of a held deformation "
            f"comes with a delay of ~{time_s:.2f} s and relaxes as slowly after the release)"
        )
        if at_search_edge(share, time_s):
            say(
                "note: that is at the edge of what is searched (q up to 0.6, tau 0.05-3 s): the press may not "
                "have been held still, or lifted quickly; record it again if gestures end too early or too late"
            )
    if path.exists():
        try:
            old = SensorGeometry.load(path)
            if press is None and old.creep is not None:
                geometry = dataclasses.replace(geometry, creep=old.creep)
                say(f"creep: q {old.creep[0]:.2f}, tau {old.creep[1]:.2f} s, kept from {path} (--press to measure it)")
            changes = calibration.sensor_changes(old, geometry)
            say(f"replacing {path}: " + ("; ".join(changes) if changes else "the same values"))
        except SensorError as exc:
            say(f"replacing {path}, which was not a valid sensor.yaml ({exc})")
        if sys.stdin.isatty() and not typer.confirm(f"Replace {path}?", default=True):
            say("nothing written")
            return
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        geometry.save(path)
    except OSError as exc:
        raise SensorError(f"{path}: cannot write the sensor file: {exc.strerror}") from None
    say(f"wrote {path}")
    if path == user_sensor_path():
        say(
            "run, track, view and eval use it when no --sensor is given and no sensor.yaml is beside the recording "
            "or in the dataset"
        )
    else:
        say(f"use it with --sensor {path}, or calibrate without --out to make it your default")
    if checked_wrong:
        sys.exit(1)


# --- profiles (mapping/) ----------------------------------------------------------------------
@profile_app.command("list")
def profile_list() -> None:
    """List the profiles: shipped ones and the user's (a user copy shadows a shipped one)."""
    from rich.table import Table

    from neurotouch_hid.errors import ProfileError
    from neurotouch_hid.mapping.profile import available_profiles, load_profile, shipped_profiles_dir

    table = Table("name", "where", "description", "status")
    shipped = {p.stem for p in shipped_profiles_dir().glob("*.yaml")}
    for name, path in available_profiles().items():
        user = path.parent != shipped_profiles_dir()
        where = ("user (shadows shipped)" if name in shipped else "user") if user else "shipped"
        try:
            loaded = load_profile(path)
            table.add_row(name, where, loaded.description, "[green]ok[/]")
        except ProfileError:
            table.add_row(name, where, "", f"[red]invalid[/] (neurotouch-hid profile validate {path})")
    console.print(table)


@profile_app.command("use")
def profile_use(name: str = typer.Argument(..., help="profile name or path")) -> None:
    """Switch the running driver (`neurotouch-hid run`) to this profile, every output neutral first.

    Talks to the driver over $XDG_RUNTIME_DIR/neurotouch-hid/control.sock; with no driver running, says so
    (exit 2)."""
    from neurotouch_hid.control import request_use

    console.print(request_use(name), highlight=False, soft_wrap=True)


@profile_app.command("show")
def profile_show(name: str = typer.Argument(..., help="profile name or path")) -> None:
    """Print a profile's file (with its comments) and where it is.

    To a pipe or a file (``profile show NAME > mine.yaml``) it writes the file's exact bytes, and
    where it is to stderr."""
    from rich.syntax import Syntax

    from neurotouch_hid.mapping.profile import find_profile

    path = find_profile(name)
    if not console.is_terminal:
        err_console.print(f"# {path}", highlight=False, markup=False, soft_wrap=True)
        sys.stdout.flush()
        sys.stdout.buffer.write(path.read_bytes())
        sys.stdout.buffer.flush()
        return
    console.print(f"# {path}", highlight=False)
    console.print(Syntax(path.read_text(encoding="utf-8"), "yaml", background_color="default"))


@profile_app.command("new")
def profile_new(
    name: str = typer.Argument(..., help="name of the new user profile"),
    from_name: str = typer.Option("default", "--from", help="profile (name or path) to copy"),
) -> None:
    """Create a user profile as a copy of another one."""
    from neurotouch_hid.mapping.editor import new_profile

    console.print(f"created {new_profile(name, from_name)} (a copy of {from_name})", highlight=False)


def _note_shadow(name: str, path: Path) -> None:
    """Say that a change to the shipped profile ``name`` went to a user copy that now shadows it."""
    err_console.print(
        f"note: '{name}' is a shipped profile, so the change went to your copy, {path}, which replaces it "
        f"from now on (neurotouch-hid profile reset {name} goes back to the shipped one)",
        highlight=False,
        markup=False,
        soft_wrap=True,
    )


@profile_app.command("set", context_settings={"ignore_unknown_options": True})  # VALUE may be -1
def profile_set(
    name: str = typer.Argument(..., help="profile name (a shipped one is copied to the user folder)"),
    key: str = typer.Argument(..., help="dotted key, e.g. mappings.push.deadzone_mm"),
    value: str = typer.Argument(..., help="YAML value, e.g. 1.5, true, ABS_RX"),
) -> None:
    """Set one value; the profile is validated first and left unchanged if the result is invalid."""
    from neurotouch_hid.mapping.editor import creates_shadow, parse_value, set_values

    shadow = creates_shadow(name)
    path, previous = set_values(name, {key: parse_value(value)})
    console.print(f"{path}: {key}: {previous[key]!r} -> {value}", highlight=False, soft_wrap=True)
    if shadow:
        _note_shadow(name, path)


@profile_app.command("unset")
def profile_unset(
    name: str = typer.Argument(..., help="profile name"),
    key: str = typer.Argument(..., help="dotted key to undo"),
) -> None:
    """Undo one key: the shipped profile's value when the profile is a copy of one, else the default.

    The profile is validated first and left unchanged if the result is invalid."""
    from neurotouch_hid.mapping.editor import creates_shadow, unset_value

    shadow = creates_shadow(name)
    path, removed, shipped = unset_value(name, key)
    now = "removed, its default applies" if shipped is None else f"back to the shipped value {shipped!r}"
    console.print(f"{path}: {key}: {removed!r} -> {now}", highlight=False, soft_wrap=True)
    if shadow:
        _note_shadow(name, path)


@profile_app.command("delete")
def profile_delete(name: str = typer.Argument(..., help="user profile name")) -> None:
    """Delete one of your profiles (a copy of a shipped one: the shipped one applies again)."""
    from neurotouch_hid.mapping.editor import delete_profile

    path, shipped = delete_profile(name)
    again = f"; the shipped '{name}' ({shipped}) applies again" if shipped is not None else ""
    console.print(f"deleted {path}{again}", highlight=False, soft_wrap=True)


@profile_app.command("reset")
def profile_reset(name: str = typer.Argument(..., help="shipped profile name")) -> None:
    """Put a shipped profile back as shipped: delete your copy of it."""
    from neurotouch_hid.mapping.editor import reset_profile

    path, shipped = reset_profile(name)
    if path is None:
        console.print(f"'{name}' is already the shipped one ({shipped}): nothing to reset", highlight=False)
    else:
        console.print(f"deleted {path}: '{name}' is the shipped one again ({shipped})", highlight=False)


@profile_app.command("validate")
def profile_validate(path: str = typer.Argument(..., help="profile file (or name)")) -> None:
    """Check a profile; every problem is listed with its file, line, field, value and expectation."""
    from neurotouch_hid.mapping.profile import find_profile, load_profile

    loaded = load_profile(path)
    console.print(f"{find_profile(path)}: ok ({len(loaded.mappings)} mappings)", highlight=False)


def _edit_again(problem: str) -> bool:
    """After an invalid edit: show why and ask (on stdin, a terminal or not) whether to edit
    again; yes by default, no at the end of the input."""
    err_console.print(problem, highlight=False, markup=False, soft_wrap=True)
    err_console.print("edit it again? [Y/n] ", end="", highlight=False, markup=False)
    try:
        answer = sys.stdin.readline()
    except (OSError, ValueError):  # no input to read from
        answer = ""
    if not answer:
        err_console.print("")
    return bool(answer) and answer.strip().lower() in ("", "y", "yes")


@profile_app.command("edit")
def profile_edit(name: str = typer.Argument(..., help="profile name (a shipped one is copied when changed)")) -> None:
    """Edit a profile in $VISUAL or $EDITOR, as crontab -e: saved only when valid.

    An invalid save shows the problem and asks to edit again; answering no leaves the profile as
    it was and keeps your edit beside it (NAME.yaml.rejected)."""
    from neurotouch_hid.mapping.editor import creates_shadow, edit_profile

    shadow = creates_shadow(name)
    path = edit_profile(name, _edit_again)
    if path is None:
        console.print(f"'{name}' unchanged", highlight=False)
        return
    console.print(f"{path}: ok", highlight=False, soft_wrap=True)
    if shadow:
        _note_shadow(name, path)


@profile_app.command("path")
def profile_path(name: str = typer.Argument(..., help="profile name")) -> None:
    """Print the file a profile name resolves to (the user's copy, else the shipped one)."""
    from neurotouch_hid.mapping.profile import find_profile

    typer.echo(str(find_profile(name)))


def _game_label(section: str, key: object) -> str:
    return f"Steam app {key}" if section == "steam" else str(key)


@auto_app.callback()
def profile_auto(ctx: typer.Context) -> None:
    """A profile per game: `add GAME PROFILE`, `remove GAME`, `list` (also without a command).

    A game is a Steam app id (Steam sets SteamAppId in its processes' environment) or an
    executable's name; the running driver looks at your processes twice a second, switches to the
    game's profile (every output released first) and back when it exits. `profile use` during a
    game wins until the game exits."""
    if ctx.invoked_subcommand is None:
        profile_auto_list()


@auto_app.command("add")
def profile_auto_add(
    game: str = typer.Argument(..., help="Steam app id (a number) or executable name (e.g. supertuxkart)"),
    profile: str = typer.Argument(..., help="profile name or path"),
) -> None:
    """Map a game to a profile (an entry already there is replaced)."""
    from neurotouch_hid.games import add_game, games_file

    section, key, profile = add_game(game, profile)
    typer.echo(f"{_game_label(section, key)} -> {profile} (in {games_file()}); a running driver follows it")


@auto_app.command("remove")
def profile_auto_remove(
    game: str = typer.Argument(..., help="Steam app id or executable name, as added"),
) -> None:
    """Remove a game's entry."""
    from neurotouch_hid.games import games_file, remove_game

    section, key, profile = remove_game(game)
    typer.echo(f"removed {_game_label(section, key)} -> {profile} (from {games_file()})")


@auto_app.command("list")
def profile_auto_list() -> None:
    """List the map, and which mapped game runs now (the one the driver follows)."""
    from neurotouch_hid.games import EXECUTABLE, STEAM, ProcessScanner, games_file, load_game_map

    path = games_file()
    game_map = load_game_map(path)
    if not game_map:
        typer.echo(f"no game is mapped ({path} has no entry); add one: neurotouch-hid profile auto add 4242 mouse")
        return
    running = ProcessScanner().games(game_map)
    typer.echo(f"games -> profiles ({path}):")
    entries = [(STEAM, k, v) for k, v in game_map.steam.items()] + [
        (EXECUTABLE, k, v) for k, v in game_map.executable.items()
    ]
    for section, key, profile in entries:
        pids = [str(g.pid) for g in running if g.section == section and g.key == key]
        now = f"  running: pid {', '.join(pids)}" if pids else ""
        typer.echo(f"  {_game_label(section, key)} -> {profile}{now}")
    if running:
        typer.echo(f"matched now: {running[0].label()} -> {running[0].profile}")
    else:
        typer.echo("matched now: none (no mapped game is running)")


@profile_app.command("test")
def profile_test(
    name: str = typer.Argument(..., help="profile name or path"),
    source: str = typer.Option("sim", "--source", help="sim, an AEDAT4 recording, or predictions PRED.jsonl"),
    plot: Optional[Path] = typer.Option(None, "--plot", help="also draw the timeline to this PNG"),
    seconds: Optional[float] = typer.Option(
        None, "--seconds", help="only the first N seconds (sim: 20 s by default)", callback=_duration
    ),
    every_ms: int = typer.Option(100, "--every-ms", help="timeline sampling period (ms)"),
    json_out: bool = typer.Option(False, "--json", help="print the summary as JSON instead of tables"),
) -> None:
    """Replay a source through the pipeline and the profile; print the axis and button timeline."""
    import json

    from rich.table import Table

    from neurotouch_hid.controller import AXES
    from neurotouch_hid.driver import estimates_from_source
    from neurotouch_hid.mapping.profile import load_profile
    from neurotouch_hid.mapping.replay import (
        deflection,
        plot_timeline,
        pressed,
        replay,
        sample_timeline,
        summarise,
    )

    loaded = load_profile(name)
    estimates = list(estimates_from_source(source, seconds))
    states = replay(loaded, estimates)
    summary = summarise(states)
    if plot is not None:
        plot_timeline(estimates, states, plot)
    if json_out:
        typer.echo(
            json.dumps(
                {"estimates": len(estimates), "max_deflection": summary.max_deflection, "presses": summary.presses}
            )
        )
        return
    moved = [a for a in AXES if summary.max_deflection[a] > 0]
    table = Table("t (s)", "gesture", "mm", *moved, "buttons", title=f"{name} on {source} ({len(estimates)} windows)")
    t0 = estimates[0].t_us if estimates else 0
    for row in sample_timeline(estimates, states, every_ms * 1000):
        down = " ".join(b.removeprefix("BTN_") for b in pressed(row.state))
        table.add_row(
            f"{(row.t_us - t0) / 1e6:.1f}",
            row.estimate.gesture.value,
            f"{row.estimate.intensity_mm:.1f}",
            *(f"{deflection(a, row.state.axes[a]):+.2f}" for a in moved),
            down,
        )
    console.print(table)
    totals = Table("axis / button", "max deflection / presses", title="summary")
    for axis in AXES:
        totals.add_row(axis, f"{summary.max_deflection[axis]:.0%}")
    for button, count in summary.presses.items():
        if count:
            totals.add_row(button, str(count))
    console.print(totals)
    if plot is not None:
        console.print(f"plot: {plot}", highlight=False)


@profile_app.command("tune")
def profile_tune(
    name: str = typer.Argument(..., help="profile name (written to the user's copy)"),
    from_source: str = typer.Option(..., "--from", help="AEDAT4 recording or predictions PRED.jsonl of this user"),
    percentile: float = typer.Option(
        95.0, "--percentile", help="intensity percentile that gives full deflection", callback=_finite
    ),
) -> None:
    """Set each analogue mapping's saturation to what this user reaches (weak fingers, for one)."""
    from neurotouch_hid.driver import estimates_from_source
    from neurotouch_hid.mapping.editor import creates_shadow, set_values
    from neurotouch_hid.mapping.profile import load_profile
    from neurotouch_hid.mapping.replay import tuned_saturations

    if not 0 < percentile <= 100:
        raise NeurotouchError(f"--percentile {percentile}: expected a value in (0, 100]")
    tuned = tuned_saturations(load_profile(name), estimates_from_source(from_source), percentile)
    if not tuned:
        raise NeurotouchError(
            f"{from_source}: no gesture there exercises an analogue mapping of '{name}'; nothing tuned"
        )
    shadow = creates_shadow(name)
    path, _ = set_values(name, {f"mappings.{m}.saturation_mm": new for m, (_, new) in tuned.items()})
    for mapping, (old, new) in tuned.items():
        console.print(f"{mapping}: saturation_mm {old:g} -> {new:g}", highlight=False)
    console.print(f"written to {path}", highlight=False, soft_wrap=True)
    if shadow:
        _note_shadow(name, path)


def main() -> None:
    """Console-script entry point: user errors become one line on stderr and exit code 2.

    typer runs in its standalone mode, so a mistyped command line (missing argument, unknown
    option or command, bad value) is printed by typer itself (usage, the error, exit code 2)
    whichever click it uses (typer 0.29 carries its own copy and no longer installs click).
    """
    if COMPLETE_ENV in os.environ:  # a shell asks for completions (the scripts the package installs)
        from typer.completion import completion_init

        completion_init()
    try:
        app()
    except NeurotouchError as exc:
        err_console.print(f"[bold red]error:[/] {exc}", highlight=False, soft_wrap=True)
        sys.exit(2)
    except KeyboardInterrupt:
        sys.exit(130)


if __name__ == "__main__":  # pragma: no cover
    main()
