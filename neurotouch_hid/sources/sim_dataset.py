"""Simulated datasets: presets, users and sequences of the simulated gel written to files.

A dataset (docs/dataset.md) is ``sensor.yaml``, ``physics.json`` and per sequence an AEDAT4
recording of the simulated camera (:class:`~neurotouch_hid.sources.recording_writer.RecordingWriter`),
its labels and per-gesture press times (:mod:`neurotouch_hid.core.dataset`) and its true marker
positions (``.markers.npz``). The presets follow the paper's dataset (section "Creation of the
Gesture Detection Dataset"): one sequence per user and gesture type, or game sessions.
"""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

import numpy as np

from neurotouch_hid.core.dataset import LabelRow, write_labels, write_pressed
from neurotouch_hid.core.errors import NeurotouchError
from neurotouch_hid.core.estimate import GestureType
from neurotouch_hid.core.sensor import SensorGeometry
from neurotouch_hid.sources.esim import NOISE_RATE_HZ
from neurotouch_hid.sources.hands import SESSION_STREAM, SIM_GESTURES, TEST_USERS, TUNING_USERS, USERS
from neurotouch_hid.sources.physics import mix_families, physics_family
from neurotouch_hid.sources.recording_writer import RecordingWriter
from neurotouch_hid.sources.simulator import GelSimulator

#: Dataset presets: simulated seconds per sequence (``quick``, ``paper``: one sequence per user
#: and gesture type; ``sessions``: one game session per user, :func:`gesture_script` with ``session``).
PRESET_SECONDS: dict[str, float] = {"quick": 3.0, "paper": 60.0, "sessions": 10.0}


def preset_users(preset: str, seed: int) -> tuple[int, ...]:
    """The user ids a preset simulates for a seed.

    ``paper`` and ``sessions``: the 5 test users (0-4) for an even seed, the 5 tuning users (5-9)
    for an odd seed. ``quick``: one user, ``seed % 10``. Raises NeurotouchError for an unknown
    preset.
    """
    if preset in ("paper", "sessions"):
        return TEST_USERS if seed % 2 == 0 else TUNING_USERS
    if preset == "quick":
        return (seed % len(USERS),)
    raise NeurotouchError(f"unknown simulation preset {preset!r}: expected one of {', '.join(PRESET_SECONDS)}")


# --- datasets ---------------------------------------------------------------------------------
def sequence_name(user_id: int, gesture: GestureType) -> str:
    """Name of the sequence of one user and gesture type, e.g. ``u3_push``."""
    return f"u{user_id}_{gesture.value}"


def write_sequence(out_dir: Path, name: str, sim: GelSimulator, seconds: float, on_chunk=None) -> None:
    """Simulate ``seconds`` (then on until the gel rests again) and write ``NAME.aedat4``,
    ``NAME.labels.csv``, ``NAME.pressed.csv`` and ``NAME.markers.npz`` into ``out_dir``.

    ``NAME.pressed.csv`` (docs/dataset.md, "Per-gesture metrics") gives, for each gesture whose
    fingers start apart (a finger lags), when the gel under its last finger to press has moved
    0.3 mm (:meth:`GelSimulator.pressed_us`).

    ``NAME.markers.npz`` holds the true marker positions: ``t_us`` (T,) int64 (every 1 ms, which
    includes every APS frame), ``positions_px`` (T, N, 2) float32 image px and ``rest_px`` (N, 2)
    float32. ``on_chunk(elapsed_us)`` is called after every frame period with the simulated
    time so far (progress).
    """
    start_us = sim.t_us
    end_us = start_us + int(round(seconds * 1e6))
    labels: list[LabelRow] = []
    times: list[np.ndarray] = []
    positions: list[np.ndarray] = []
    with RecordingWriter(out_dir / f"{name}.aedat4", width=sim.sensor.width, height=sim.sensor.height) as writer:
        while True:
            chunk = sim.step()
            writer.write_frame(chunk.frame)
            writer.write_events(chunk.events)
            labels.append(chunk.label)
            times.append(chunk.t_us)
            positions.append(chunk.positions_px)
            if on_chunk is not None:
                on_chunk(sim.t_us - start_us)
            if sim.t_us >= end_us and chunk.label.resting:
                break
    write_labels(out_dir / f"{name}.labels.csv", labels)
    apart = [g for g in sim.performed if g.t_start_us < sim.t_us and any(lag > 0 for lag in g.lags_us)]
    write_pressed(
        out_dir / f"{name}.pressed.csv",
        [(g.t_start_us, t) for g in apart if (t := sim.pressed_us(g)) is not None],
    )
    save_npz(
        out_dir / f"{name}.markers.npz",
        t_us=np.concatenate(times),
        positions_px=np.concatenate(positions),
        rest_px=sim.gel.rest_px.astype(np.float32),
    )


