"""Enrolment: ``enrol`` (a guided session, its plan, or labelling a recording made by following one)
and ``adapt`` (the recogniser fitted to one gel and hand from enrolments).

Each command parses its options, calls one function of the stage it drives
(enrolment/plan.py, enrolment/label.py, enrolment/session.py; enrolment/adapt.py,
enrolment/model.py) and prints.
"""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from neurotouch_hid.cli.common import console, err_console, human_console, long_lived_start_up, no_stdout, say_err
from neurotouch_hid.core.errors import NeurotouchError

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
    source: Optional[str] = typer.Option(
        None,
        "--source",
        help="davis (the live camera: you follow the prompts; the default) or sim (the simulated hand does)",
    ),
    serial: Optional[str] = typer.Option(
        None, "--serial", help="with --source davis: the camera's serial number (default: the first DAVIS-346)"
    ),
    physics: str = typer.Option("default", "--physics", hidden=True, help="with --source sim: the gel's family"),
    sim_miss: list[int] = typer.Option(
        [], "--sim-miss", hidden=True, help="with --source sim: a prompt number the hand misses (repeatable)"
    ),
    sim_miss_rate: float = typer.Option(
        1 / 20, "--sim-miss-rate", hidden=True, min=0.0, max=1.0, help="with --source sim: the share of prompts missed"
    ),
    fast: bool = typer.Option(False, "--fast", hidden=True, help="with --source sim: do not pace in real time"),
    force: bool = typer.Option(False, "--force", help="replace the dataset --out holds, whole"),
) -> None:
    """Teach the driver your gel and your hand: a guided session of at most 3 minutes.

    --plan-out FILE writes the session's prompts without running it. --from REC.aedat4 --plan FILE
    --out DIR labels a recording made by following that plan elsewhere: the type from each prompt,
    the moments, contacts and intensity from the gel; a prompt with no gesture near its cue, or
    whose gesture is not what it asked, is left out and said; a recording that does not follow
    the plan is refused (docs/dataset.md). The folder written is a dataset (docs/dataset.md) that `eval DIR` reads,
    written whole at the end: a dataset there is refused unless --force, then replaced."""
    from neurotouch_hid.enrolment.plan import MAX_SESSION_S, make_plan, read_plan, write_plan

    no_stdout("--out", out, "an enrolment is a dataset folder")
    chosen = read_plan(plan) if plan is not None else make_plan(seed)
    if plan_out is not None:
        if from_recording is not None:
            raise NeurotouchError("--plan-out writes a plan and stops: give it without --from")
        write_plan(chosen, plan_out, inputs=(plan,))
        human_console(plan_out).print(  # standard output holds the plan
            f"{len(chosen.prompts)} prompts over {chosen.end_s:.0f} s -> {plan_out}", highlight=False, soft_wrap=True
        )
        return
    if from_recording is not None:
        session_only = {
            "--source": source is not None,
            "--serial": serial is not None,
            "--physics": physics != "default",
            "--sim-miss": bool(sim_miss),
            "--sim-miss-rate": sim_miss_rate != 1 / 20,
            "--fast": fast,
        }
        given = [name for name, on in session_only.items() if on]
        if given:
            raise NeurotouchError(
                f"{', '.join(given)}: for a guided session, not for --from (which labels a recording made "
                "elsewhere, by the camera that recorded it): give --from without "
                + ("it" if len(given) == 1 else "them")
            )
        _label(from_recording, plan, chosen, out, sensor, force)
        return
    source = source if source is not None else "davis"
    if source not in ("davis", "sim"):
        raise NeurotouchError(f"--source {source!r}: expected davis (the live camera) or sim (the simulated hand)")
    if chosen.end_s > MAX_SESSION_S:
        raise NeurotouchError(
            f"{plan}: the plan lasts {chosen.end_s:.0f} s, more than an enrolment's {MAX_SESSION_S:.0f} s"
        )
    _session(chosen, source, out, sensor, seed, serial, physics, sim_miss, sim_miss_rate, fast, force)


