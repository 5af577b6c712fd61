"""A read-only install: the package, its Python environment and the home folder cannot be written.

Each test runs the real command in a mount namespace (``unshare -rm``, util-linux) where the
package's folder, ``sys.prefix`` and a fresh HOME are read-only bind mounts: a system package
and a kiosk account, or a service with ProtectSystem=strict and ProtectHome=read-only. numba's
``cache=True`` finds no folder of its own there; the driver must start anyway (jit_cache.py).
"""

from __future__ import annotations

import functools
import json
import shlex
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from helpers import EARLY_NICE, niced, reap

import neurotouch_hid

PACKAGE = Path(neurotouch_hid.__file__).resolve().parent
MEMORY_LINE = "no writable cache folder (package, XDG cache, $XDG_RUNTIME_DIR): numba compiles the pipeline"


@functools.cache
def _namespaces_work() -> str | None:
    if shutil.which("unshare") is None:
        return "util-linux's unshare is not installed"
    import tempfile

    with tempfile.TemporaryDirectory() as folder:
        probe = subprocess.run(
            [
                "unshare",
                "-rm",
                "sh",
                "-c",
                'mount --bind "$0" "$0" && mount -o remount,bind,ro "$0" && ! touch "$0/x" 2>/dev/null',
                folder,
            ],
            capture_output=True,
            text=True,
        )
    return None if probe.returncode == 0 else f"no mount namespaces here: {probe.stderr.strip()}"


pytestmark = pytest.mark.skipif(_namespaces_work() is not None, reason=str(_namespaces_work()))


def start_read_only(tmp_path: Path, *args: str, env: dict[str, str], nice: int = 0) -> subprocess.Popen:
    """``python -m neurotouch_hid.cli ARGS`` started with the package, sys.prefix and HOME mounted
    read-only (text pipes for stdout and stderr), at niceness ``nice`` (0: as this process)."""
    home = tmp_path / "home"
    home.mkdir(exist_ok=True)
    read_only = [
        PACKAGE.parent if (PACKAGE.parent / "pyproject.toml").exists() else PACKAGE,
        Path(sys.prefix).resolve(),
        home,
    ]
    mounts = " && ".join(
        f"mount --bind {shlex.quote(str(d))} {shlex.quote(str(d))} && mount -o remount,bind,ro {shlex.quote(str(d))}"
        for d in read_only
    )
    command = " ".join(shlex.quote(a) for a in (sys.executable, "-m", "neurotouch_hid.cli", *args))
    full_env = {"PATH": "/usr/bin:/bin", "HOME": str(home), "LANG": "C.UTF-8", **env}
    return subprocess.Popen(
        niced(["unshare", "-rm", "sh", "-c", f"{mounts} && exec {command}"], nice),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=full_env,
        cwd=tmp_path,
        stdin=subprocess.DEVNULL,
    )


def finish(proc: subprocess.Popen, timeout: float = 600) -> subprocess.CompletedProcess:
    """Wait for ``proc`` (from :func:`start_read_only`) and return what it did."""
    try:
        out, err = proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        proc.kill()
        raise
    return subprocess.CompletedProcess(proc.args, proc.returncode, out, err)


def run_read_only(tmp_path: Path, *args: str, env: dict[str, str]) -> subprocess.CompletedProcess:
    """:func:`start_read_only`, waited for."""
    return finish(start_read_only(tmp_path, *args, env=env))


#: The two compiles from nothing, once started: (folder, process) by name.
_compiles: dict[str, tuple[Path, subprocess.Popen]] = {}


def _start_compiles(tmp_path_factory, recording: Path, nice: int = 0) -> None:
    """The two tests' compiles from nothing (each ~40 s of one core), started together: ``run``
    with no writable folder (compiles in memory), and ``track`` with a writable $XDG_RUNTIME_DIR
    (compiles into it)."""
    memory = tmp_path_factory.mktemp("memory")
    cached = tmp_path_factory.mktemp("cached")
    runtime = cached / "run-user"
    runtime.mkdir()
    _compiles["memory"] = (
        memory,
        start_read_only(
            memory,
            "run",
            "--source",
            str(recording),
            "--output",
            "jsonl",
            "--fast",
            "--out",
            str(memory / "states.jsonl"),
            env={},
            nice=nice,
        ),
    )
    _compiles["cached"] = (
        cached,
        start_read_only(
            cached,
            "track",
            str(recording),
            "--out",
            str(cached / "pred.jsonl"),
            env={"XDG_RUNTIME_DIR": str(runtime)},
            nice=nice,
        ),
    )


def start_early(request) -> None:
    """The compiles started at the session's start (conftest.py, ``started_early``), niced: in a
    whole test run they are done, or nearly, when these tests come."""
    if _namespaces_work() is None:
        _start_compiles(
            request.getfixturevalue("tmp_path_factory"),
            request.getfixturevalue("sim_gel_short_recording"),
            nice=EARLY_NICE,
        )


