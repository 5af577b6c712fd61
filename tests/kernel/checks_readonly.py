"""Guest check: the driver starts from a read-only root (the package and HOME read-only, as the
host's file system is in the guest, made sure of with read-only bind mounts) with no cache
variable set: numba's ``cache=True`` functions are defined
(what used to fail with "cannot cache function ...: no locator available") and ``doctor`` says
where compiled code goes.

Compiling the pipeline itself is out of reach here (the emulated guest is ~100x slower than the
host: tests/kernel/checks_runtime.py); tests/test_readonly_install.py runs ``track`` and ``run``
on the host in a mount namespace with the same read-only package and home.
Run by tests/kernel/guest.py; asserted on by tests/test_readonly_kernel.py.
"""

from __future__ import annotations

import os
import shlex
import subprocess
import sys
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent.parent
TIMEOUT_S = 600
CACHE_VARIABLES = ("NUMBA_CACHE_DIR", "XDG_CACHE_HOME", "XDG_RUNTIME_DIR", "CACHE_DIRECTORY")
#: Every module with ``@numba.njit(cache=True)`` functions.
JIT_MODULES = (
    "neurotouch_hid.pipeline.tracker",
    "neurotouch_hid.pipeline.contacts",
    "neurotouch_hid.pipeline.gesture",
    "neurotouch_hid.sources.esim",
    "neurotouch_hid.sources.simulator",
)


def _read_only(argv: list[str], folders: list[Path], env: dict, timeout: float) -> subprocess.CompletedProcess:
    """Run ``argv`` in a mount namespace where ``folders`` are read-only bind mounts (the guest's
    root is the host's, shared read-only, but a checkout under a writable path, e.g. the guest's
    /tmp, would not be)."""
    mounts = " && ".join(
        f"mount --bind {shlex.quote(str(f))} {shlex.quote(str(f))} && mount -o remount,bind,ro {shlex.quote(str(f))}"
        for f in folders
    )
    command = " ".join(shlex.quote(a) for a in argv)
    return subprocess.run(
        ["unshare", "-m", "sh", "-c", f"{mounts} && exec {command}"],
        capture_output=True,
        text=True,
        env=env,
        timeout=timeout,
        cwd="/",
    )


def check_driver_starts_from_the_read_only_root() -> dict:
    package = REPO / "neurotouch_hid"
    home = Path(tempfile.mkdtemp(prefix="readonly-home-"))
    env = {k: v for k, v in os.environ.items() if k not in CACHE_VARIABLES}
    env.update(PYTHONPATH=str(REPO), COLUMNS="200", HOME=str(home))
    code = "import " + ", ".join(JIT_MODULES) + "; from neurotouch_hid.jit_cache import chosen; print(chosen().kind)"
    imported = _read_only([sys.executable, "-c", code], [package, home], env, TIMEOUT_S - 180)
    assert imported.returncode == 0 and "Traceback" not in imported.stderr, imported.stderr[-2000:]
    doctor = _read_only([sys.executable, "-m", "neurotouch_hid.cli", "doctor"], [package, home], env, 150)
    assert "Traceback" not in doctor.stderr, doctor.stderr[-2000:]
    line = next((row for row in doctor.stdout.splitlines() if "compiled-code cache" in row), "")
    assert line, doctor.stdout + doctor.stderr
    return {
        "cache": imported.stdout.strip(),
        "said": imported.stderr.strip(),
        "doctor": " ".join(line.split("│")).strip(),
    }
