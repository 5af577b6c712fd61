"""A termination signal that arrives inside a finalizer or an import still ends the command.

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


IMPORTED = """
import os, signal, sys, time
from neurotouch_hid.cli import _Terminated, _unwind_on_termination

_unwind_on_termination()
sys.path.insert(0, sys.argv[1])
try:
    import nt_signalled_while_imported as module  # its body sends the signal, then goes on

    time.sleep(5)
except _Terminated as exc:
    whole = getattr(sys.modules.get("nt_signalled_while_imported"), "DONE", False)
    print("terminated", exc.signum, "whole" if whole else "half-made", flush=True)
    sys.exit(0)
print("ran on", flush=True)
sys.exit(1)
"""


def test_a_sigterm_inside_an_import_unwinds_the_command_once_the_import_is_over(tmp_path):
    """Raised inside an import, the unwinding left the module half-made (OpenCV's loader then stays
    marked as loading: every later ``import cv2`` in the process fails, so a way out that imports
    it ends in that error, not the signal). The handler delivers the signal again once the import
    is over."""
    (tmp_path / "nt_signalled_while_imported.py").write_text(
        "import os, signal, time\n"
        "os.kill(os.getpid(), signal.SIGTERM)\n"
        "for _ in range(20):\n"
        "    time.sleep(0.01)\n"
        "DONE = True\n"
    )
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    done = subprocess.run(
        [sys.executable, "-c", IMPORTED, str(tmp_path)], env=env, capture_output=True, text=True, timeout=120
    )
    said = done.stdout.strip()
    assert done.returncode == 0 and said == f"terminated {int(signal.SIGTERM)} whole", (done.stdout, done.stderr)