def save_npz(path: Path, **arrays: np.ndarray) -> None:
    """``numpy.savez_compressed`` with the fastest deflate level (the 1 ms marker positions of
    a minute are ~85 MB raw; level 1 keeps the paper preset's writing time small)."""
    import zipfile

    from neurotouch_hid.core.atomic import replacing

    with (
        replacing(path, what="arrays file") as tmp,
        zipfile.ZipFile(tmp, "w", compression=zipfile.ZIP_DEFLATED, compresslevel=1) as zf,
    ):
        for key, value in arrays.items():
            with zf.open(f"{key}.npy", "w", force_zip64=True) as fh:
                np.lib.format.write_array(fh, np.asanyarray(value), allow_pickle=False)


def write_dataset(out_dir: str | Path, *args, force: bool = False, **kw) -> Path:
    """:func:`write_whole_dataset` written whole (:class:`~neurotouch_hid.core.dataset_out.DatasetOut`):
    into a new folder beside ``out_dir``, put in its place at the end; a dataset already in
    ``out_dir`` is refused unless ``force`` (then replaced whole), any other file there always.

    Raises:
        DatasetError: ``out_dir`` holds a dataset or other files, or cannot be written (nothing
            changed); and what :func:`write_whole_dataset` raises (nothing changed either).
    """
    from neurotouch_hid.core.dataset_out import DatasetOut

    target = DatasetOut(out_dir, force=force)
    try:
        write_whole_dataset(target.work, *args, **kw)
    except BaseException:
        target.discard()
        raise
    return target.commit()


