"""A termination signal that arrives inside a finalizer still ends the command.

Python drops an exception raised in ``__del__`` ("Exception ignored in ..."): a SIGTERM whose
handler raised there, as during a first run's compile in llvmlite's finalizers, was lost and the
command ran on (``simulate`` to its end). The handler now delivers the signal again outside it."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

CHILD = """
import os, signal, sys, time
from neurotouch_hid.cli import _Terminated, _unwind_on_termination

_unwind_on_termination()

class Finalized:
    def __del__(self):
        os.kill(os.getpid(), signal.SIGTERM)
        time.sleep(0.2)  # the handler runs here, inside __del__

try:
    Finalized()  # dropped at once: its __del__ runs now
    time.sleep(5)
except _Terminated as exc:
    print("terminated", exc.signum, flush=True)
    sys.exit(0)
print("ran on", flush=True)
sys.exit(1)
"""


def test_a_sigterm_inside_a_finalizer_still_unwinds_the_command():
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    done = subprocess.run([sys.executable, "-c", CHILD], env=env, capture_output=True, text=True, timeout=120)
    said = done.stdout.strip()
    assert done.returncode == 0 and said == f"terminated {int(signal.SIGTERM)}", (done.stdout, done.stderr)
