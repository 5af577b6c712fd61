"""The contacts stage alone, replayed on the windows of real pipeline runs: contact count per
gesture type for variants of :func:`~neurotouch_hid.pipeline.contacts.detect_contacts`.

    python3 docs/lab/contact_replay.py record --out DIR --families default,fingers,...
    python3 docs/lab/contact_replay.py score --out DIR --families default,fingers,... [--variant NAME]

``record`` runs the product's pipeline over each family's dataset ``DIR/FAMILY`` (as
``family_eval.py --out DIR`` made it) and keeps, per window, the inputs its contacts stage saw
(rest and current positions with the gel's motion removed, valid markers; image px) in
``DIR/replay/FAMILY.npz``. ``score`` runs a variant of the contacts stage on those windows and
prints the contact count per labelled gesture type (and in brackets the share of windows with
more contacts than labelled) (windows whose estimate is ``none`` keep 0
contacts), and the share of ``none`` windows inside gestures left aside. The gesture step, which
reads the contacts, is not rerun, and each window is replayed without its press (a round flat top
read by its area, ``detect_contacts``' ``long_before``): the full effect is ``family_eval.py``'s.
Figures only.
"""

from __future__ import annotations

from pathlib import Path
from typing import Callable

import numpy as np
import typer

from neurotouch_hid.core.dataset import labels_at, list_sequences, read_labels
from neurotouch_hid.core.estimate import GestureType
from neurotouch_hid.pipeline import contacts as contacts_mod
from neurotouch_hid.pipeline import fit_path
from neurotouch_hid.pipeline import pipeline as pipeline_mod
from neurotouch_hid.views.console import command_app

app = command_app()


def record_sequence(dataset: Path, name: str) -> dict:
    """One sequence's windows: t (W,) int64 us, emitted (W,) bool (the estimate had a gesture),
    rest and current (W, N, 2) float64 px (NaN where not fitted), valid (W, N) bool, fitted (W,)
    bool, and the labels' type (W,) str and count (W,) int64."""
    from neurotouch_hid.core.sensor import SensorGeometry
    from neurotouch_hid.evaluation.runner import pipeline_config
    from neurotouch_hid.pipeline.methods import pipeline_for
    from neurotouch_hid.sources.recording import RecordingReader

    state: dict = {"last": None, "called": False}
    original_detect = fit_path.detect_contacts
    original_cg = pipeline_mod.GesturePipeline._contacts_and_gesture

    def detect(rest_px, current_px, valid, **kw):
        state["last"] = (np.array(rest_px), np.array(current_px), np.array(valid, dtype=bool), kw)
        return original_detect(rest_px, current_px, valid, **kw)

    def cg(self, rest_px, current, valid):
        state["called"] = True
        return original_cg(self, rest_px, current, valid)

    fit_path.detect_contacts = detect
    pipeline_mod.GesturePipeline._contacts_and_gesture = cg
    try:
        sensor = SensorGeometry.load(dataset / "sensor.yaml")
        pipeline = pipeline_for(sensor, pipeline_config([], "default"))
        rows = []
        with RecordingReader(dataset / f"{name}.aedat4") as reader:
            stream = pipeline.run(reader.stream())
            while True:
                state["called"] = False
                try:
                    est = next(stream)
                except StopIteration:
                    break
                fitted = state["called"] and state["last"] is not None
                rows.append((est, state["last"] if fitted else None))
    finally:
        fit_path.detect_contacts = original_detect
        pipeline_mod.GesturePipeline._contacts_and_gesture = original_cg
    labels = read_labels(dataset / f"{name}.labels.csv")
    t = np.array([e.t_us for e, _ in rows], dtype=np.int64)
    truth = labels_at(labels, t)
    first = next((r for _, r in rows if r is not None), None)
    n = len(first[0]) if first is not None else 0
    rest = np.full((len(rows), n, 2), np.nan)
    current = np.full((len(rows), n, 2), np.nan)
    valid = np.zeros((len(rows), n), dtype=bool)
    fitted = np.zeros(len(rows), dtype=bool)
    for k, (_, r) in enumerate(rows):
        if r is not None:
            rest[k], current[k], valid[k], fitted[k] = r[0], r[1], r[2], True
    return {
        "t": t,
        "emitted": np.array([e.gesture is not GestureType.NONE for e, _ in rows]),
        "count": np.array([len(e.contacts_px) for e, _ in rows], dtype=np.int64),
        "current": current,
        "valid": valid,
        "fitted": fitted,
        "rest": rest,
        "true_type": np.array([tr.gesture.value if tr else "skip" for tr in truth]),
        "true_count": np.array([len(tr.contacts_px) if tr else -1 for tr in truth], dtype=np.int64),
        # the settings, not the press: a window replayed alone reads a round flat top by its area
        "kw": {k: v for k, v in (first[3] if first else {}).items() if k not in ("neighbours", "long_before")},
    }


