"""Event-blob tracker: accuracy against the simulator's truth, throughput, and a 12 M events/s
stress stream, side by side with dv-processing's MeanShiftTracker (docs/performance.md, "Tracker").

1. Simulated recordings (``neurotouch_hid.sources.sim_dataset.write_dataset``, read back through
   ``RecordingReader``): the markers are detected on the first APS frame, tracked in 10 ms
   windows, and each tracker's position is compared, at every window end, with the true position
   of the SAME marker (blob i is matched to true marker j once, at rest, by nearest neighbour; the
   identity is then kept), on markers that moved (> 1 px from rest). Three trackers:
   ours on events only (the paper's method), ours plus APS-frame correction
   (``BlobTracker.correct`` on every frame's detections), and dv-processing's
   ``dv.features.MeanShiftTracker`` behind ``dv.noise.BackgroundActivityNoiseFilter``, seeded with
   the same detections (drawn as dots for its ``EventFeatureBlobDetector``).
2. Stress: 177 markers circling at 0.5 px/ms (the fastest simulated gestures move ~0.15 px/ms)
   plus uniform noise, 120 k events per 10 ms window (12 M events/s, the DAVIS-346's USB limit);
   per-window time (median, p99) on one core and the position error against the generator's truth.

Run: ``python3 benchmarks/bench_tracker.py`` (``--help`` for options).
"""

from __future__ import annotations

import argparse
import datetime
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
from rich.table import Table

from neurotouch_hid.core.sensor import SensorGeometry
from neurotouch_hid.pipeline.markers import detect_markers
from neurotouch_hid.pipeline.tracker import BlobTracker, TrackerConfig
from neurotouch_hid.sources import EVENT_DTYPE
from neurotouch_hid.sources.dv import store_from_events
from neurotouch_hid.sources.recording import RecordingReader
from neurotouch_hid.sources.sim_dataset import write_dataset
from neurotouch_hid.views.console import make_console

WINDOW_US = 10_000


@dataclass
class Run:
    """One tracker's figures over all sequences."""

    name: str
    errors: list = field(default_factory=list)  # per-sample position errors (px), moved markers
    lags: list = field(default_factory=list)  # per-sample lag along the motion (ms), moving markers
    tracked: int = 0  # moved-marker samples with a valid track
    samples: int = 0  # moved-marker samples
    events: int = 0
    seconds: float = 0.0  # CPU time of this thread (the machine is shared: wall time waits for a core)
    window_s: list = field(default_factory=list)  # CPU time per 10 ms window
    wall_s: list = field(default_factory=list)  # wall time per 10 ms window

    def add(self, cpu_s: float, wall_s: float, n_events: int) -> None:
        self.window_s.append(cpu_s)
        self.wall_s.append(wall_s)
        self.seconds += cpu_s
        self.events += n_events

    def row(self) -> list[str]:
        e = np.concatenate(self.errors) if self.errors else np.zeros(0)
        lag = np.concatenate(self.lags) if self.lags else np.zeros(0)
        w = np.array(self.window_s) * 1e3
        wall = np.array(self.wall_s) * 1e3

        def stat(a, q):
            return f"{np.percentile(a, q):.3f}" if len(a) else "-"

        return [
            self.name,
            stat(e, 50),
            stat(e, 90),
            stat(e, 99),
            f"{np.median(lag):.2f}" if len(lag) else "-",
            f"{100.0 * self.tracked / self.samples:.1f}" if self.samples else "-",
            f"{self.events / max(self.seconds, 1e-12) / 1e6:.2f}",
            stat(w, 50),
            stat(w, 99),
            stat(wall, 50),
            stat(wall, 99),
        ]


def identity(start_px: np.ndarray, rest_px: np.ndarray, max_px: float = 2.0) -> np.ndarray:
    """Index of the true marker of each tracked blob (nearest at rest), -1 beyond ``max_px``."""
    d = np.hypot(start_px[:, None, 0] - rest_px[None, :, 0], start_px[:, None, 1] - rest_px[None, :, 1])
    j = d.argmin(axis=1)
    return np.where(d[np.arange(len(j)), j] <= max_px, j, -1)


