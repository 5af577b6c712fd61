"""Blobs left between two markers by a deep press's release, the creep they calibrate, and what
that creep does on the creeping gels' sessions (docs/lab/accuracy-history.md, "Blobs left between
two markers after a deep press, and the creep they calibrate").

    python3 docs/lab/stuck_blobs.py --out DIR [--families viscoelastic,compound,compound2]
        [--sessions/--no-sessions]

``DIR`` is a ``benchmarks/family_eval.py --sessions`` folder: each family's sessions, its
sensor.yaml and its calibration press ``DIR/presses/FAMILY/u5_push`` (with the simulator's true
marker positions, ``.markers.npz``).

Two repairs of the frame correction are compared: the product's (``tracker.swapped_blobs``: a
blob more than ``tracker.SWAP_PITCHES`` pitch from its neighbours' median, or more than
``tracker.SWAP_FOUND_PITCHES`` from it and on no marker of the frame, moves to the free detection
within that 0.3 pitch of where the median puts it) and the one before it, without the second kind
of suspect (the *lost* blobs). Printed per family:

* **the press**: its tracked amplitude (``calibration.measure.press_amplitude``: the mean of the
  largest tracked displacements) against the true markers' every 40 ms from the release, the
  creep ``calibrate --press`` fits on each (``creep.fit_creep``), and the windows where a blob is
  more than 0.3 pitch from its own marker's true position;
* **the sessions** (``--sessions``): each sequence run through the product's pipeline with each
  repair and the creep filter replayed with the creep that repair calibrates
  (``creep_release.replayed``: the tail watch is not replayed), scored: gesture under the 0.3 mm
  rule, felt wrong, dead-zone latency p90, false activations, and the tracked amplitude against
  the true markers' at the windows answered with a gesture where the labels rest.
"""

from __future__ import annotations

import sys
from contextlib import contextmanager
from dataclasses import replace
from pathlib import Path

import numpy as np
import typer

sys.path.insert(0, str(Path(__file__).resolve().parent))  # creep_release.py
sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))  # workdir.py
import creep_release  # noqa: E402
from workdir import families_in  # noqa: E402

from neurotouch_hid.calibration.measure import PRESS_MARKERS  # noqa: E402
from neurotouch_hid.core.sensor import SensorGeometry  # noqa: E402
from neurotouch_hid.pipeline import creep, frame_path, tracker  # noqa: E402
from neurotouch_hid.pipeline.pipeline import GesturePipeline  # noqa: E402
from neurotouch_hid.pipeline.track import pipeline_over  # noqa: E402
from neurotouch_hid.views.console import command_app  # noqa: E402

app = command_app()
PRODUCT = tracker.swapped_blobs


def before(positions_px, valid, rest_px, neighbours, detections_px, pitch_px):
    """``tracker.swapped_blobs`` before the lost blobs: only the blobs more than
    ``tracker.SWAP_PITCHES`` pitch from their neighbours' median are suspects."""
    none = (np.zeros(0, dtype=np.int64), np.zeros((0, 2)))
    det = np.asarray(detections_px, dtype=np.float64).reshape(-1, 2)
    if not len(det):
        return none
    shared = np.full((len(valid), 2), np.nan)
    suspects = np.flatnonzero(
        tracker._suspects(
            np.ascontiguousarray(positions_px, dtype=np.float64),
            np.ascontiguousarray(valid, dtype=np.bool_),
            np.ascontiguousarray(rest_px, dtype=np.float64),
            np.ascontiguousarray(neighbours, dtype=np.int64),
            tracker.SWAP_PITCHES * float(pitch_px),
            shared,
        )
    )
    if not len(suspects):
        return none
    reach = tracker.SWAP_FOUND_PITCHES * float(pitch_px)
    wanted = shared[suspects] + rest_px[suspects]
    return tracker.moves_to_free_detections(positions_px, valid, suspects, wanted, det, reach)


@contextmanager
def tracking(rule):
    """The frame correction's blob repair set to ``rule`` for the block."""
    frame_path.swapped_blobs = rule
    try:
        yield
    finally:
        frame_path.swapped_blobs = PRODUCT


