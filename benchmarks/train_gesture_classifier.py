"""Train the learned gesture type (``pipeline/learned.py``) and measure it leave-one-family-out.

    python3 benchmarks/train_gesture_classifier.py --out DIR --test DIR2 [--families a,b,...] [--write]

Protocol (docs/method.md, "Gesture"):

* **Training data**: each development family (every physics family but the final one,
  ``family_eval.FINAL_FAMILY``, ``contrast``; nor ``mix``, which draws it)
  simulated for the tuning users 5 and 8 with the odd seed 1 (4 s per gesture type and user, as
  ``family_eval.py``), written under ``DIR/FAMILY``. The pipeline runs once per
  sequence (the defaults, classifier off) and saves the tracked markers at every window's end
  (``tune_pipeline.record_sequence``); each window the rule calls a gesture and the labels call
  a gesture gives one row of :func:`~neurotouch_hid.pipeline.learned.gesture_features`.
* **Held-out measure**: for every development family F, a model fitted on the *other* families'
  tuning rows is scored on F's test users (``DIR2/F``: ``family_eval.py``'s datasets, users 0
  and 3, seed 2), against the rule on the same windows: the classifier is kept only if it wins
  there.
* Needs scikit-learn (``pip install -e '.[train]'``).
* **The model**: scikit-learn's ``LogisticRegression`` (multinomial, L2, C = 1) on standardised
  features, fitted on all development families' tuning rows; ``--write`` writes its constants
  to ``neurotouch_hid/pipeline/gesture_model.py`` (no scikit-learn at run time).
"""

from __future__ import annotations

import subprocess
import sys
import textwrap
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import typer

sys.path.insert(0, str(Path(__file__).resolve().parent))
from family_eval import FINAL_FAMILY  # noqa: E402  (never trained on: docs/accuracy.md)
from tune_pipeline import record_sequence  # noqa: E402

from neurotouch_hid.core.dataset import labels_at, list_sequences, read_labels  # noqa: E402
from neurotouch_hid.core.estimate import GestureType  # noqa: E402
from neurotouch_hid.core.sensor import SensorGeometry  # noqa: E402
from neurotouch_hid.evaluation.runner import pipeline_config  # noqa: E402
from neurotouch_hid.pipeline.learned import CLASSES, FEATURES, gesture_features  # noqa: E402
from neurotouch_hid.pipeline.pipeline import GesturePipeline  # noqa: E402
from neurotouch_hid.sources.physics import PHYSICS  # noqa: E402
from neurotouch_hid.sources.sim_dataset import write_dataset  # noqa: E402
from neurotouch_hid.views.console import command_app

MODEL_FILE = Path(__file__).resolve().parents[1] / "neurotouch_hid" / "pipeline" / "gesture_model.py"

app = command_app()


