"""bench_rest.py's measurements in its own process (docs/performance.md, "At rest"): the resting
recording's items as a paced run hands them on (:func:`rest_items`), the stages' own CPU per window
hot, spread, evicted and spun (:func:`measure_work`, ``--work``), the design at rest with nothing
around it, one wake-up a window (:func:`measure_floor`, ``--floor``), and a wake-up with no work
(:func:`measure_wakes`, ``--wakes``). bench_rest.py's docstring says what each measures; it runs
them and prints them.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np


def rest_items(recording: Path, window_us: int = 10_000) -> list:
    """The recording's items as a paced run hands them on at rest: each window's 1 ms event
    batches joined into one (``runtime.REST_WAKE_AFTER_END_US``), APS frames in time order."""
    from neurotouch_hid.sources import Frame, join_events
    from neurotouch_hid.sources.recording import RecordingReader

    items, held = [], []
    for item in RecordingReader(recording).stream(1000):
        if isinstance(item, Frame):
            items += [join_events(held), item] if held else [item]
            held = []
            continue
        held.append(item)
        if int(item["timestamp"][-1]) // window_us != (int(item["timestamp"][-1]) + 1000) // window_us:
            items.append(join_events(held))
            held = []
    return items


def measure_work(recording: Path, gap_s: float) -> dict[str, float]:
    """The stages' CPU (this thread's, s) per window at rest, per pass (bench_rest.py's docstring,
    ``--work``: hot, spread with ``gap_s`` of sleep after each item, evicted, spun), each on its own
    part of the recording after a first part that warms the stages up; ``PASS/call`` and
    ``PASS/verdict``: of it the resting window's compiled call and the resting verdict."""
    from neurotouch_hid.core.sensor import SensorGeometry
    from neurotouch_hid.engine.assembly import build_pipeline
    from neurotouch_hid.mapping.mapper import Mapper
    from neurotouch_hid.mapping.profile import load_profile
    from neurotouch_hid.pipeline import window_path
    from neurotouch_hid.service.warmup import compile_pipeline
    from neurotouch_hid.sources import Frame

    compile_pipeline()
    items = rest_items(recording)
    pipeline, resting = build_pipeline(SensorGeometry.load(recording.parent / "sensor.yaml"), 10_000)
    mapper = Mapper(load_profile("default"))

    junk = np.ones(64 << 17)  # 64 MiB: more than any cache of the machine

    def spin(seconds: float) -> None:
        until = time.perf_counter() + seconds
        while time.perf_counter() < until:
            pass

    spent = {"call": 0.0, "verdict": 0.0}
    rest_batch = window_path.rest_batch

    def timed_call(*args):  # the compiled resting call, as the window path makes it
        begin = time.thread_time()
        try:
            return rest_batch(*args)
        finally:
            spent["call"] += time.thread_time() - begin

    def run(part: list, gap: float, before=None) -> tuple[int, float]:
        windows, cpu = 0, 0.0
        spent.update(call=0.0, verdict=0.0)
        for item in part:
            if before is not None:
                before()
            begin = time.thread_time()
            if isinstance(item, Frame):
                verdict = resting.update(item)
                spent["verdict"] += time.thread_time() - begin
                if verdict is not None:
                    pipeline.set_resting(verdict, item.t_us)
            for estimate in pipeline.process(item):
                mapper.update(estimate)
                windows += 1
            cpu += time.thread_time() - begin
            if gap:
                time.sleep(gap)
        return windows, cpu

    passes = (
        ("hot", 0.0, None),
        ("spread", gap_s, None),
        ("evicted", 0.0, junk.sum),
        ("spun", gap_s, lambda: spin(1e-3)),
    )
    part = len(items) // (2 * len(passes) + 1)  # the warm-up, then each pass on its own part
    run(items[:part], 0.0)
    out, windows_of = {}, {}
    window_path.rest_batch = timed_call
    try:
        for k, (name, gap, before) in enumerate(passes):
            windows_of[name], cpu = run(items[(1 + 2 * k) * part : (3 + 2 * k) * part], gap, before)  # time goes on
            out[name] = cpu / windows_of[name]
            out.update({f"{name}/{key}": value / windows_of[name] for key, value in spent.items()})
    finally:
        window_path.rest_batch = rest_batch
    begin = time.thread_time()
    for _ in range(2 * part):  # the sleeps alone, as many as the spread pass's
        time.sleep(gap_s)
    out["sleeps"] = (time.thread_time() - begin) / windows_of["spread"]
    return out


#: Each part of ``--floor`` (s of the recording, in real time).
FLOOR_PART_S = 10.0
#: ``--floor``'s parts, in their order.
FLOOR_PARTS = ("stages", "compiled", "wake")
#: ``--floor``'s warm-up before its parts, back to back (us of the recording).
FLOOR_WARM_UP_US = 2_000_000


