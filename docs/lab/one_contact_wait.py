"""Why the one-contact wait cannot end before 90 ms on what the episode vote reads: the gestures
whose felt verdict or dead-zone latency a shorter wait changes, window by window from their onset
(docs/accuracy.md, "A second simulator's sessions and multi-finger starts"; docs/method.md,
"Episode vote").

    python3 docs/lab/one_contact_wait.py --out DIR [--families fingers,late,starts]
        [--waits-ms 80,90] [--deadzone-mm 0.8]

``DIR`` is a ``benchmarks/family_eval.py --sessions`` folder. Each sequence is run once through
the product's pipeline, recording what its episode vote is given in each window (the window's own
type, intensity in mm, contact count and time: all it reads), into
``DIR/predictions/FAMILY/vote_inputs/NAME.npz``; those inputs are replayed through
:class:`EpisodeVote` with each wait (``first_finger_us``) and scored per gesture (docs/dataset.md,
felt wrong from the last finger's 0.3 mm). Printed per family: felt wrong and the dead-zone
latency p90 per wait; for every gesture whose felt verdict or dead-zone latency differs between
the shortest and the longest wait, its windows from the onset (ms after it: type, count,
intensity mm) and when the gel under its last finger moved 0.3 mm (``SEQUENCE.pressed.csv``);
and, over the gestures whose fingers start apart, how long after that moment the pipeline first
sees two contacts at 0.4 mm or more (the provisional limit).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import typer

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))  # workdir.py, a benchmark's helper
from workdir import families_in, numbers  # noqa: E402

from neurotouch_hid.core.dataset import list_sequences, read_labels, read_pressed  # noqa: E402
from neurotouch_hid.core.estimate import GestureEstimate, GestureType  # noqa: E402
from neurotouch_hid.core.sensor import SensorGeometry  # noqa: E402
from neurotouch_hid.evaluation.felt import DEFAULT_DEADZONE_MM, gesture_records, gesture_spans, pressed_at  # noqa: E402
from neurotouch_hid.pipeline.episode import PROVISIONAL_MM, EpisodeVote  # noqa: E402
from neurotouch_hid.pipeline.pipeline import GesturePipeline  # noqa: E402
from neurotouch_hid.sources.recording import RecordingReader  # noqa: E402
from neurotouch_hid.views.console import command_app  # noqa: E402

app = command_app()
TYPES = list(GestureType)


class Recorded(GesturePipeline):
    """The product's pipeline, keeping what its episode vote is given in each window."""

    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self.inputs: list[tuple[int, float, int, int]] = []

    def _vote(self, gesture: GestureType, intensity_mm: float, n_contacts: int, t_us: int) -> GestureType:
        self.inputs.append((TYPES.index(gesture), float(intensity_mm), int(n_contacts), int(t_us)))
        return super()._vote(gesture, intensity_mm, n_contacts, t_us)


def vote_inputs(dataset: Path, dst: Path) -> None:
    """Each sequence of ``dataset`` through :class:`Recorded`, its vote inputs into
    ``dst/NAME.npz`` (kind int64, intensity float64 mm, contacts int64, t_us int64, and the
    intensity each window answered, answered_mm float64 mm, the one the felt metrics read; kept:
    a sequence already there is not run again)."""
    sensor = SensorGeometry.load(dataset / "sensor.yaml")
    dst.mkdir(parents=True, exist_ok=True)
    for name in list_sequences(dataset):
        if (dst / f"{name}.npz").exists():
            continue
        pipeline = Recorded(sensor)
        with RecordingReader(dataset / f"{name}.aedat4") as reader:
            answered = [p.intensity_mm for p in pipeline.run(reader.stream())]
        a = np.array(pipeline.inputs, dtype=np.float64).reshape(-1, 4)
        if len(a) != len(answered):
            raise RuntimeError(f"{dataset / name}: {len(a)} votes for {len(answered)} windows")
        np.savez(
            dst / f"{name}.npz",
            kind=a[:, 0].astype(np.int64),
            intensity=a[:, 1],
            contacts=a[:, 2].astype(np.int64),
            t_us=a[:, 3].astype(np.int64),
            answered_mm=np.array(answered, dtype=np.float64),
        )


