"""Mapping cost per window: the figures of docs/performance.md ("Mapping").

    python3 benchmarks/bench_mapper.py [--windows 20000]

Replays hand-made estimates (pushes, twists, pinches, zooms and rests, 10 ms apart) through each
shipped profile's :class:`Mapper` and prints the time per ``update`` (wall and process CPU), the
updates per second, and the ratio to the 1 ms budget of the smallest window (paper, section
"Runtime Performance": down to 3 ms windows; the project allows 1 ms). Then what ``eval
--profile`` adds per window of a dataset: the same estimates taken as a sequence's answers and
as its labels (one every 40 ms), counted through each profile
(:func:`neurotouch_hid.evaluation.through_profile.tally`: the answers and the labels each through
a fresh mapper). Last, the whole road of a window through the runtime with the default profile:
the queue, the mapper, the record published to a JSON-lines subscriber
(:class:`neurotouch_hid.engine.engine.Engine` over the estimates replayed as a predictions file is,
``engine.assembly.EstimateReplay``).
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from neurotouch_hid.core.dataset import LabelRow
from neurotouch_hid.core.estimate import GestureEstimate, GestureType
from neurotouch_hid.core.sensor import SensorGeometry
from neurotouch_hid.evaluation.through_profile import ProfileUnderTest, tally
from neurotouch_hid.mapping.mapper import Mapper
from neurotouch_hid.mapping.profile import load_profile, shipped_profiles_dir


def estimates(n: int) -> list[GestureEstimate]:
    """n estimates, 10 ms apart: 0.5 s of each gesture then 0.5 s of rest, repeated."""
    rng = np.random.default_rng(0)
    cycle = [GestureType.PUSH, GestureType.TWIST_CCW, GestureType.PINCH, GestureType.ZOOM, GestureType.TWIST_CW]
    out = []
    for i in range(n):
        phase = (i // 50) % (2 * len(cycle))
        gesture = cycle[phase // 2] if phase % 2 == 0 else GestureType.NONE
        active = gesture is not GestureType.NONE
        out.append(
            GestureEstimate(
                t_us=10_000 * i,
                gesture=gesture,
                resting=not active,
                intensity_mm=float(rng.uniform(1, 9)) if active else 0.0,
                contacts_px=np.zeros((1, 2)),
                contacts_mm=rng.uniform(-20, 20, (1, 2)),
                translation_mm=rng.normal(size=2),
            )
        )
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--windows", type=int, default=20_000)
    args = parser.parse_args()
    stream = estimates(args.windows)
    labels = [
        LabelRow(e.t_us, e.gesture, e.resting, e.intensity_mm, e.contacts_px if not e.resting else np.zeros((0, 2)))
        for e in stream[::4]
    ]
    print(
        "| profile | mappings | us/update (wall) | us/update (CPU) | updates/s (CPU) | x 1 ms budget (CPU) "
        "| eval --profile: us/window (CPU) |"
    )
    print("| --- | ---: | ---: | ---: | ---: | ---: | ---: |")
    for path in sorted(shipped_profiles_dir().glob("*.yaml")):
        profile = load_profile(path)
        mapper = Mapper(profile)
        wall, cpu = time.perf_counter(), time.process_time()
        for e in stream:
            mapper.update(e)
        wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
        per_cpu = cpu / len(stream)
        tested = ProfileUnderTest.probe(path.stem, profile)
        counted = time.process_time()
        tally(tested, labels, stream, SensorGeometry())
        counted = (time.process_time() - counted) / len(stream)
        print(
            f"| {path.stem} | {len(profile.mappings)} | {wall / len(stream) * 1e6:.1f} | {per_cpu * 1e6:.1f} | "
            f"{1 / per_cpu:,.0f} | {1e-3 / per_cpu:.0f} | {counted * 1e6:.1f} |"
        )
    road = road_per_window(stream)
    print(
        f"\nthe runtime's road, default profile, JSON lines: {road * 1e6:.1f} us/window (CPU), "
        f"{1e-3 / road:.0f} x the 1 ms budget"
    )


def road_per_window(stream: list[GestureEstimate]) -> float:
    """Process CPU (s) per window of a runtime run over ``stream`` (replayed, not paced), the
    default profile, one JSON-lines subscriber writing to /dev/null."""
    import os

    from neurotouch_hid.engine.assembly import EstimateReplay
    from neurotouch_hid.engine.engine import Engine, RunParts
    from neurotouch_hid.engine.mode import RunMode, RunOptions
    from neurotouch_hid.views.jsonl import StateJsonlWriter

    with StateJsonlWriter(os.devnull) as out:
        runtime = Engine(
            RunParts(iter(stream), EstimateReplay()), load_profile("default"), [out], RunOptions(mode=RunMode.FAST)
        )
        cpu = time.process_time()
        stats = runtime.run()
        return (time.process_time() - cpu) / stats.windows


if __name__ == "__main__":
    main()
