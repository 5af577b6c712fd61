"""Where contact count is lost, per gesture type: from the predictions ``family_eval.py`` wrote.

    python3 docs/lab/contact_count.py --out DIR [--families default,fingers,...] [--method ours]

Reads ``DIR/FAMILY`` (the dataset) and ``DIR/predictions/FAMILY/METHOD`` (its predictions) as
``family_eval.py --out DIR`` leaves them and prints, per family and labelled gesture type, over
the windows labelled with that type (docs/dataset.md, "Predictions (JSON lines)": the ground
truth at each prediction's time):

* count: the share of windows whose contact count is the labelled one; count >= 0.12 mm: the same
  over the windows whose labelled intensity is at least the gesture step's minimum (:data:`SEEN_MM`);
* too few / too many: the shares with fewer / more contacts than labelled;
* by time since the gesture's first labelled frame (onset 0-100 ms, 100-200 ms, later): the
  share of each part's windows with too few contacts, and the part's share of all windows;
* 3 -> 2: windows of a 3-finger gesture read as 2 (a weak third finger);
* whole gestures read with too few contacts in >= 80 % of their windows after 200 ms (fingers
  merged through a hold).

Figures only; nothing here is a pass or fail.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import typer

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))  # workdir.py, a benchmark's helper
from workdir import families_in  # noqa: E402

from neurotouch_hid.core.dataset import labels_at, list_sequences, read_labels, read_predictions  # noqa: E402
from neurotouch_hid.core.estimate import GestureType  # noqa: E402
from neurotouch_hid.views.console import command_app  # noqa: E402

app = command_app()

#: The gesture step's minimum intensity (mm; ``GestureConfig.min_intensity_mm``): below it a
#: window is ``none`` and has no contact whatever the contacts stage finds.
SEEN_MM = 0.12
#: Time since a gesture's first labelled frame (ms): the parts the losses are split into.
PARTS_MS = ((0.0, 100.0), (100.0, 200.0), (200.0, np.inf))


def sequence_windows(dataset: Path, predictions: Path, name: str) -> list[tuple[str, int, int, float, int, float]]:
    """The windows of one sequence inside labelled gestures: (type, labelled count, predicted
    count, ms since the gesture's first labelled frame, the gesture's running number, labelled
    intensity mm)."""
    labels = read_labels(dataset / f"{name}.labels.csv")
    preds = read_predictions(predictions / f"{name}.jsonl")
    truth = labels_at(labels, np.array([p.t_us for p in preds], dtype=np.int64))
    out = []
    start, number, last = None, -1, GestureType.NONE
    for p, t in zip(preds, truth):
        if t is None or t.gesture is GestureType.NONE:
            last = GestureType.NONE
            continue
        if t.gesture is not last:
            start, number, last = t.t_us, number + 1, t.gesture
        out.append(
            (t.gesture.value, len(t.contacts_px), p.n_contacts, (p.t_us - start) / 1000.0, number, t.intensity_mm)
        )
    return out


def family_rows(dataset: Path, predictions: Path) -> dict[str, dict]:
    """Per gesture type (value string) the figures the module docstring lists."""
    rows: dict[str, list] = {}
    for name in list_sequences(dataset):
        if not (predictions / f"{name}.jsonl").exists():
            continue
        for w in sequence_windows(dataset, predictions, name):
            rows.setdefault(w[0], []).append((*w[1:5], name, w[5]))
    result = {}
    for kind, ws in sorted(rows.items()):
        true = np.array([w[0] for w in ws])
        pred = np.array([w[1] for w in ws])
        ms = np.array([w[2] for w in ws])
        gid = np.array([f"{w[4]}#{w[3]}" for w in ws])
        seen = np.array([w[5] for w in ws]) >= SEEN_MM
        few = pred < true
        parts = []
        for lo, hi in PARTS_MS:
            m = (ms >= lo) & (ms < hi)
            parts.append((few[m].mean() if m.any() else float("nan"), m.mean()))
        three = true == 3
        merged = 0
        gestures = np.unique(gid)
        for g in gestures:
            m = (gid == g) & (ms >= 200.0) & (true >= 2)
            if m.sum() >= 5 and few[m].mean() >= 0.8:
                merged += 1
        result[kind] = {
            "n": len(ws),
            "count": float((pred == true).mean()),
            "count_seen": float((pred == true)[seen].mean()) if seen.any() else float("nan"),
            "few": float(few.mean()),
            "many": float((pred > true).mean()),
            "parts": parts,
            "three_as_two": (float((pred[three] == 2).mean()) if three.any() else float("nan"), int(three.sum())),
            "merged": (merged, len(gestures)),
        }
    return result


@app.command()
def main(
    out: Path = typer.Option(..., "--out", help="family_eval.py's working folder"),
    families: str = typer.Option("", "--families", help="comma-separated (default: every family with predictions)"),
    method: str = typer.Option("ours", "--method", help="the predictions' method name"),
) -> None:
    names = families_in(out, families, method)
    head = "few @0-100 / 100-200 / 200+ ms (share of windows)"
    cols = f"count | count >= 0.12 mm | too few | too many | {head} | 3 -> 2 | merged gestures"
    print(f"| family | type | windows | {cols} |")
    print("| --- | --- | ---: | ---: | ---: | ---: | ---: | --- | ---: | ---: |")
    for fam in names:
        for kind, r in family_rows(out / fam, out / "predictions" / fam / method).items():
            parts = " / ".join(f"{100 * f:.0f} % ({100 * s:.0f})" for f, s in r["parts"])
            three, n3 = r["three_as_two"]
            three_s = f"{100 * three:.0f} % of {n3}" if n3 else "-"
            print(
                f"| {fam} | {kind} | {r['n']} | {100 * r['count']:.1f} % | {100 * r['count_seen']:.1f} % | "
                f"{100 * r['few']:.1f} % | "
                f"{100 * r['many']:.1f} % | {parts} | {three_s} | {r['merged'][0]} of {r['merged'][1]} |"
            )


if __name__ == "__main__":
    app()
