"""How the tests of inputs crafted to break the driver run it (tests/test_hostile_*.py,
test_nothing_lost_*.py, docs/limits.md): commands run in child processes, measured with ``wait4``
(their peak memory) and guarded by an address-space limit, so that a bound that does not hold fails
the test without taking the machine's memory; a refusal is exit 2, one short message, no traceback."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import neurotouch_hid

#: The tree whose package the tests import (children import the same one).
ROOT = Path(neurotouch_hid.__file__).resolve().parents[1]


#: Peak memory a crafted input may cost a command (KB, ru_maxrss): "well under 1 GiB".
MAX_RSS_KB = 512 * 1024


#: Most a refusal may print (bytes): one line, a few KB at most.
MAX_OUTPUT = 4096


#: Runs in the child in place of the command: it forks the command from its own small process,
#: limits the command's address space, waits for it and writes the command's peak memory (wait4's
#: ru_maxrss, KB) to the file descriptor given. Forked straight from the test process, the command
#: would report that process's memory as its own peak (exec records the high-water mark of the
#: memory the child was forked with), and the suite's process passes 512 MB.
_LAUNCHER = """
import os, resource, sys
fd, limit, argv = int(sys.argv[1]), int(sys.argv[2]), sys.argv[3:]
pid = os.fork()
if pid == 0:
    os.close(fd)
    resource.setrlimit(resource.RLIMIT_AS, (limit, limit))
    os.execv(argv[0], argv)
_, status, usage = os.wait4(pid, 0)
os.write(fd, str(usage.ru_maxrss).encode())
code = os.waitstatus_to_exitcode(status)
os._exit(code if code >= 0 else 128 - code)
"""


def bounded_run(args: list[str], *, env: dict | None = None, timeout_s: float = 30.0, address_space_gib: float = 3):
    """Run ``args``; (exit code, stdout, stderr, peak RSS in KB). Killed after ``timeout_s`` (exit
    code None then); its address space is limited so that a runaway allocation fails in it. A
    command killed by a signal exits 128 + the signal's number."""
    size = int(address_space_gib * (1 << 30))
    read_fd, write_fd = os.pipe()
    launcher = [sys.executable, "-c", _LAUNCHER, str(write_fd), str(size), *args]
    with tempfile.TemporaryFile() as out, tempfile.TemporaryFile() as err:
        try:
            proc = subprocess.Popen(
                launcher, stdout=out, stderr=err, env=env, cwd=ROOT, pass_fds=(write_fd,), start_new_session=True
            )
        finally:
            os.close(write_fd)
        end = time.monotonic() + timeout_s
        code = None
        while time.monotonic() < end:
            pid, status, _ = os.wait4(proc.pid, os.WNOHANG)
            if pid:
                code = os.waitstatus_to_exitcode(status)
                break
            time.sleep(0.05)
        else:
            os.killpg(proc.pid, signal.SIGKILL)  # the launcher and the command
            os.wait4(proc.pid, 0)
        proc.returncode = code  # reaped here: keep Popen from waiting again
        with os.fdopen(read_fd, "rb") as report:
            rss = int(report.read() or 0)
        out.seek(0)
        err.seek(0)
        return code, out.read().decode(errors="replace"), err.read().decode(errors="replace"), rss


def cli(*args: str, env: dict | None = None, **kw):
    return bounded_run([sys.executable, "-m", "neurotouch_hid.cli", *args], env=env or _env(), **kw)


def _env(**extra) -> dict:
    return dict(os.environ, PYTHONPATH=str(ROOT), **extra)


def assert_refused(result, *must_say: str) -> None:
    """Exit 2, one short line naming the problem, no traceback, bounded memory."""
    code, out, err, rss = result
    assert code == 2, f"exit {code}: {err[-2000:]}"
    assert "Traceback" not in err and len(out) + len(err) <= MAX_OUTPUT, err[-2000:]
    assert len(err.strip().splitlines()) == 1, err
    for words in must_say:
        assert words in err, err
    assert rss < MAX_RSS_KB, f"peak memory {rss // 1024} MB"


def _predictions(folder: Path, seconds: float) -> Path:
    """Estimates alternating a 2 s push and 0.3 s of rest: the states change all the time, and a
    push holds A long enough to stop the process while it is held."""
    from neurotouch_hid.core.dataset import write_predictions
    from neurotouch_hid.core.estimate import GestureEstimate, GestureType

    step_us, estimates = 10_000, []
    for i in range(int(seconds * 1e6 / step_us)):
        pushing = i % 230 < 200
        estimates.append(
            GestureEstimate(
                t_us=i * step_us,
                gesture=GestureType.PUSH if pushing else GestureType.NONE,
                intensity_mm=4.0 if pushing else 0.0,
                translation_mm=(3.0, 0.0) if pushing else (0.0, 0.0),
                resting=not pushing,
            )
        )
    path = folder / "preds.jsonl"
    write_predictions(path, estimates)
    return path


def _user_profiles(config: Path) -> Path:
    folder = config / "neurotouch-hid" / "profiles"
    folder.mkdir(parents=True, exist_ok=True)
    return folder
