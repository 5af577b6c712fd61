"""The controller and its devices: ``run``, ``demo``, ``devices``, ``doctor`` and ``calibrate``.

Each command parses its options, calls one function of what it drives (driver.py, runtime.py,
sources/discovery.py, doctor.py, calibration.py, calibration_guide.py) and prints.
"""

from __future__ import annotations

import contextlib
import math
import sys
from pathlib import Path
from typing import Iterator, Optional

import typer

from neurotouch_hid.cli.common import (
    METHOD_HELP,
    MODEL_OPTION,
    chosen_model,
    console,
    davis_config,
    duration,
    err_console,
    finite,
    no_stdout,
    say_err,
)
from neurotouch_hid.core.errors import NeurotouchError
from neurotouch_hid.core.kinds import OutputKind, SourceKind
from neurotouch_hid.core.tables import print_table
from neurotouch_hid.targets.protocols import choices as protocol_choices
from neurotouch_hid.targets.protocols import help_text as protocol_help

#: The protocols of ``run --protocol`` (the protocol table's).
Protocol = protocol_choices()

app = typer.Typer()


@app.command()
def run(
    source: str = typer.Option(
        "davis",
        "--source",
        help="davis (live camera), sim (simulated gel), a recording path, or predictions PRED.jsonl "
        "(replayed without the pipeline)",
    ),
    profile: Optional[str] = typer.Option(
        None,
        "--profile",
        help="profile name or path (default, or empty: the camera's own profile.yaml when --serial has one, "
        "else default)",
    ),
    output: OutputKind = typer.Option(OutputKind.GAMEPAD, "--output", help="where the states go"),
    seconds: Optional[float] = typer.Option(None, "--seconds", help="stop after this many seconds", callback=duration),
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
        None,
        "--serial",
        help="the camera's serial number: with --source davis the camera to open (default: the only DAVIS-346), "
        "with sim the simulated camera's, with a recording the camera it is replayed as; its controller's "
        "identity and its own config folder follow from it (docs/several-sensors.md)",
    ),
    exposure_us: str = typer.Option(
        "4000", "--exposure-us", help="with --source davis: APS exposure in microseconds, or 'auto'"
    ),
    stall_timeout: float = typer.Option(
        1.0,
        "--stall-timeout",
        help="with --source davis: seconds without data that count as a lost camera",
        callback=finite,
    ),
    max_lag_ms: float = typer.Option(
        200.0,
        "--max-lag-ms",
        help="how far the pipeline may fall behind the camera (or a paced replay) before the oldest "
        "data is dropped; more lets a slow machine track every event, later",
        callback=finite,
    ),
    method: str = typer.Option("default", "--method", help=METHOD_HELP),
    model: Optional[str] = MODEL_OPTION,
    protocol: Optional[Protocol] = typer.Option(
        None,
        "--protocol",
        help=(
            f"with --output usb or hid, the protocol the controller speaks: {protocol_help()} "
            "(default: the profile's device: protocol, else the gadget set up here's, else hid)"
        ),
    ),
) -> None:
    """Run the driver: source -> pipeline -> profile -> virtual gamepad.

    Stops at the end of the source, after --seconds, on Ctrl-C (exit 130) or SIGTERM (a clean
    stop, exit 0), always leaving the gamepad neutral. SIGHUP reloads the profile. A camera that
    is unplugged or stalls centres the gamepad at once; the driver reconnects when it is back."""
    from neurotouch_hid.engine.driver import DriverOptions, run_driver

    with _summary_on_interrupt():
        stats = run_driver(
            source,
            profile or None,  # an empty --profile (the templated unit's default) is not given
            output,
            DriverOptions(
                seconds=seconds,
                fast=fast,
                out=out,
                window_us=window_us,
                sensor=sensor,
                seed=seed,
                console=console,
                wait=wait,
                davis=davis_config(serial, exposure_us, stall_timeout),
                say=say_err,
                max_lag_us=round(max_lag_ms * 1000),
                method=method,
                model=chosen_model(model),
                protocol=None if protocol is None else str(protocol),
                serial=serial,
            ),
        )
    err_console.print(stats.summary(), highlight=False, soft_wrap=True)