def rows(dataset: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(features (W, 9), true class (W,), the rule's class (W,)) of a dataset's windows that both
    the rule and the labels call a gesture; the snapshots are recorded under ``dataset/snap``."""
    sensor = SensorGeometry.load(dataset / "sensor.yaml")
    config = pipeline_config()
    snaps = dataset / "snap"
    snaps.mkdir(exist_ok=True)
    x, y, rule = [], [], []
    for name in list_sequences(dataset):
        if not (snaps / f"{name}.npz").exists():
            record_sequence(dataset, name, config, snaps)
        data = np.load(snaps / f"{name}.npz")
        pipeline = GesturePipeline(sensor, config)
        pipeline._learned_type = lambda result, *_: result  # the rule's type: what the classifier learns from
        pipeline.rest_px = data["rest_px"]
        pipeline._use_camera_model()
        labels = labels_at(read_labels(dataset / f"{name}.labels.csv"), data["t_us"])
        for pos, ok, resting, label in zip(data["positions_px"], data["valid"], data["resting"], labels):
            if label is None or resting or label.gesture is GestureType.NONE:
                continue
            pipeline.tracker = SimpleNamespace(positions_px=pos, valid=ok)
            contacts, result = pipeline._fit(pipeline.rest_px, pos, ok)
            if result.gesture is GestureType.NONE:
                continue
            c = pipeline.config
            x.append(
                gesture_features(
                    result, contacts.points_px, pipeline.rest_px, pos, ok, pipeline.sensor, c.r_px, c.origin_radius_px
                )
            )
            y.append(CLASSES.index(label.gesture))
            rule.append(CLASSES.index(result.gesture))
    return np.array(x), np.array(y), np.array(rule)


def fit(x: np.ndarray, y: np.ndarray):
    """Standardisation and the logistic regression: (mean, scale, weights (5, 9), intercept (5,))."""
    from sklearn.linear_model import LogisticRegression

    mean, scale = x.mean(axis=0), x.std(axis=0) + 1e-9
    model = LogisticRegression(C=1.0, max_iter=5000).fit((x - mean) / scale, y)
    return mean, scale, model.coef_, model.intercept_


def predict(params, x: np.ndarray) -> np.ndarray:
    mean, scale, weights, intercept = params
    return np.argmax(((x - mean) / scale) @ weights.T + intercept, axis=1)


def write_model(params, families: list[str], n: int) -> None:
    mean, scale, weights, intercept = params

    def arr(a) -> str:
        return "np.array(" + np.array2string(np.asarray(a), precision=8, separator=", ", max_line_width=110) + ")"

    doc = textwrap.fill(
        "Constants of the learned gesture type (``learned.py``): written by "
        "``benchmarks/train_gesture_classifier.py --write`` (scikit-learn LogisticRegression, C = 1, on "
        f"{n} windows of the tuning users 5 and 8, seed 1, of the families {', '.join(families)}). "
        f"Features: {', '.join(FEATURES)}; classes: {', '.join(c.value for c in CLASSES)}.",
        width=100,
    )
    MODEL_FILE.write_text(
        f'"""{doc}"""\n\n'
        "import numpy as np\n\n"
        f"MEAN = {arr(mean)}\nSCALE = {arr(scale)}\nWEIGHTS = {arr(weights)}\nINTERCEPT = {arr(intercept)}\n"
    )
    subprocess.run([sys.executable, "-m", "ruff", "format", "-q", str(MODEL_FILE)], check=False)  # the tree's style


@app.command()
def main(
    out: Path = typer.Option(..., "--out", help="training datasets (tuning users 5, 8, seed 1)"),
    test: Path = typer.Option(..., "--test", help="family_eval.py's folder (test users 0, 3, seed 2)"),
    families: str = typer.Option(",".join(f for f in PHYSICS if f != FINAL_FAMILY), "--families"),
    write: bool = typer.Option(False, "--write", help=f"write {MODEL_FILE.name}"),
) -> None:
    names = [f.strip() for f in families.split(",") if f.strip()]
    if FINAL_FAMILY in names or "mix" in names:
        raise typer.BadParameter(f"{FINAL_FAMILY} is the final family (and mix draws it): never trained on")
    train, held = {}, {}
    for fam in names:
        folder = out / fam
        if not (folder / "done").exists():
            write_dataset(folder, seed=1, users=[5, 8], minutes=4.0 * 10 / 60.0, physics=fam, progress=False)
            (folder / "done").write_text("")
        train[fam] = rows(folder)
        held[fam] = rows(test / fam)
    print("| held-out family | windows | rule | learned | difference |")
    print("| --- | ---: | ---: | ---: | ---: |")
    for fam in names:
        x = np.concatenate([train[f][0] for f in names if f != fam])
        y = np.concatenate([train[f][1] for f in names if f != fam])
        hx, hy, hrule = held[fam]
        rule, learned = np.mean(hrule == hy) * 100, np.mean(predict(fit(x, y), hx) == hy) * 100
        print(f"| {fam} | {len(hy)} | {rule:.2f} % | {learned:.2f} % | {learned - rule:+.2f} |")
    if write:
        x = np.concatenate([train[f][0] for f in names])
        y = np.concatenate([train[f][1] for f in names])
        write_model(fit(x, y), names, len(y))
        print(f"-> {MODEL_FILE}")


if __name__ == "__main__":
    app()
