"""What a creep model of the gel would do for the ``viscoelastic`` family's release tails
(docs/accuracy.md, "Round 5: a creep model of the gel, measured and not adopted").

A standard linear solid (the ``viscoelastic`` family, ``sources/physics.py``) deforms by
``d = (1 - q) f + q y`` under a load f, with ``tau dy/dt = f - y``. Given q and tau, the load
follows from the deformation alone: y is d low-passed with the time constant ``(1 - q) tau``
and ``f = (d - q y) / (1 - q)``. Once the fingers leave, f is ~0 while d still holds the creep:
a window whose estimated load is below the gesture step's ``min_intensity_px`` would answer
``none``. Two measurements, no pipeline change:

* ``replay``: a family_eval.py method's predictions, each window's intensity run through the
  load estimate with a given (q, tau) and turned to ``none`` below the threshold, scored
  against the labels (the other metrics do not change: only the type of gesture windows does).
* ``press``: what a calibration would measure: one simulated push sequence of the tuning user
  5 (seed 1, 6 s, ``write_dataset``) on a family, tracked by the pipeline; its amplitude (the
  mean of the 10 largest tracked displacements, px, every 10 ms window) fitted by the (q, tau)
  whose load is flattest while the finger holds (>= 0.5 of the peak, 120 ms after it got
  there until 80 ms before it left) and nearest 0 over the 1.5 s after it left (grid: q 0 to
  0.6 by 0.02, tau 0.05 to 3 s, 40 steps geometric).

Run::

    python3 benchmarks/creep_replay.py replay --dataset W/viscoelastic \\
        --predictions W/predictions/viscoelastic/all --share 0.3 --time-s 0.3
    python3 benchmarks/creep_replay.py press --out P --families viscoelastic,default,fingers
"""

from __future__ import annotations

import argparse
from dataclasses import replace
from pathlib import Path

import numpy as np

from neurotouch_hid.dataset import list_sequences, read_labels, read_predictions
from neurotouch_hid.estimate import GestureType
from neurotouch_hid.evaluation.metrics import Observations, align, evaluate
from neurotouch_hid.pipeline.pipeline import GesturePipeline, PipelineConfig
from neurotouch_hid.sensor import SensorGeometry
from neurotouch_hid.sources.recording import RecordingReader
from neurotouch_hid.sources.simulator import write_dataset

SHARES = np.arange(0.0, 0.61, 0.02)
TIMES_S = np.geomspace(0.05, 3.0, 40)


def load_estimate(deformation: np.ndarray, t_us: np.ndarray, share, time_s) -> np.ndarray:
    """The standard linear solid's load f = (d - q y) / (1 - q), y = d low-passed with
    (1 - q) tau, for a deformation series (T,) at times (T,) int64 us; ``share`` q and
    ``time_s`` tau scalars or arrays of one shape S (a grid of candidates). Returns (T, *S)."""
    q = np.asarray(share, dtype=np.float64)
    tau = np.asarray(time_s, dtype=np.float64)
    out = np.empty((len(deformation), *np.broadcast(q, tau).shape))
    y = np.zeros(np.broadcast(q, tau).shape)
    dt = np.diff(np.asarray(t_us, dtype=np.float64), prepend=float(t_us[0])) * 1e-6
    for k, d in enumerate(deformation):
        y = y + (d - y) * (1.0 - np.exp(-dt[k] / ((1.0 - q) * tau)))
        out[k] = (d - q * y) / (1.0 - q)
    return out


def replay(dataset: Path, predictions: Path, share: float, time_s: float) -> dict:
    """The predictions of ``predictions`` (one JSON lines file per sequence of ``dataset``) with
    every gesture window whose estimated load is below ``PipelineConfig().min_intensity_px``
    answered ``none``, scored against the labels. Returns the metrics and the windows changed."""
    sensor = SensorGeometry.load(dataset / "sensor.yaml")
    threshold_mm = PipelineConfig().min_intensity_px / sensor.px_per_mm
    parts, changed = [], 0
    for name in list_sequences(dataset):
        windows = read_predictions(predictions / f"{name}.jsonl")
        if share > 0:
            t = np.array([w.t_us for w in windows], dtype=np.int64)
            load = load_estimate(np.array([w.intensity_mm for w in windows]), t, share, time_s)
            light = [w.gesture is not GestureType.NONE and f < threshold_mm for w, f in zip(windows, load)]
            changed += sum(light)
            windows = [replace(w, gesture=GestureType.NONE) if off else w for w, off in zip(windows, light)]
        parts.append(align(read_labels(dataset / f"{name}.labels.csv"), windows, sensor))
    return {**evaluate(Observations.concatenate(parts)).to_dict(), "changed": changed}


