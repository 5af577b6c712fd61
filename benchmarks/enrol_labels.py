"""How well ``enrol --from`` labels agree with the simulator's own labels (docs/dataset.md).

    python3 benchmarks/enrol_labels.py --out DIR [--families default,powerlaw,...] [--seed 2]
        [--prompts 24] [--miss-rate 0.05]

Per family: the simulated hand (``neurotouch_hid/enrolment/hand.py``, user ``seed % 10``, a
prompt missed at ``--miss-rate``) performs the first ``--prompts`` prompts of the plan of
``--seed`` (``enrol --plan-out``'s) on that family's gel; the recording is labelled from the plan
alone (``neurotouch_hid/enrolment/label.py``) and compared with the simulator's labels on the APS
frames further than 100 ms from a gesture's start or end: the share of the same gesture type
(``none`` included), of the same contact count (frames where both say the same gesture) and the
mean intensity difference there; and whether each prompt the hand missed was left out, and
only those. Each family's recording is written once under ``DIR/FAMILY``.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from neurotouch_hid.core.dataset import read_labels  # noqa: E402
from neurotouch_hid.core.sensor import SensorGeometry  # noqa: E402
from neurotouch_hid.enrolment.hand import simulate_enrolment  # noqa: E402
from neurotouch_hid.enrolment.label import (  # noqa: E402
    agreement,
    check_gestures,
    find_gestures,
    label_frames,
    measure_motion,
)
from neurotouch_hid.enrolment.plan import Plan, make_plan  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--out", required=True, type=Path)
    parser.add_argument("--families", default="default")
    parser.add_argument("--seed", type=int, default=2)
    parser.add_argument("--prompts", type=int, default=24)
    parser.add_argument("--miss-rate", type=float, default=0.05)
    args = parser.parse_args()
    full = make_plan(args.seed)
    plan = Plan(full.prompts[: args.prompts])
    print("| family | frames | gesture | contact count | intensity MAE (mm) | missed by the hand | left out |")
    print("| --- | --- | --- | --- | --- | --- | --- |")
    for family in args.families.split(","):
        folder = args.out / family
        start = time.perf_counter()
        performed = simulate_enrolment(plan, folder, seed=args.seed, physics=family, miss_rate=args.miss_rate)
        sensor = SensorGeometry.load(folder / "sensor.yaml")
        motion = measure_motion(folder / "enrolment.aedat4", sensor)
        found = check_gestures(find_gestures(plan, motion), motion, sensor)  # as enrol --from
        score = agreement(read_labels(folder / "enrolment.labels.csv"), label_frames(motion, found, sensor.px_per_mm))
        missed = [i + 1 for i, p in enumerate(performed) if p.gesture is None]
        left_out = [i + 1 for i, f in enumerate(found) if not f.labelled]
        print(
            f"| {family} | {score.frames} | {100 * score.gesture:.1f} % | {100 * score.contacts:.1f} % | "
            f"{score.intensity_mae_mm:.2f} | {missed} | {left_out} |",
            flush=True,
        )
        print(f"  ({time.perf_counter() - start:.0f} s)", file=sys.stderr)


if __name__ == "__main__":
    main()