def press(press_dir: Path) -> dict:
    """The press tracked by the pipeline: per window its time (us), tracked amplitude (px), the
    true markers' (px) and how many blobs are more than 0.3 pitch from their true marker."""
    sensor = SensorGeometry.load(press_dir / "sensor.yaml")
    recording = press_dir / "u5_push"
    truth = np.load(recording.with_suffix(".markers.npz"))
    rows: list[tuple[int, np.ndarray]] = []
    pipeline = GesturePipeline(sensor, on_window=lambda e: rows.append((e.t_us, pipeline.marker_positions().copy())))
    for _ in pipeline_over(recording.with_suffix(".aedat4"), pipeline):
        pass
    rest = pipeline.rest_px
    own = np.argmin(((truth["rest_px"][:, None, :] - rest[None]) ** 2).sum(-1), axis=1)  # true -> blob
    t = np.array([r[0] for r in rows], dtype=np.int64)
    k = np.minimum(np.searchsorted(truth["t_us"], t), len(truth["t_us"]) - 1)
    true_pos = truth["positions_px"][k]  # (T, N, 2)
    blobs = np.stack([r[1] for r in rows])[:, own]  # (T, N, 2), in the truth's order
    moved = np.hypot(*(blobs - rest[own][None]).transpose(2, 0, 1))
    tracked = np.array([np.sort(m[np.isfinite(m)])[-PRESS_MARKERS:].mean() for m in moved])
    true_moved = np.hypot(*(true_pos - truth["rest_px"][None]).transpose(2, 0, 1))
    true_amp = np.sort(true_moved, axis=1)[:, -PRESS_MARKERS:].mean(axis=1)
    off = (
        np.hypot(*(blobs - true_pos).transpose(2, 0, 1)) > tracker.SWAP_FOUND_PITCHES * pipeline.config.marker_pitch_px
    )
    return {"t": t, "tracked": tracked, "true": true_amp, "off": off.sum(axis=1)}


@app.command()
def main(
    out: Path = typer.Option(..., "--out", help="a family_eval --sessions folder"),
    families: str = typer.Option("viscoelastic,compound,compound2", "--families"),
    sessions: bool = typer.Option(True, "--sessions/--no-sessions", help="also replay the sessions"),
) -> None:
    for fam in families_in(out, families):
        press_dir = out / "presses" / fam
        print(f"## {fam}\n")
        fits = {}
        for label, rule in (("before", before), ("product", PRODUCT)):
            with tracking(rule):
                p = press(press_dir)
            fits[label] = creep.fit_creep(p["t"], p["tracked"])
            truth_fit = creep.fit_creep(p["t"], p["true"])
            end = p["t"][np.flatnonzero(p["tracked"] >= 0.5 * p["tracked"].max())[-1]]
            after = np.flatnonzero(p["t"] >= end)[::4][:14]
            print(
                f"{label}: creep fitted {_fmt(fits[label])} (on the true markers {_fmt(truth_fit)}); "
                f"windows with a blob > 0.3 pitch off its marker: {int((p['off'] > 0).sum())}"
            )
            print("  ms after the release | " + " | ".join(f"{(p['t'][k] - end) / 1000:.0f}" for k in after))
            print("  tracked px           | " + " | ".join(f"{p['tracked'][k]:.2f}" for k in after))
            print("  true px              | " + " | ".join(f"{p['true'][k]:.2f}" for k in after))
            print("  blobs off            | " + " | ".join(f"{p['off'][k]}" for k in after))
        if not sessions:
            print()
            continue
        dataset = out / fam
        print("\n| tracker | creep | gesture, 0.3 mm rule | felt wrong | dead-zone p90 ms | false activations |")
        print("| --- | --- | ---: | ---: | ---: | ---: |")
        sensor = SensorGeometry.load(dataset / "sensor.yaml")
        for label, rule in (("before", before), ("product", PRODUCT)):
            fit = fits[label]
            with tracking(rule):
                recorded, lag = record(_with_creep(dataset, sensor, fit))
            for share, time_s in {fit, *(() if sensor.creep is None else (tuple(sensor.creep),))}:
                r = creep_release.replayed(dataset, recorded, share, time_s, creep.LOAD_MARGIN)
                print(
                    f"| {label} | q {share:.2f}, tau {time_s:.3f} s | {100 * r['rule']:.2f} % | "
                    f"{100 * r['felt_wrong_share']:.1f} % | {r['deadzone_latency_p90_ms']:.0f} | "
                    f"{r['false_activations']} |",
                    flush=True,
                )
            print(
                f"|  | tracked minus true amplitude (px) at the {len(lag)} windows the run answers with a gesture "
                f"where the labels rest: median {np.median(lag) if len(lag) else float('nan'):.2f}, "
                f"largest {np.max(np.abs(lag)) if len(lag) else float('nan'):.2f} | | | | |"
            )
        print()