@app.command()
def record(
    out: Path = typer.Option(...),
    families: str = typer.Option("default,fingers,strong,powerlaw,camera"),
) -> None:
    (out / "replay").mkdir(exist_ok=True)
    for fam in [f for f in families.split(",") if f]:
        target = out / "replay" / f"{fam}.npz"
        if target.exists():
            continue
        seqs = {}
        for name in list_sequences(out / fam):
            seqs[name] = record_sequence(out / fam, name)
            print(fam, name, len(seqs[name]["t"]), flush=True)
        arrays = {}
        for name, s in seqs.items():
            for key, value in s.items():
                arrays[f"{name}|{key}"] = np.array(repr(value)) if key == "kw" else value
        np.savez_compressed(target, **arrays)


def load(out: Path, fam: str) -> dict[str, dict]:
    data = np.load(out / "replay" / f"{fam}.npz")
    seqs: dict[str, dict] = {}
    for key in data.files:
        name, field = key.split("|")
        seqs.setdefault(name, {})[field] = data[key]
    for s in seqs.values():
        text = str(s["kw"])
        text = text[: text.index(", 'neighbours'")] + "}" if "'neighbours'" in text else text
        s["kw"] = eval(text, {})  # noqa: S307 (our own repr of floats, ints and strings)
    return seqs


#: Variants by name: (rest, current, valid, kw) -> contact count.
VARIANTS: dict[str, Callable] = {
    "current": lambda rest, cur, valid, kw: contacts_mod.detect_contacts(rest, cur, valid, **kw).count,
}


def score_family(out: Path, fam: str, variant: Callable) -> dict[str, tuple[int, int, int]]:
    """Per labelled type: (windows with the labelled count, windows, windows with more)."""
    result: dict[str, list[int]] = {}
    for s in load(out, fam).values():
        for k in range(len(s["t"])):
            kind = str(s["true_type"][k])
            if kind in ("skip", "none"):
                continue
            if not (s["emitted"][k] or s["count"][k] > 0):
                pred = 0
            elif s["fitted"][k]:
                pred = variant(s["rest"][k], s["current"][k], s["valid"][k], s["kw"])
            else:
                pred = int(s["count"][k])
            hit = result.setdefault(kind, [0, 0, 0])
            hit[0] += int(pred == s["true_count"][k])
            hit[1] += 1
            hit[2] += int(pred > s["true_count"][k])
    return {k: (v[0], v[1], v[2]) for k, v in result.items()}


@app.command()
def score(
    out: Path = typer.Option(...),
    families: str = typer.Option("default,fingers,strong,powerlaw,camera"),
    variant: str = typer.Option("current"),
) -> None:
    for fam in [f for f in families.split(",") if f]:
        r = score_family(out, fam, VARIANTS[variant])
        cells = " | ".join(f"{k} {100 * h / n:.1f} (+{100 * m / n:.1f})" for k, (h, n, m) in sorted(r.items()))
        print(f"| {fam} | {variant} | {cells} |", flush=True)


if __name__ == "__main__":
    app()
