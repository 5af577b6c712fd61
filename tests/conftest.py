"""Shared fixtures: the real-kernel boots of a test session (tests/kernel/vm.py: two guests side
by side, their results merged), a user config folder in tmp for every other test,
``cli``: the profile commands run in this process, and the recordings many test modules read:
each simulated once per session, the real street recording where it is, and a simulated street
for a clone without it (../shared).

The boots start in the background as soon as the tests are collected, when any test needs them,
and the tests that need them run last: the host's tests run while the guests boot and check."""

from __future__ import annotations

import os
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))
from helpers import STREET, run_main, started  # noqa: E402
from kernel.vm import (  # noqa: E402
    KernelUnavailable,
    boot_summary,
    cancel_background_boot,
    guest_results,
    start_background_boot,
)


def _needs_guest(item: pytest.Item) -> bool:
    return "guest" in getattr(item, "fixturenames", ())


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """The tests on the guest's results last (in their own order), so that the boot overlaps the
    host's tests."""
    items.sort(key=_needs_guest)  # stable: the order within each group is kept


def pytest_collection_finish(session: pytest.Session) -> None:
    if not session.config.option.collectonly and any(_needs_guest(item) for item in session.items):
        # the guests' checks outlast the host's tests: both guests boot at once (vm.BackgroundBoot)
        start_background_boot(side_by_side=True)


def pytest_terminal_summary(terminalreporter, exitstatus: int, config: pytest.Config) -> None:
    line = boot_summary()
    if line:
        terminalreporter.write_line(line)


def pytest_sessionfinish(session: pytest.Session, exitstatus: int) -> None:
    cancel_background_boot()  # an interrupted or -x session leaves no qemu behind


@pytest.fixture(scope="session", autouse=True)
def started_early(request):
    """Work some test modules start at the session's start, in the background, for their tests to
    take later: each module among the session's tests that defines ``start_early(request)`` (given
    this fixture's request, for session fixtures) has it called once, before the first test, and
    its ``stop_early()`` at the session's end (what its tests did not take: a ``-x`` or ``-k``
    session stops it). A module's own fixture waits for what it started, or starts it then when it
    was not started early (the module run alone still starts it at once)."""
    modules = list(dict.fromkeys(item.module for item in request.session.items if hasattr(item, "module")))
    starters = [m for m in modules if hasattr(m, "start_early")]
    for module in starters:
        request.addfinalizer(module.stop_early)
        module.start_early(request)
    yield


@pytest.fixture(autouse=True)
def user_config_in_tmp(request, tmp_path, monkeypatch) -> Path | None:
    """Every test's user config folder (profiles, calibrated sensor.yaml) is an empty folder in
    tmp, so that tests never read or write the real one (platformdirs follows XDG_CONFIG_HOME).
    Not for the kernel tests: the guest boots with the environment it always had."""
    if request.node.get_closest_marker("kernel"):
        return None
    folder = tmp_path / "config"
    monkeypatch.setenv("XDG_CONFIG_HOME", str(folder))
    return folder


@pytest.fixture(scope="session")
def guest() -> dict:
    """The JSON results of every guest check (tests/kernel/checks_*.py), from the session's boots of
    Debian's kernel under qemu. Skips, with the reason, only where qemu cannot be installed at all."""
    try:
        return guest_results()
    except KernelUnavailable as exc:
        pytest.skip(reason=f"cannot boot a real kernel here: {exc}")


def passed(guest: dict, name: str) -> dict:
    """The details of guest check ``name``, failing the test with the guest's error if it failed."""
    entry = guest.get(name)
    assert entry is not None, f"the guest did not run {name} (setup: {guest.get('setup')})"
    assert entry["ok"], f"{name}: {entry.get('error')}\n{entry.get('traceback', '')}\nboot: {guest.get('_boot')}"
    return entry["details"]


def passed_part(guest: dict, check: str, name: str) -> dict:
    """The details of part ``name`` of guest check ``check`` (checks_davis.py's parts), failing the
    test with the part's error if it failed."""
    entry = passed(guest, check)[name]
    assert entry["ok"], f"{name}: {entry.get('error')}\n{entry.get('traceback', '')}"
    return entry["details"]


@pytest.fixture()
def cli(tmp_path, monkeypatch, capsys):
    """``neurotouch-hid profile ARGS`` in this process (cli.main: errors -> exit 2), XDG in tmp;
    ``cli.user_dir``: the user's profiles folder."""
    monkeypatch.setenv("XDG_CONFIG_HOME", str(tmp_path / "config"))
    monkeypatch.delenv("VISUAL", raising=False)

    def run(*args: str, editor: str | None = None) -> subprocess.CompletedProcess:
        if editor is not None:
            monkeypatch.setenv("EDITOR", editor)
        done = run_main(monkeypatch, capsys, ["profile", *args])
        return subprocess.CompletedProcess(args, done.returncode, done.stdout, done.stderr)

    run.user_dir = tmp_path / "config" / "neurotouch-hid" / "profiles"
    return run


