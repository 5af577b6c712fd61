"""What the first-run tests share (tests/test_warmup_*.py): a command's environment with its own numba cache."""

from __future__ import annotations

import os
import sys


def _env(cache) -> dict:
    return dict(os.environ, NUMBA_CACHE_DIR=str(cache), PYTHONPATH=os.pathsep.join(sys.path))