#: A marker moving at least this fast (px/ms) counts in the lag; slower, the lag is ill-defined.
LAG_MIN_SPEED_PX_PER_MS = 0.03


def score(
    run: Run,
    est: np.ndarray,
    ok: np.ndarray,
    truth: np.ndarray,
    rest: np.ndarray,
    who: np.ndarray,
    velocity: np.ndarray,
) -> None:
    """Add one window end: est (M, 2) positions of tracks with identities ``who`` (M,), ok (M,)
    valid; truth (N, 2) true positions; rest (N, 2); velocity (N, 2) the true markers' velocity
    (px/ms), for the lag along the motion, -(error . v) / |v|^2 (ms), of markers moving at least
    :data:`LAG_MIN_SPEED_PX_PER_MS`."""
    moved = np.linalg.norm(truth - rest, axis=1) > 1.0
    run.samples += int(moved.sum())
    sel = ok & (who >= 0)
    sel[sel] &= moved[who[sel]]
    # A marker counts once even if two tracks claim it (first wins).
    _, first = np.unique(who[sel], return_index=True)
    idx = np.flatnonzero(sel)[first]
    run.tracked += len(idx)
    error = est[idx] - truth[who[idx]]
    run.errors.append(np.linalg.norm(error, axis=1))
    v = velocity[who[idx]]
    speed2 = (v * v).sum(axis=1)
    moving = speed2 >= LAG_MIN_SPEED_PX_PER_MS**2
    run.lags.append(-(error[moving] * v[moving]).sum(axis=1) / speed2[moving])


def true_velocity(t_grid: np.ndarray, positions: np.ndarray, k: int, span_us: int = 5_000) -> np.ndarray:
    """(N, 2) the true markers' velocity (px/ms) over the ``span_us`` before grid sample ``k``."""
    j = int(np.searchsorted(t_grid, t_grid[k] - span_us))
    if j >= k:
        return np.zeros_like(positions[k])
    return (positions[k] - positions[j]) / ((t_grid[k] - t_grid[j]) / 1000.0)


def windows(events: np.ndarray, t0: int, t1: int) -> list[tuple[int, np.ndarray]]:
    """(window end, events of the window) for 10 ms windows from t0 to t1."""
    ends = np.arange(t0 + WINDOW_US, t1 + 1, WINDOW_US, dtype=np.int64)
    cuts = np.searchsorted(events["timestamp"], ends)
    starts = np.concatenate([[np.searchsorted(events["timestamp"], t0)], cuts[:-1]])
    return [(int(e), events[a:b]) for e, a, b in zip(ends, starts, cuts)]


def run_ours(run: Run, seq, sensor: SensorGeometry, config: TrackerConfig, with_frames: bool) -> None:
    events, frames, t_grid, positions, rest = seq
    start = detect_markers(frames[0].image, sensor).centroids_px.astype(np.float64)
    who = identity(start, rest)
    tracker = BlobTracker(start, sensor.width, sensor.height, config, sensor=sensor)
    frame_dets = [(f.t_us, detect_markers(f.image, sensor).centroids_px) for f in frames[1:]] if with_frames else []
    fi = 0
    for end, batch in windows(events, int(frames[0].t_us), int(t_grid[-1])):
        pieces = [batch]
        cuts = []
        while fi < len(frame_dets) and frame_dets[fi][0] < end:
            cuts.append(fi)
            fi += 1
        if cuts:  # deliver each frame before the events at or after its timestamp
            bounds = np.searchsorted(batch["timestamp"], [frame_dets[c][0] for c in cuts])
            pieces = np.split(batch, bounds)
        t, c = time.perf_counter(), time.thread_time()
        for k, piece in enumerate(pieces):
            if k > 0:
                tracker.correct(frame_dets[cuts[k - 1]][1], frame_dets[cuts[k - 1]][0])
            tracker.update(piece)
        run.add(time.thread_time() - c, time.perf_counter() - t, len(batch))
        k = int(np.searchsorted(t_grid, end))
        if k < len(t_grid) and t_grid[k] == end:
            velocity = true_velocity(t_grid, positions, k)
            score(run, tracker.positions_px, tracker.valid, positions[k], rest, who, velocity)


