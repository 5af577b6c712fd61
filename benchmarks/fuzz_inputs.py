"""Long fuzzing run of every loader of outside input (docs/limits.md, Fuzzing).

The targets and input strategies of tests/test_fuzz_inputs.py (tests/hostile_inputs.py), run with
many more examples: the recording reader (real LZ4, zstd and uncompressed recordings with bytes
replaced and cuts), profiles and sensor.yaml (random text, random documents, shipped profiles and
the alias bomb spliced), ``--set`` strings and control-socket request lines. A *crash* is any
exception other than the one error of the loader's kind with a short message; each distinct one
(type and place) is listed. Prints a Markdown table: inputs tried, crashes, distinct crashes,
seconds.

Usage: PYTHONPATH=. python benchmarks/fuzz_inputs.py [--examples 2000] [--only profile,sensor]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
import traceback
from collections import Counter
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

import hostile_inputs as targets  # noqa: E402


def run(name: str, examples: int, folder: Path, recordings: dict) -> tuple[int, Counter, float]:
    """Fuzz one target with ``examples`` inputs; (inputs tried, crash signatures, seconds)."""
    from hypothesis import HealthCheck, given, settings

    tried, crashes = 0, Counter()
    calls = {
        "profile": lambda x: targets.fuzz_profile(x),
        "sensor": lambda x: targets.fuzz_sensor(x, folder),
        "set": lambda x: targets.fuzz_set(x),
        "control": lambda x: targets.fuzz_control(x),
        "recording": lambda x: targets.fuzz_recording(recordings[x[0]], x[1], x[2], folder),
    }

    @settings(
        max_examples=examples,
        deadline=None,
        database=None,
        suppress_health_check=list(HealthCheck),
    )
    @given(targets.strategies()[name])
    def fuzz(value):
        nonlocal tried
        tried += 1
        try:
            calls[name](value)
        except Exception as exc:  # a crash: counted, and the run goes on
            where = traceback.extract_tb(exc.__traceback__)[-1]
            crashes[f"{type(exc).__name__} at {Path(where.filename).name}:{where.lineno}: {str(exc)[:80]!r}"] += 1

    start = time.perf_counter()
    fuzz()
    return tried, crashes, time.perf_counter() - start


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--examples", type=int, default=2000, help="inputs per target")
    parser.add_argument("--only", default="profile,sensor,set,control,recording", help="targets, comma-separated")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        recordings = {c: targets.small_recording(folder, c) for c in ("LZ4", "ZSTD", "NONE")}
        print("| target | inputs tried | crashes | distinct crashes | s |")
        print("|---|---:|---:|---:|---:|")
        found = {}
        for name in args.only.split(","):
            tried, crashes, seconds = run(name, args.examples, folder, recordings)
            found[name] = crashes
            print(f"| {name} | {tried} | {sum(crashes.values())} | {len(crashes)} | {seconds:.0f} |", flush=True)
        for name, crashes in found.items():
            for signature, n in crashes.most_common():
                print(f"- {name}: {n} x {signature}")


if __name__ == "__main__":
    main()
