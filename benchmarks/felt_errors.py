"""Where the felt (per-gesture) errors come from: onset, hold, release; one finger found for two.

    python3 benchmarks/felt_errors.py --out DIR --method NAME [--families default,drift,...]
        [--deadzone-mm 0.8]

DIR is a ``family_eval.py`` working folder (each family's dataset under ``DIR/FAMILY``, a
method's predictions under ``DIR/predictions/FAMILY/NAME``), typically made with ``--sessions``.
Per family, and over all of them, it prints:

* the gestures (and the multi-finger ones) felt wrong (another type at or above the dead zone,
  docs/dataset.md "Per-gesture metrics"), short ones (<= 0.5 s from first to last labelled
  frame) apart from the others;
* the felt wrong windows (another type, not ``none``, at or above the dead zone) by labelled and
  answered type, and by phase: *onset* (before the gesture's first window of its type, or all
  of a gesture never recognised), *hold* (label intensity >= 80 % of the gesture's labelled
  peak), *attack* or *release* (before or after the peak, below that);
* the failure modes of multi-finger gestures: *onset push* (the first window at or above the dead
  zone says push, whatever follows: the first finger's bump answered alone) and *one contact
  throughout* (every answered window has fewer contacts than the label, from start to end),
  and the share of answered windows with fewer contacts than labelled;
* the onset against the gel's own motion: the label's intensity at the first window of the
  right type, and how long after the label reached 0.1 mm (the gel has moved) and the dead zone
  it came;
* the gestures whose dead-zone latency (docs/dataset.md) exceeds 40 ms, by labelled type, and
  how many of them waited out the episode vote's undecided lone contact (a window answered
  ``none`` with one contact at or above its provisional limit between the label passing the
  dead zone and the answer; docs/method.md, "Episode vote").

The gesture type outside the 40 ms collar (docs/dataset.md) is also split: its windows scored, those
answered wrong, and of these the ones no detector could answer right, in a gesture whose last finger
had not yet moved the gel under it 0.3 mm (``SEQUENCE.pressed.csv``, fingers starting apart: the
fingers seen are fewer than the type has) or whose label is below 0.1 mm (the gel has not moved),
with the accuracy were every other window right.

``--traces``: also, for each such gesture, its windows from 20 ms before its first labelled frame
to one past its answer: ms from that frame, the label's type, intensity (mm) and contact count,
and the answer's type, intensity and contact count (``*`` marks a resting window).
"""

from __future__ import annotations

from collections import Counter
from pathlib import Path

import numpy as np
import typer
from workdir import families_in

from neurotouch_hid.core.dataset import labels_at, list_sequences, read_labels, read_predictions, read_pressed
from neurotouch_hid.core.estimate import GESTURE_ORDER, GestureType
from neurotouch_hid.evaluation.felt import (
    DEFAULT_DEADZONE_MM,
    FRAME_PERIOD_US,
    deadzone_crossing,
    gesture_records,
    gesture_spans,
    pressed_at,
)
from neurotouch_hid.evaluation.metrics import TYPE_COLLAR_US, outside_collar
from neurotouch_hid.pipeline.episode import PROVISIONAL_MM
from neurotouch_hid.views.console import command_app

app = command_app()
#: A gesture this short or shorter (first to last labelled frame, ms) counts as a tap.
TAP_MS = 500.0
#: The gel has moved: label intensity (mm) at least the simulator's rest tolerance.
MOVED_MM = 0.1
#: The hold: label intensity at least this share of the gesture's labelled peak.
HOLD_SHARE = 0.8
#: A dead-zone latency above this (ms) is listed with its cause.
SLOW_MS = 40.0


class Tally:
    """Counts over gestures and windows (see the module docstring)."""

    def __init__(self) -> None:
        self.gestures = Counter()  # (multi, tap) -> gestures
        self.wrong = Counter()  # (multi, tap) -> gestures felt wrong
        self.pairs = Counter()  # (label type, answered type) -> felt wrong windows
        self.phases = Counter()  # phase -> felt wrong windows
        self.onset_push = 0
        self.one_contact = 0
        self.fewer = [0, 0]  # answered windows of multi-finger gestures with fewer contacts, all
        self.onsets: list[tuple[float, float, float, float]] = []  # ms; label mm at onset; ms past 0.1 mm, dz
        self.slow = Counter()  # (label type, waited as an undecided lone contact) -> gestures past SLOW_MS
        self.traces: list[str] = []  # their windows (slow_trace)
        self.collared = Counter()  # "scored", and the wrong windows outside the collar by cause

    def add(self, other: "Tally") -> None:
        for name in ("gestures", "wrong", "pairs", "phases", "slow", "collared"):
            getattr(self, name).update(getattr(other, name))
        self.onset_push += other.onset_push
        self.one_contact += other.one_contact
        self.fewer = [a + b for a, b in zip(self.fewer, other.fewer)]
        self.onsets += other.onsets
        self.traces += other.traces