@contextlib.contextmanager
def _summary_on_interrupt() -> Iterator[None]:
    """A run ended by Ctrl-C still prints its summary (how far a first run's compile got) before
    the interrupt goes on (exit 130); one stopped before its first window (its start-up: a first
    run's imports and compile, the source opening) says that instead."""
    try:
        yield
    except KeyboardInterrupt as exc:
        stats = getattr(exc, "stats", None)
        said = (
            stats.summary()
            if stats is not None
            else "stopped during the start, before the first window: no output was sent"
        )
        err_console.print(said, highlight=False, soft_wrap=True)
        raise


@app.command()
def demo(
    seconds: Optional[float] = typer.Option(
        30.0, "--seconds", help="how long to run (the gesture under way then is finished)", callback=duration
    ),
) -> None:
    """A simulated gel performing every gesture, through the default profile, to the gamepad.

    Without a writable /dev/uinput the gamepad is shown in the terminal instead (one line says
    why); without a terminal, a line at each button or key change and at most one a second otherwise."""
    from neurotouch_hid.engine.driver import run_demo

    with _summary_on_interrupt():
        stats = run_demo(seconds, console=console, say=say_err)
    err_console.print(stats.summary(), highlight=False, soft_wrap=True)


@app.command()
def devices(json_out: bool = typer.Option(False, "--json", help="print JSON (for scripts) instead of a table")) -> None:
    """List the DAVIS-346 cameras: every USB 152a:841a device (pyusb) and what dv-processing sees;
    then which outputs are possible here (uinput pad, UHID device, USB gadget).

    For each: where it is, whether this user can open it and, if not, why and what to do (the
    udev rule, another program holding it, firmware); then which driver runs for each camera (and
    for a simulated or replayed one) and which config it uses (docs/several-sensors.md). Exit code
    0 when a camera is ready to use, 1 otherwise."""
    import json

    from rich.markup import escape
    from rich.table import Table
    from rich.text import Text

    from neurotouch_hid.service.doctor import camera_drivers, describe_camera_driver
    from neurotouch_hid.sources.discovery import discover, explain
    from neurotouch_hid.targets.gadget.support import possible_outputs

    found = discover()
    outputs = possible_outputs()
    drivers = camera_drivers(found)
    if json_out:
        listed = {**found.to_json(), "drivers": drivers, "outputs": outputs, "inputs": _mergeable_json()}
        typer.echo(json.dumps(listed, indent=1))
    elif not found.cameras:
        console.print(explain(found), style="bold red", highlight=False, soft_wrap=True)
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
                usb,
                dv,
                Text(c.status, style=style.get(c.status, "bold red")),
            )
        print_table(console, table)
        for c in found.cameras:
            if c.ready:
                console.print(f"[green]ready:[/] {escape(c.label())}", highlight=False, markup=True, soft_wrap=True)
            else:
                fix = "".join(f"\n  {escape(step)}" for step in c.fix.splitlines())
                console.print(f"[bold red]{escape(c.problem)}[/]{fix}", highlight=False, markup=True, soft_wrap=True)
    if not json_out:
        for line in found.dv_log:
            console.print(f"[dim]dv-processing said: {escape(line)}[/]", highlight=False, markup=True, soft_wrap=True)
        for what, error in (("pyusb", found.usb_error), ("dv-processing", found.dv_error)):
            if error:
                console.print(f"[yellow]{what}: {escape(error)}[/]", highlight=False, markup=True, soft_wrap=True)
        for row in drivers:
            console.print(escape(describe_camera_driver(row)), highlight=False, markup=True, soft_wrap=True)
        for kind, why in outputs.items():
            said = "[green]possible[/]" if why is None else f"[yellow]not here[/] ({escape(why)})"
            console.print(f"--output {kind}: {said}", highlight=False, markup=True, soft_wrap=True)
        _say_mergeable()
    if not found.ready:
        sys.exit(1)


def _mergeable_json() -> list[dict]:
    """``devices --json``'s ``inputs``: the input devices a profile's ``copilot:`` could name."""
    from neurotouch_hid.inputs.match import mergeable_devices, to_json

    return [to_json(info) for info in mergeable_devices()]