def voted(inputs, wait_us: int) -> list[GestureEstimate]:
    """The recorded inputs through ``EpisodeVote(first_finger_us=wait_us)``, as estimates with the
    intensity each window answered."""
    vote = EpisodeVote(first_finger_us=wait_us)
    rows = zip(inputs["kind"], inputs["intensity"], inputs["contacts"], inputs["t_us"], inputs["answered_mm"])
    return [
        GestureEstimate(
            t_us=int(t),
            gesture=vote.update(TYPES[k], float(i), int(n), int(t)),
            resting=False,
            intensity_mm=float(a),
        )
        for k, i, n, t, a in rows
    ]


@app.command()
def main(
    out: Path = typer.Option(..., "--out", help="a family_eval --sessions folder"),
    families: str = typer.Option("fingers,late,starts", "--families"),
    waits_ms: str = typer.Option("80,90", "--waits-ms", help="waits to compare (ms)"),
    deadzone_mm: float = typer.Option(DEFAULT_DEADZONE_MM, "--deadzone-mm", min=0.0),
) -> None:
    waits = sorted(int(w * 1000) for w in numbers(waits_ms, "--waits-ms", finite=True))
    for fam in families_in(out, families):
        src = out / "predictions" / fam / "vote_inputs"
        vote_inputs(out / fam, src)
        records: dict[int, list] = {w: [] for w in waits}
        traces, found = [], []
        for name in list_sequences(out / fam):
            inputs = dict(np.load(src / f"{name}.npz"))
            labels = read_labels(out / fam / f"{name}.labels.csv")
            pressed = read_pressed(out / fam / f"{name}.pressed.csv")
            per = {w: gesture_records(labels, voted(inputs, w), deadzone_mm, pressed) for w in waits}
            for w in waits:
                records[w].append(per[w])
            t, kind, n, mm = inputs["t_us"], inputs["kind"], inputs["contacts"], inputs["intensity"]
            for g, (gesture, t0, t1) in enumerate(gesture_spans(labels)):
                span = np.flatnonzero((t >= t0 - 50_000) & (t <= t1) & (kind != 0))
                if not len(span):
                    continue
                onset = t[span[0]]
                last = pressed_at(pressed, t0, t1)
                two = span[(n[span] >= 2) & (mm[span] >= PROVISIONAL_MM)]
                if last is not None and gesture is not GestureType.PUSH and len(two):
                    found.append((t[two[0]] - last) / 1000)
                a, b = per[waits[0]], per[waits[-1]]
                if a.felt_wrong[g] == b.felt_wrong[g] and np.isclose(
                    a.deadzone_latency_ms[g], b.deadzone_latency_ms[g]
                ):
                    continue
                windows = " ".join(
                    f"{(t[j] - onset) // 1000}:{TYPES[kind[j]].value}/{n[j]}/{mm[j]:.2f}" for j in span[:12]
                )
                when = "fingers together" if last is None else f"last finger 0.3 mm at {(last - onset) / 1000:.0f} ms"
                verdicts = ", ".join(
                    f"{w // 1000} ms: {'felt wrong' if per[w].felt_wrong[g] else 'right'}, "
                    f"dead-zone latency {per[w].deadzone_latency_ms[g]:.0f} ms"
                    for w in waits
                )
                traces.append(
                    f"- {name} {gesture.value} ({(t1 - t0) / 1000:.0f} ms; {when}): {verdicts}\n    {windows}"
                )
        for w in waits:
            felt_wrong = np.concatenate([r.felt_wrong for r in records[w]])
            latency = np.concatenate([r.deadzone_latency_ms for r in records[w]])
            latency = latency[np.isfinite(latency)]
            print(
                f"{fam}, wait {w // 1000} ms: felt wrong {felt_wrong.sum()} of {len(felt_wrong)}, "
                f"dead-zone latency p90 {np.percentile(latency, 90):.1f} ms"
            )
        if found:
            f = np.array(found)
            print(
                f"{fam}: two contacts first seen after the last finger's 0.3 mm, over {len(f)} gestures whose "
                f"fingers start apart: median {np.median(f):.0f}, p90 {np.percentile(f, 90):.0f}, max {f.max():.0f} ms"
            )
        print("\n".join(traces) + "\n", flush=True)


if __name__ == "__main__":
    app()