def _session(plan, source, out, sensor, seed, serial, physics, sim_miss, sim_miss_rate, fast, force=False) -> None:
    """The guided session: prompts on the terminal while the camera records; the dataset written."""
    import contextlib
    import signal
    import threading

    with long_lived_start_up():
        from neurotouch_hid.core.sensor import SensorGeometry, default_sensor
        from neurotouch_hid.enrolment.plan import Script
        from neurotouch_hid.enrolment.prompt_view import PromptView
        from neurotouch_hid.enrolment.session import CameraSource, SimulatedHandSource, enrolment_folder, run_session
        from neurotouch_hid.pipeline.pipeline import GesturePipeline
        from neurotouch_hid.service.warmup import compile_before

        if source == "sim":
            if sensor is not None:
                raise NeurotouchError("--sensor is for the live camera: the simulated gel has its own geometry")
            guide = SimulatedHandSource(seed, physics=physics, miss_rate=sim_miss_rate, misses=sim_miss)
            geometry = guide.sensor
        else:
            from neurotouch_hid.cli.common import davis_config
            from neurotouch_hid.sources.davis import require_camera_listed

            geometry = SensorGeometry.load(sensor) if sensor is not None else default_sensor()
            config = davis_config(serial, "4000", 1.0)
            require_camera_listed(config)  # not after a first run's compile
            guide = CameraSource(config)
        compile_before(say_err, simulator=source == "sim")  # a first run: compiled in child processes, said
        GesturePipeline(geometry).compile_kernels()  # before the camera opens: nothing waits for it
    from neurotouch_hid.core.dataset_out import DatasetOut

    target = DatasetOut(out if out is not None else enrolment_folder(), force=force)  # before the session
    stop = threading.Event()
    with contextlib.ExitStack() as stack:
        stack.callback(target.discard)  # what is left of it when the session did not put it in place
        for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):  # SIGHUP: the terminal closed
            stack.callback(signal.signal, sig, signal.signal(sig, lambda *_: stop.set()))
        if isinstance(guide, CameraSource):
            stack.enter_context(guide)
        script = Script(plan)
        view = stack.enter_context(PromptView(console, script, by_hand=guide.by_hand))
        result = run_session(
            script, guide, target, geometry, [view],
            pace=source == "sim" and not fast, stop=stop, on_progress=view.labelling,
        )  # fmt: skip
    if result.stopped:
        console.print("stopped: what was recorded is labelled", highlight=False, soft_wrap=True)
    say_labelled(result.labelled, dict(result.asked_again), simulated=source == "sim")


def _at(found) -> str:
    from neurotouch_hid.enrolment.prompt_view import clock

    return f"{found.prompt.name} at {clock(found.prompt.cue_s)}"


def _label(
    recording: Path, plan_path: Optional[Path], plan, out: Optional[Path], sensor: Optional[Path], force: bool = False
) -> None:
    """``enrol --from``: label ``recording`` with ``plan`` into ``out``, say what was left out."""
    import dataclasses

    from neurotouch_hid.core.dataset_out import DatasetOut

    if plan_path is None or out is None:
        raise NeurotouchError("--from REC.aedat4 needs the plan it followed (--plan FILE) and --out DIR")
    with long_lived_start_up():
        from neurotouch_hid.core.sensor import chosen_sensor_file, find_sensor_file, user_sensor_path
        from neurotouch_hid.enrolment.label import label_recording
        from neurotouch_hid.pipeline.pipeline import GesturePipeline
        from neurotouch_hid.pipeline.track import recording_progress
        from neurotouch_hid.service.warmup import compile_before

        geometry = find_sensor_file(recording, sensor)
        chosen = chosen_sensor_file(recording, sensor)
        if chosen is None:
            say_err(
                f"{recording}: no sensor.yaml beside it, no --sensor and no calibration of yours: labelled with the "
                "built-in geometry, not the gel's that recorded it (give --sensor FILE, or put its sensor.yaml "
                "beside the recording)"
            )
        elif sensor is None and chosen == user_sensor_path():
            say_err(f"{recording}: no sensor.yaml beside it: labelled with your calibration ({chosen})")
        compile_before(say_err)  # a first run: compiled in child processes, said
        GesturePipeline(geometry).compile_kernels()
    beside = recording.with_name("sensor.yaml")
    inputs = [plan_path, sensor if sensor is not None else beside]
    target = DatasetOut(out, force=force)  # before the work: a dataset there is never at risk
    try:
        with recording_progress(err_console, "labelling") as report:
            done = label_recording(
                recording, plan, target.work, geometry, inputs=inputs, on_progress=report, past_end=True, strict=True
            )
    except BaseException:
        target.discard()
        raise
    from neurotouch_hid.enrolment.adapt import simulated_sequences

    folder = target.commit()  # adapt refuses a simulated enrolment as the user's model: say --out then
    say_labelled(dataclasses.replace(done, folder=folder), simulated=bool(simulated_sequences([folder])))