def write_whole_dataset(
    out_dir: str | Path,
    preset: str = "quick",
    seed: int = 0,
    minutes: float | None = None,
    progress: bool = True,
    users: Sequence[int] | None = None,
    gestures: Sequence[GestureType | str] | None = None,
    sensor: SensorGeometry | None = None,
    noise_hz: float = NOISE_RATE_HZ,
    physics: str = "default",
) -> Path:
    """Simulate and write a labelled dataset (docs/dataset.md): ``sensor.yaml`` and, per user and
    gesture type, ``u{user}_{gesture}.aedat4``, ``.labels.csv`` and ``.markers.npz`` (the
    ``sessions`` preset: per user and session, ``u{user}_session{k}.*``).

    Args:
        out_dir: the dataset folder (created if missing).
        preset: ``quick`` (1 user x 5 gestures x 3 s, for tests), ``paper`` (5 users x 5
            gestures x 60 s: the paper's 25 minutes; section "Creation of the Gesture Detection
            Dataset") or ``sessions`` (5 users x one 10 s game session, :func:`gesture_script` with ``session``:
            the type changes from one gesture to the next, taps, ordinary gestures, long holds,
            short rests).
        seed: the same seed writes the same files; it also picks the users (:func:`preset_users`).
        minutes: total simulated minutes instead of the preset's (split over the sequences;
            ``sessions``: as many 10 s sessions per user as make it up, at least one).
        progress: show a rich progress bar on stderr.
        users: user ids (0-9) instead of the preset's, e.g. ``TUNING_USERS``.
        gestures: gesture types instead of all five.
        sensor: geometry (default docs/dataset.md's).
        noise_hz: background-activity noise rate per pixel (Hz, >= 0) of the simulated event
            camera (default 0.1, a DAVIS-346 in good light; real sensors reach a few Hz in dim
            light). The gesture scripts and labels do not depend on it.
        physics: a family of :data:`~neurotouch_hid.sources.physics.PHYSICS` for every sequence,
            or ``mix`` (one family per sequence, :func:`~neurotouch_hid.sources.physics.mix_families`).
            ``physics.json`` in the folder maps each sequence to its family.
    Returns:
        the dataset folder.
    Raises:
        NeurotouchError: unknown preset, user id, gesture or physics family, minutes <= 0 or
            noise_hz < 0.
        RecordingError: the folder cannot be written.
    """
    if preset not in PRESET_SECONDS:
        raise NeurotouchError(f"unknown simulation preset {preset!r}: expected one of {', '.join(PRESET_SECONDS)}")
    user_ids = tuple(users) if users is not None else preset_users(preset, seed)
    bad = [u for u in user_ids if not 0 <= int(u) < len(USERS)]
    if bad or not user_ids:
        raise NeurotouchError(f"simulated users are 0 to {len(USERS) - 1}, got {list(user_ids)}")
    try:
        kinds = [GestureType(g) for g in gestures] if gestures is not None else list(SIM_GESTURES)
    except ValueError as exc:
        raise NeurotouchError(f"unknown gesture type: {exc}") from None
    if not kinds or GestureType.NONE in kinds:
        raise NeurotouchError("gestures must be among push, pinch, zoom, twist_cw, twist_ccw")
    if minutes is not None and not minutes > 0:
        raise NeurotouchError(f"--minutes must be positive, got {minutes}")
    sessions = preset == "sessions"
    if sessions:
        per_user = 1 if minutes is None else max(1, round(minutes * 60.0 / PRESET_SECONDS[preset] / len(user_ids)))
        pairs: list[tuple[int, GestureType | int]] = [(int(u), k) for u in user_ids for k in range(per_user)]
    else:
        pairs = [(int(u), g) for u in user_ids for g in kinds]
    n_seq = len(pairs)
    families = mix_families(n_seq, seed) if physics == "mix" else [physics_family(physics)] * n_seq
    if not noise_hz >= 0:
        raise NeurotouchError(f"--noise-hz must be >= 0 (events per pixel per second), got {noise_hz}")
    seconds = PRESET_SECONDS[preset] if minutes is None or sessions else minutes * 60.0 / n_seq
    sensor = sensor or SensorGeometry()
    out = Path(out_dir)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise NeurotouchError(f"{out}: cannot create the dataset folder: {exc.strerror}") from None
    sensor.save(out / "sensor.yaml")
    import json

    names = [f"u{u}_session{k}" if sessions else sequence_name(u, k) for u, k in pairs]
    from neurotouch_hid.core.atomic import AtomicFile

    with AtomicFile(out / "physics.json", what="physics file") as fh:
        fh.write(
            json.dumps({"physics": physics, "sequences": {name: f.name for name, f in zip(names, families)}}, indent=1)
            + "\n"
        )

    from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn

    columns = (
        TextColumn("{task.description}", style="bold", markup=False),
        BarColumn(),
        TextColumn("{task.completed:.0f}/{task.total:.0f} s"),
        TimeElapsedColumn(),
        TimeRemainingColumn(),
    )
    from rich.console import Console

    # on stderr: what goes to stdout is the command's result only (a pipe got the bar's last frame)
    with Progress(*columns, console=Console(stderr=True), disable=not progress, transient=False) as bar:
        task = bar.add_task("simulating", total=n_seq * seconds)
        for k, ((uid, kind), name) in enumerate(zip(pairs, names)):
            bar.update(task, description=name)
            sim = GelSimulator(
                sensor,
                USERS[uid],
                kinds if sessions else [kind],
                seed=seed,
                stream_seed=(uid, SESSION_STREAM + kind if sessions else SIM_GESTURES.index(kind)),
                noise_rate_hz=noise_hz,
                physics=families[k],
                hand="session" if sessions else "drawn",
            )
            write_sequence(
                out,
                name,
                sim,
                seconds,
                on_chunk=lambda us, k=k: bar.update(task, completed=k * seconds + min(us * 1e-6, seconds)),
            )
    return out
