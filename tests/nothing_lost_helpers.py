"""What the nothing-lost tests share (tests/test_nothing_lost_*.py, docs/limits.md): a real full disk,
a small tmpfs mounted for the test (root and ``mount`` are needed: CI runs as root; elsewhere those
tests are skipped, saying why), a folder's snapshot to compare byte for byte, the commands'
environment, a quick simulation's arguments and a labels file's header."""

from __future__ import annotations

import contextlib
import os
import subprocess
from pathlib import Path

import pytest
from hostile_helpers import ROOT


def _mount(*args: str) -> None:
    done = subprocess.run(["mount", *args], capture_output=True, text=True)
    if done.returncode != 0:
        pytest.skip(
            reason=f"cannot mount here ({done.stderr.strip() or 'mount failed'}): run as root to test a full disk"
        )


@contextlib.contextmanager
def full_disk(folder: Path, size_kb: int = 64, prepare=None):
    """``folder`` as a tmpfs of ``size_kb`` KB (``prepare(folder)`` run on it first), filled to its
    last byte; unmounted afterwards."""
    folder.mkdir(parents=True, exist_ok=True)
    _mount("-t", "tmpfs", "-o", f"size={size_kb}k", "tmpfs", str(folder))
    try:
        if prepare is not None:
            prepare(folder)
        with open(folder / ".filler", "wb", buffering=0) as fh, contextlib.suppress(OSError):
            while fh.write(b"\0" * 4096):
                pass
        yield folder
    finally:
        subprocess.run(["umount", "-l", str(folder)], check=False)


def _snapshot(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def _env(config: Path) -> dict:
    return dict(os.environ, PYTHONPATH=str(ROOT), XDG_CONFIG_HOME=str(config))


SIMULATE = ("simulate", "--preset", "quick", "--users", "0", "--minutes", "0.01")


_HEADER = "t_us,gesture,resting,intensity_mm,n_contacts,x1_px,y1_px,x2_px,y2_px,x3_px,y3_px\n"