def _say_mergeable() -> None:
    """The input devices a profile's ``copilot:`` could merge into the pad, with what to write
    there: the name, the USB ids, or a stable path (docs/profiles.md, "Copilot")."""
    from rich.table import Table

    from neurotouch_hid.inputs.match import mergeable_devices

    inputs = mergeable_devices()
    if not inputs:
        console.print("no input device to merge into the pad (copilot:) is plugged in", highlight=False)
        return
    table = Table("device: (name)", "or ids", "or stable path", "node", title="input devices a copilot: can merge")
    for info in inputs:
        table.add_row(f'"{info.name}"', info.ids, "\n".join(info.links) or "-", info.path)
    print_table(console, table)


@app.command()
def doctor() -> None:
    """Check the camera, permissions, /dev/uinput and libraries; print the fix for each failure."""
    from neurotouch_hid.service.doctor import report, run_checks

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


def _sensor_file_replaceable(path: Path, inputs) -> None:
    """Before any work: ``path`` (calibrate's output) may be written: no link, folder or input
    (``atomic.check_output``), and when it exists, a YAML mapping (a sensor.yaml, even a broken
    one) or the config folder's sensor.yaml (``user_sensor_path``, replaced even when it is not
    YAML: doctor's fix for a broken one is calibrate). Raises NeurotouchError for any other file
    (a recording given as --out by mistake)."""
    from neurotouch_hid.core.atomic import check_output
    from neurotouch_hid.core.errors import SensorError
    from neurotouch_hid.core.limits import MAX_YAML_BYTES, YamlError, load_yaml, printable, read_outside_text
    from neurotouch_hid.core.sensor import user_sensor_path

    check_output(path, inputs, what="sensor file")
    if not path.parent.is_dir() and path != user_sensor_path():  # a typo in --out: said before the session
        raise NeurotouchError(
            f"{printable(path, 200)}: cannot write in {printable(path.parent, 200)}: no such folder (create it first)"
        )
    if not path.exists() or path == user_sensor_path():
        return
    try:
        data, _ = load_yaml(read_outside_text(path, MAX_YAML_BYTES, "sensor file", SensorError))
    except (SensorError, YamlError):
        data = None
    if not isinstance(data, dict):
        raise NeurotouchError(
            f"{printable(path, 200)} is not a sensor.yaml: calibrate replaces only a sensor file; "
            "give --out another name"
        )


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
        callback=finite,
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
        callback=finite,
    ),
    sim_mirror: bool = typer.Option(
        True,
        "--sim-mirror/--sim-no-mirror",
        help="with --source sim: whether the simulated camera sees the gel mirrored (from inside, as the real one)",
    ),
    seed: int = typer.Option(0, "--seed", min=0, help="with --source sim: the simulation's seed"),
    force: bool = typer.Option(
        False, "--force", help="write the sensor.yaml even when the guided check reads gestures wrong"
    ),
    serial: Optional[str] = typer.Option(
        None,
        "--serial",
        help="the camera to calibrate (--source davis); its sensor.yaml goes to its own config folder "
        "(sensors/SERIAL/, docs/several-sensors.md) unless --out",
    ),
) -> None:
    """Measure the gel's circle and scale on rest frames, and (camera or simulator) which way you
    look at it from two guided pushes, check each gesture, and save sensor.yaml (docs/dataset.md).
    A calibration the check finds wrong is not written (exit 1) unless --force.

    Keep your hands off the gel until asked to push. Nothing is typed: each gesture is waited
    for up to 12 s, and one started is watched to its end. With --press, also measure the gel's
    creep (how slowly it relaxes after a release) on a recorded press; without it, a creep
    already in the sensor.yaml being replaced is kept."""
    import dataclasses

    from neurotouch_hid.calibration import guide as calibration_guide
    from neurotouch_hid.calibration import measure as calibration
    from neurotouch_hid.core.errors import SensorError
    from neurotouch_hid.core.sensor import SensorGeometry, user_sensor_path
    from neurotouch_hid.pipeline.creep import at_search_edge

    def say(line: str) -> None:
        console.print(line, highlight=False, markup=False, soft_wrap=True)

    if source != SourceKind.SIM and (sim_rotation != 0.0 or not sim_mirror):
        raise NeurotouchError("--sim-rotation and --sim-no-mirror are for --source sim (the simulated camera)")
    if source in (SourceKind.DAVIS, SourceKind.SIM) and (mirror is None) != (rotation is None):
        raise NeurotouchError(
            "--mirror/--no-mirror and --rotation go together with the camera or simulator (both instead of the "
            "guided pushes): give both or neither"
        )
    no_stdout("--out", out, "calibrate writes a sensor file that run, track and eval read")
    if serial is not None:
        from neurotouch_hid.service.serials import check_serial, own_path

        try:
            check_serial(serial)
            out = own_path(serial, "sensor") if out is None else out
        except ValueError as exc:
            raise NeurotouchError(f"--serial: {exc}") from None
    path = user_sensor_path() if out is None else (out / "sensor.yaml" if out.is_dir() else out)
    _sensor_file_replaceable(path, (source if source not in (SourceKind.DAVIS, SourceKind.SIM) else None, press))
    if press is not None:  # read before the camera and the compile are needed: a wrong file fails now
        from neurotouch_hid.sources.recording import RecordingReader

        with RecordingReader(press):
            pass
    if source == SourceKind.DAVIS:  # no camera: said now, not after a first run's compile
        from neurotouch_hid.sources.davis import DavisConfig, require_camera_listed

        require_camera_listed(DavisConfig(serial=serial))
    if source in (SourceKind.DAVIS, SourceKind.SIM) and (check or mirror is None):
        from neurotouch_hid.service.warmup import (  # the guided pushes and the check use it
            compile_before,
            compile_pipeline,
        )

        compile_before(say_err, simulator=source == SourceKind.SIM)  # a first run: compiled in child processes, said
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
            guide = stack.enter_context(calibration_guide.LiveCamera(calibration.CAMERA_WAIT_S, serial=serial))
        rest = guide.rest_frames(frames) if guide is not None else calibration.read_rest_frames(source, frames)
        result = calibration.calibrate(rest, expected_markers=markers, n_frames=frames)
        geometry = result.sensor
        _say_rest_geometry(say, source, result, markers)
        for note in result.notes:  # said now: what looks off can be fixed before any push
            say(f"note: {note}")
        items = guide.stream() if guide is not None else None
        given = mirror is not None and rotation is not None  # no guided pushes: the options say
        if guide is None or given:
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
        results, wrong = [], []
        if guide is not None and check:
            say("guided check: each gesture, read with this calibration")
            results = calibration_guide.guided_check(guide, items, geometry, say, orientation_given=given)
            wrong = [r for r in results if not r.right and not r.again]  # read wrong: the calibration's fault
            undone = [r for r in results if not r.right and r.again]  # not done as asked, twice: not checked
            say(
                f"guided check: {sum(r.right for r in results)} of {len(results)} gestures right"
                + (f"; wrong: {', '.join(r.step.name for r in wrong)}" if wrong else "")
                + (f"; not done as asked: {', '.join(r.step.name for r in undone)}" if undone else "")
            )
            if undone and not wrong:
                say(
                    "gestures not done as asked say nothing against this calibration: they do not keep it "
                    "from being written (calibrate again to check them)"
                )
            advice = calibration_guide.check_advice(results, geometry, orientation_given=given)
            if advice:
                say(f"what to do: {advice}")
    if wrong and not force:  # nothing written unless --force; exit 1
        say(
            "nothing written: the guided check read gestures wrong with this calibration "
            "(do what is said above, or --force to write it anyway)"
        )
        sys.exit(1)

    if source == SourceKind.SIM and out is None:
        say(
            "nothing written: a simulated camera's calibration does not replace your sensor's in your config "
            "folder (--out FILE to keep it)"
        )
        sys.exit(1 if wrong else 0)
    if press is not None:
        creep = calibration.measure_creep(press, geometry)
        geometry = dataclasses.replace(geometry, creep=creep)
        if creep is None:
            say(f"creep: none (a press in {press} relaxes as an elastic gel's does: gestures end when the gel is back)")
        else:
            share, time_s = creep
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
    try:
        if path == user_sensor_path():  # your config folder, made on the first calibration
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
    elif not wrong:
        say(f"use it with --sensor {path}, or calibrate without --out to make it your default")
    if wrong:
        say("written with --force although the guided check read gestures wrong: gestures may come out turned")
        sys.exit(1)