def slow_trace(labels, predictions, t0: int, answer_us: float, seq: str) -> list[str]:
    """The windows of a gesture begun at ``t0`` (us) whose answer came at ``answer_us`` (us), one
    line each (the module docstring's ``--traces``)."""
    window = [p for p in predictions if t0 - 20_000 <= p.t_us <= answer_us + FRAME_PERIOD_US / 4]
    truth = labels_at(labels, np.array([p.t_us for p in window], dtype=np.int64))
    lines = []
    for p, r in zip(window, truth):
        lab = "-" if r is None else f"{r.gesture.value} {r.intensity_mm:.2f} mm n{r.n_contacts}"
        rest = "*" if p.resting else ""
        lines.append(
            f"    {seq} {(p.t_us - t0) / 1e3:5.0f} ms  label {lab:22s} answer {p.gesture.value} "
            f"{p.intensity_mm:.2f} mm n{p.n_contacts}{rest}"
        )
    return lines


def tally_collared(t: "Tally", labels, predictions, pressed) -> None:
    """Add the gesture type's windows outside the collar to ``t.collared`` (the module docstring):
    ``scored``, and the wrong ones as ``unpressed``, ``unmoved`` or ``seen``."""
    label_t = np.array([r.t_us for r in labels], dtype=np.int64)
    kept = [p for p in predictions if len(label_t) and p.t_us >= label_t[0]]
    t_pred = np.array([p.t_us for p in kept], dtype=np.int64)
    kinds = np.array([GESTURE_ORDER.index(r.gesture) for r in labels], dtype=np.int64)
    scored = outside_collar(label_t, kinds, t_pred, TYPE_COLLAR_US)
    spans = gesture_spans(labels)
    for p, r, s in zip(kept, labels_at(labels, t_pred), scored):
        if not s or r is None:
            continue
        t.collared["scored"] += 1
        if p.gesture is r.gesture:
            continue
        span = next(((t0, t1) for g, t0, t1 in spans if g is r.gesture and t0 <= p.t_us <= t1), None)
        felt_from = None if span is None else pressed_at(pressed, *span)
        if felt_from is not None and p.t_us < felt_from:
            t.collared["unpressed"] += 1
        elif r.gesture is not GestureType.NONE and r.intensity_mm < MOVED_MM:
            t.collared["unmoved"] += 1
        else:
            t.collared["seen"] += 1


def tally_sequence(labels, predictions, deadzone_mm: float, pressed=(), seq: str = "") -> Tally:
    t = Tally()
    tally_collared(t, labels, predictions, pressed)
    t_pred = np.array([p.t_us for p in predictions], dtype=np.int64)
    label_times = np.array([r.t_us for r in labels], dtype=np.int64)
    latencies = gesture_records(labels, predictions, deadzone_mm, pressed).deadzone_latency_ms
    for k, (kind, t0, t1) in enumerate(gesture_spans(labels)):
        rows = [r for r in labels if t0 <= r.t_us <= t1]
        n_true = max(r.n_contacts for r in rows)
        peak = max(r.intensity_mm for r in rows)
        t_peak = next(r.t_us for r in rows if r.intensity_mm == peak)
        multi, tap = n_true >= 2, (t1 - t0) / 1000.0 <= TAP_MS
        lo, hi = np.searchsorted(t_pred, t0), np.searchsorted(t_pred, t1 + FRAME_PERIOD_US)
        inside = predictions[lo:hi]
        onset = next((p.t_us for p in inside if p.gesture is kind), None)
        truth = labels_at(labels, t_pred[lo:hi]) if len(label_times) else []
        answered = [(p, r) for p, r in zip(inside, truth) if p.gesture is not GestureType.NONE]
        felt = [(p, r) for p, r in answered if p.intensity_mm >= deadzone_mm]
        felt_from = pressed_at(pressed, t0, t1)
        wrong = [(p, r) for p, r in felt if p.gesture is not kind and (felt_from is None or p.t_us >= felt_from)]
        if onset is not None:
            at = labels_at(labels, np.array([onset], dtype=np.int64))[0]
            moved = next((r.t_us for r in rows if r.intensity_mm >= MOVED_MM), t1)
            felt_t = next((r.t_us for r in rows if r.intensity_mm >= deadzone_mm), t1)
            t.onsets.append(((onset - t0) / 1e3, at.intensity_mm, (onset - moved) / 1e3, (onset - felt_t) / 1e3))
        if latencies[k] > SLOW_MS:
            crossing = deadzone_crossing(
                np.array([r.t_us for r in rows]), np.array([r.intensity_mm for r in rows]), deadzone_mm
            )
            answer = crossing + latencies[k] * 1e3
            waited = any(
                p.gesture is GestureType.NONE and p.n_contacts == 1 and p.intensity_mm >= PROVISIONAL_MM
                for p in inside
                if crossing <= p.t_us < answer
            )
            t.slow[(kind.value, waited)] += 1
            t.traces.append(f"  {kind.value}, {latencies[k]:.0f} ms late:")
            t.traces += slow_trace(labels, predictions, t0, answer, seq)
        t.gestures[(multi, tap)] += 1
        t.wrong[(multi, tap)] += bool(wrong)
        for p, r in wrong:
            t.pairs[(kind.value, p.gesture.value)] += 1
            if onset is None or p.t_us < onset:
                phase = "onset"
            elif r is not None and r.gesture is kind and r.intensity_mm >= HOLD_SHARE * peak:
                phase = "hold"
            else:
                phase = "attack" if p.t_us < t_peak else "release"
            t.phases[phase] += 1
        if multi:
            if felt and felt[0][0].gesture is GestureType.PUSH:
                t.onset_push += 1
            if answered and all(p.n_contacts < n_true for p, _ in answered):
                t.one_contact += 1
            t.fewer[0] += sum(1 for p, _ in answered if p.n_contacts < n_true)
            t.fewer[1] += len(answered)
    return t


