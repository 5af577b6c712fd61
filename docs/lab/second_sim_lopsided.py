"""Why the contacts of the second simulator's session_c twist_cw are found ~3 mm off its fingers
(docs/accuracy.md, "A second simulator's sessions"; docs/lab/second_sim_twist.py measures what
the markers tell about either set of centres).

    python3 docs/lab/second_sim_lopsided.py [--data ../shared/data/second-simulator]

The session is run through the product's pipeline. In every window of the twist's hold (100 ms
after its first labelled frame to 100 ms before its last) the tracked markers' displacements
(image frame, px) are explained two ways about two sets of centres at rest: the labelled contact
points, and the pipeline's own. Each centre is put at rest by subtracting the displacement of the
marker nearest to it now, as the pipeline's contact step does.

* **symmetric bumps**: the contact step's model (``pipeline/contacts_bump.py``): v(x) = sum_k
  g(|x - c_k|) u_k, one radial profile g (piecewise linear, knots one marker pitch apart, g(0) = 1)
  and one displacement u_k per finger. The centres stay where they are given; g and u are fitted.
* **lopsided bumps**: the same plus a fore-aft term h(|x - c_k|) cos(theta) u_k, theta the angle
  between x - c_k and u_k: a field stronger ahead of a dragged finger than behind it.

Per set and model: the median squared residual (px^2) over the windows. To first order a lopsided
bump about c is a symmetric bump about c shifted along u (g(|x - c - d|) ~ g - g' d cos(theta)),
so when the lopsided fit explains the field as well about either set of centres, the markers alone
do not tell where along its motion a finger is. Also per finger: the mean displacement of the
markers 4-12 px ahead of the labelled centre along its motion and as far behind (within 8 px of
the line), over the hold windows.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from neurotouch_hid.core.dataset import labels_at, read_labels
from neurotouch_hid.core.sensor import SensorGeometry
from neurotouch_hid.pipeline.methods import pipeline_for
from neurotouch_hid.sources.recording import RecordingReader

KNOTS = 9
ROUNDS = 30


def _hat(r: np.ndarray, knot: float) -> np.ndarray:
    """(M, KNOTS) piecewise-linear basis at distances ``r`` (M,) px, constant past the last knot."""
    t = np.minimum(r / knot, KNOTS - 1 - 1e-9)
    j = t.astype(int)
    f = t - j
    basis = np.zeros((len(r), KNOTS))
    basis[np.arange(len(r)), j] = 1 - f
    basis[np.arange(len(r)), j + 1] = f
    return basis


def residual(rest: np.ndarray, v: np.ndarray, centres: np.ndarray, knot: float, lopsided: bool) -> float:
    """Squared residual (px^2) of the bumps about fixed ``centres`` (K, 2) explaining ``v`` (M, 2)
    at ``rest`` (M, 2): alternating least squares of u given (g, h) and (g, h) given u."""
    d = rest[:, None, :] - centres[None]
    r = np.linalg.norm(d, axis=2)
    n = d / np.maximum(r, 1e-9)[..., None]
    bases = [_hat(r[:, k], knot) for k in range(len(centres))]
    g = np.exp(-4.5 * (np.arange(KNOTS) / (KNOTS - 1)) ** 2)
    h = np.zeros(KNOTS)
    u = np.zeros((len(centres), 2))

    def columns(u: np.ndarray) -> np.ndarray:
        unit = u / np.maximum(np.linalg.norm(u, axis=1, keepdims=True), 1e-9)
        return np.einsum("mkd,kd->mk", n, unit) if lopsided else np.zeros_like(r)

    for _ in range(ROUNDS):
        cos = columns(u)
        a = np.stack([b @ g + (b @ h) * cos[:, k] for k, b in enumerate(bases)], axis=1)
        u = np.linalg.lstsq(a, v, rcond=None)[0]
        rows = []
        for comp in range(2):
            gg = sum(b * u[k, comp] for k, b in enumerate(bases))
            hh = sum(b * cos[:, k : k + 1] * u[k, comp] for k, b in enumerate(bases))
            rows.append(np.hstack([gg, hh]) if lopsided else gg)
        sol = np.linalg.lstsq(np.vstack(rows), np.concatenate([v[:, 0], v[:, 1]]), rcond=None)[0]
        scale = sol[0] if abs(sol[0]) > 1e-9 else 1.0
        g, h, u = sol[:KNOTS] / scale, (sol[KNOTS:] / scale if lopsided else h), u * scale
    cos = columns(u)
    a = np.stack([b @ g + (b @ h) * cos[:, k] for k, b in enumerate(bases)], axis=1)
    return float(((v - a @ u) ** 2).sum())


def at_rest(now: np.ndarray, current: np.ndarray, v: np.ndarray) -> np.ndarray:
    """(K, 2) points ``now`` less the displacement of the marker nearest to each now."""
    nearest = np.argmin(np.linalg.norm(current[None] - now[:, None], axis=2), axis=1)
    return now - v[nearest]


def main(data: Path) -> None:
    sensor = SensorGeometry.load(data / "sensor.yaml")
    labels = read_labels(data / "session_c.labels.csv")
    twist = [r for r in labels if r.gesture.value == "twist_cw"]
    t0, t1 = twist[0].t_us, twist[-1].t_us
    pipeline = pipeline_for(sensor, None)
    knot = 4.0 * sensor.px_per_mm  # the marker pitch, 4 mm
    sse: dict[tuple[str, bool], list[float]] = {}
    ahead: list[list[float]] = []
    behind: list[list[float]] = []
    with RecordingReader(data / "session_c.aedat4") as reader:
        for estimate in pipeline.run(reader.stream()):
            if not t0 + 100_000 <= estimate.t_us <= t1 - 100_000:
                continue
            label = labels_at(labels, np.array([estimate.t_us]))[0]
            ok = pipeline.tracker.valid & np.isfinite(pipeline.tracker.positions_px).all(axis=1)
            rest = pipeline.rest_px[ok].astype(np.float64)
            current = pipeline.tracker.positions_px[ok].astype(np.float64)
            v = current - rest
            labelled = at_rest(np.asarray(label.contacts_px[: label.n_contacts], dtype=float), current, v)
            found = np.asarray(estimate.contacts_px, dtype=float).reshape(-1, 2)
            if len(found) < 2:
                continue
            for which, centres in (
                ("labelled contacts", labelled),
                ("pipeline's contacts", at_rest(found, current, v)),
            ):
                for lopsided in (False, True):
                    sse.setdefault((which, lopsided), []).append(residual(rest, v, centres, knot, lopsided))
            row_a, row_b = [], []
            for c in labelled:
                d = rest - c
                near = np.linalg.norm(d, axis=1) < 12
                motion = v[near].sum(axis=0)
                motion /= max(np.linalg.norm(motion), 1e-9)
                along, across = d @ motion, np.abs(d @ np.array([-motion[1], motion[0]]))
                size = np.linalg.norm(v, axis=1)
                front = size[(along >= 4) & (along < 12) & (across < 8)]
                back = size[(along > -12) & (along <= -4) & (across < 8)]
                row_a.append(front.mean() if len(front) else np.nan)
                row_b.append(back.mean() if len(back) else np.nan)
            ahead.append(row_a)
            behind.append(row_b)
    print("| centres | model | windows | median squared residual px^2 |")
    print("| --- | --- | ---: | ---: |")
    for (which, lopsided), values in sse.items():
        model = "lopsided bumps" if lopsided else "symmetric bumps"
        print(f"| {which} | {model} | {len(values)} | {np.median(values):.1f} |")
    a, b = np.nanmean(np.array(ahead), axis=0), np.nanmean(np.array(behind), axis=0)
    print(
        "\nper labelled finger, mean |v| px 4-12 px ahead / behind along its motion: "
        + ", ".join(f"{x:.2f} / {y:.2f}" for x, y in zip(a, b))
    )


if __name__ == "__main__":
    args = sys.argv[1:]
    main(Path(args[args.index("--data") + 1]) if "--data" in args else Path("../shared/data/second-simulator"))