def seed_image(points_px: np.ndarray, shape: tuple[int, int], radius_px: float = 2.0) -> np.ndarray:
    """uint8 image with a white dot at each point (the MeanShiftTracker's detector finds them)."""
    img = np.zeros(shape, np.uint8)
    for x, y in points_px:
        cv2.circle(
            img, (int(round(x * 16)), int(round(y * 16))), int(radius_px * 16), 255, -1, lineType=cv2.LINE_AA, shift=4
        )
    return img


def meanshift(seeds_px: np.ndarray, width: int, height: int):
    """dv-processing's background-activity filter and MeanShiftTracker, the tracker seeded with
    ``seeds_px`` (drawn as dots for its ``EventFeatureBlobDetector``, never redetected)."""
    import dv_processing as dv

    seeds = seed_image(seeds_px, (height, width))
    resolution = (width, height)
    noise = dv.noise.BackgroundActivityNoiseFilter(resolution, datetime.timedelta(milliseconds=2))
    tracker = dv.features.MeanShiftTracker(resolution, 4, datetime.timedelta(milliseconds=10))
    tracker.setDetector(dv.features.EventFeatureBlobDetector(resolution, 0, lambda _img: seeds))
    tracker.setMaxTracks(4 * len(seeds_px) + 10)
    tracker.setRedetectionStrategy(dv.features.NoRedetection())
    return noise, tracker


def meanshift_window(noise, tracker, batch: np.ndarray, run: Run, who: dict, rest_px: np.ndarray):
    """Filter and track one window (timed); returns (track ids (M,), positions (M, 2), their true
    marker (M,)). A track's marker is fixed at its first appearance (nearest at rest)."""
    store = store_from_events(batch)  # conversion not timed: it is our numpy <-> dv glue
    t, c = time.perf_counter(), time.thread_time()
    noise.accept(store)
    tracker.accept(noise.generateEvents())
    result = tracker.runTracking()
    run.add(time.thread_time() - c, time.perf_counter() - t, len(batch))
    kps = result.keypoints if result is not None else []
    ids = np.array([kp.class_id for kp in kps], dtype=np.int64)
    pts = np.array([kp.pt for kp in kps], dtype=np.float64).reshape(-1, 2)
    for cid, p in zip(ids, pts):
        if int(cid) not in who:
            who[int(cid)] = int(identity(p[None], rest_px)[0])
    return pts, np.array([who[int(c)] for c in ids], dtype=np.int64)


def run_meanshift(run: Run, seq, sensor: SensorGeometry) -> None:
    events, frames, t_grid, positions, rest = seq
    noise, tracker = meanshift(detect_markers(frames[0].image, sensor).centroids_px, sensor.width, sensor.height)
    who: dict[int, int] = {}
    for end, batch in windows(events, int(frames[0].t_us), int(t_grid[-1])):
        pts, idx = meanshift_window(noise, tracker, batch, run, who, rest)
        k = int(np.searchsorted(t_grid, end))
        if k < len(t_grid) and t_grid[k] == end:
            score(run, pts, np.ones(len(idx), bool), positions[k], rest, idx, true_velocity(t_grid, positions, k))


