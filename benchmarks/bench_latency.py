"""Runtime latency, sustained event rate and memory: the figures of docs/performance.md
("Runtime latency").

    python3 benchmarks/bench_latency.py [--seconds 30] [--rss-minutes 30] [--workdir DIR] [--no-busy]
        [--idle-ms 0.8]

1. Event-to-output latency with 10 ms windows while a simulated-gel recording is replayed in
   real time (``Engine``, ``RunMode.PACED``, 1 ms source batches, the default pipeline (noise filter
   on), the default profile, the JSON-lines state writer into /dev/null; the uinput gamepad too
   where /dev/uinput is writable): p50/p99 of (a) processing latency: the item closing a window
   is read -> output up to date, and (b) window latency: the window's end in paced wall time ->
   output up to date. Then the same with a game beside the driver (``--busy``, on by default):
   a CPU-bound process (a busy loop, its own interpreter) runs for the whole case, so the
   driver's threads share the cores with it; both cases' p99 are printed together at the end.
   Then the pipeline alone on the same items, without threads: its CPU per window-closing item
   back to back, and with ``--idle-ms`` of sleep after each 1 ms batch (a core that idled
   between the camera's batches, as the driver's does: cold caches).
2. 1 ms windows at 2 M events/s: the same recording time-compressed so its mean event rate is
   2 M events/s, replayed in real time; reports dropped data (must be 0) and the rate achieved.
3. Resident memory over a 30-minute simulated session at --fast speed (the recording looped
   with shifted timestamps), sampled from /proc/self/statm every second.

The recording is made once by the simulator (``SimulatedSource``, every gesture) and kept in
``--workdir`` (default: a fresh temporary folder).
"""

from __future__ import annotations

import argparse
import contextlib
import os
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from neurotouch_hid.core.sensor import SensorGeometry
from neurotouch_hid.core.stats import RunStats
from neurotouch_hid.engine.assembly import build_pipeline
from neurotouch_hid.engine.engine import Engine, RunParts
from neurotouch_hid.engine.mode import RunMode, RunOptions
from neurotouch_hid.mapping.profile import load_profile
from neurotouch_hid.service.warmup import compile_pipeline
from neurotouch_hid.sources import Frame
from neurotouch_hid.sources.batches import merge_stream
from neurotouch_hid.sources.recording import RecordingReader
from neurotouch_hid.sources.recording_writer import RecordingWriter
from neurotouch_hid.sources.simulator import SimulatedSource
from neurotouch_hid.views.jsonl import StateJsonlWriter

PAGE = os.sysconf("SC_PAGE_SIZE")


def make_recording(folder: Path, seconds: float, seed: int = 0) -> Path:
    """A simulated-gel recording performing every gesture (AEDAT4 + sensor.yaml)."""
    path = folder / f"sim-{seconds:g}s-seed{seed}.aedat4"
    if path.exists():
        return path
    sim = SimulatedSource(seed=seed)
    sim.sensor.save(folder / "sensor.yaml")
    with RecordingWriter(path) as writer:
        for chunk in sim.chunks(seconds):
            writer.write_frame(chunk.frame)
            writer.write_events(chunk.events)
    return path


def load(path: Path) -> tuple[np.ndarray, list[Frame]]:
    with RecordingReader(path) as reader:
        return reader.read_all()


def compressed(events: np.ndarray, frames: list[Frame], factor: float) -> tuple[np.ndarray, list[Frame]]:
    """Time divided by ``factor`` around the first frame (a ``factor`` times faster replay), APS
    frames thinned back to the camera's rate (one every 40 ms of the new time), as a camera
    seeing ``factor`` times more events would still deliver 25 frames a second."""
    t0 = frames[0].t_us
    ev = events.copy()
    ev["timestamp"] = t0 + ((events["timestamp"] - t0) / factor).astype(np.int64)
    step = max(1, int(round(factor)))
    return ev, [replace(f, t_us=t0 + int((f.t_us - t0) / factor)) for f in frames[::step]]