# --- recordings ----------------------------------------------------------------------------------
@dataclass(frozen=True)
class KnownRecording:
    """An AEDAT4 recording and what is known of it independently of the reader under test (the
    dataset's README, or what was written)."""

    path: Path
    camera_name: str
    n_events: int
    n_frames: int
    duration_s: float  # rounded to 10 ms


@pytest.fixture(scope="session")
def street_recording() -> KnownRecording:
    """The real street recording (LZ4, a street in view, no gel), as its README describes it;
    skips, saying so, where the shared data is not beside the repository."""
    if not STREET.exists():
        pytest.skip(reason=f"{STREET} (the real DAVIS-346 street recording in shared/) is not on this machine")
    return KnownRecording(STREET, "DAVIS346_00000002", 78_830, 59, 2.36)


def street_scene(seconds: float = 2.5, seed: int = 0, t0_us: int = 1_700_000_000_000_000):
    """A made-up street as a DAVIS-346 would see it: sky, road, two buildings, a car driving by
    (4 px a frame), nine small street lamps (bright blobs, no grid), pixel noise; APS frames at
    25 Hz and events where the log intensity changed between frames plus background activity
    (~50 k events/s). Returns (events EVENT_DTYPE time-ordered, [Frame]) with Unix-time stamps (us)."""
    from neurotouch_hid.sources import EVENT_DTYPE, Frame

    rng = np.random.default_rng(seed)
    h, w = 260, 346
    yy, xx = np.mgrid[0:h, 0:w]
    still = 150 + 60 * (1 - yy / h)  # the sky, brighter at the top
    still[150:, :] = 70  # the road
    still[60:150, 30:110] = 100
    still[40:150, 220:300] = 120
    lamps = np.zeros((h, w))
    for lx, ly in zip(rng.uniform(20, w - 20, 9), rng.uniform(160, 250, 9)):
        lamps += 160 * np.exp(-((xx - lx) ** 2 + (yy - ly) ** 2) / (2 * 0.8**2))
    frames, events, previous = [], [], None
    for k in range(int(seconds * 25)):
        t_us = t0_us + k * 40_000
        image = still.copy()
        car = (20 + 4 * k) % (w + 80) - 80
        image[170:215, max(car, 0) : max(car + 80, 0)] = 40
        image = np.clip(image + lamps + rng.normal(0, 2, image.shape), 0, 255).astype(np.uint8)
        frames.append(Frame(t_us, image))
        if previous is not None:
            change = np.log1p(image.astype(float)) - np.log1p(previous.astype(float))
            ys, xs = np.nonzero(np.abs(change) > 0.15)
            moved = np.zeros(len(ys), EVENT_DTYPE)
            moved["x"], moved["y"], moved["polarity"] = xs, ys, change[ys, xs] > 0
            moved["timestamp"] = t_us - 40_000 + rng.integers(0, 40_000, len(ys))
            events.append(moved)
        noise = np.zeros(rng.poisson(2000), EVENT_DTYPE)
        noise["x"], noise["y"] = rng.integers(0, w, len(noise)), rng.integers(0, h, len(noise))
        noise["polarity"] = rng.integers(0, 2, len(noise))
        noise["timestamp"] = t_us + rng.integers(0, 40_000, len(noise))
        events.append(noise)
        previous = image
    events = np.concatenate(events)
    return events[np.argsort(events["timestamp"], kind="stable")], frames


@pytest.fixture(scope="session")
def sim_street_recording(tmp_path_factory) -> KnownRecording:
    """:func:`street_scene` written as an AEDAT4 recording (LZ4, like the camera's): what the
    street recording's tests also run on where it is missing."""
    from neurotouch_hid.sources.recording_writer import write_recording

    events, frames = street_scene()
    path = tmp_path_factory.mktemp("street") / "street.aedat4"
    write_recording(path, events, frames, camera_name="DAVIS346_00000499")
    start_us = min(int(events["timestamp"][0]), frames[0].t_us)
    duration_s = round((max(int(events["timestamp"][-1]), frames[-1].t_us) - start_us) / 1e6, 2)
    return KnownRecording(path, "DAVIS346_00000499", len(events), len(frames), duration_s)


@pytest.fixture(scope="session", params=["real", "simulated"])
def any_street(request) -> KnownRecording:
    """A street in view, no gel: the real recording (skipped where it is missing) and the
    simulated one."""
    return request.getfixturevalue("street_recording" if request.param == "real" else "sim_street_recording")


@pytest.fixture(scope="session")
def sim_gel_chunks() -> list:
    """7 s of the simulated gel, seed 0 (``SimulatedSource(seed=0).chunks``: rest, a push held
    from 0.6 to 2.8 s, rest from 3.0 s, a pinch from 4.6 s), one chunk per APS frame period."""
    from neurotouch_hid.sources.simulator import SimulatedSource

    return list(SimulatedSource(seed=0).chunks(7.0))


