"""How much a creep model's error costs: the ``viscoelastic`` family's predictions replayed
through the load estimate with a given (q, tau) (docs/method.md, "Creep").

The pipeline (docs/method.md, "Creep") answers ``none`` in a window whose load, the
window's intensity through the standard linear solid's inverse with the gel's measured creep
(``pipeline/creep.py``), is below the minimum intensity. ``calibrate --press`` measures (q, tau)
on a press; this replays a family_eval.py method's predictions (made without the rule, e.g.
a sensor.yaml without ``creep``) with any (q, tau) instead, after the episode vote: every gesture window
whose load is below the threshold is turned to ``none``, and the result scored against the
labels (only the type of gesture windows can change). It shows how far from the gel's true creep
a calibration may be before the rule stops paying.

Run::

    python3 docs/lab/creep_replay.py --dataset W/viscoelastic \\
        --predictions W/predictions/viscoelastic/r4 --share 0.3 --time-s 0.3
"""

from __future__ import annotations

import argparse
from dataclasses import replace
from pathlib import Path

from neurotouch_hid.core.dataset import list_sequences, read_labels, read_predictions
from neurotouch_hid.core.estimate import GestureType
from neurotouch_hid.core.sensor import SensorGeometry
from neurotouch_hid.evaluation.metrics import Observations, align, evaluate
from neurotouch_hid.pipeline.creep import CreepFilter
from neurotouch_hid.pipeline.pipeline import PipelineConfig

METRICS = ("gesture_accuracy", "contact_count_accuracy", "contact_distance_mm", "intensity_mae_mm", "resting_f1")


def replay(dataset: Path, predictions: Path, share: float, time_s: float) -> dict:
    """The predictions of ``predictions`` (one JSON lines file per sequence of ``dataset``) with
    every gesture window whose estimated load (mm, :class:`CreepFilter` over the windows'
    intensities, bounded as the pipeline's) is below ``PipelineConfig().gesture.min_intensity_mm``
    answered ``none``, scored against the labels. Returns the metrics and ``changed``, the windows
    turned to ``none``."""
    sensor = SensorGeometry.load(dataset / "sensor.yaml")
    threshold_mm = PipelineConfig().gesture.min_intensity_mm
    parts, changed = [], 0
    for name in list_sequences(dataset):
        windows = read_predictions(predictions / f"{name}.jsonl")
        if share > 0:
            creep = CreepFilter(share, time_s, floor=threshold_mm)
            load = [creep.update(w.intensity_mm, w.t_us) for w in windows]
            light = [w.gesture is not GestureType.NONE and f < threshold_mm for w, f in zip(windows, load)]
            changed += sum(light)
            windows = [replace(w, gesture=GestureType.NONE) if off else w for w, off in zip(windows, light)]
        parts.append(align(read_labels(dataset / f"{name}.labels.csv"), windows, sensor))
    return {**evaluate(Observations.concatenate(parts)).to_dict(), "changed": changed}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--dataset", type=Path, required=True)
    parser.add_argument("--predictions", type=Path, required=True, help="a family_eval method's predictions")
    parser.add_argument("--share", type=float, required=True, help="q, the delayed share (0: no change)")
    parser.add_argument("--time-s", type=float, default=0.3, help="tau, the retardation time (s)")
    args = parser.parse_args()
    result = replay(args.dataset, args.predictions, args.share, args.time_s)
    print(
        f"q {args.share:g}, tau {args.time_s:g} s: {result['changed']} windows answered none; "
        + ", ".join(f"{k} {result[k]:.4f}" for k in METRICS)
    )


if __name__ == "__main__":
    main()
