"""Slow-tier guest check: the gesture pipeline on the emulated DAVIS-346 (checks_davis.py's
:data:`~checks_davis.PIPELINE_PARTS`: ``calibrate``, ``run --output jsonl``, ``run`` on the gamepad
through an unplug).

Its numba code runs under software emulation: about 5 minutes on an idle host, 8 to 17 and flaky
on a loaded one, so it is left out of the default test run: vm.py boots it on its own guest for
tests/test_davis_pipeline_kernel.py (``pytest -m slow``).
"""

from __future__ import annotations

import checks_davis

TIMEOUT_S = checks_davis.TIMEOUT_S


def check_pipeline_on_the_emulated_davis() -> dict:
    """:func:`checks_davis.against_the_camera` with :data:`checks_davis.PIPELINE_PARTS`."""
    return checks_davis.against_the_camera(checks_davis.PIPELINE_PARTS)
