"""What many test modules share that is not a fixture: the one way to run the CLI in a fresh
process (:func:`run_cli`) and in this one (:func:`run_main`), reading its JSON-lines states
(:func:`read_states`), waiting for what a test waits on (:func:`wait_until`), and pyproject.toml's
requirements on a platform (:func:`project_requirements`). Fixtures (the
simulated recordings, the real street recording) are in tests/conftest.py."""

from __future__ import annotations

import importlib.util
import json
import os
import subprocess
import sys
import time
import tomllib
import types
from collections.abc import Iterable
from pathlib import Path

from packaging.markers import default_environment
from packaging.requirements import Requirement

#: The real DAVIS-346 street recording (the shared dataset beside the repository, docs/dataset.md);
#: tests read it through the ``street_recording`` fixture (tests/conftest.py), which skips without it.
STREET = Path(__file__).resolve().parents[2] / "shared" / "data" / "davis346-street" / "recording.aedat4"

#: The repository (pyproject.toml's folder).
REPO = Path(__file__).resolve().parents[1]

#: The repository's benchmark scripts (not a package: tests load them with :func:`load_benchmark`).
BENCHMARKS = REPO / "benchmarks"

#: ``neurotouch-hid`` as a command: this interpreter, this tree's package.
CLI = (sys.executable, "-m", "neurotouch_hid.cli")
#: The niceness of what a test module starts at the session's start (conftest.py,
#: ``started_early``): it takes the cores the other tests leave idle.
EARLY_NICE = 19


def niced(command: list[str], nice: int) -> list[str]:
    """``command`` run at niceness ``nice`` (``nice -n``; 0: unchanged)."""
    return ["nice", "-n", str(nice), *command] if nice else list(command)


def reap(procs: Iterable[subprocess.Popen]) -> None:
    """Each of ``procs`` killed if it still runs, and waited for (what a module started early
    and its tests did not take: conftest.py, ``started_early``)."""
    for proc in procs:
        if proc.poll() is None:
            proc.kill()
        proc.wait()


def started(proc: subprocess.Popen, timeout_s: float = 60.0) -> subprocess.Popen:
    """``proc`` once its program has started, as another process sees it: ``Popen`` returns when
    the child's exec has replaced its memory, before the kernel has written its arguments and
    environment there (``/proc/PID/environ`` then reads empty: in ``fs/exec.c`` ``begin_new_exec``
    closes the close-on-exec pipe ``Popen`` waits on, then ``fs/binfmt_elf.c`` fills the stack).
    A game is looked for when it runs, not in the microseconds of its exec.

    Raises:
        AssertionError: the environment is still empty after ``timeout_s`` (s), or ``proc`` ended.
    """
    end = time.monotonic() + timeout_s
    while time.monotonic() < end and proc.poll() is None:
        with open(f"/proc/{proc.pid}/environ", "rb") as file:
            if file.read(1):
                return proc
        time.sleep(0.001)
    raise AssertionError(f"pid {proc.pid} showed no environment within {timeout_s} s (exit code {proc.poll()})")


def exited(pid: int) -> bool:
    """Whether process ``pid`` has ended (gone, or a zombie waiting to be reaped)."""
    try:
        with open(f"/proc/{pid}/stat") as stat:
            return stat.read().rsplit(")", 1)[1].split()[0] == "Z"
    except FileNotFoundError:
        return True


def fill_unread(fd: int) -> None:
    """Write to the non-blocking pipe end ``fd`` until it is full: it stands for a node whose
    reader (a USB host) has not read, and refuses the next write with EAGAIN."""
    while True:
        try:
            os.write(fd, b"\xff" * 65536)
        except BlockingIOError:
            return


