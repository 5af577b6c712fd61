"""What the markers tell of the second simulator's session_c twist_cw (three fingers, 1.25 mm at
its peak, read zoom: docs/accuracy.md, "A second simulator's sessions").

    python3 docs/lab/second_sim_twist.py [--data ../shared/data/second-simulator]

The session is run through the product's pipeline; in every window of the twist's hold (100 ms
after its first labelled frame to 100 ms before its last) the tracked markers whose rest position
lies within R mm of a set of centres are fitted a similarity rest -> now about the centres' mean
(OpenCV's ``estimateAffinePartial2D``, least median of squares), for R = 4, 6, 8, 10 and 15 mm,
around two sets of centres: the labelled contact points (where the fingers are) and the
pipeline's own contact points. One markdown row per set and radius: the markers, the median
scale - 1 and rotation (image frame, degrees), the median ratio of the rotation's term to the
scale's (|theta| / |s - 1|: the paper's terms at one radius) and the share of windows in which the
rotation's term is the larger (a twist).
"""

from __future__ import annotations

import sys
from pathlib import Path

import cv2
import numpy as np

from neurotouch_hid.core.dataset import labels_at, read_labels
from neurotouch_hid.core.sensor import SensorGeometry
from neurotouch_hid.pipeline.methods import pipeline_for
from neurotouch_hid.sources.recording import RecordingReader

RADII_MM = (4, 6, 8, 10, 15)


def main(data: Path) -> None:
    sensor = SensorGeometry.load(data / "sensor.yaml")
    labels = read_labels(data / "session_c.labels.csv")
    twist = [r for r in labels if r.gesture.value == "twist_cw"]
    t0, t1 = twist[0].t_us, twist[-1].t_us
    pipeline = pipeline_for(sensor, None)
    fits: dict[tuple[str, int], list[tuple[float, float, int]]] = {}
    with RecordingReader(data / "session_c.aedat4") as reader:
        for estimate in pipeline.run(reader.stream()):
            if not t0 + 100_000 <= estimate.t_us <= t1 - 100_000:
                continue
            label = labels_at(labels, np.array([estimate.t_us]))[0]
            centres = {
                "labelled contacts": np.asarray(label.contacts_px[: label.n_contacts], dtype=float),
                "pipeline's contacts": np.asarray(estimate.contacts_px, dtype=float).reshape(-1, 2),
            }
            current, valid, rest = pipeline.tracker.positions_px, pipeline.tracker.valid, pipeline.rest_px
            for which, c in centres.items():
                if len(c) == 0:
                    continue
                near = np.min(np.linalg.norm(rest[:, None, :] - c[None], axis=2), axis=1)
                for radius in RADII_MM:
                    m = valid & (near < radius * sensor.px_per_mm) & np.isfinite(current).all(axis=1)
                    o = c.mean(axis=0)
                    matrix, _ = cv2.estimateAffinePartial2D(
                        (rest[m] - o).astype(np.float32), (current[m] - o).astype(np.float32), method=cv2.LMEDS
                    )
                    scale = float(np.hypot(matrix[0, 0], matrix[1, 0]))
                    theta = float(np.arctan2(matrix[1, 0], matrix[0, 0]))
                    fits.setdefault((which, radius), []).append((scale - 1.0, theta, int(m.sum())))
    print("| centres | R mm | markers | scale - 1 | rotation deg | rotation / scale term | windows read twist |")
    print("| --- | ---: | ---: | ---: | ---: | ---: | ---: |")
    for (which, radius), values in fits.items():
        v = np.array(values)
        ratio = np.abs(v[:, 1]) / np.abs(v[:, 0])
        print(
            f"| {which} | {radius} | {np.median(v[:, 2]):.0f} | {np.median(v[:, 0]):+.4f} | "
            f"{np.degrees(np.median(v[:, 1])):+.2f} | {np.median(ratio):.2f} | "
            f"{100 * np.mean(ratio > 1):.0f} % of {len(v)} |"
        )


if __name__ == "__main__":
    args = sys.argv[1:]
    main(Path(args[args.index("--data") + 1]) if "--data" in args else Path("../shared/data/second-simulator"))
