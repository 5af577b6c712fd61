"""bench_rest.py's ``--floor`` (docs/performance.md, "At rest"): it runs the design at rest on a
resting gel's recording part by part, and refuses a recording that does not rest or is too short
for it. No speed is asserted."""

from __future__ import annotations

import pytest
from helpers import load_benchmark


@pytest.fixture(scope="module")
def bench_rest():
    return load_benchmark("bench_rest")


@pytest.fixture
def short_parts(bench_rest, monkeypatch):
    """rest_work.py, where bench_rest.py's ``--floor`` is measured, with short parts."""
    rest_work = load_benchmark("rest_work")
    monkeypatch.setattr(rest_work, "FLOOR_PART_S", 0.2)
    return rest_work


def test_the_floor_runs_every_part_on_a_resting_gel(bench_rest, short_parts, tmp_path):
    recording = bench_rest.make_rest_recording(tmp_path, 3.0)
    floor = short_parts.measure_floor(recording)
    assert list(floor) == list(short_parts.FLOOR_PARTS)  # each part ran (the CPU it took is the benchmark's)


def test_the_floor_refuses_a_recording_too_short_for_its_parts(bench_rest, short_parts, tmp_path):
    recording = bench_rest.make_rest_recording(tmp_path, 2.0)
    with pytest.raises(RuntimeError, match="shorter than --floor's warm-up and parts"):
        short_parts.measure_floor(recording)


def test_the_floor_refuses_a_gel_that_does_not_rest(short_parts, tmp_path):
    recording = load_benchmark("bench_latency").make_recording(tmp_path, 4.0)  # gestures from the start
    with pytest.raises(RuntimeError, match="does not rest"):
        short_parts.measure_floor(recording)


def test_every_step_parts_wraps_is_where_the_code_keeps_it(bench_rest):
    """``--parts`` wraps each step by its module and name: a step moved by a split stops it at its
    first wrap, so each must resolve to a callable."""
    import importlib

    for module, cls, attr, _name in bench_rest.PARTS:
        owner = importlib.import_module(module)
        owner = owner if cls is None else getattr(owner, cls)
        assert callable(getattr(owner, attr)), (module, cls, attr)
