"""CPU per pipeline step, hot and cold, and where the slowest windows' time goes: the figures of
docs/performance.md ("Pipeline stages"; "Runtime latency", "Where the p99 goes").

    python3 benchmarks/bench_stages.py [--workdir DIR] [--idle-ms 0.8] [--json PATH]

On the 30 s simulated recording of ``bench_latency.make_recording`` (every gesture, seed 0; kept
and reused in ``--workdir``), the product's pipeline (``GesturePipeline``, 10 ms windows, the
noise filter on, the resting detector inline as ``--fast`` runs it) is fed 1 ms batches, and
each estimate goes through ``Mapper.update`` on the default profile, as the runtime does. Two
passes after the same warm-up as ``bench_latency.py`` (``compile_pipeline()``, 0.2 s of the
recording): **hot**, the batches back to back; **cold**, ``--idle-ms`` of ``time.sleep`` after
each batch, as the driver idles between the camera's batches (bench_latency.py's cold line).

Every figure is CPU time of the calling thread (``time.thread_time_ns``), p50 and p99 in us:
a shared machine's other jobs inflate wall-clock figures, not these. Where it comes from:

- the pipeline's own profiling hooks (``GesturePipeline(profile=True)``, ``cpu_timings``): the
  noise filter and the tracker summed per window (as ``bench_pipeline.py`` does), the contact
  step (the gel-motion fit + ``detect_contacts``) and the gesture step (``estimate_gesture`` + the
  learned type) per window that fitted afresh (a window whose tracked markers did not move since
  the one before reuses its fit and is counted apart), the resting detector per APS frame, the
  frame correction per APS frame that corrects the blobs;
- wrappers the benchmark puts around the real functions for its passes (module attributes
  replaced, restored afterwards; no product code changes): ``estimate_gel_motion`` and its
  ``cv2.estimateAffinePartial2D`` (LMEDS), ``detect_contacts`` and, inside it,
  ``cv2.findHomography`` (USAC), the peak refinement (summed over a window's peaks) and the bump
  fit kernel, each only where it ran; ``estimate_gesture`` and its similarity
  (``cv2.estimateAffinePartial2D``, RANSAC), the learned type. A wrapper costs about 1 us.
- ``pipeline.process`` of each 1 ms batch (or APS frame) that closes a window: the pipeline
  alone's share of the processing latency (bench_latency.py's "CPU per item closing a window").

"The slowest windows": the items closing a window whose CPU is at or above the
``100 - --slowest-percent`` percentile (default: the slowest 2 %), and the mean CPU of each
step within them (0 where it did not run), i.e. where the p99 processing latency goes (the
noise filter and the tracker: the closing item's own batch, not the whole window's).

An unwrapped hot pass first gives the reference estimates: the wrapped passes must give the same
(printed as a check).
"""

from __future__ import annotations

import argparse
import contextlib
import hashlib
import json
import os
import sys
import tempfile
import time
from collections import defaultdict
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from unittest import mock

import cv2
import numpy as np
from rich.table import Table

sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_latency import items, load, make_recording  # noqa: E402

from neurotouch_hid.core.estimate import GestureEstimate  # noqa: E402
from neurotouch_hid.core.sensor import SensorGeometry  # noqa: E402
from neurotouch_hid.mapping.mapper import Mapper  # noqa: E402
from neurotouch_hid.mapping.profile import load_profile  # noqa: E402
from neurotouch_hid.pipeline import contacts as contacts_module  # noqa: E402
from neurotouch_hid.pipeline import fit_path as fit_module  # noqa: E402
from neurotouch_hid.pipeline.pipeline import GesturePipeline, PipelineConfig  # noqa: E402
from neurotouch_hid.service.warmup import compile_pipeline  # noqa: E402
from neurotouch_hid.sources import Frame  # noqa: E402
from neurotouch_hid.views.console import make_console  # noqa: E402