def write_chunks(path: Path, chunks: list) -> Path:
    """Chunks of the simulated gel written as an AEDAT4 recording (each frame, then its events)."""
    from neurotouch_hid.sources.recording_writer import RecordingWriter

    with RecordingWriter(path) as writer:
        for chunk in chunks:
            writer.write_frame(chunk.frame)
            writer.write_events(chunk.events)
    return path


@pytest.fixture(scope="session")
def sim_gel_recording(sim_gel_chunks, tmp_path_factory) -> tuple[Path, list]:
    """:func:`sim_gel_chunks` as an AEDAT4 recording, with its labels as (seconds from the
    start, gesture, resting)."""
    path = write_chunks(tmp_path_factory.mktemp("gel") / "gel.aedat4", sim_gel_chunks)
    t0 = sim_gel_chunks[0].label.t_us
    return path, [((c.label.t_us - t0) / 1e6, c.label.gesture, c.label.resting) for c in sim_gel_chunks]


@pytest.fixture(scope="session")
def sim_gel_short_recording(sim_gel_chunks, tmp_path_factory) -> Path:
    """The first 1.5 s of :func:`sim_gel_recording` (it starts with the push): what
    ``SimulatedSource(seed=0).stream(1.5)`` gives, as an AEDAT4 recording."""
    return write_chunks(tmp_path_factory.mktemp("gel") / "sim.aedat4", sim_gel_chunks[:38])  # 38 x 40 ms


@pytest.fixture(scope="session")
def sim_push_only_recording(tmp_path_factory) -> Path:
    """4.5 s of the simulated gel, seed 0, one push (rest, push, release, rest), as an AEDAT4
    recording with its sensor.yaml beside it, the way `neurotouch-hid simulate` stores sequences."""
    from neurotouch_hid.core.estimate import GestureType
    from neurotouch_hid.sources.simulator import SimulatedSource

    folder = tmp_path_factory.mktemp("push")
    sim = SimulatedSource(seed=0, gestures=["push"])
    sim.sensor.save(folder / "sensor.yaml")
    chunks = list(sim.chunks(4.5))
    # up to the rest after the first push: the next push may begin within the 4.5 s
    first = next(i for i, c in enumerate(chunks) if c.label.gesture is GestureType.PUSH)
    rest = next(i for i in range(first, len(chunks)) if chunks[i].label.gesture is GestureType.NONE)
    end = next((i for i in range(rest, len(chunks)) if chunks[i].label.gesture is not GestureType.NONE), len(chunks))
    chunks = chunks[:end]
    assert chunks[-1].frame.t_us - chunks[rest].frame.t_us >= 1_000_000, (
        "the push's release needs a second of rest after it"
    )
    return write_chunks(folder / "push.aedat4", chunks)


@pytest.fixture(scope="session")
def sim_quick_dataset(tmp_path_factory) -> Path:
    """``neurotouch-hid simulate --preset quick --seed 0``: one user, 5 gestures x 3 s, each an
    AEDAT4 recording with labels and true markers, and the sensor.yaml (docs/dataset.md)."""
    from typer.testing import CliRunner

    from neurotouch_hid.cli import app

    out = tmp_path_factory.mktemp("sim") / "quick"
    result = CliRunner().invoke(app, ["simulate", "--out", str(out), "--preset", "quick", "--seed", "0"])
    assert result.exit_code == 0, result.output
    return out


@pytest.fixture(scope="session")
def sim_push_recording(sim_quick_dataset) -> Path:
    """The push of :func:`sim_quick_dataset` (u0_push.aedat4, labels, markers, sensor.yaml beside)."""
    return sim_quick_dataset / "u0_push.aedat4"


@pytest.fixture(scope="session")
def sim_rest_dataset(tmp_path_factory) -> Path:
    """A dataset of one 0.6 s simulated sequence ``u0_push`` (the gel rests until the push would
    start at 0.6 s) with the simulator's own sensor.yaml."""
    from neurotouch_hid.sources.sim_dataset import write_dataset

    return write_dataset(tmp_path_factory.mktemp("rest"), users=[0], gestures=["push"], minutes=0.01, progress=False)


@pytest.fixture
def children():
    """Start real processes, each returned once its program runs (``helpers.started``); every one
    still running is killed at the end."""
    procs: list[subprocess.Popen] = []

    def start(argv: list[str], env: dict | None = None) -> subprocess.Popen:
        proc = subprocess.Popen(argv, env=env if env is not None else dict(os.environ))
        procs.append(proc)
        return started(proc)

    yield start
    for proc in procs:
        if proc.poll() is None:
            proc.kill()
        proc.wait(10)
