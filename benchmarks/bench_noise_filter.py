"""Noise filter in front of the tracker: its cost, conversions included, against the tracker's
(docs/performance.md, "Event path and noise filter").

The simulated gel (``GelSimulator``, every gesture type in turn, user 0) is simulated in memory
at each background-activity rate (``--noise-hz``, Hz per pixel), cut into the batches a source
yields (``split_batches``: 1 ms like the live runtime, 10 ms like ``eval``/``track``), and each
batch goes through :class:`neurotouch_hid.pipeline.noise.EventNoiseFilter` (what the pipeline
calls: ``store_from_events`` -> dv-processing ``accept`` + ``generateEvents`` ->
``events_from_store``), then through a :class:`BlobTracker` started on the true rest positions.
Three parts of the filter are timed separately (numpy -> ``EventStore``, the library's filter,
``EventStore`` -> numpy), all in CPU time of the calling thread (the machine is shared: wall
time mostly measures waiting for a core).

Printed per noise rate, batch length and filter: events in and kept, M events/s of the library's
filter with its conversions (events offered / CPU s), of the library's filter alone, and of the
pipeline's call (``EventNoiseFilter.__call__``: for the background-activity filter the numba
kernel, checked to keep the same events batch by batch; for the others the library between the
copies); then, for the pipeline's call: us per batch (median, p99), its share of one core in
real time, and the ratios filter / tracker (the tracker on every event, as without a filter)
and (filter + tracker on the kept events) / (tracker on every event), and the event path's
rate: events offered / CPU s of the pipeline's filter call plus the tracker on the kept events.

Then what each filter keeps (``--selectivity``, on by default): the markers' own events of the
same simulation without background activity (hot pixels dropped), with uniform Poisson noise
added at each rate (the simulator's noise model, ``EventCamera.noise_events``), filtered in 1 ms
batches: % of the marker events kept and % of the injected noise kept, beside what the
background-activity filter's rule predicts for isolated noise (kept when one of the 8
neighbours fired within the time T: 1 - exp(-8 r T) for r Hz per pixel).

Run: ``python3 benchmarks/bench_noise_filter.py`` (``--help`` for options).
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np
from rich.console import Console
from rich.table import Table

from neurotouch_hid.core.sensor import SensorGeometry
from neurotouch_hid.pipeline.noise import NOISE_FILTERS, EventNoiseFilter
from neurotouch_hid.pipeline.tracker import BlobTracker
from neurotouch_hid.sources.batches import split_batches
from neurotouch_hid.sources.dv import events_from_store, store_from_events
from neurotouch_hid.sources.hands import SIM_GESTURES, USERS
from neurotouch_hid.sources.simulator import GelSimulator
from neurotouch_hid.views.console import make_console


def simulate(sensor: SensorGeometry, seconds: float, noise_hz: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """(events EVENT_DTYPE, rest positions (N, 2) px) of ``seconds`` of the gel cycling through
    every gesture type, with ``noise_hz`` background activity per pixel."""
    sim = GelSimulator(sensor, USERS[0], SIM_GESTURES, seed=seed, stream_seed=(seed,), noise_rate_hz=noise_hz)
    events = np.concatenate([chunk.events for chunk in sim.run(seconds)])
    return events, sim.gel.rest_px


def time_tracker(batches: list[np.ndarray], rest_px: np.ndarray, sensor: SensorGeometry) -> float:
    """CPU s of a fresh BlobTracker over ``batches``."""
    tracker = BlobTracker(rest_px, sensor.width, sensor.height, sensor=sensor)
    cpu = 0.0
    for batch in batches:
        c = time.thread_time()
        tracker.update(batch)
        cpu += time.thread_time() - c
    return cpu


def time_filter(name: str, time_us: int, batches: list[np.ndarray], sensor: SensorGeometry) -> dict:
    """Per-batch CPU times (s) of the three parts of one filter over ``batches``, and the kept
    batches."""
    noise = EventNoiseFilter(name, sensor.width, sensor.height, time_us)
    lib = noise._library_filter()  # the dv-processing object, to time its parts one by one
    to_store, core, from_store, total, kept = [], [], [], [], []
    for batch in batches:
        c0 = time.thread_time()
        store = store_from_events(batch)
        c1 = time.thread_time()
        lib.accept(store)
        out = lib.generateEvents()
        c2 = time.thread_time()
        got = events_from_store(out)
        c3 = time.thread_time()
        to_store.append(c1 - c0)
        core.append(c2 - c1)
        from_store.append(c3 - c2)
        total.append(c3 - c0)
        kept.append(got)
    # the pipeline's call (EventNoiseFilter.__call__: the numba kernel for the background-activity
    # filter, the library between the copies for the others) on a fresh filter: same events
    again = EventNoiseFilter(name, sensor.width, sensor.height, time_us)
    again(batches[0][:2])  # numba: compiled or loaded from its cache before the timing
    again.reset()
    pipeline = []
    for batch, k in zip(batches, kept):
        c0 = time.thread_time()
        got = again(batch)
        pipeline.append(time.thread_time() - c0)
        assert np.array_equal(got, k)
    return {
        "to_store": np.array(to_store),
        "core": np.array(core),
        "from_store": np.array(from_store),
        "total": np.array(total),
        "pipeline": np.array(pipeline),
        "kept": kept,
    }


def selectivity(
    sensor: SensorGeometry,
    seconds: float,
    rates: list[float],
    filters: list[tuple[str, int]],
    seed: int,
    console: Console,
) -> None:
    """% of marker events and of injected noise each filter keeps (module docstring)."""
    sim = GelSimulator(sensor, USERS[0], SIM_GESTURES, seed=seed, stream_seed=(seed,), noise_rate_hz=0.0)
    markers = np.concatenate([chunk.events for chunk in sim.run(seconds)])
    hot = np.isin(
        markers["y"].astype(np.int64) * sensor.width + markers["x"],
        sim.camera.hot_y.astype(np.int64) * sensor.width + sim.camera.hot_x,
    )
    markers = markers[~hot]
    t0, t1 = int(markers["timestamp"][0]), int(markers["timestamp"][-1]) + 1
    table = Table(
        title=f"what the filters keep: {len(markers):,} marker events over {(t1 - t0) / 1e6:.1f} s + injected noise"
    )
    for col in ("noise Hz/px", "filter", "time us", "marker events kept %", "noise kept %", "1 - exp(-8 r T) %"):
        table.add_column(col, justify="left" if col == "filter" else "right")
    rng = np.random.default_rng(seed + 1)
    for rate in rates:
        n = rng.poisson(rate * sensor.width * sensor.height * (t1 - t0) * 1e-6)
        noise = np.zeros(n, dtype=markers.dtype)
        noise["timestamp"] = rng.integers(t0, t1, n)
        noise["x"], noise["y"] = rng.integers(0, sensor.width, n), rng.integers(0, sensor.height, n)
        noise["polarity"] = rng.integers(0, 2, n)
        events = np.concatenate([markers, noise])
        is_marker = np.r_[np.ones(len(markers), bool), np.zeros(n, bool)]
        order = np.argsort(events["timestamp"], kind="stable")
        events, is_marker = events[order], is_marker[order]
        key = (
            (events["timestamp"].astype(np.int64) * sensor.width + events["x"]) * sensor.height + events["y"]
        ) * 2 + events["polarity"]
        for name, time_us in filters:
            f = EventNoiseFilter(name, sensor.width, sensor.height, time_us)
            out = np.concatenate([f(b) for b in split_batches(events, 1000)])
            out_key = (
                (out["timestamp"].astype(np.int64) * sensor.width + out["x"]) * sensor.height + out["y"]
            ) * 2 + out["polarity"]
            kept = np.isin(key, out_key)
            rule = (
                f"{100 * (1 - np.exp(-8 * rate * time_us * 1e-6)):.1f}"
                if name == "BackgroundActivityNoiseFilter"
                else "-"
            )
            table.add_row(
                f"{rate:g}",
                name.removesuffix("NoiseFilter"),
                str(time_us),
                f"{100 * kept[is_marker].mean():.1f}",
                f"{100 * kept[~is_marker].mean():.1f}",
                rule,
            )
    console.print(table)


def parse_filter(text: str) -> tuple[str, int]:
    """``NAME`` or ``NAME:US`` -> (name, time parameter us)."""
    name, _, us = text.partition(":")
    if name not in NOISE_FILTERS:
        raise argparse.ArgumentTypeError(f"unknown filter {name!r}: one of {', '.join(NOISE_FILTERS)}")
    return name, int(us) if us else NOISE_FILTERS[name]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=20.0, help="simulated seconds per noise rate (default 20)")
    parser.add_argument(
        "--noise-hz",
        type=float,
        nargs="+",
        default=[0.1, 1.0, 3.0],
        help="background activity per pixel, Hz (default 0.1 1 3)",
    )
    parser.add_argument(
        "--batch-us", type=int, nargs="+", default=[1000, 10_000], help="batch lengths, us (default 1000 10000)"
    )
    parser.add_argument(
        "--filter",
        type=parse_filter,
        nargs="+",
        dest="filters",
        default=[(name, us) for name, us in NOISE_FILTERS.items()],
        help="NAME or NAME:US (default: each filter with the library's default time)",
    )
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument(
        "--selectivity-rates",
        type=float,
        nargs="*",
        default=[0.1, 1.0, 3.0, 5.0, 10.0],
        help="noise rates (Hz/px) of the selectivity table; none: skip it (default 0.1 1 3 5 10)",
    )
    parser.add_argument(
        "--cost", action=argparse.BooleanOptionalAction, default=True, help="the cost table (default on)"
    )
    args = parser.parse_args()
    console = make_console()
    sensor = SensorGeometry()

    warm, rest = simulate(sensor, 0.2, 1.0, args.seed)  # numba JIT of the simulator and tracker
    time_tracker(split_batches(warm, 1000), rest, sensor)

    if args.selectivity_rates:
        selectivity(sensor, args.seconds, args.selectivity_rates, args.filters, args.seed, console)
    if not args.cost:
        return
    table = Table(title=f"noise filter cost, {args.seconds:g} simulated s per rate (CPU time of one thread)")
    for col in (
        "noise Hz/px",
        "batch us",
        "filter",
        "time us",
        "M events in",
        "kept %",
        "M ev/s filter+conv",
        "M ev/s filter alone",
        "conv share %",
        "M ev/s pipeline's call",
        "us/batch median",
        "us/batch p99",
        "core % (real time)",
        "filter / tracker",
        "(filter + tracker kept) / tracker all",
        "M ev/s event path (filter + tracker)",
    ):
        table.add_column(col, justify="left" if col == "filter" else "right")
    for noise_hz in args.noise_hz:
        events, rest = simulate(sensor, args.seconds, noise_hz, args.seed)
        span_s = (int(events["timestamp"][-1]) - int(events["timestamp"][0])) * 1e-6
        for batch_us in args.batch_us:
            batches = split_batches(events, batch_us)
            tracker_all = time_tracker(batches, rest, sensor)
            for name, time_us in args.filters:
                t = time_filter(name, time_us, batches, sensor)
                n_in = len(events)
                n_kept = sum(len(k) for k in t["kept"])
                tracker_kept = time_tracker([k for k in t["kept"] if len(k)], rest, sensor)
                total = float(t["total"].sum())
                called = float(t["pipeline"].sum())  # the pipeline's call: what the rest of the row is about
                per_batch_us = t["pipeline"] * 1e6
                table.add_row(
                    f"{noise_hz:g}",
                    str(batch_us),
                    name.removesuffix("NoiseFilter"),
                    str(time_us),
                    f"{n_in / 1e6:.2f}",
                    f"{100 * n_kept / n_in:.1f}",
                    f"{n_in / total / 1e6:.2f}",
                    f"{n_in / float(t['core'].sum()) / 1e6:.1f}",
                    f"{100 * (t['to_store'].sum() + t['from_store'].sum()) / total:.0f}",
                    f"{n_in / called / 1e6:.1f}",
                    f"{np.median(per_batch_us):.0f}",
                    f"{np.percentile(per_batch_us, 99):.0f}",
                    f"{100 * called / span_s:.1f}",
                    f"{called / tracker_all:.2f}",
                    f"{(called + tracker_kept) / tracker_all:.2f}",
                    f"{n_in / (called + tracker_kept) / 1e6:.1f}",
                )
            console.print(
                f"noise {noise_hz:g} Hz/px, {batch_us} us batches: tracker on every event "
                f"{len(events) / tracker_all / 1e6:.1f} M events/s ({100 * tracker_all / span_s:.1f} % of a core)",
                highlight=False,
            )
    console.print(table)
    console.print(f"load average during the run: {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores")


if __name__ == "__main__":
    main()