def press_amplitude(recording: Path, sensor: SensorGeometry) -> tuple[np.ndarray, np.ndarray]:
    """(t_us (T,) int64, amplitude (T,) float64 px): at each 10 ms window's end, the mean of the
    10 largest tracked displacements from rest (the pipeline's tracker, defaults)."""
    times, amplitude = [], []
    pipeline: GesturePipeline

    def keep(estimate) -> None:
        moved = np.linalg.norm(pipeline.marker_positions() - pipeline.rest_px, axis=1)
        moved = moved[np.isfinite(moved)]
        times.append(estimate.t_us)
        amplitude.append(float(np.sort(moved)[-10:].mean()) if len(moved) else 0.0)

    pipeline = GesturePipeline(sensor, on_window=keep)
    with RecordingReader(recording) as reader:
        for item in reader.stream(batch_us=pipeline.config.window_us):
            pipeline.process(item)
    return np.array(times, dtype=np.int64), np.array(amplitude)


def fit_creep(t_us: np.ndarray, amplitude: np.ndarray) -> tuple[float, float, float]:
    """(q, tau s, cost): the grid's candidate whose load is flattest over the holds and nearest 0
    after the releases (module docstring); cost in px^2."""
    pressed = amplitude >= 0.5 * amplitude.max()
    hold = np.zeros(len(amplitude), dtype=bool)
    after = np.zeros(len(amplitude), dtype=bool)
    edges = np.flatnonzero(np.diff(pressed.astype(np.int8))) + 1
    bounds = np.concatenate(([0], edges, [len(pressed)]))
    for a, b in zip(bounds[:-1], bounds[1:]):
        if pressed[a]:
            hold |= (t_us >= t_us[a] + 120_000) & (t_us <= t_us[b - 1] - 80_000)
            after |= (t_us > t_us[b - 1] + 120_000) & (t_us <= t_us[b - 1] + 1_500_000)
    q, tau = np.meshgrid(SHARES, TIMES_S, indexing="ij")
    load = load_estimate(amplitude, t_us, q, tau)
    level = np.median(load[hold], axis=0)
    cost = ((load[hold] - level) ** 2).sum(axis=0) + (load[after] ** 2).sum(axis=0)
    i, j = np.unravel_index(np.argmin(cost), cost.shape)
    return float(SHARES[i]), float(TIMES_S[j]), float(cost[i, j])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="command", required=True)
    r = sub.add_parser("replay", help="score predictions with the load estimate")
    r.add_argument("--dataset", type=Path, required=True)
    r.add_argument("--predictions", type=Path, required=True)
    r.add_argument("--share", type=float, required=True, help="q, the delayed share (0: no change)")
    r.add_argument("--time-s", type=float, default=0.3, help="tau, the retardation time (s)")
    p = sub.add_parser("press", help="simulate a press per family and fit (q, tau) to it")
    p.add_argument("--out", type=Path, required=True, help="folder for the simulated presses")
    p.add_argument("--families", default="viscoelastic,default")
    args = parser.parse_args()
    if args.command == "replay":
        result = replay(args.dataset, args.predictions, args.share, args.time_s)
        keys = ("gesture_accuracy", "contact_count_accuracy", "contact_distance_mm", "intensity_mae_mm", "resting_f1")
        print(f"q {args.share:g}, tau {args.time_s:g} s: {result['changed']} windows answered none; "
              + ", ".join(f"{k} {result[k]:.4f}" for k in keys))
        return
    for family in args.families.split(","):
        folder = args.out / family
        if not (folder / "u5_push.aedat4").exists():
            write_dataset(folder, seed=1, users=[5], gestures=["push"], minutes=0.1, progress=False, physics=family)
        t, amplitude = press_amplitude(folder / "u5_push.aedat4", SensorGeometry.load(folder / "sensor.yaml"))
        share, time_s, cost = fit_creep(t, amplitude)
        print(f"{family}: q {share:.2f}, tau {time_s:.2f} s (cost {cost:.1f} px^2, peak {amplitude.max():.1f} px)")


if __name__ == "__main__":
    main()
