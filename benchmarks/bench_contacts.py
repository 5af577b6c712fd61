"""CPU of the contact step's parts per fit at 1 ms windows and 4.5 M events/s, and a digest of
its contacts: the figures of docs/performance.md ("Runtime latency", the 4.5 M events/s row).

    python3 benchmarks/bench_contacts.py [--workdir DIR] [--rate 4.5e6] [--passes 3]

The 30 s recording of ``bench_latency.make_recording`` (kept and reused in ``--workdir``),
time-compressed to ``--rate`` as ``bench_latency.py``'s rate case, runs once through the product's
pipeline (``GesturePipeline``, 1 ms windows); every ``detect_contacts`` call's arguments are kept.
Then, after ``compile_pipeline()``, those calls are repeated ``--passes`` times with a timer
(``time.thread_time_ns``, CPU of the calling thread) around ``detect_contacts`` and around each
part it calls (module attributes replaced, restored after): the figures are mean us per fit.
The md5 of every call's ``Contacts`` (all fields, with their dtypes) is printed: a speed change
must leave it unchanged (run the command on both versions).
"""

from __future__ import annotations

import argparse
import copy
import hashlib
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_latency import compressed, items, load, make_recording  # noqa: E402

from neurotouch_hid.core.sensor import SensorGeometry  # noqa: E402
from neurotouch_hid.pipeline import contacts as contacts_module  # noqa: E402
from neurotouch_hid.pipeline import fit_path as fit_module  # noqa: E402
from neurotouch_hid.pipeline.pipeline import GesturePipeline, PipelineConfig  # noqa: E402
from neurotouch_hid.service.warmup import compile_pipeline  # noqa: E402

#: the parts of ``detect_contacts`` timed, by their name in ``contacts.py``
PARTS = (
    "homography_outliers",
    "with_missed_finger",
    "_refine_peak",
    "bump_fit",
    "_maxima",
    "_usable",
    "_valid_table",
    "plateau_contacts",
    "_still_held",
    "_held_levels",
    "marker_arrays",
    "field_at",
    "_at_rest",
)


def recorded_calls(folder: Path, rate: float) -> list[tuple[tuple, dict]]:
    """Every ``detect_contacts`` call (args, kwargs, copied) of the pipeline on the recording at ``rate``."""
    path = make_recording(folder, 30.0)
    sensor = SensorGeometry.load(folder / "sensor.yaml")
    events, frames = load(path)
    span_s = (int(events["timestamp"][-1]) - frames[0].t_us) / 1e6
    ev, fr = compressed(events, frames, rate * span_s / len(events))
    calls: list[tuple[tuple, dict]] = []
    real = fit_module.detect_contacts

    def kept(*args, **kwargs):
        calls.append((copy.deepcopy(args), copy.deepcopy(kwargs)))
        return real(*args, **kwargs)

    fit_module.detect_contacts = kept
    try:
        pipeline = GesturePipeline(sensor, PipelineConfig(window_us=1000))
        for item in items(ev, fr, 1000):
            pipeline.process(item)
    finally:
        fit_module.detect_contacts = real
    return calls


def digest(calls: list[tuple[tuple, dict]]) -> str:
    """md5 of every call's ``Contacts``."""
    h = hashlib.md5()
    for args, kwargs in calls:
        c = contacts_module.detect_contacts(*args, **kwargs)
        for x in (c.indices, c.points_px, c.peaks_px, c.candidates, c.held[0], c.held[1]):
            h.update(np.ascontiguousarray(x).tobytes() + str(x.dtype).encode())
        h.update(f"{c.reproj_threshold_px!r} {c.long_flat_top}".encode())
    return h.hexdigest()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--workdir", type=Path, default=None, help="keep (and reuse) the recording here")
    ap.add_argument("--rate", type=float, default=4.5e6, help="event rate (events/s), default 4.5e6")
    ap.add_argument("--passes", type=int, default=3, help="timed passes over the recorded calls, default 3")
    args = ap.parse_args()
    folder = args.workdir or Path(tempfile.mkdtemp(prefix="bench-contacts-"))
    folder.mkdir(parents=True, exist_ok=True)
    calls = recorded_calls(folder, args.rate)
    compile_pipeline()
    print(f"{len(calls)} fits at {args.rate / 1e6:g} M events/s, 1 ms windows; contacts md5 {digest(calls)}")
    spent = dict.fromkeys(PARTS, 0)
    real = {name: getattr(contacts_module, name) for name in PARTS}

    def timed(name):
        def call(*a, **k):
            begin = time.thread_time_ns()
            out = real[name](*a, **k)
            spent[name] += time.thread_time_ns() - begin
            return out

        return call

    for name in PARTS:
        setattr(contacts_module, name, timed(name))
    try:
        begin = time.thread_time_ns()
        for _ in range(args.passes):
            for a, k in calls:
                contacts_module.detect_contacts(*a, **k)
        total = time.thread_time_ns() - begin
    finally:
        for name in PARTS:
            setattr(contacts_module, name, real[name])
    per = args.passes * len(calls) * 1e3
    parts = ", ".join(f"{name} {spent[name] / per:.1f}" for name in PARTS)
    print(
        f"detect_contacts {total / per:.0f} us CPU per fit (timers included); of it: {parts}; "
        f"load average {os.getloadavg()[0]:.1f}"
    )


if __name__ == "__main__":
    main()