def items(events: np.ndarray, frames: list[Frame], batch_us: int) -> list:
    return list(merge_stream([events], frames, batch_us))


def looped(events: np.ndarray, frames: list[Frame], batch_us: int, total_us: int):
    """The recording again and again, timestamps shifted by its length, for ``total_us``: the
    next loop's first APS frame one batch after the last event, as a camera streaming this fast
    never falls silent (a pause would leave its windows waiting for the next loop's data to close
    them, a latency the driver does not make)."""
    span = int(events["timestamp"][-1]) - frames[0].t_us + batch_us
    base = items(events, frames, batch_us)
    shift = 0
    while shift < total_us:
        for item in base:
            if isinstance(item, Frame):
                yield Frame(item.t_us + shift, item.image)
            else:
                moved = item.copy()
                moved["timestamp"] += shift
                yield moved
        shift += span


class RssSampler(threading.Thread):
    """Resident set size (bytes) from /proc/self/statm every ``period_s``."""

    def __init__(self, period_s: float = 1.0):
        super().__init__(daemon=True)
        self.period_s = period_s
        self.samples: list[tuple[float, int]] = []
        self._halt = threading.Event()

    @staticmethod
    def rss() -> int:
        with open("/proc/self/statm") as fh:
            return int(fh.read().split()[1]) * PAGE

    def run(self) -> None:
        t0 = time.perf_counter()
        while not self._halt.wait(self.period_s):
            self.samples.append((time.perf_counter() - t0, self.rss()))

    def stop(self) -> None:
        self._halt.set()
        self.join()


def run(stream, sensor: SensorGeometry, window_us: int, *, pace: bool, output=None) -> RunStats:
    profile = load_profile("default")
    pipeline, resting = build_pipeline(sensor, window_us, resting_beside=pace)
    with StateJsonlWriter(os.devnull) as null:
        out = output if output is not None else null
        return Engine(
            RunParts(stream, pipeline, resting=resting), profile, [out], RunOptions(mode=RunMode.of(pace=pace))
        ).run()


def show(name: str, stats: RunStats) -> None:
    rate = stats.events / stats.wall_s if stats.wall_s else 0.0
    line = (
        f"{name}: {stats.windows} windows, {stats.events} events in {stats.wall_s:.1f} s wall "
        f"({rate / 1e6:.2f} M events/s), dropped {stats.dropped_items} items ({stats.dropped_events} events), "
        f"{stats.coalesced_windows} queued windows decided with a newer one, "
        f"resting detector skipped {stats.resting_dropped_frames} frames; "
        f"processing latency p50 {stats.latency.percentile_us(50):.0f} us p99 {stats.latency.percentile_us(99):.0f} us"
    )
    if len(stats.window_latency):
        line += (
            f"; window latency p50 {stats.window_latency.percentile_us(50):.0f} us "
            f"p99 {stats.window_latency.percentile_us(99):.0f} us"
        )
    print(line, flush=True)


@contextlib.contextmanager
def busy_process():
    """A CPU-bound process beside the driver for the duration (a game on the other core): a pure
    Python busy loop in its own interpreter, at the driver's priority, ended on exit."""
    proc = subprocess.Popen([sys.executable, "-c", "while True:\n    pass"])
    try:
        time.sleep(0.2)  # let it start spinning
        yield proc
    finally:
        proc.terminate()
        proc.wait()


