"""Why the slowest one-finger pushes wait longer above the dead zone than others, and what a wait
counted from the first finger's depth instead of its first window would trade (docs/lab/type-commitment.md,
"The slowest pushes: the fastest attacks, not a longer wait").

    python3 docs/lab/fast_push_wait.py --out DIR [--families fingers,late,starts,default,strong]
        [--depths-mm 0.4,0.3,0.2] [--slowest 4]

``DIR`` is a ``benchmarks/family_eval.py --sessions`` folder. Each sequence's episode-vote inputs
are recorded once by ``one_contact_wait.py`` (``DIR/predictions/FAM/vote_inputs``). Printed per
family: the ``--slowest`` gestures by dead-zone latency, each with its onset (the episode's first
window, ms after the labelled start) and that window's intensity, the labelled dead-zone crossing,
the first window read at or above the dead zone and the commitment (the first window answered with
a type at 0.4 mm or more), all ms after the onset, and the most contacts seen from 0.4 mm on before
the commitment; over every push committed on one contact, the commitment and the crossing after the
onset (min / median / max). Then felt wrong and the dead-zone latency p90 of the vote as it is and
with the lone contact's wait counted from when the episode's intensity passed each depth of
``--depths-mm``, extrapolated back along the rise of its first two windows when the first is
already deeper (at most one APS frame period back).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import typer

sys.path.insert(0, str(Path(__file__).resolve().parent))  # one_contact_wait.py, beside it
sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))  # workdir.py
from one_contact_wait import TYPES, vote_inputs  # noqa: E402
from workdir import families_in, numbers  # noqa: E402

from neurotouch_hid.core.dataset import list_sequences, read_labels, read_pressed  # noqa: E402
from neurotouch_hid.core.estimate import GestureEstimate, GestureType  # noqa: E402
from neurotouch_hid.evaluation.felt import deadzone_crossing, gesture_records, gesture_runs  # noqa: E402
from neurotouch_hid.pipeline.episode import FIRM_GAP_US, PROVISIONAL_MM, EpisodeVote  # noqa: E402
from neurotouch_hid.views.console import command_app  # noqa: E402

app = command_app()


class Backdated(EpisodeVote):
    """The product's vote, its lone contact's wait counted from when the episode passed
    ``depth_mm`` (a candidate, not the product)."""

    def __init__(self, depth_mm: float) -> None:
        super().__init__()
        self.depth_mm = depth_mm

    def reset(self) -> None:
        super().reset()
        self._first: tuple[int, float] | None = None  # the episode's first window: t_us, mm

    def _vote(self, gesture: GestureType, intensity_mm: float, n_contacts: int, t_us: int) -> GestureType:
        first = self._first
        answer = super()._vote(gesture, intensity_mm, n_contacts, t_us)
        if first is None:
            self._first = (t_us, float(intensity_mm))
        elif (
            self._decision is None
            and self._trusted_since_us == self._onset_us == first[0]
            and self.depth_mm < first[1] < intensity_mm
        ):
            rate = (intensity_mm - first[1]) / (t_us - first[0])  # mm / us along the attack
            self._trusted_since_us = first[0] - int(min((first[1] - self.depth_mm) / rate, FIRM_GAP_US))
            self._first = (first[0], np.inf)  # once
        return answer


def answers(inputs: dict, vote: EpisodeVote) -> list[GestureEstimate]:
    """The recorded vote inputs through ``vote``, with the intensity each window answered."""
    rows = zip(inputs["kind"], inputs["intensity"], inputs["contacts"], inputs["t_us"], inputs["answered_mm"])
    return [
        GestureEstimate(
            t_us=int(t), gesture=vote.update(TYPES[k], float(i), int(n), int(t)), resting=False, intensity_mm=float(a)
        )
        for k, i, n, t, a in rows
    ]


def traced(inputs: dict, labels, preds: list[GestureEstimate], latency: np.ndarray, deadzone_mm: float) -> list[dict]:
    """One row per labelled gesture with a dead-zone latency: the times of the module docstring."""
    t, kind, n, mm = inputs["t_us"], inputs["kind"], inputs["contacts"], inputs["intensity"]
    said = np.array([TYPES.index(p.gesture) for p in preds])
    t_lab = np.array([r.t_us for r in labels])
    i_lab = np.array([r.intensity_mm for r in labels])
    rows = []
    for k, (gesture, a, b) in enumerate(gesture_runs(labels)):
        t0, t1 = int(t_lab[a]), int(t_lab[b])
        span = np.flatnonzero((t >= t0 - 50_000) & (t <= t1) & (kind != 0))
        if not len(span) or not np.isfinite(latency[k]):
            continue
        on = int(t[span[0]])
        deep = span[inputs["answered_mm"][span] >= deadzone_mm]
        commit = span[(said[span] != 0) & (mm[span] >= PROVISIONAL_MM)]
        before = span[(mm[span] >= PROVISIONAL_MM) & ((t[span] < t[commit[0]]) if len(commit) else True)]
        rows.append(
            dict(
                gesture=gesture.value,
                latency=float(latency[k]),
                onset=(on - t0) / 1000,
                first_mm=float(mm[span[0]]),
                crossing=(deadzone_crossing(t_lab[a : b + 1], i_lab[a : b + 1], deadzone_mm) - on) / 1000,
                deep=(t[deep[0]] - on) / 1000 if len(deep) else np.nan,
                commit=(t[commit[0]] - on) / 1000 if len(commit) else np.nan,
                contacts=int(n[before].max()) if len(before) else 0,
                lone=bool(len(commit)) and n[commit[0]] <= 1,
            )
        )
    return rows


@app.command()
def main(
    out: Path = typer.Option(..., "--out", help="a family_eval --sessions folder"),
    families: str = typer.Option("fingers,late,starts,default,strong", "--families"),
    depths_mm: str = typer.Option("0.4,0.3,0.2", "--depths-mm", help="depths to count the wait from (mm)"),
    slowest: int = typer.Option(4, "--slowest", min=0),
    deadzone_mm: float = typer.Option(0.8, "--deadzone-mm", min=0.0),
) -> None:
    depths = numbers(depths_mm, "--depths-mm", finite=True)
    for fam in families_in(out, families):
        src = out / "predictions" / fam / "vote_inputs"
        vote_inputs(out / fam, src)
        rows, scores = [], {}
        for label, make in [("today", EpisodeVote), *[(f"from {d:g} mm", lambda d=d: Backdated(d)) for d in depths]]:
            felt, lat = [], []
            for name in list_sequences(out / fam):
                inputs = dict(np.load(src / f"{name}.npz"))
                labels = read_labels(out / fam / f"{name}.labels.csv")
                preds = answers(inputs, make())
                rec = gesture_records(labels, preds, deadzone_mm, read_pressed(out / fam / f"{name}.pressed.csv"))
                felt.append(rec.felt_wrong)
                lat.append(rec.deadzone_latency_ms)
                if label == "today":
                    rows += [
                        dict(r, name=name) for r in traced(inputs, labels, preds, rec.deadzone_latency_ms, deadzone_mm)
                    ]
            f, la = np.concatenate(felt), np.concatenate(lat)
            scores[label] = f"felt wrong {f.sum()} of {len(f)}, p90 {np.percentile(la[np.isfinite(la)], 90):.1f} ms"
        print(f"{fam}:")
        for r in sorted(rows, key=lambda r: -r["latency"])[:slowest]:
            print(
                f"  {r['name']} {r['gesture']}: {r['latency']:.0f} ms late; onset {r['onset']:.0f} ms after the labels "
                f"at {r['first_mm']:.2f} mm; from it: crossing {r['crossing']:.0f}, first window at the dead zone "
                f"{r['deep']:.0f}, committed {r['commit']:.0f} ms on {'one contact' if r['lone'] else 'several'} "
                f"(most seen before: {r['contacts']})"
            )
        lone = [r for r in rows if r["lone"] and r["gesture"] == "push"]
        if lone:
            c, x = np.array([r["commit"] for r in lone]), np.array([r["crossing"] for r in lone])
            print(
                f"  {len(lone)} pushes committed on one contact: committed {c.min():.0f} / {np.median(c):.0f} / "
                f"{c.max():.0f} ms after the onset, the labels at the dead zone {x.min():.0f} / {np.median(x):.0f} / "
                f"{x.max():.0f} ms after it (min / median / max)"
            )
        print("  " + "; ".join(f"{k}: {v}" for k, v in scores.items()))


if __name__ == "__main__":
    app()