def stress_stream(
    rest_px: np.ndarray,
    n_windows: int,
    per_window: int,
    noise_frac: float,
    seed: int,
    speed_px_per_ms: float = 0.5,
    amplitude_px: float = 6.0,
):
    """Synthetic fast stream: the gel swings back and forth (a common translation of
    ``amplitude_px`` plus a rotation about the gel's centre, sinusoidal, peak marker speed about
    ``speed_px_per_ms``); each marker's events fall around p +- 1.2 px along its motion (ON ahead,
    OFF behind) with 0.8 px spread; ``noise_frac`` of the events are uniform noise.
    Returns (events, truth(t_us) -> (T, N, 2))."""
    rng = np.random.default_rng(seed)
    n = len(rest_px)
    centre = rest_px.mean(axis=0)
    rel = rest_px - centre
    omega = speed_px_per_ms / (1.5 * amplitude_px) / 1000.0  # rad/us: translation + rotation
    direction = np.array([np.cos(0.7), np.sin(0.7)])
    spin = amplitude_px / 2.0 / max(np.abs(rel).max(), 1.0)  # rotation amplitude (rad)

    def place(t_us, who=None):
        t = np.asarray(t_us, float).reshape(-1, 1)
        r = rel[None] if who is None else rel[who][:, None]
        s = np.sin(omega * t)[..., None]
        a = spin * s[..., 0]
        cos, sin = np.cos(a)[..., None], np.sin(a)[..., None]
        rot = np.concatenate([cos * r[..., :1] - sin * r[..., 1:], sin * r[..., :1] + cos * r[..., 1:]], axis=-1)
        return centre + rot + amplitude_px * s * direction

    def truth(t_us):
        return place(t_us)

    total = n_windows * per_window
    ts = np.sort(rng.integers(0, n_windows * WINDOW_US, total))
    is_noise = rng.random(total) < noise_frac
    ev = np.zeros(total, EVENT_DTYPE)
    ev["timestamp"] = ts
    ev["polarity"] = rng.integers(0, 2, total)
    m = np.flatnonzero(~is_noise)
    who = rng.integers(0, n, len(m))
    pos = place(ts[m], who)[:, 0]
    ahead = place(ts[m] + 100, who)[:, 0] - pos
    ahead /= np.maximum(np.linalg.norm(ahead, axis=1, keepdims=True), 1e-9)
    s = np.where(ev["polarity"][m] > 0, 1.0, -1.0)[:, None]
    pos = pos + 1.2 * s * ahead + rng.normal(0, 0.8, pos.shape)
    ev["x"][m] = np.clip(np.rint(pos[:, 0]), 0, 345)
    ev["y"][m] = np.clip(np.rint(pos[:, 1]), 0, 259)
    ev["x"][is_noise] = rng.integers(0, 346, int(is_noise.sum()))
    ev["y"][is_noise] = rng.integers(0, 260, int(is_noise.sum()))
    return ev, truth


def run_stress(rest_px: np.ndarray, n_windows: int, seed: int, config: TrackerConfig):
    events, truth = stress_stream(rest_px, n_windows, 120_000, 0.4, seed)
    tracker = BlobTracker(truth(0)[0], config=config)
    run = Run("ours, stress 12 M ev/s")
    for end, batch in windows(events, 0, n_windows * WINDOW_US):
        t, c = time.perf_counter(), time.thread_time()
        tracker.update(batch)
        run.add(time.thread_time() - c, time.perf_counter() - t, len(batch))
        true = truth(end)[0]
        run.samples += len(true)
        run.tracked += int(tracker.valid.sum())
        run.errors.append(np.linalg.norm(tracker.positions_px - true, axis=1)[tracker.valid])
    return run, events, truth