def say_labelled(done, again: dict[int, int] | None = None, simulated: bool = False) -> None:
    """Print where a labelled enrolment went (``enrolment.label.Labelled``) and each prompt left
    out; ``again`` (a session's: prompt index -> the index of the prompt that asked it again) says
    how each prompt not seen fared when asked again; ``simulated``: the simulated hand's (its
    model is written only where ``adapt --out`` says)."""
    adapt = f"adapt {done.folder} --out sim-model.yaml" if simulated else f"adapt {done.folder}"
    console.print(
        f"labelled {done.labelled} of {len(done.found)} prompts -> {done.folder} ({done.name}.aedat4, "
        f"{done.name}.labels.csv, sensor.yaml); `neurotouch-hid {adapt}` fits the recogniser to it, "
        f"`neurotouch-hid eval {done.folder}` scores it",
        highlight=False,
        soft_wrap=True,
    )
    if done.kept == "linked":
        console.print(
            f"{done.name}.aedat4 there is a second name (a hard link) of the recording, not a copy: no space taken",
            highlight=False,
            soft_wrap=True,
        )
    elif done.kept == "referred":
        console.print(
            f"{done.name}.aedat4 there refers to the recording (a symbolic link, on another file system): keep the "
            "recording where it is, or copy it into the folder",
            highlight=False,
            soft_wrap=True,
        )
    for i, f in enumerate(done.found):
        if f.seen and not f.labelled:
            console.print(
                f"prompt {i + 1} ({_at(f)}): {f.disagrees}, not the {f.prompt.name} asked: left out",
                highlight=False,
                soft_wrap=True,
            )
    if again is not None:
        retries = set(again.values())
        for i, f in enumerate(done.found):
            if f.seen or i in retries:
                continue
            line = f"prompt {i + 1} ({_at(f)}): not seen"
            if i not in again:
                line += ", no time left to ask again: left out"
            else:
                j = again[i]
                redone = done.found[j]
                if redone.labelled:
                    fared = "seen"
                elif redone.seen:
                    fared = "seen, but not the gesture asked (above): left out"
                else:
                    fared = "not seen either: left out"
                line += f"; asked again as prompt {j + 1} ({_at(done.found[j])}): {fared}"
            console.print(line, highlight=False, soft_wrap=True)
        return
    if done.past_end:
        first = len(done.found) + 1
        console.print(
            f"prompts {first} to {first + done.past_end - 1} are cued after the recording's end: left out",
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


@app.command()
def adapt(
    datasets: Optional[list[Path]] = typer.Argument(
        None, help="enrolment datasets (docs/dataset.md folders), one or more"
    ),
    out: Optional[Path] = typer.Option(
        None,
        "--out",
        help="the model file to write (default: your model.yaml beside sensor.yaml, used by default; "
        "- : standard output)",
    ),
    jobs: int = typer.Option(2, "--jobs", min=1, help="sequences run in parallel processes"),
    reset: bool = typer.Option(
        False, "--reset", help="go back to the shipped recogniser: your model.yaml is renamed model.yaml.bak"
    ),
) -> None:
    """Fit the recogniser to your gel and hand from enrolment datasets; hold part out to check it.

    Refits the learned gesture type (the shipped one as its prior), the contact and resting
    thresholds, the wait for a second finger and the intensity scale; keeps the shipped value
    wherever the fit does not beat it on the held-out gestures, and says what it changed
    (docs/method.md, "Adaptation"); with too few gestures to hold 3 out, it replaces no model. An
    enrolment from the simulated camera (--source sim) is written only where --out says, never as
    your model. Labels that the shipped recogniser reads as other types for most gestures are
    refused (they follow a plan the recording did not). --reset goes back to the shipped one."""
    from neurotouch_hid.enrolment.adapt import adapt as fit
    from neurotouch_hid.enrolment.adapt import check_output, fitted_info, simulated_sequences, summary
    from neurotouch_hid.enrolment.adapt_record import contradiction, record_datasets
    from neurotouch_hid.enrolment.model import Model, reset_user_model, user_model_path

    if reset:
        if datasets or out is not None:
            raise NeurotouchError("--reset goes back to the shipped recogniser: give it without datasets or --out")
        console.print(reset_user_model(), highlight=False, soft_wrap=True, markup=False)
        return
    if not datasets:
        raise NeurotouchError(
            "adapt needs enrolment datasets (the folders `neurotouch-hid enrol` wrote), or --reset to go back to the "
            "shipped recogniser"
        )
    if out is None:
        simulated = simulated_sequences(datasets)
        if simulated:
            raise NeurotouchError(
                f"{simulated[0]} was recorded from the simulated camera (enrol --source sim): a model fitted to the "
                "simulated hand would make every command read your gel as the simulation moves, so it does not "
                "become your model; give --out FILE to write it elsewhere (and try it with --model FILE)"
            )
    target = check_output(out if out is not None else user_model_path(), datasets)
    datasets = _once(datasets)

    records = record_datasets(datasets, jobs=jobs, on_sequence=lambda name: say_err(f"recorded {name}"))
    wrong = contradiction(records)
    if wrong is not None:
        raise NeurotouchError(f"{', '.join(map(str, datasets))}: {wrong}")
    adaptation = fit(records, rerun=lambda config: record_datasets(datasets, jobs=jobs, config=config))
    said = human_console(out)  # stderr when the model goes to standard output
    for line in summary(adaptation):
        said.print(line, highlight=False, soft_wrap=True, markup=False)
    if adaptation.note and target.is_file():  # nothing fitted: a model of nothing would replace one fitted before
        raise NeurotouchError(
            f"no model written to {target} (the one there is left as it was): too few gestures to check a change "
            "on (above)"
        )
    model = adaptation.model
    written = Model(model.settings, model.classifier, fitted_info(adaptation, datasets)).save(target)
    said.print(f"-> {written}", highlight=False, soft_wrap=True, markup=False)
    if out is None:
        console.print(
            "run, the service and every command use it from now on (--model none on one of them: the shipped one); "
            "`neurotouch-hid adapt --reset` goes back to the shipped recogniser",
            highlight=False,
            soft_wrap=True,
            markup=False,
        )


def _once(datasets: list[Path]) -> list[Path]:
    """``datasets`` with each folder once (the same folder by its device and inode, however it is
    spelled), the others said: a copy of a fitted gesture would be held out as unseen."""
    import os

    kept, seen = [], set()
    for d in datasets:
        try:
            info = os.stat(d)
            key: object = (info.st_dev, info.st_ino)
        except OSError:
            key = d  # missing: the reader says so
        if key in seen:
            say_err(f"{d}: given more than once: read once (a copy's gestures would be held out as never seen)")
            continue
        seen.add(key)
        kept.append(d)
    return kept