def stages(
    events: np.ndarray,
    frames: list[Frame],
    sensor: SensorGeometry,
    window_us: int,
    idle_s: float = 0.0,
    join: int = 1,
) -> None:
    """Where the pipeline's time goes on this data (GesturePipeline's own per-stage CPU timings),
    and the CPU time of each ``process`` call that closes a window (p50/p99): the processing
    latency the pipeline's thread would have with a core to itself, which a machine shared with
    other work does not inflate (resting detection inline here, as ``--fast`` runs it).

    ``idle_s`` > 0: the thread sleeps that long after each 1 ms batch, as the running driver
    waits for the camera's next one. Its caches are then cold when a window closes: on this
    machine class every step costs 2-4x its back-to-back CPU time (docs/performance.md, "Runtime latency").

    ``join`` > 1: every ``join`` event batches (none across an APS frame) go to the pipeline as
    one, as the runtime hands on batches that queued up behind it, and of the windows they close
    only the newest is decided (``process_newest``): the CPU a run that fell behind needs."""
    from neurotouch_hid.pipeline.pipeline import GesturePipeline, PipelineConfig
    from neurotouch_hid.sources import join_events

    pipeline = GesturePipeline(sensor, PipelineConfig(window_us=window_us), profile=True)
    closing: list[int] = []
    windows = coalesced = 0
    run: list[np.ndarray] = []
    stream = items(events, frames, 1000)
    t0 = time.process_time()
    for k, item in enumerate(stream):
        c = time.thread_time_ns()
        if join > 1 and not isinstance(item, Frame):
            run.append(item)
            last = k + 1 == len(stream) or isinstance(stream[k + 1], Frame)
            if len(run) < join and not last:
                continue
            out, skipped = pipeline.process_newest(join_events(run))
            run, n = [], len(out)
            coalesced += len(skipped)
        else:
            n = len(pipeline.process(item))
        if n:
            closing.append(time.thread_time_ns() - c)
            windows += n
        if idle_s:
            time.sleep(idle_s)
    cpu = time.process_time() - t0
    parts = ", ".join(f"{name} {sum(v) / 1e9:.3f} s" for name, v in pipeline.cpu_timings.items())
    per = np.array(closing) / 1e3
    print(
        f"pipeline alone, {window_us} us windows{f', idle {idle_s * 1e3:g} ms after each batch' if idle_s else ''}"
        f"{f', {join} batches a call, the newest window decided' if join > 1 else ''}: "
        f"{len(events)} events, {windows} windows{f' (+ {coalesced} coalesced)' if coalesced else ''} "
        f"in {cpu:.2f} s CPU "
        f"({len(events) / cpu / 1e6:.2f} M events/s); CPU per stage: {parts}; CPU per item closing a window "
        f"p50 {np.percentile(per, 50):.0f} us p99 {np.percentile(per, 99):.0f} us",
        flush=True,
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seconds", type=float, default=30.0, help="length of the simulated recording (s)")
    ap.add_argument("--rate", type=float, default=2e6, help="event rate of the 1 ms window case (events/s)")
    ap.add_argument("--rate-seconds", type=float, default=10.0, help="how long the 1 ms window case runs (s)")
    ap.add_argument("--rss-minutes", type=float, default=30.0, help="simulated session length of the memory case")
    ap.add_argument("--workdir", type=Path, default=None, help="keep the recording here")
    ap.add_argument("--skip", nargs="*", default=[], choices=["latency", "rate", "rss"])
    ap.add_argument(
        "--busy",
        action=argparse.BooleanOptionalAction,
        default=True,
        help="also run the 10 ms latency case with a CPU-bound process beside the driver (default on)",
    )
    ap.add_argument(
        "--idle-ms",
        type=float,
        default=0.8,
        help="also time the pipeline alone (10 ms windows) sleeping this long after each 1 ms batch, as the "
        "driver idles between the camera's batches: the window's CPU on a cold core (0: skip)",
    )
    args = ap.parse_args()
    folder = args.workdir or Path(tempfile.mkdtemp(prefix="bench-latency-"))
    folder.mkdir(parents=True, exist_ok=True)
    t = time.perf_counter()
    path = make_recording(folder, args.seconds)
    sensor = SensorGeometry.load(folder / "sensor.yaml")
    events, frames = load(path)
    print(f"load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores", flush=True)
    span_s = (int(events["timestamp"][-1]) - frames[0].t_us) / 1e6
    print(
        f"recording {path}: {len(events)} events, {len(frames)} frames, {span_s:.1f} s, "
        f"mean {len(events) / span_s / 1e3:.0f} k events/s (made/read in {time.perf_counter() - t:.1f} s)",
        flush=True,
    )
    base10 = items(events, frames, 1000)
    # warm-up as `run` does it (compile_pipeline: every numba kernel, OpenCV's RANSAC and the learned
    # type on a synthetic bump), then 0.2 s of the recording; without the first, the first gesture's
    # window paid ~40 ms of first calls inside the measurement and backed up the windows after it
    compile_pipeline()
    run(iter(base10[:200]), sensor, 10_000, pace=False)

    p99: dict[str, float] = {}
    if "latency" not in args.skip:
        name = "real time, 10 ms windows, JSON lines -> /dev/null"
        stats = run(iter(base10), sensor, 10_000, pace=True)
        show(name, stats)
        p99[name] = stats.latency.percentile_us(99)
        if args.busy:
            name += ", a CPU-bound process beside it"
            with busy_process():
                stats = run(iter(base10), sensor, 10_000, pace=True)
            show(name, stats)
            p99[name] = stats.latency.percentile_us(99)
        if os.access("/dev/uinput", os.W_OK):
            from neurotouch_hid.targets.uinput.gamepad import VirtualGamepad

            with VirtualGamepad() as pad:
                show(
                    "real time, 10 ms windows, uinput gamepad", run(iter(base10), sensor, 10_000, pace=True, output=pad)
                )
        else:
            print("uinput gamepad: skipped, /dev/uinput is not writable here", flush=True)

    if "rate" not in args.skip:
        factor = args.rate * span_s / len(events)
        ev, fr = compressed(events, frames, factor)
        print(
            f"time compressed x{factor:.1f}: {len(ev)} events over "
            f"{(int(ev['timestamp'][-1]) - fr[0].t_us) / 1e6:.2f} s "
            f"= {args.rate / 1e6:.1f} M events/s, {len(fr)} frames; looped for {args.rate_seconds:g} s",
            flush=True,
        )
        cpu = time.process_time()
        stats = run(looped(ev, fr, 1000, int(args.rate_seconds * 1e6)), sensor, 1000, pace=True)
        cpu = time.process_time() - cpu
        show(f"real time, 1 ms windows, {args.rate / 1e6:.1f} M events/s", stats)
        print(f"  the process's CPU: {cpu:.2f} s, {cpu / stats.wall_s:.2f} of a core (all threads)", flush=True)
        stages(ev, fr, sensor, 1000)
        stages(ev, fr, sensor, 1000, join=2)

    if "latency" not in args.skip:
        stages(events, frames, sensor, 10_000)
        if args.idle_ms:
            stages(events, frames, sensor, 10_000, idle_s=args.idle_ms / 1e3)
    if p99:
        print("p99 processing latency: " + "; ".join(f"{k}: {v / 1e3:.2f} ms" for k, v in p99.items()), flush=True)

    if "rss" not in args.skip:
        total_us = int(args.rss_minutes * 60e6)
        sampler = RssSampler()
        sampler.start()
        stats = run(looped(events, frames, 1000, total_us), sensor, 10_000, pace=False)
        sampler.stop()
        show(f"--fast, {args.rss_minutes:g} simulated minutes (recording looped)", stats)
        rss = np.array([r for _, r in sampler.samples]) / 2**20
        n = len(rss)
        if n:
            q = [
                rss[: max(1, n // 10)].mean(),
                rss[n // 2 - n // 20 : n // 2 + n // 20 + 1].mean(),
                rss[-max(1, n // 10) :].mean(),
            ]
            print(
                f"RSS over {stats.wall_s:.0f} s ({stats.stream_us / 60e6:.1f} simulated minutes): "
                f"first tenth {q[0]:.1f} MiB, "
                f"middle {q[1]:.1f} MiB, last tenth {q[2]:.1f} MiB, max {rss.max():.1f} MiB, "
                f"min {rss.min():.1f} MiB",
                flush=True,
            )


if __name__ == "__main__":
    main()