def run_stress_meanshift(events: np.ndarray, truth, n_windows: int) -> Run:
    rest0 = truth(0)[0]
    noise, tracker = meanshift(rest0, 346, 260)
    run = Run("MeanShift + BA filter, stress")
    who: dict[int, int] = {}
    for end, batch in windows(events, 0, n_windows * WINDOW_US):
        pts, idx = meanshift_window(noise, tracker, batch, run, who, rest0)
        true = truth(end)[0]
        run.samples += len(true)
        ok = idx >= 0
        _, first = np.unique(idx[ok], return_index=True)
        keep = np.flatnonzero(ok)[first]
        run.tracked += len(keep)
        run.errors.append(np.linalg.norm(pts[keep] - true[idx[keep]], axis=1))
    return run


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--dataset", type=Path, help="an existing simulated dataset (default: write one)")
    parser.add_argument("--preset", default="quick")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--stress-windows", type=int, default=100, help="10 ms windows of 120 k events")
    parser.add_argument("--meanshift-stress-windows", type=int, default=20)
    parser.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="FIELD=VALUE",
        help="a TrackerConfig field (float), in mm and us, e.g. --set max_offset_mm=0 (repeatable)",
    )
    args = parser.parse_args()
    console = make_console()
    fields = set(TrackerConfig.model_fields)
    overrides = {}
    for item in args.set:
        name, _, value = item.partition("=")
        if name not in fields:
            parser.error(f"--set {item}: {name!r} is not a TrackerConfig field ({', '.join(sorted(fields))})")
        overrides[name] = float(value)
    config = TrackerConfig(**overrides)
    if overrides:
        console.print(f"TrackerConfig overrides: {overrides}")

    with tempfile.TemporaryDirectory(prefix="bench-tracker-") as tmp:
        folder = args.dataset
        if folder is None:
            t = time.perf_counter()
            folder = write_dataset(Path(tmp), preset=args.preset, seed=args.seed, progress=False)
            console.print(f"simulated dataset ({args.preset}, seed {args.seed}) in {time.perf_counter() - t:.0f} s")
        sensor = SensorGeometry.load(folder / "sensor.yaml")
        seqs = []
        for path in sorted(folder.glob("*.aedat4")):
            with RecordingReader(path) as reader:
                events, frames = reader.read_all()
            truth = np.load(path.with_name(path.name.replace(".aedat4", ".markers.npz")))
            seqs.append(
                (
                    events,
                    frames,
                    truth["t_us"],
                    truth["positions_px"].astype(np.float64),
                    truth["rest_px"].astype(np.float64),
                )
            )

    det_err = []
    for _events, frames, _t_grid, _positions, rest in seqs:
        found = detect_markers(frames[0].image, sensor).centroids_px
        d = np.hypot(found[:, None, 0] - rest[None, :, 0], found[:, None, 1] - rest[None, :, 1])
        det_err.append(d.min(axis=1))
        console.print(f"detect_markers on the first APS frame: {len(found)} found of {len(rest)} markers")
    det_err = np.concatenate(det_err)
    console.print(f"detection error at rest: median {np.median(det_err):.3f} px, max {det_err.max():.3f} px")

    # Compile the numba kernels outside the timings.
    warm = BlobTracker(seqs[0][4][:5], config=config)
    warm.update(seqs[0][0][:1000])
    warm.correct(seqs[0][4][:5])

    runs = [Run("ours, events only (paper)"), Run("ours + APS-frame correction"), Run("MeanShift + BA filter (dv)")]
    for seq in seqs:
        run_ours(runs[0], seq, sensor, config, with_frames=False)
        run_ours(runs[1], seq, sensor, config, with_frames=True)
        run_meanshift(runs[2], seq, sensor)
    whole = Run("ours, one update() per sequence (loop only)")
    for events, frames, *_ in seqs:
        tracker = BlobTracker(detect_markers(frames[0].image, sensor).centroids_px, config=config, sensor=sensor)
        c = time.thread_time()
        tracker.update(events)
        whole.seconds += time.thread_time() - c
        whole.events += len(events)
    runs.append(whole)
    n_events = sum(len(s[0]) for s in seqs)
    seconds = sum((s[2][-1] - s[2][0]) / 1e6 for s in seqs)

    stress, events, truth = run_stress(seqs[0][4], args.stress_windows, args.seed, config)
    stress_ms = run_stress_meanshift(events, truth, args.meanshift_stress_windows)

    table = Table(
        title=f"Tracker: {len(seqs)} simulated sequences ({n_events:,} events, {seconds:.1f} s), "
        f"then the stress stream ({args.stress_windows} x 120 k events)"
    )
    for col in (
        "tracker",
        "err median px",
        "err p90 px",
        "err p99 px",
        "lag median ms",
        "tracked %",
        "M events/s (CPU)",
        "window median ms (CPU)",
        "window p99 ms (CPU)",
        "window median ms (wall)",
        "window p99 ms (wall)",
    ):
        table.add_column(col, justify="left" if col == "tracker" else "right")
    for run in [*runs, stress, stress_ms]:
        table.add_row(*run.row())
    console.print(table)
    console.print(
        "errors: per marker against its own true position, on markers > 1 px from rest, at every "
        "10 ms window end; lag: how far behind its marker a blob is along the marker's motion (ms), "
        f"on those moving >= {LAG_MIN_SPEED_PX_PER_MS} px/ms; tracked %: moved-marker samples with a live track"
    )


if __name__ == "__main__":
    main()