def measure_floor(recording: Path) -> dict[str, float]:
    """``--floor`` (bench_rest.py's docstring): CPU of this process (s per s) in each of
    :data:`FLOOR_PARTS`, one wake-up a window on ``recording`` (a resting gel's, 10 ms windows)
    in real time. Raises RuntimeError when a window of it does not rest, or it is shorter than
    :data:`FLOOR_WARM_UP_US` and the parts."""
    from neurotouch_hid.core.sensor import SensorGeometry
    from neurotouch_hid.engine.assembly import build_pipeline
    from neurotouch_hid.engine.rest import REST_WAKE_AFTER_END_US
    from neurotouch_hid.pipeline.rest_window import OPEN, RESTING, rest_batch
    from neurotouch_hid.service.warmup import compile_pipeline
    from neurotouch_hid.sources import Frame

    window_us = 10_000
    compile_pipeline()
    items = rest_items(recording, window_us)
    pipeline, resting = build_pipeline(SensorGeometry.load(recording.parent / "sensor.yaml"), window_us)
    config = pipeline.config
    moved_sq = config.motion_override_px**2

    def end_of(item) -> int:
        return int(item.t_us) if isinstance(item, Frame) else int(item["timestamp"][-1])

    def verdict(frame: Frame) -> None:  # the resting verdict, handed to the pipeline as run does
        result = resting.update(frame)
        if result is not None:
            pipeline.set_resting(result, frame.t_us)

    def stages(item) -> None:
        if isinstance(item, Frame):
            verdict(item)
        pipeline.process(item)

    def compiled(item) -> None:
        if isinstance(item, Frame):
            verdict(item)
            return
        pipeline._apply_pending()  # the last verdict's re-anchoring, as every item applies it
        end = pipeline._next_end
        done = rest_batch(
            item,
            pipeline.noise_filter,
            pipeline.tracker,
            pipeline.rest_px,
            end,
            window_us,
            moved_sq,
            config.override_min_markers,
        )
        if done is None or done[0] not in (OPEN, RESTING):
            raise RuntimeError(f"{recording}: the window ending at {end} us does not rest")
        if done[0] == RESTING:
            pipeline._next_end = end + window_us

    work = {"stages": stages, "compiled": compiled, "wake": None}
    t0_us = end_of(items[0])
    needed_us = FLOOR_WARM_UP_US + int(len(FLOOR_PARTS) * FLOOR_PART_S * 1e6) + 2 * window_us
    if end_of(items[-1]) - t0_us < needed_us:
        raise RuntimeError(f"{recording}: shorter than --floor's warm-up and parts ({needed_us / 1e6:g} s)")
    k = 0
    while end_of(items[k]) < t0_us + FLOOR_WARM_UP_US:  # the markers found, the rest settled
        stages(items[k])
        k += 1
    first_us = end_of(items[k])
    wake_us = (first_us // window_us + 1) * window_us + REST_WAKE_AFTER_END_US
    start_ns = time.monotonic_ns()
    out = {}
    for name in FLOOR_PARTS:
        handle = work[name]
        until_us = wake_us + int(FLOOR_PART_S * 1e6)
        wall, cpu = time.monotonic(), time.process_time()
        while wake_us < until_us:
            delay_ns = start_ns + (wake_us - first_us) * 1000 - time.monotonic_ns()
            if delay_ns > 0:
                time.sleep(delay_ns / 1e9)
            while k < len(items) and end_of(items[k]) < wake_us:
                if handle is not None:
                    handle(items[k])
                k += 1
            wake_us += window_us
        out[name] = (time.process_time() - cpu) / (time.monotonic() - wall)
    return out


def measure_wakes(n: int = 1000, period_s: float = 0.01) -> dict[str, float]:
    """CPU s of the process per wake-up with no work: ``sleep``, one thread waking at ``n``
    deadlines ``period_s`` apart; ``handoff``, a second thread woken at each one through a
    ``threading.Condition`` (both threads' CPU)."""
    import threading
    from collections import deque

    stop = threading.Event()

    def paced(each) -> None:
        t0 = time.perf_counter()
        for k in range(n):
            delay = t0 + (k + 1) * period_s - time.perf_counter()
            if delay > 0:
                stop.wait(delay)
            each(k)

    begin = time.process_time()
    paced(lambda k: None)
    out = {"sleep": (time.process_time() - begin) / n}
    cond, items = threading.Condition(), deque()

    def hand(k) -> None:
        with cond:
            items.append(k)
            cond.notify()

    def take() -> None:
        for _ in range(n):
            with cond:
                while not items:
                    cond.wait()
                items.popleft()

    taker = threading.Thread(target=take)
    begin = time.process_time()
    taker.start()
    paced(hand)
    taker.join()
    out["handoff"] = (time.process_time() - begin) / n
    return out