#: (key, label, per what): the rows, in order. ``hook:`` keys come from the pipeline's
#: ``cpu_timings``, the others from the benchmark's wrappers or its own clock.
STEPS: list[tuple[str, str, str]] = [
    ("item", "pipeline.process, item closing a window", "1 ms batch or frame closing a window"),
    ("noise_filter", "noise filter", "window"),
    ("tracker", "tracker", "window"),
    ("contact_step", "contact step (gel motion + detect_contacts)", "fit"),
    ("gel_motion", "  of it: estimate_gel_motion", "fit"),
    ("lmeds", "    of it: cv2.estimateAffinePartial2D LMEDS", "where it ran"),
    ("detect_contacts", "  of it: detect_contacts", "fit"),
    ("homography", "    of it: cv2.findHomography (USAC)", "where it ran"),
    ("refine", "    of it: peak refinement", "where it ran"),
    ("bump_fit", "    of it: bump fit (bump_fit or with_missed_finger kernel)", "where it ran"),
    ("gesture_step", "gesture step (estimate_gesture + learned type)", "fit"),
    ("estimate_gesture", "  of it: estimate_gesture", "fit"),
    ("similarity", "    of it: cv2.estimateAffinePartial2D RANSAC", "where it ran"),
    ("learned", "  of it: learned type", "fit"),
    ("resting", "resting detector", "APS frame"),
    ("frame_correction", "frame correction", "APS frame correcting"),
    ("mapper", "Mapper.update, default profile", "estimate"),
]


#: the hooks recorded per event batch or per frame, attributed to the item that ran them
PER_ITEM_HOOKS = ("noise_filter", "tracker", "resting", "frame_correction")


@dataclass
class Pass:
    """One pass's samples (CPU ns)."""

    name: str
    idle_s: float
    steps: dict[str, list[int]] = field(default_factory=lambda: defaultdict(list))
    #: per item closing a window: (its CPU, {step: CPU within the item}, whether it is a frame)
    closing: list[tuple[int, dict[str, int], bool]] = field(default_factory=list)
    windows: int = 0
    fits: int = 0
    reused: int = 0
    digest: str = ""
    cpu_s: float = 0.0


class Wrappers:
    """CPU of the wrapped functions, accumulated until :meth:`take`."""

    def __init__(self) -> None:
        self.acc: dict[str, int] = defaultdict(int)

    def timed(self, name: str | Callable[..., str], fn: Callable) -> Callable:
        def wrapper(*args, **kwargs):
            start = time.thread_time_ns()
            try:
                return fn(*args, **kwargs)
            finally:
                key = name if isinstance(name, str) else name(*args, **kwargs)
                self.acc[key] += time.thread_time_ns() - start

        return wrapper

    def take(self) -> dict[str, int]:
        out, self.acc = dict(self.acc), defaultdict(int)
        return out

    @contextlib.contextmanager
    def installed(self) -> Iterator[None]:
        """The wrappers in place of the real functions, restored on exit."""

        def affine_kind(*args, **kwargs) -> str:
            return "lmeds" if kwargs.get("method") == cv2.LMEDS else "similarity"

        patches = [
            mock.patch.object(
                fit_module, "estimate_gel_motion", self.timed("gel_motion", fit_module.estimate_gel_motion)
            ),
            mock.patch.object(fit_module, "detect_contacts", self.timed("detect_contacts", fit_module.detect_contacts)),
            mock.patch.object(
                fit_module, "estimate_gesture", self.timed("estimate_gesture", fit_module.estimate_gesture)
            ),
            mock.patch.object(GesturePipeline, "_learned_type", self.timed("learned", GesturePipeline._learned_type)),
            mock.patch.object(contacts_module, "bump_fit", self.timed("bump_fit", contacts_module.bump_fit)),
            mock.patch.object(
                contacts_module, "with_missed_finger", self.timed("bump_fit", contacts_module.with_missed_finger)
            ),
            mock.patch.object(contacts_module, "_refine_peak", self.timed("refine", contacts_module._refine_peak)),
            mock.patch.object(cv2, "findHomography", self.timed("homography", cv2.findHomography)),
            mock.patch.object(cv2, "estimateAffinePartial2D", self.timed(affine_kind, cv2.estimateAffinePartial2D)),
        ]
        with contextlib.ExitStack() as stack:
            for p in patches:
                stack.enter_context(p)
            yield


def digest_of(estimates: list[GestureEstimate]) -> str:
    """A hash of the estimates' predictions lines (``GestureEstimate.to_json_dict``, what
    ``track`` writes): equal digests, byte-identical predictions."""
    h = hashlib.sha256()
    for e in estimates:
        h.update(json.dumps(e.to_json_dict()).encode())
    return h.hexdigest()[:16]