def share(k: int, n: int) -> str:
    return f"{k} of {n} ({100 * k / n:.0f} %)" if n else "-"


def lines_for(name: str, t: Tally) -> list[str]:
    g, w = t.gestures, t.wrong
    multi = sum(v for (m, _), v in g.items() if m)
    out = [
        f"## {name}",
        "",
        f"- gestures felt wrong: {share(sum(w.values()), sum(g.values()))}; multi-finger taps "
        f"{share(w[(True, True)], g[(True, True)])}, longer multi-finger {share(w[(True, False)], g[(True, False)])}, "
        f"one-finger taps {share(w[(False, True)], g[(False, True)])}, longer one-finger "
        f"{share(w[(False, False)], g[(False, False)])}",
        f"- felt wrong windows: {sum(t.phases.values())}; by phase "
        + ", ".join(f"{k} {v}" for k, v in t.phases.most_common())
        + "; label -> answered "
        + ", ".join(f"{a} as {b} {v}" for (a, b), v in t.pairs.most_common()),
        f"- multi-finger gestures: {multi}; first felt window push {share(t.onset_push, multi)}; "
        f"fewer contacts than labelled in every answered window {share(t.one_contact, multi)}; answered windows "
        f"with fewer contacts {share(t.fewer[0], t.fewer[1])}",
    ]
    if t.onsets:
        ms, mm, after_moved, after_felt = (np.array(v) for v in zip(*t.onsets))

        def mp(v: np.ndarray, unit: str) -> str:
            return f"{np.median(v):.0f} / {np.percentile(v, 90):.0f} {unit}"

        out.append(
            f"- onset (median / p90): {mp(ms, 'ms')} after the first labelled frame; label intensity there "
            f"{np.median(mm):.2f} / {np.percentile(mm, 90):.2f} mm; {mp(after_moved, 'ms')} after the label "
            f"reaches {MOVED_MM} mm; {mp(after_felt, 'ms')} after it reaches the dead zone (negative: before)"
        )
    c = t.collared
    if c["scored"]:
        wrong = c["unpressed"] + c["unmoved"] + c["seen"]
        out.append(
            f"- gesture type outside the collar: {c['scored']} windows, {wrong} wrong "
            f"({100 * (1 - wrong / c['scored']):.2f} % right); of the wrong, before the gesture's last finger "
            f"pressed {c['unpressed']}, label below {MOVED_MM} mm {c['unmoved']}, the rest {c['seen']}: "
            f"{100 * (1 - (c['unpressed'] + c['unmoved']) / c['scored']):.2f} % were the rest right"
        )
    slow = sum(t.slow.values())
    out.append(
        f"- dead-zone latency above {SLOW_MS:.0f} ms: {slow} gestures"
        + "".join(
            f"; {kind} {sum(v for (k, _), v in t.slow.items() if k == kind)} (of them waiting as an undecided "
            f"lone contact {t.slow[(kind, True)]})"
            for kind in sorted({k for k, _ in t.slow})
        )
    )
    out.append("")
    return out


@app.command()
def main(
    out: Path = typer.Option(..., "--out", help="family_eval.py working folder"),
    method: str = typer.Option("ours", "--method", help="whose predictions (DIR/predictions/FAMILY/METHOD)"),
    families: str = typer.Option("", "--families", help="comma-separated (default: every family with predictions)"),
    deadzone_mm: float = typer.Option(DEFAULT_DEADZONE_MM, "--deadzone-mm", min=0.0),
    traces: bool = typer.Option(False, "--traces", help=f"each gesture past {SLOW_MS:.0f} ms, window by window"),
) -> None:
    names = families_in(out, families, method)
    total = Tally()
    for fam in names:
        t = Tally()
        for seq in list_sequences(out / fam):
            labels = read_labels(out / fam / f"{seq}.labels.csv")
            preds = read_predictions(out / "predictions" / fam / method / f"{seq}.jsonl")
            t.add(tally_sequence(labels, preds, deadzone_mm, read_pressed(out / fam / f"{seq}.pressed.csv"), seq))
        total.add(t)
        print("\n".join(lines_for(fam, t)))
        if traces and t.traces:
            print("\n".join(["Gestures answered late above the dead zone:", *t.traces, ""]))
    print("\n".join(lines_for(f"all {len(names)} families", total)))


if __name__ == "__main__":
    app()
