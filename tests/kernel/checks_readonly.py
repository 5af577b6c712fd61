"""Guest check: the driver starts from the guest's read-only root (the host's file system, shared
read-only by virtme-ng) with no cache variable set: numba's ``cache=True`` functions are defined
(what used to fail with "cannot cache function ...: no locator available") and ``doctor`` says
where compiled code goes.

Compiling the pipeline itself is out of reach here (the emulated guest is ~100x slower than the
host: tests/kernel/checks_runtime.py); tests/test_readonly_install.py runs ``track`` and ``run``
on the host in a mount namespace with the same read-only package and home.
Run by tests/kernel/guest.py; asserted on by tests/test_readonly_kernel.py.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent.parent
TIMEOUT_S = 600
CACHE_VARIABLES = ("NUMBA_CACHE_DIR", "XDG_CACHE_HOME", "XDG_RUNTIME_DIR", "CACHE_DIRECTORY")
#: Every module with ``@numba.njit(cache=True)`` functions.
JIT_MODULES = ("neurotouch_hid.pipeline.tracker", "neurotouch_hid.pipeline.contacts",
               "neurotouch_hid.pipeline.gesture", "neurotouch_hid.sources.esim", "neurotouch_hid.sources.simulator")


def check_driver_starts_from_the_read_only_root() -> dict:
    package = REPO / "neurotouch_hid"
    probe = package / "pipeline" / "__pycache__" / "guest-write-probe"
    try:
        probe.write_text("")
        probe.unlink()
        read_only = False
    except OSError:
        read_only = True
    assert read_only, f"{package} is writable in the guest: this check needs the read-only root"
    env = {k: v for k, v in os.environ.items() if k not in CACHE_VARIABLES}
    env.update(PYTHONPATH=str(REPO), COLUMNS="200")
    code = ("import " + ", ".join(JIT_MODULES) + "; from neurotouch_hid.jit_cache import chosen; "
            "print(chosen().kind)")
    imported = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env,
                              timeout=TIMEOUT_S - 60, cwd="/")
    assert imported.returncode == 0 and "Traceback" not in imported.stderr, imported.stderr[-2000:]
    doctor = subprocess.run([sys.executable, "-m", "neurotouch_hid.cli", "doctor"], capture_output=True, text=True,
                            env=env, timeout=120, cwd="/")
    assert "Traceback" not in doctor.stderr, doctor.stderr[-2000:]
    line = next((row for row in doctor.stdout.splitlines() if "compiled-code cache" in row), "")
    assert line, doctor.stdout
    return {"cache": imported.stdout.strip(), "said": imported.stderr.strip(), "doctor": " ".join(line.split("│")).strip(),
            "home": os.environ.get("HOME")}
