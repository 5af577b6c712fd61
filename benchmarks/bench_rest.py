"""What the driver costs while the gel rests: CPU of a core at steady state, wake-ups and memory
(docs/performance.md, "At rest").

    python3 benchmarks/bench_rest.py [--workdir DIR] [--seconds 40] [--repeat 1] [--sim]

A resting gel's recording is made once by the simulator (``GelSimulator`` with an empty script:
the markers at rest, the camera's noise events, 25 APS frames a second; 45 s, seed 0) and kept in
``--workdir`` (default: a fresh temporary folder). It is replayed in real time through
``neurotouch-hid run --source REC --output jsonl --out /dev/null --seconds S`` in a child
process. Its steady state, from :data:`STEADY_AFTER_S` after its start (imports, the compiled
pipeline loaded, the first frame's markers) to the last reading with all its threads: its CPU
time (user + sys of all its threads, ``/proc/PID/stat``) and its threads' context switches
(``voluntary_ctxt_switches`` + ``nonvoluntary_ctxt_switches`` of ``/proc/PID/task/*/status``),
read every 0.5 s, per second of that span. Memory: the child's peak resident set
(``ru_maxrss``) and its anonymous memory, the process's own pages (``Anonymous:`` of
``/proc/PID/smaps_rollup``, the largest reading of the steady state, and of the whole run).
``--repeat N`` runs each N times and prints every run and the medians.

``--sim``: also the simulated gel at rest (``GelSimulator`` with an empty script, seed 0) through
the same runtime, pipeline and output as ``run --source sim`` (paced; the simulated gel waits
rather than drops), in a child of this script, measured as above; and the simulator alone
(its stream read back to back, CPU per second of gel), which that figure includes.

``--work``: also the stages' own CPU at rest, without the runtime's threads: the same recording's
items as the runtime hands them at rest (a window's event batches joined, APS frames between them),
through the pipeline, its resting detector and the default profile's mapper in this thread, once
back to back ("hot") and once with ``--gap-ms`` of sleep after each item, as the driver idles
between windows ("spread"), the items' own CPU of this thread per window (the sleeps apart) and as
a share of a core at 100 windows a second, and what as many sleeps alone cost. Two more passes say
what a sleep costs the work after it: "evicted", back to back but with the data caches evicted
before each item (a pass over 64 MiB, not counted), and "spun", the sleep then 1 ms of busy waiting
before each item (not counted: the core awake and at its clock, but what ran elsewhere meanwhile
still evicted). Only the items' own CPU is counted in each; each pass is also split into the
resting window's compiled call, the resting verdict and the rest (the Python around them).

``--parts``: also where a resting run's CPU goes: ``run`` on the same recording in a child of this
script whose runtime, reader, pipeline and resting detector have each step wrapped to add up the
CPU time of its thread (``time.thread_time_ns``) around every call; per step over the steady
state, its share of a core, calls a second and CPU per call (a step's figure includes the steps
it calls: the reader's next item, the source thread's hand-on of what it held, each item's
handling, the pipeline's resting window and its compiled call, the estimate ``none``, the
resting verdict). The wrappers add a little to each figure.

``--floor``: also what the design at rest costs with nothing around it, in this process: the same
recording's items as ``--work`` takes them, in real time, one wake-up a window (at its end +
``runtime.REST_WAKE_AFTER_END_US``, a ``time.sleep`` to that deadline), handing on the items that
ended before it, in three parts of ``rest_work.FLOOR_PART_S`` each after a warm-up: "stages", each
item through the pipeline (an APS frame's resting verdict first) as ``--work`` does; "compiled",
only a window's compiled call (``rest_window.rest_batch``) per event batch, the resting verdict
per APS frame and its re-anchoring of the tracker (``_apply_pending``), nothing else; "wake", the
wake-ups and the loop over the items, no work. CPU of this process per second of each part: the
floor under ``run`` at rest, with no reader, no runtime, no Python around the compiled call.
``--repeat`` repeats it.

``--wakes``: also what this machine charges for waking a thread, with no work at all: one thread
sleeping to a deadline every 10 ms (``threading.Event.wait``, as the paced source waits), and one
thread waking another every 10 ms through a ``threading.Condition`` (as the source hands a window
to the pipeline's thread), CPU of the process per wake and as a share of a core at 100 a second:
the floor under a driver that wakes once or twice per window.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from rest_work import FLOOR_PARTS, measure_floor, measure_wakes, measure_work  # noqa: E402

#: Length of the resting recording (s): the longest run plus the start's margin.
RECORDING_S = 45.0
#: A run's steady state is measured from this long after its start (s): imports, the pipeline
#: loaded, the first frame's markers are over by then.
STEADY_AFTER_S = 12.0


def make_rest_recording(folder: Path, seconds: float = RECORDING_S, seed: int = 0) -> Path:
    """A resting gel (noise events, 25 APS frames a second) as AEDAT4 with its sensor.yaml beside it."""
    from neurotouch_hid.core.sensor import SensorGeometry
    from neurotouch_hid.sources.recording_writer import RecordingWriter
    from neurotouch_hid.sources.simulator import GelSimulator

    path = folder / f"rest-{seconds:g}s-seed{seed}.aedat4"
    if path.exists():
        return path
    sim = GelSimulator(SensorGeometry(), seed=seed, script=())
    sim.sensor.save(folder / "sensor.yaml")
    partial = path.with_suffix(".partial.aedat4")
    with RecordingWriter(partial) as writer:
        for chunk in sim.run(seconds):
            writer.write_frame(chunk.frame)
            writer.write_events(chunk.events)
    partial.rename(path)
    return path


def proc_reading(pid: int) -> dict[str, float] | None:
    """A running process's CPU time so far (s, user + sys of all its threads, ``/proc/PID/stat``),
    its context switches so far, summed over its threads (``/proc/PID/task/*/status``), its
    threads, and its anonymous memory (MiB, ``Anonymous:`` of ``/proc/PID/smaps_rollup``); None
    once it is gone."""
    switches = 0
    try:
        with open(f"/proc/{pid}/stat") as file:
            fields = file.read().rsplit(")", 1)[1].split()
        cpu = (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
        tasks = os.listdir(f"/proc/{pid}/task")
        for task in tasks:
            with contextlib.suppress(FileNotFoundError):  # a thread that just ended
                with open(f"/proc/{pid}/task/{task}/status") as file:
                    for line in file:
                        if line.startswith(("voluntary_ctxt_switches:", "nonvoluntary_ctxt_switches:")):
                            switches += int(line.split()[1])
        with open(f"/proc/{pid}/smaps_rollup") as file:
            anon = next(int(line.split()[1]) for line in file if line.startswith("Anonymous:"))
    except (FileNotFoundError, ProcessLookupError, StopIteration):
        return None
    return {"t": time.perf_counter(), "cpu": cpu, "switches": switches, "threads": len(tasks), "anon_mib": anon / 1024}


def measure(command: list[str], settle_s: float = STEADY_AFTER_S) -> dict[str, float]:
    """One real-time run of ``command`` (a child): CPU s (user + sys), peak RSS, the largest
    anonymous memory (MiB) over the whole run (``anon_start_mib``: the start's peak, before
    numba's linking modules are freed) and over its steady state (``anon_mib``), wall s, and over
    its steady state (from ``settle_s`` after its start to the last reading with all its threads)
    CPU s per s and context switches per s."""
    start = time.perf_counter()
    child = subprocess.Popen(command, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    readings = []
    while os.waitid(os.P_PID, child.pid, os.WEXITED | os.WNOWAIT | os.WNOHANG) is None:  # not reaped:
        reading = proc_reading(child.pid)  # wait4 below gets its usage
        if reading is not None:
            readings.append(reading)
        time.sleep(0.5)
    _, status, usage = os.wait4(child.pid, 0)
    wall = time.perf_counter() - start
    err = child.stderr.read().decode(errors="replace")
    child.stderr.close()
    child.returncode = os.waitstatus_to_exitcode(status)
    if child.returncode != 0:
        sys.exit(f"bench_rest.py: {' '.join(command)} failed ({child.returncode}): {err.strip()}")
    steady = [r for r in readings if r["t"] - start >= settle_s]
    steady = [r for r in steady if r["threads"] >= max((r["threads"] for r in steady), default=0)]
    first, last = (steady[0], steady[-1]) if len(steady) >= 2 else ({"t": 0, "cpu": 0, "switches": 0},) * 2
    span = last["t"] - first["t"]
    return {
        "cpu": usage.ru_utime + usage.ru_stime,
        "rss_mib": usage.ru_maxrss / 1024,
        "anon_mib": max((r["anon_mib"] for r in steady), default=float("nan")),
        "anon_start_mib": max((r["anon_mib"] for r in readings), default=float("nan")),
        "wall": wall,
        "share": (last["cpu"] - first["cpu"]) / span if span > 0 else float("nan"),
        "switches_per_s": (last["switches"] - first["switches"]) / span if span > 0 else float("nan"),
        "span_s": span,
    }


def run_command(recording: Path, seconds: float) -> list[str]:
    """``neurotouch-hid run`` of ``seconds`` of ``recording``, paced, to JSON lines in /dev/null."""
    command = [sys.executable, "-m", "neurotouch_hid.cli", "run", "--source", str(recording)]
    return command + ["--output", "jsonl", "--out", os.devnull, "--seconds", f"{seconds:g}"]


def sim_command(seconds: float) -> list[str]:
    """This script's child that runs the simulated gel at rest for ``seconds`` (:func:`run_sim`)."""
    return [sys.executable, __file__, "--child-sim", f"{seconds:g}"]


def rest_stream(seconds: float, seed: int = 0, batch_us=1000):
    """The simulated gel at rest, as ``SimulatedSource.stream`` yields a gel: per APS frame
    period the frame, then its events in 1 ms batches (or as a ``BatchCut`` says)."""
    from neurotouch_hid.core.sensor import SensorGeometry
    from neurotouch_hid.sources.batches import split_batches
    from neurotouch_hid.sources.simulator import GelSimulator

    sim = GelSimulator(SensorGeometry(), seed=seed, script=())
    for chunk in sim.run(seconds):
        yield chunk.frame
        yield from split_batches(chunk.events, batch_us)


def run_sim(seconds: float) -> None:
    """The simulated gel at rest through the runtime as ``run --source sim --output jsonl`` runs
    it (the warm pipeline loaded first, as ``run`` does; paced, the source waits rather than drops)."""
    from neurotouch_hid.core.sensor import SensorGeometry
    from neurotouch_hid.engine.assembly import build_pipeline
    from neurotouch_hid.engine.engine import Engine, RunParts
    from neurotouch_hid.engine.mode import RunMode, RunOptions
    from neurotouch_hid.mapping.profile import load_profile
    from neurotouch_hid.service.warmup import PIPELINE_OF, SIMULATOR, Warmup
    from neurotouch_hid.sources.batches import BatchCut, CuttingStream, read_ahead
    from neurotouch_hid.views.jsonl import StateJsonlWriter

    Warmup([SIMULATOR, *PIPELINE_OF["default"]], say=lambda line: None, interpreted=False).start()
    sensor = SensorGeometry()
    pipeline, resting = build_pipeline(sensor, 10_000)
    cut = BatchCut(1000)  # as run --source sim: one batch a window while the gel rests
    stream = CuttingStream(read_ahead(rest_stream(seconds + 1.0, batch_us=cut), cut), cut)
    with StateJsonlWriter(os.devnull) as out:
        runtime = Engine(
            RunParts(stream, pipeline, resting=resting),
            load_profile("default"),
            [out],
            RunOptions(mode=RunMode.PACED_WAITING),
        )
        runtime.run(seconds)


def simulator_alone(seconds: float = 10.0) -> float:
    """CPU s per s of gel of the simulated gel at rest alone (its stream read back to back, after
    its first second)."""
    stream = rest_stream(seconds + 1.0)
    for item in stream:  # the first second: its kernels loaded
        if not isinstance(item, np.ndarray) and item.t_us >= 1_000_000:
            break
    begin = time.process_time()
    for _ in stream:
        pass
    return (time.process_time() - begin) / seconds


#: The steps ``--parts`` wraps: (module, class or None, attribute, name printed).
PARTS = (
    ("neurotouch_hid.sources.batches", "CuttingStream", "__next__", "reader: next item"),
    ("neurotouch_hid.engine.rest", "RestHandover", "release", "source: the held items handed on"),
    ("neurotouch_hid.engine.engine", "Engine", "_hand_on", "source: one item handed on"),
    ("neurotouch_hid.engine.engine", "Engine", "_handle", "an item handled"),
    ("neurotouch_hid.engine.engine", "Engine", "_rest_verdict", "the resting verdict, handed over"),
    ("neurotouch_hid.pipeline.pipeline", "GesturePipeline", "process", "pipeline: an item"),
    ("neurotouch_hid.pipeline.pipeline", "GesturePipeline", "_resting_events", "pipeline: a resting batch"),
    ("neurotouch_hid.pipeline.window_path", None, "rest_batch", "pipeline: its compiled call"),
    ("neurotouch_hid.pipeline.pipeline", "GesturePipeline", "_none", "pipeline: the estimate none"),
    ("neurotouch_hid.pipeline.resting", "RestingDetector", "update", "resting detector: a frame"),
)


def run_parts(recording: Path, seconds: float) -> None:
    """``--parts``' child: ``run`` on ``recording`` for ``seconds`` with :data:`PARTS` wrapped;
    prints each step's CPU over the steady state (from :data:`STEADY_AFTER_S` to 3 s before the
    end)."""
    import importlib
    import threading

    totals: dict[str, list[int]] = {}

    def wrap(owner, attr: str, name: str) -> None:
        inner = getattr(owner, attr)
        total = totals.setdefault(name, [0, 0])

        def timed(*args, **kwargs):
            begin = time.thread_time_ns()
            try:
                return inner(*args, **kwargs)
            finally:
                total[0] += time.thread_time_ns() - begin
                total[1] += 1

        setattr(owner, attr, timed)

    for module, cls, attr, name in PARTS:
        owner = importlib.import_module(module)
        wrap(owner if cls is None else getattr(owner, cls), attr, name)
    marks: list[tuple[float, dict[str, tuple[int, int]]]] = []

    def sample() -> None:
        for delay in (STEADY_AFTER_S, seconds - 3 - STEADY_AFTER_S):
            time.sleep(delay)
            marks.append((time.monotonic(), {k: (v[0], v[1]) for k, v in totals.items()}))

    threading.Thread(target=sample, daemon=True).start()
    from neurotouch_hid.cli import app

    with contextlib.suppress(SystemExit):
        app(run_command(recording, seconds)[3:], standalone_mode=False)
    (t0, before), (t1, after) = marks
    span = t1 - t0
    for name, (cpu, calls) in after.items():
        d_cpu, d_calls = cpu - before[name][0], calls - before[name][1]
        print(
            f"  {name:34s} {100 * d_cpu / 1e9 / span:5.2f} % of a core, {d_calls / span:6.1f} calls/s, "
            f"{d_cpu / max(d_calls, 1) / 1e3:6.1f} us a call",
            flush=True,
        )


def steady(name: str, command, seconds: float, repeat: int) -> None:
    """Print the steady state of ``repeat`` runs of ``command(seconds)`` (CPU share, context
    switches a second, peak RSS and anonymous memory), and their medians."""
    shares, rates, peaks, anons = [], [], [], []
    for _ in range(repeat):
        run = measure(command(seconds))
        shares.append(run["share"])
        rates.append(run["switches_per_s"])
        peaks.append(run["rss_mib"])
        anons.append(run["anon_mib"])
        print(
            f"{name}: run {seconds:g} s: {run['cpu']:.2f} s CPU; steady state over {run['span_s']:.0f} s: "
            f"{100 * shares[-1]:.1f} % of a core, {rates[-1]:.0f} context switches/s; peak RSS {peaks[-1]:.0f} MiB, "
            f"anonymous {anons[-1]:.0f} MiB steady, {run['anon_start_mib']:.0f} MiB at most; "
            f"load average {os.getloadavg()[0]:.1f}",
            flush=True,
        )
    print(
        f"{name} at rest: {100 * statistics.median(shares):.1f} % of a core, {statistics.median(rates):.0f} "
        f"context switches/s (medians of {len(shares)}); peak RSS {max(peaks):.0f} MiB, anonymous "
        f"{max(anons):.0f} MiB in the steady state",
        flush=True,
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--workdir", type=Path, default=None, help="keep the recording here")
    ap.add_argument("--seconds", type=float, default=40.0, help="each run (s)")
    ap.add_argument("--repeat", type=int, default=1, help="pairs of runs")
    ap.add_argument("--work", action="store_true", help="also the stages' own CPU, hot and spread")
    ap.add_argument("--gap-ms", type=float, default=8.0, help="--work: sleep after each item (ms)")
    ap.add_argument("--wakes", action="store_true", help="also the CPU of a wake-up with no work")
    ap.add_argument("--floor", action="store_true", help="also the design at rest with nothing around it")
    ap.add_argument("--sim", action="store_true", help="also the simulated gel at rest")
    ap.add_argument("--parts", action="store_true", help="also where the recording's run spends its CPU, step by step")
    ap.add_argument("--child-sim", type=float, default=None, help=argparse.SUPPRESS)
    ap.add_argument("--child-parts", type=Path, default=None, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child_sim is not None:
        run_sim(args.child_sim)
        return
    if args.child_parts is not None:
        run_parts(args.child_parts, args.seconds)
        return
    if not STEADY_AFTER_S + 5 < args.seconds <= RECORDING_S:
        sys.exit(f"bench_rest.py: expected {STEADY_AFTER_S + 5:g} < --seconds <= {RECORDING_S:g}")
    folder = args.workdir or Path(tempfile.mkdtemp(prefix="bench-rest-"))
    folder.mkdir(parents=True, exist_ok=True)
    recording = make_rest_recording(folder)
    print(f"recording {recording}; load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores", flush=True)
    cases = [("recording", lambda seconds: run_command(recording, seconds))]
    if args.sim:
        cases.append(("simulated gel", sim_command))
    for name, command in cases:
        steady(name, command, args.seconds, args.repeat)
    if args.sim:
        print(f"the simulated gel at rest alone: {100 * simulator_alone():.1f} % of a core", flush=True)
    if args.work:
        work = measure_work(recording, args.gap_ms / 1e3)
        print(
            f"the stages alone, one thread: hot {work['hot'] * 1e6:.0f} us a window "
            f"({100 * work['hot'] * 100:.2f} % of a core at 100 windows/s); spread ({args.gap_ms:g} ms of "
            f"sleep after each item) {work['spread'] * 1e6:.0f} us ({100 * work['spread'] * 100:.2f} %), "
            f"x{work['spread'] / work['hot']:.1f}, the sleeps themselves (not in it) {work['sleeps'] * 1e6:.0f} us; "
            f"evicted caches, no sleep, {work['evicted'] * 1e6:.0f} us (x{work['evicted'] / work['hot']:.1f}); "
            f"sleep then 1 ms spun {work['spun'] * 1e6:.0f} us (x{work['spun'] / work['hot']:.1f})",
            flush=True,
        )
        for name in ("hot", "spread", "evicted", "spun"):
            call, verdict = work[f"{name}/call"], work[f"{name}/verdict"]
            print(
                f"  {name}: the compiled resting call {call * 1e6:.0f} us a window, the resting verdict "
                f"{verdict * 1e6:.0f} us (a frame every fourth window), "
                f"the rest {(work[name] - call - verdict) * 1e6:.0f} us",
                flush=True,
            )
    if args.parts:
        print("the recording's run, step by step (each step's CPU includes the steps it calls):", flush=True)
        subprocess.run([sys.executable, __file__, "--child-parts", str(recording), "--seconds", f"{args.seconds:g}"])
    if args.floor:
        floors = [measure_floor(recording) for _ in range(args.repeat)]
        for floor in floors:
            print(
                "the design at rest alone, one wake-up a window: "
                + ", ".join(f"{name} {100 * floor[name]:.2f} %" for name in FLOOR_PARTS)
                + f" of a core; load average {os.getloadavg()[0]:.1f}",
                flush=True,
            )
    if args.wakes:
        wakes = measure_wakes()
        print(
            f"a wake-up with no work: one thread {wakes['sleep'] * 1e6:.0f} us "
            f"({100 * wakes['sleep'] * 100:.2f} % of a core at 100 a second); one thread waking another "
            f"{wakes['handoff'] * 1e6:.0f} us ({100 * wakes['handoff'] * 100:.2f} %)",
            flush=True,
        )


if __name__ == "__main__":
    main()