def run_pass(
    stream: list, sensor: SensorGeometry, window_us: int, idle_s: float, name: str, wrappers: Wrappers | None
) -> Pass:
    """Feed ``stream`` to a fresh pipeline (and each estimate to a fresh default-profile
    Mapper), sleeping ``idle_s`` after each item; without ``wrappers``, only the digest."""
    result = Pass(name, idle_s)
    marks = {"tracker": 0, "noise_filter": 0, "contacts": 0, "gesture": 0}
    window_records: list[dict[str, int]] = []

    def delta(stage: str) -> int:
        values = pipeline.cpu_timings[stage]
        total = sum(values[marks[stage] :])
        marks[stage] = len(values)
        return total

    def on_window(estimate: GestureEstimate) -> None:
        record = {"tracker": delta("tracker"), "noise_filter": delta("noise_filter")}
        contacts, gesture = delta("contacts"), delta("gesture")
        if wrappers is not None:
            record.update(wrappers.take())
        if "detect_contacts" in record:
            record["contact_step"], record["gesture_step"] = contacts, gesture
        window_records.append(record)

    pipeline = GesturePipeline(sensor, PipelineConfig(window_us=window_us), on_window=on_window, profile=True)
    mapper = Mapper(load_profile("default"))
    estimates: list[GestureEstimate] = []
    cpu0 = time.process_time()
    with wrappers.installed() if wrappers is not None else contextlib.nullcontext():
        for item in stream:
            first_window = len(window_records)
            before = {s: len(pipeline.cpu_timings[s]) for s in PER_ITEM_HOOKS}
            start = time.thread_time_ns()
            out = pipeline.process(item)
            cpu = time.thread_time_ns() - start
            # this item's own share of the per-batch and per-frame hooks (a window's tracker and
            # noise filter span its ~10 batches: only the closing batch's count in the item)
            own = {s: pipeline.cpu_timings[s][before[s] :] for s in PER_ITEM_HOOKS}
            result.steps["resting"].extend(own["resting"])
            result.steps["frame_correction"].extend(own["frame_correction"])
            for e in out:
                start = time.thread_time_ns()
                mapper.update(e)
                result.steps["mapper"].append(time.thread_time_ns() - start)
            if out:
                within: dict[str, int] = {s: sum(v) for s, v in own.items() if v}
                for record in window_records[first_window:]:
                    for key, value in record.items():
                        if key not in PER_ITEM_HOOKS:
                            within[key] = within.get(key, 0) + value
                result.steps["item"].append(cpu)
                result.closing.append((cpu, dict(within), isinstance(item, Frame)))
            estimates.extend(out)
            if idle_s:
                time.sleep(idle_s)
    result.cpu_s = time.process_time() - cpu0
    result.windows = len(window_records)
    for record in window_records:
        for key, value in record.items():
            if key in ("tracker", "noise_filter") or wrappers is not None:
                result.steps[key].append(value)
        if "detect_contacts" in record:
            result.fits += 1
    result.reused = len(pipeline.cpu_timings["contacts"]) - result.fits
    result.digest = digest_of(estimates)
    return result


def percentiles(values: list[int]) -> dict:
    if not values:
        return {"n": 0, "p50_us": None, "p99_us": None}
    us = np.asarray(values, dtype=np.float64) / 1e3
    return {"n": len(us), "p50_us": round(float(np.median(us)), 1), "p99_us": round(float(np.percentile(us, 99)), 1)}


def slowest(p: Pass, percent: float) -> dict:
    """The items closing a window at or above the (100 - percent) percentile of their CPU: the
    mean CPU of each step within them (0 where it did not run) and how many ran it."""
    cpu = np.array([c for c, _, _ in p.closing], dtype=np.float64)
    cut = float(np.percentile(cpu, 100 - percent))
    chosen = [(c, w, f) for c, w, f in p.closing if c >= cut]
    keys = [k for k, _, _ in STEPS if k not in ("item", "mapper")]
    return {
        "percent": percent,
        "threshold_us": round(cut / 1e3, 1),
        "n": len(chosen),
        "frames": sum(f for _, _, f in chosen),
        "item_mean_us": round(float(np.mean([c for c, _, _ in chosen])) / 1e3, 1),
        "steps": {
            k: {
                "mean_us": round(float(np.mean([w.get(k, 0) for _, w, _ in chosen])) / 1e3, 1),
                "ran": sum(k in w for _, w, _ in chosen),
            }
            for k in keys
        },
    }