def stop_early() -> None:
    """Kill the compiles that are still running (their tests never came) and forget them."""
    reap(proc for _, proc in _compiles.values())
    _compiles.clear()


@pytest.fixture(scope="module")
def first_compiles(tmp_path_factory, sim_gel_short_recording):
    """The two tests' compiles from nothing (:func:`_start_compiles`), started at the session's
    start (:func:`start_early`) or now; each test waits for its own and goes on from there; both
    are killed if a test never took its own."""
    if not _compiles:
        _start_compiles(tmp_path_factory, sim_gel_short_recording)
    yield dict(_compiles)
    stop_early()


def assert_clean(result: subprocess.CompletedProcess) -> None:
    assert "Traceback" not in result.stderr and result.returncode == 0, result.stderr


def assert_states(path: Path) -> None:
    """``run --output jsonl`` wrote gamepad states (one JSON object a line, with the axes)."""
    lines = path.read_text().splitlines()
    assert lines and all("axes" in json.loads(line) for line in lines), path


def test_no_writable_folder_compiles_at_start_and_runs(first_compiles):
    """Nothing writable but the output's folder: `run` starts, says so in one line, and works."""
    tmp_path, proc = first_compiles["memory"]
    result = finish(proc)
    assert_clean(result)
    assert result.stderr.count(MEMORY_LINE) == 1, result.stderr
    assert_states(tmp_path / "states.jsonl")
    doctor = run_read_only(tmp_path, "doctor", env={})
    said = " ".join(doctor.stdout.split())  # doctor wraps its details at 100 columns when piped
    assert MEMORY_LINE in said and "removed at exit" in said, doctor.stdout


def test_runtime_dir_caches_track_and_run(first_compiles, sim_gel_short_recording):
    """With $XDG_RUNTIME_DIR writable, `track` compiles once into it, and `run` reuses that."""
    recording = str(sim_gel_short_recording)
    tmp_path, proc = first_compiles["cached"]
    runtime = tmp_path / "run-user"
    env = {"XDG_RUNTIME_DIR": str(runtime)}
    track = finish(proc)
    assert_clean(track)
    assert MEMORY_LINE not in track.stderr
    assert len((tmp_path / "pred.jsonl").read_text().splitlines()) > 50
    cache = runtime / "neurotouch-hid" / "numba"
    assert list(cache.rglob("*.nbi")), f"nothing cached in {cache}"
    states = tmp_path / "states.jsonl"
    run = run_read_only(
        tmp_path, "run", "--source", recording, "--output", "jsonl", "--fast", "--out", str(states), env=env
    )
    assert_clean(run)
    assert_states(states)
    doctor = run_read_only(tmp_path, "doctor", env=env)
    assert f"runtime dir: {cache}" in " ".join(doctor.stdout.split()), doctor.stdout


@pytest.mark.parametrize("writable", ["service", "xdg-cache", "runtime", "none"])
def test_cache_folder_choice(tmp_path, writable):
    """The choice's order: systemd's CacheDirectory, the user's XDG cache folder, then
    $XDG_RUNTIME_DIR, then a temporary folder (removed at exit)."""
    env = {"XDG_RUNTIME_DIR": str(tmp_path / "run-user")} if writable != "none" else {}
    if writable in ("service", "xdg-cache"):
        env["XDG_CACHE_HOME"] = str(tmp_path / "cache")
    if writable == "service":
        env["CACHE_DIRECTORY"] = str(tmp_path / "unit-cache")
    code = "from neurotouch_hid.service.jit_cache import chosen; c = chosen(); print(c.kind, c.folder)"
    home = tmp_path / "home"
    home.mkdir()
    mounts = " && ".join(
        f"mount --bind {d} {d} && mount -o remount,bind,ro {d}"
        for d in (shlex.quote(str(PACKAGE)), shlex.quote(str(home)))
    )
    result = subprocess.run(
        ["unshare", "-rm", "sh", "-c", f"{mounts} && exec {shlex.quote(sys.executable)} -c {shlex.quote(code)}"],
        capture_output=True,
        text=True,
        timeout=120,
        env={"PATH": "/usr/bin:/bin", "HOME": str(home), **env},
    )
    assert result.returncode == 0, result.stderr
    expected = {
        "service": f"service cache {tmp_path / 'unit-cache' / 'numba'}",
        "xdg-cache": f"user cache {tmp_path / 'cache' / 'neurotouch-hid' / 'numba'}",
        "runtime": f"runtime dir {tmp_path / 'run-user' / 'neurotouch-hid' / 'numba'}",
        "none": "temporary",
    }[writable]
    assert result.stdout.strip().startswith(expected), result.stdout
