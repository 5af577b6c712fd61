"""The memory a warm pipeline keeps (neurotouch_hid/service/jit_cache.py, docs/performance.md): the
linking modules released leave the kernels working and linkable, and a warm group's are freed as it
is loaded, before the next loads."""

from __future__ import annotations

import subprocess
import sys

from warmup_helpers import _env

from neurotouch_hid.service import warmup

RELEASE_CHILD = """
import numba, numpy as np
from neurotouch_hid.service import jit_cache
from neurotouch_hid.pipeline.moves import _largest_move_sq
rng = np.random.default_rng(0)
current, rest = rng.normal(size=(40, 2)), rng.normal(size=(40, 2))
valid = np.ones(40, dtype=np.bool_)
before = _largest_move_sq(current, valid, rest)
(library,) = [result.library for result in _largest_move_sq.overloads.values()]
assert library._shared_module is not None
assert jit_cache.release_linking_modules([_largest_move_sq]) == 1
assert library._shared_module is None
assert jit_cache.release_linking_modules([_largest_move_sq]) == 0
assert _largest_move_sq(current, valid, rest) == before

@numba.njit
def twice(current, valid, rest):
    return 2.0 * _largest_move_sq(current, valid, rest)

assert twice(current, valid, rest) == 2.0 * before
assert library._shared_module is not None
print("loaded" if sum(_largest_move_sq.stats.cache_hits.values()) else "compiled")
"""


def test_released_linking_modules_leave_kernels_working_and_linkable(tmp_path):
    """After :func:`jit_cache.release_linking_modules` a kernel runs as before, and a compile
    that links it (a new kernel calling it) parses its module back from the kept bitcode: a
    kernel compiled here, then the same loaded from numba's cache (whose library has no other
    module to link from)."""
    for expected in ("compiled", "loaded"):
        out = subprocess.run(
            [sys.executable, "-c", RELEASE_CHILD],
            capture_output=True,
            text=True,
            env=_env(tmp_path / "numba"),
            timeout=300,
        )
        assert out.returncode == 0, out.stderr[-2000:]
        assert out.stdout.strip() == expected


def test_a_warm_group_s_linking_modules_are_freed_as_it_is_loaded_before_the_next_loads(monkeypatch):
    """On a warm cache each group's linking modules are freed right after its own load and before
    the next group loads (so that the start never holds two groups' modules: its peak memory),
    not seconds after the last."""
    seen: list[tuple[str, list]] = []
    found = {g.name: {f"{g.name}.k{i}": object() for i in range(3)} for g in warmup.PIPELINE_OF["default"]}
    monkeypatch.setattr(warmup, "kernels", lambda group: found[group.name])
    monkeypatch.setattr(warmup, "cached_signatures", lambda dispatcher: ["(float64,)"])
    monkeypatch.setattr(warmup, "_call", lambda where: seen.append(("load", [where])))
    released = lambda dispatchers: seen.append(("release", list(dispatchers))) or 0  # noqa: E731
    monkeypatch.setattr(warmup.jit_cache, "release_linking_modules", released)
    run = warmup.Warmup(list(warmup.PIPELINE_OF["default"]), say=lambda line: None, interpreted=False)
    try:
        run.start()
    finally:
        run.close()
    tracker, pipeline = warmup.PIPELINE_OF["default"]
    assert seen[:4] == [
        ("load", [tracker.warm]),
        ("release", list(found["tracker"].values())),
        ("load", [pipeline.warm]),
        ("release", list(found["pipeline"].values())),
    ], seen
    assert not run.compiling