def fmt(value: float | None) -> str:
    return "-" if value is None else f"{value:.0f}"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seconds", type=float, default=30.0, help="length of the simulated recording (s), default 30")
    ap.add_argument("--workdir", type=Path, default=None, help="keep (and reuse) the recording here")
    ap.add_argument(
        "--idle-ms",
        type=float,
        default=0.8,
        help="the cold pass sleeps this long after each 1 ms batch (default 0.8; 0: no cold pass)",
    )
    ap.add_argument("--window-us", type=int, default=10_000, help="window length (us), default 10000")
    ap.add_argument("--slowest-percent", type=float, default=2.0, help="'the slowest windows': this top percent")
    ap.add_argument("--json", type=Path, default=None, metavar="PATH", help="also write the figures here as JSON")
    args = ap.parse_args()
    if args.idle_ms < 0:
        ap.error("--idle-ms must be >= 0")
    if not 0 < args.slowest_percent < 100:
        ap.error("--slowest-percent must be in (0, 100)")
    console = make_console()

    folder = args.workdir or Path(tempfile.mkdtemp(prefix="bench-stages-"))
    folder.mkdir(parents=True, exist_ok=True)
    path = make_recording(folder, args.seconds)
    sensor = SensorGeometry.load(folder / "sensor.yaml")
    events, frames = load(path)
    stream = items(events, frames, 1000)
    console.print(f"recording {path}: {len(events)} events, {len(frames)} APS frames, {len(stream)} items")
    load_before = os.getloadavg()

    # warm-up as bench_latency.py does: every kernel compiled or loaded, OpenCV's first calls
    compile_pipeline()
    run_pass(stream[:200], sensor, args.window_us, 0.0, "warm-up", None)

    reference = run_pass(stream, sensor, args.window_us, 0.0, "reference (unwrapped)", None)
    passes = [run_pass(stream, sensor, args.window_us, 0.0, "hot", Wrappers())]
    if args.idle_ms:
        passes.append(run_pass(stream, sensor, args.window_us, args.idle_ms / 1e3, "cold", Wrappers()))
    load_after = os.getloadavg()

    figures = {
        "recording": {"path": str(path), "events": len(events), "aps_frames": len(frames)},
        "window_us": args.window_us,
        "idle_ms": args.idle_ms,
        "load_before": [round(x, 2) for x in load_before],
        "load_after": [round(x, 2) for x in load_after],
        "cpu_count": os.cpu_count(),
        "estimates_identical": all(p.digest == reference.digest for p in passes),
        "reference_cpu_s": round(reference.cpu_s, 2),
        "passes": {
            p.name: {
                "idle_ms": p.idle_s * 1e3,
                "cpu_s": round(p.cpu_s, 2),
                "windows": p.windows,
                "fits": p.fits,
                "fits_reused": p.reused,
                "steps": {k: percentiles(p.steps.get(k, [])) for k, _, _ in STEPS},
                "slowest": slowest(p, args.slowest_percent),
            }
            for p in passes
        },
    }

    title = f"CPU per step (us, calling thread), {args.window_us} us windows, 1 ms batches; " + ", ".join(
        f"{p.name}: {p.windows} windows, {p.fits} fits, {p.reused} reused" for p in passes
    )
    table = Table(title=title)
    table.add_column("step")
    table.add_column("per")
    for p in passes:
        label = p.name if not p.idle_s else f"{p.name} ({p.idle_s * 1e3:g} ms idle)"
        for col in ("n", "p50", "p99"):
            table.add_column(f"{label} {col}", justify="right")
    for key, label, per in STEPS:
        row = [label, per]
        for p in passes:
            q = figures["passes"][p.name]["steps"][key]
            row += [str(q["n"]), fmt(q["p50_us"]), fmt(q["p99_us"])]
        table.add_row(*row)
    console.print(table)

    for p in passes:
        s = figures["passes"][p.name]["slowest"]
        t = Table(
            title=(
                f"{p.name}: the slowest {s['percent']:g} % of items closing a window ({s['n']} items, CPU >= "
                f"{s['threshold_us']:.0f} us, mean {s['item_mean_us']:.0f} us; {s['frames']} APS frames among them)"
            )
        )
        t.add_column("step")
        t.add_column("mean us", justify="right")
        t.add_column("ran in", justify="right")
        for key, label, _ in STEPS:
            if key in s["steps"]:
                t.add_row(label, f"{s['steps'][key]['mean_us']:.0f}", f"{s['steps'][key]['ran']}/{s['n']}")
        console.print(t)

    same = "yes" if figures["estimates_identical"] else "NO"
    console.print(f"estimates of the wrapped passes identical to the unwrapped pass: {same}")
    console.print(
        f"load average (1, 5, 15 min) before {', '.join(f'{x:.2f}' for x in load_before)}, after "
        f"{', '.join(f'{x:.2f}' for x in load_after)}, on {os.cpu_count()} cores"
    )
    if args.json is not None:
        args.json.write_text(json.dumps(figures, indent=2) + "\n", encoding="utf-8")
        console.print(f"figures written to {args.json}")
    if not figures["estimates_identical"]:
        sys.exit(1)


if __name__ == "__main__":
    main()