def run_cli(
    *args: str,
    home: Path | None = None,
    env: dict[str, str] | None = None,
    columns: int | None = None,
    cwd: Path | str | None = None,
    text: bool = True,
    stdout: int | None = subprocess.PIPE,
    timeout: float = 300,
) -> subprocess.CompletedProcess:
    """``neurotouch-hid ARGS`` in a fresh process, stdin closed, no terminal; stdout and stderr
    captured (``stdout`` may instead be an open file, to test what goes to a file).

    Args:
        home: run as a new user would, in a bare environment: only PATH, HOME=``home``,
            XDG_CONFIG_HOME=``home``/config and COLUMNS=80, in ``home`` (unless ``cwd``).
            Without it, this process's environment (the test's tmp config folder,
            tests/conftest.py).
        env: variables set on top of either environment (None: unset it).
        columns: COLUMNS, the width rich lays out to without a terminal (None: the
            environment's).
        text: decode the output (str) or keep the bytes (to compare files exactly).
        timeout: seconds before the run counts as hung (a hang, not a slow machine).
    """
    if home is not None:
        base = {"PATH": "/usr/bin:/bin", "HOME": str(home), "XDG_CONFIG_HOME": str(Path(home) / "config")}
        base["COLUMNS"] = "80"
        cwd = home if cwd is None else cwd
    else:
        base = dict(os.environ)
    if columns is not None:
        base["COLUMNS"] = str(columns)
    return subprocess.run(
        [*CLI, *args],
        stdout=stdout,
        stderr=subprocess.PIPE,
        text=text,
        env={k: v for k, v in {**base, **(env or {})}.items() if v is not None},
        cwd=cwd,
        stdin=subprocess.DEVNULL,
        timeout=timeout,
    )


def run_main(monkeypatch, capsys, args: list[str]) -> subprocess.CompletedProcess:
    """``neurotouch-hid ARGS`` in this process (``cli.main``, with pytest's ``monkeypatch`` and
    ``capsys``): its exit code and what it printed, as :func:`run_cli` returns them."""
    from neurotouch_hid.cli import main

    monkeypatch.setattr(sys, "argv", ["neurotouch-hid", *args])
    capsys.readouterr()
    try:
        main()
        code = 0
    except SystemExit as exc:
        code = exc.code or 0
    out, err = capsys.readouterr()
    return subprocess.CompletedProcess(args, code, out, err)


def wait_until(condition, timeout_s: float = 60.0) -> bool:
    """Poll ``condition()`` every 10 ms until it holds (True) or ``timeout_s`` passes (False): a
    test waits for what happened, not for a delay a loaded machine can overrun; ``timeout_s``
    only ends a hang."""
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        if condition():
            return True
        time.sleep(0.01)
    return False


def read_states(text: str) -> list[dict]:
    """The controller states of ``run --output jsonl`` (one JSON object a line)."""
    return [json.loads(line) for line in text.splitlines() if line.strip()]


def load_benchmark(name: str) -> types.ModuleType:
    """``benchmarks/NAME.py`` imported as the module ``NAME``, registered in ``sys.modules`` (where
    a script's dataclasses look their module up); later calls return the same module. The
    benchmarks folder is put on ``sys.path``, as running a script there does, so that a script
    imports its neighbours (``workdir.py``)."""
    if name in sys.modules:
        return sys.modules[name]
    if str(BENCHMARKS) not in sys.path:
        sys.path.append(str(BENCHMARKS))
    spec = importlib.util.spec_from_file_location(name, BENCHMARKS / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    spec.loader.exec_module(module)
    return module


def project_requirements(extras: tuple[str, ...] = (), environment: dict[str, str] | None = None) -> list[Requirement]:
    """pyproject.toml's dependencies (and those of ``extras``) whose environment markers hold in
    ``environment`` (PEP 508 marker values; None: this machine's, ``packaging``)."""
    project = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]
    lines = list(project["dependencies"])
    for extra in extras:
        lines += project["optional-dependencies"][extra]
    where = {**(environment if environment is not None else default_environment()), "extra": ""}
    return [r for r in map(Requirement, lines) if r.marker is None or r.marker.evaluate(where)]
