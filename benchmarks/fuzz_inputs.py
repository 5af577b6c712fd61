"""Long fuzzing run of every loader of outside input (docs/limits.md, Fuzzing).

The targets and input strategies of tests/test_fuzz_inputs.py (tests/hostile_inputs.py), run with
many more examples: the recording reader (real LZ4, zstd and uncompressed recordings with bytes
replaced and cuts), profiles, sensor.yaml and games.yaml (random text, random documents, shipped
profiles, a games map and the alias bomb spliced), ``--set`` strings, control-socket request lines
and bytes sent on a running control server's real socket (a valid request must still be answered
after each). A *crash* is any
exception other than the one error of the loader's kind with a short message; each distinct one
(type and place) is listed. Prints a Markdown table: inputs tried, crashes, distinct crashes,
seconds.

Two engines: hypothesis (property-based: the strategies of tests/hostile_inputs.py) and atheris
(coverage-guided libFuzzer over the same targets, the package's code instrumented; bytes from
libFuzzer become the targets' text, byte lines, ``--set`` lists or recording edits; each target
runs in a child process, which libFuzzer takes over).

Usage: PYTHONPATH=. python benchmarks/fuzz_inputs.py [--engine hypothesis|atheris]
       [--examples 2000] [--only profile,sensor,games,set,control,socket,recording]
"""

from __future__ import annotations

import argparse
import os
import subprocess
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
        "games": lambda x: targets.fuzz_games(x, folder),
        "socket": lambda x: targets.fuzz_control_socket(folder / "neurotouch-hid" / "control.sock", x),
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

    server = targets.control_server(folder) if name == "socket" else None
    start = time.perf_counter()
    try:
        fuzz()
    finally:
        if server is not None:
            server.stop()
    return tried, crashes, time.perf_counter() - start


def _atheris_child(name: str, examples: int) -> None:
    """One target under atheris: print its table row after ``examples`` inputs, then exit."""
    import atheris

    with atheris.instrument_imports(include=["neurotouch_hid"]):
        import neurotouch_hid.core.limits  # noqa: F401
        import neurotouch_hid.core.sensor  # noqa: F401
        import neurotouch_hid.evaluation.runner  # noqa: F401
        import neurotouch_hid.mapping.profile  # noqa: F401
        import neurotouch_hid.service.control  # noqa: F401
        import neurotouch_hid.service.games  # noqa: F401
        import neurotouch_hid.sources.packet_bounds  # noqa: F401
        import neurotouch_hid.sources.recording  # noqa: F401
    folder = Path(tempfile.mkdtemp(prefix="fuzz-atheris-"))
    recordings = {c: targets.small_recording(folder, c) for c in ("LZ4", "ZSTD", "NONE")}
    server = targets.control_server(folder) if name == "socket" else None
    tried, crashes, start = 0, Counter(), time.perf_counter()

    def one(data: bytes) -> None:
        nonlocal tried
        fdp = atheris.FuzzedDataProvider(data)
        try:
            if name in ("profile", "sensor", "games"):
                text = fdp.ConsumeUnicodeNoSurrogates(len(data))
                if name == "profile":
                    targets.fuzz_profile(text)
                elif name == "sensor":
                    targets.fuzz_sensor(text, folder)
                else:
                    targets.fuzz_games(text, folder)
            elif name == "socket":
                assert server is not None
                targets.fuzz_control_socket(server.path, fdp.ConsumeBytes(len(data)))
            elif name == "set":
                targets.fuzz_set([fdp.ConsumeUnicodeNoSurrogates(64) for _ in range(fdp.ConsumeIntInRange(0, 4))])
            elif name == "control":
                targets.fuzz_control(fdp.ConsumeBytes(len(data)))
            else:
                kind = fdp.PickValueInList(["LZ4", "ZSTD", "NONE"])
                edits = [(fdp.ConsumeIntInRange(0, 10**7), fdp.ConsumeIntInRange(0, 255)) for _ in range(16)]
                cut = fdp.ConsumeIntInRange(0, 10**7) if fdp.ConsumeBool() else None
                targets.fuzz_recording(recordings[kind], edits, cut, folder)
        except Exception as exc:  # a crash: counted, and the run goes on
            where = traceback.extract_tb(exc.__traceback__)[-1]
            crashes[f"{type(exc).__name__} at {Path(where.filename).name}:{where.lineno}: {str(exc)[:80]!r}"] += 1
        tried += 1
        if tried >= examples:
            print(
                f"| {name} (atheris) | {tried} | {sum(crashes.values())} | {len(crashes)} | "
                f"{time.perf_counter() - start:.0f} |",
                flush=True,
            )
            for signature, n in crashes.most_common():
                print(f"- {name}: {n} x {signature}", flush=True)
            os._exit(0)

    atheris.Setup([sys.argv[0], "-max_len=4096"], one)
    atheris.Fuzz()


def main() -> None:
    import logging

    logging.getLogger("neurotouch_hid.service.control").setLevel(logging.CRITICAL)  # every refusal is logged
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--examples", type=int, default=2000, help="inputs per target")
    parser.add_argument(
        "--only", default="profile,sensor,games,set,control,socket,recording", help="targets, comma-separated"
    )
    parser.add_argument("--engine", choices=("hypothesis", "atheris"), default="hypothesis")
    parser.add_argument("--atheris-child", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.atheris_child:
        _atheris_child(args.atheris_child, args.examples)
        return
    if args.engine == "atheris":
        print("| target | inputs tried | crashes | distinct crashes | s |")
        print("|---|---:|---:|---:|---:|", flush=True)
        for name in args.only.split(","):
            child = [sys.executable, __file__, "--atheris-child", name, "--examples", str(args.examples)]
            done = subprocess.run(child, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
            print(
                done.stdout.strip() or f"| {name} (atheris) | the child ended with exit {done.returncode} |||",
                flush=True,
            )
        return
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