def record(dataset: Path) -> tuple[dict, np.ndarray]:
    """``creep_release.record`` of ``dataset``, and at each window the run answers with a gesture
    where the labels rest (``evaluation.felt.at_rest``: a false activation) the tracked amplitude
    (the mean of the largest tracked displacements, as ``press_amplitude``) minus the true
    markers' (px)."""
    from neurotouch_hid.core.dataset import list_sequences, read_labels
    from neurotouch_hid.core.estimate import GestureType
    from neurotouch_hid.evaluation.felt import at_rest
    from neurotouch_hid.sources.recording import RecordingReader

    sensor = SensorGeometry.load(dataset / "sensor.yaml")
    out, lag = {}, []
    for name in list_sequences(dataset):
        amp: list[float] = []
        pipeline = creep_release.Recorded(sensor)
        pipeline.on_window = _keeper(pipeline, amp)
        with RecordingReader(dataset / f"{name}.aedat4") as reader:
            estimates = list(pipeline.run(reader.stream()))
        out[name] = (pipeline.windows, estimates)
        t = np.array([e.t_us for e in estimates], dtype=np.int64)
        truth = np.load(dataset / f"{name}.markers.npz")
        k = np.minimum(np.searchsorted(truth["t_us"], t), len(truth["t_us"]) - 1)
        moved = np.hypot(*(truth["positions_px"][k] - truth["rest_px"][None]).transpose(2, 0, 1))
        true_amp = np.sort(moved, axis=1)[:, -PRESS_MARKERS:].mean(axis=1)
        rest = at_rest(read_labels(dataset / f"{name}.labels.csv"), t)
        for j in np.flatnonzero(rest):
            if estimates[j].gesture is not GestureType.NONE:
                lag.append(amp[j] - true_amp[j])
    return out, np.array(lag)


def _keeper(pipeline: GesturePipeline, amp: list[float]):
    """An ``on_window`` that appends the pipeline's tracked amplitude to ``amp``."""
    return lambda _estimate: amp.append(_amplitude(pipeline))


def _amplitude(pipeline: GesturePipeline) -> float:
    if pipeline.rest_px is None:
        return 0.0
    moved = np.hypot(*(pipeline.marker_positions() - pipeline.rest_px).T)
    moved = moved[np.isfinite(moved)]
    return float(np.sort(moved)[-PRESS_MARKERS:].mean()) if len(moved) else 0.0


def _fmt(fit) -> str:
    return "none" if fit is None else f"q {fit[0]:.2f}, tau {fit[1]:.3f} s"


def _with_creep(dataset: Path, sensor: SensorGeometry, fit) -> Path:
    """``dataset`` itself when its sensor.yaml has the creep ``fit``, else a scratch folder of links
    to its files with a sensor.yaml that has it (the recording runs the filter it names)."""
    if fit is None or (sensor.creep is not None and tuple(sensor.creep) == tuple(fit)):
        return dataset
    import tempfile

    scratch = Path(tempfile.mkdtemp(prefix="stuck_blobs_"))
    for f in dataset.iterdir():
        if f.name != "sensor.yaml":
            (scratch / f.name).symlink_to(f.resolve())
    replace(sensor, creep=fit).save(scratch / "sensor.yaml")
    return scratch


if __name__ == "__main__":
    app()
