"""Presenting an :class:`~neurotouch_hid.evaluation.metrics.EvaluationResult`: rich tables for the
terminal, PNG figures like the paper's (matplotlib, Agg backend) and a Markdown summary.

The figures follow the paper's section "Results": the balanced gesture type confusion matrix,
precision/recall/F1 per gesture type with the contact count accuracy, gesture type and contact
count accuracy against ground-truth intensity (0.6 mm bins), contact distance error and
intensity MAE per gesture type.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
from rich.console import Console
from rich.table import Table

from neurotouch_hid.core.atomic import AtomicFile, replacing
from neurotouch_hid.core.tables import print_table
from neurotouch_hid.evaluation.metrics import EvaluationResult
from neurotouch_hid.service.extras import require

#: The paper's results (section "Results"), to print beside ours.
PAPER_RESULTS: dict[str, float] = {
    "gesture_accuracy": 0.9112,
    "contact_count_accuracy": 0.8322,
    "contact_distance_mm": 3.41,
    "intensity_mae_mm": 0.96,
    "resting_f1": 0.9403,
}

#: Display names of the gesture types, as the paper's figures write them.
DISPLAY_NAMES: dict[str, str] = {
    "none": "No Gesture",
    "push": "Push",
    "pinch": "Pinch",
    "zoom": "Zoom",
    "twist_cw": "CW Twist",
    "twist_ccw": "CCW Twist",
}

#: The figures :func:`write_figures` writes, file name -> caption.
FIGURES: dict[str, str] = {
    "confusion.png": "Balanced gesture type confusion matrix, mean of row- and column-normalised values",
    "metrics_per_class.png": "Gesture type precision, recall, F1 and contact count accuracy per gesture type",
    "accuracy_vs_intensity.png": "Gesture type and contact count accuracy against ground-truth intensity (0.6 mm bins)",
    "error_per_gesture.png": "Contact distance error and intensity MAE per gesture type",
}


#: Where the figures' legends go: beside the axes, right of them, never over the data.
LEGEND_BESIDE = {"loc": "upper left", "bbox_to_anchor": (1.01, 1.0), "borderaxespad": 0.0}


def _pct(value: float) -> str:
    return "-" if value is None or math.isnan(value) else f"{100 * value:.2f} %"


def _mm(value: float) -> str:
    return "-" if value is None or math.isnan(value) else f"{value:.2f} mm"


def summary_rows(result: EvaluationResult) -> list[tuple[str, str, str]]:
    """(metric, ours, paper) rows of the headline metrics, formatted."""
    paper = PAPER_RESULTS
    return [
        ("Gesture type accuracy", _pct(result.gesture_accuracy), _pct(paper["gesture_accuracy"])),
        ("Gesture type accuracy outside the 40 ms collar", _pct(result.gesture_collared_accuracy), "-"),
        ("Contact count accuracy", _pct(result.contact_count_accuracy), _pct(paper["contact_count_accuracy"])),
        ("Contact count accuracy outside the 40 ms collar", _pct(result.contact_count_collared_accuracy), "-"),
        ("Contact distance error", _mm(result.contact_distance_mm), _mm(paper["contact_distance_mm"])),
        ("Intensity MAE", _mm(result.intensity_mae_mm), _mm(paper["intensity_mae_mm"])),
        ("Resting precision", _pct(result.resting_precision), "-"),
        ("Resting recall", _pct(result.resting_recall), "-"),
        ("Resting F1", _pct(result.resting_f1), _pct(paper["resting_f1"])),
        ("Resting F1 outside the 40 ms collar", _pct(result.resting_collared_f1), "-"),
    ]


def per_class_rows(result: EvaluationResult) -> list[list[str]]:
    """Per gesture type: name, precision, recall, F1 (%), support, contact count accuracy (%),
    contact distance error (mm), intensity MAE (mm), formatted without units ("-": undefined)."""

    def num(value: float, scale: float = 1.0) -> str:
        return "-" if math.isnan(value) else f"{scale * value:.1f}" if scale != 1.0 else f"{value:.2f}"

    return [
        [
            DISPLAY_NAMES.get(name, name),
            num(result.precision[k], 100),
            num(result.recall[k], 100),
            num(result.f1[k], 100),
            str(int(result.support[k])),
            num(result.contact_count_accuracy_by_gesture[k], 100),
            num(result.contact_distance_by_gesture_mm[k]),
            num(result.intensity_mae_by_gesture_mm[k]),
        ]
        for k, name in enumerate(result.classes)
    ]


def felt_rows(result: EvaluationResult) -> list[tuple[str, str]]:
    """(metric, value) rows of the per-gesture figures (docs/dataset.md, "Per-gesture metrics"),
    formatted."""
    f = result.felt

    def ms(value: float) -> str:
        return "-" if math.isnan(value) else f"{value:.0f} ms"

    def per(value: float) -> str:
        return "-" if math.isnan(value) else f"{value:.2f}"

    dz = f"{f.deadzone_mm:g} mm"
    return [
        ("Gestures", str(f.n_gestures)),
        ("Onset latency, median / p90", f"{ms(f.onset_median_ms)} / {ms(f.onset_p90_ms)}"),
        ("Never recognised", f"{f.never_recognised} of {f.n_gestures}"),
        ("Type changes per gesture", per(f.type_changes_per_gesture)),
        (f"Type changes per gesture >= {dz}", per(f.felt_type_changes_per_gesture)),
        (f"Gestures felt wrong (another type >= {dz})", _pct(f.felt_wrong_share)),
        ("False activations at rest (> 300 ms from a gesture)", f"{f.false_activations} of {f.n_rest} windows"),
        (f"False activations at rest >= {dz}", f"{f.felt_false_activations} of {f.n_rest} windows"),
        (
            f"Dead-zone latency, median / p90 (the gel past {dz} to the answer past it)",
            f"{ms(f.deadzone_latency_median_ms)} / {ms(f.deadzone_latency_p90_ms)}",
        ),
        (f"Missed above {dz} (no answer of the type past it)", f"{f.missed_above_deadzone} of {f.reached_deadzone}"),
    ]


PROFILE_HEADER = ["Profile", "Gestures", "Wrong output", "Missed (of those the labels move)", "Went active at rest"]


def profile_rows(result: EvaluationResult) -> list[list[str]]:
    """Per profile replayed (``eval --profile``): gestures, those with a wrong output, those missed
    (of those whose labels move an output of their type) and the rest windows in which an output
    went active (docs/dataset.md, "Through a profile"), formatted."""
    return [
        [name, str(t.gestures), str(t.wrong), f"{t.missed} of {t.ideal}", f"{t.rest_active} of {t.rest} windows"]
        for name, t in result.through_profiles.items()
    ]


PER_CLASS_HEADER = ["Gesture", "Prec. %", "Recall %", "F1 %", "Support", "Count acc. %", "Dist. mm", "MAE mm"]


def intensity_rows(result: EvaluationResult) -> list[list[str]]:
    """Per non-empty ground-truth intensity bin: range (mm), observations, gesture type accuracy,
    contact count accuracy (formatted)."""
    edges = result.intensity_bin_edges_mm
    return [
        [
            f"{edges[b]:.1f}-{edges[b + 1]:.1f}",
            str(int(n)),
            _pct(result.gesture_accuracy_by_intensity[b]),
            _pct(result.contact_count_accuracy_by_intensity[b]),
        ]
        for b, n in enumerate(result.n_by_intensity)
        if n > 0
    ]


def _print_table(console: Console, title: str, header: list[str], rows) -> None:
    """One rich table: the first column left-aligned, the others right-aligned."""
    table = Table(title=title)
    for k, col in enumerate(header):
        table.add_column(col, justify="right" if k else "left")
    for row in rows:
        table.add_row(*row)
    print_table(console, table)


def print_tables(result: EvaluationResult, console: Console) -> None:
    """Print the paper's metrics as rich tables: headline metrics beside the paper's, the
    per-gesture figures, the counts through each profile replayed, per gesture type metrics, the
    balanced confusion matrix, and accuracy against intensity."""
    _print_table(
        console,
        f"NeuroTouch evaluation: {result.n_sequences} sequences, {result.n_observations} observations "
        f"({result.n_skipped} predictions before the first label skipped)",
        ["Metric", "Ours", "Paper"],
        summary_rows(result),
    )
    _print_table(
        console, "Per gesture (what a controller's user feels; docs/dataset.md)", ["Metric", "Ours"], felt_rows(result)
    )
    if result.through_profiles:
        _print_table(
            console,
            "Through the profiles (what each output does; docs/dataset.md)",
            PROFILE_HEADER,
            profile_rows(result),
        )
    _print_table(
        console,
        "Per gesture type (precision, recall, F1 of the gesture type; errors on labelled type)",
        PER_CLASS_HEADER,
        per_class_rows(result),
    )

    confusion = Table(title="Balanced confusion matrix (rows: ground truth, columns: prediction)")
    confusion.add_column("")
    for name in result.classes:
        confusion.add_column(DISPLAY_NAMES.get(name, name), justify="right")
    for k, name in enumerate(result.classes):
        confusion.add_row(DISPLAY_NAMES.get(name, name), *(f"{v:.2f}" for v in result.balanced_confusion[k]))
    print_table(console, confusion)

    by_intensity = Table(title="Accuracy against ground-truth intensity (gesture observations)")
    for col in ("Intensity (mm)", "Observations", "Gesture type acc.", "Contact count acc."):
        by_intensity.add_column(col, justify="right")
    for row in intensity_rows(result):
        by_intensity.add_row(*row)
    print_table(console, by_intensity)


def write_figures(result: EvaluationResult, out_dir: str | Path) -> list[Path]:
    """Write the PNG figures of :data:`FIGURES` into ``out_dir`` (created if missing).

    Uses matplotlib's Agg backend (no display needed), the optional extra ``plots``. Returns the
    paths written.

    Raises:
        MissingExtraError: matplotlib is not installed (the message says how to install it).
    """
    require("plots", "eval --report")
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    names = [DISPLAY_NAMES.get(n, n) for n in result.classes]
    x = np.arange(len(names))
    written: list[Path] = []

    def save(fig, name: str) -> None:
        fig.tight_layout()
        with replacing(out_dir / name, what="figure") as tmp:  # renamed into place when complete
            fig.savefig(tmp, dpi=120, bbox_inches="tight")  # the legends beside the axes too
        plt.close(fig)
        written.append(out_dir / name)

    fig, ax = plt.subplots(figsize=(7, 6))
    image = ax.imshow(result.balanced_confusion, vmin=0, vmax=1, cmap="Blues")
    for i in range(len(names)):
        for j in range(len(names)):
            v = result.balanced_confusion[i, j]
            ax.text(j, i, f"{v:.2f}", ha="center", va="center", color="white" if v > 0.5 else "black", fontsize=9)
    ax.set_xticks(x, names, rotation=30, ha="right")
    ax.set_yticks(x, names)
    ax.set_xlabel("Predicted gesture type")
    ax.set_ylabel("Ground-truth gesture type")
    ax.set_title("Balanced confusion matrix")
    fig.colorbar(image, ax=ax, fraction=0.046)
    save(fig, "confusion.png")

    fig, ax = plt.subplots(figsize=(9, 4.5))
    series = [
        ("Precision", result.precision),
        ("Recall", result.recall),
        ("F1", result.f1),
        ("Contact count acc.", result.contact_count_accuracy_by_gesture),
    ]
    width = 0.2
    for s, (label, values) in enumerate(series):
        ax.bar(x + (s - 1.5) * width, np.nan_to_num(np.asarray(values, dtype=float)) * 100, width, label=label)
    ax.set_xticks(x, names)
    ax.set_ylabel("%")
    ax.set_ylim(0, 105)
    ax.legend(**LEGEND_BESIDE, fontsize=8)
    ax.set_title(
        f"Gesture type accuracy {_pct(result.gesture_accuracy)}, "
        f"contact count accuracy {_pct(result.contact_count_accuracy)}"
    )
    save(fig, "metrics_per_class.png")

    fig, ax = plt.subplots(figsize=(10, 4.5))
    edges = result.intensity_bin_edges_mm
    centres = (edges[:-1] + edges[1:]) / 2 if len(edges) > 1 else np.zeros(0)
    bar = (edges[1] - edges[0]) * 0.42 if len(edges) > 1 else 0.25
    ax.bar(centres - bar / 2, np.nan_to_num(result.gesture_accuracy_by_intensity) * 100, bar, label="Gesture type")
    ax.bar(
        centres + bar / 2, np.nan_to_num(result.contact_count_accuracy_by_intensity) * 100, bar, label="Contact count"
    )
    ax.set_xlabel("Ground-truth intensity (mm), 0.6 mm bins")
    ax.set_ylabel("Accuracy (%)")
    ax.set_ylim(0, 115)
    ax.legend(**LEGEND_BESIDE)
    ax.set_title("Accuracy against ground-truth intensity (gesture observations)")
    save(fig, "accuracy_vs_intensity.png")

    gestures = [k for k, n in enumerate(result.classes) if n != "none"]
    fig, axes = plt.subplots(1, 2, figsize=(10, 4))
    gx = np.arange(len(gestures))
    panels = (
        ("Contact distance error", result.contact_distance_by_gesture_mm, result.contact_distance_mm, "tab:purple"),
        ("Intensity MAE", result.intensity_mae_by_gesture_mm, result.intensity_mae_mm, "tab:orange"),
    )
    for ax, (title, per_gesture, overall, colour) in zip(axes, panels):
        ax.bar(gx, np.nan_to_num(per_gesture[gestures]), color=colour)
        ax.axhline(overall, color="black", ls="--", lw=1)  # named in the title: no legend over the bars
        ax.set_xticks(gx, [names[k] for k in gestures])
        ax.set_ylabel("mm")
        ax.set_title(f"{title} (dashed: all, {_mm(overall)})")
    save(fig, "error_per_gesture.png")
    return written


def _md_table(header: list[str], rows: list[list[str]] | list[tuple[str, ...]]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + " --- |" * len(header)]
    lines += ["| " + " | ".join(row) + " |" for row in rows]
    return "\n".join(lines)


def write_report(
    result: EvaluationResult,
    out_dir: str | Path,
    *,
    title: str = "NeuroTouch evaluation",
    command: str | None = None,
    config: dict | None = None,
) -> Path:
    """Write the figures and ``out_dir/summary.md`` (Markdown tables and the embedded figures).

    Args:
        result: the metrics.
        out_dir: folder to write (created if missing).
        title: the summary's heading.
        command: the command line that produced the result, quoted in the summary.
        config: the pipeline hyperparameters used, listed in the summary.
    Returns:
        The path of ``summary.md``.
    """
    out_dir = Path(out_dir)
    write_figures(result, out_dir)
    parts = [f"# {title}", ""]
    if command:
        parts += ["```sh", command, "```", ""]
    parts += [
        f"{result.n_sequences} sequences, {result.n_observations} evaluated predictions "
        f"({result.n_gesture_observations} during a gesture, {result.n_skipped} before the first label "
        f"skipped), {result.n_contact_pairs} contact pairs.",
        "",
    ]
    parts += [_md_table(["Metric", "Ours", "Paper"], summary_rows(result)), ""]
    parts += [
        "## Per gesture (what a controller's user feels)",
        "",
        _md_table(["Metric", "Ours"], felt_rows(result)),
        "",
    ]
    if result.through_profiles:
        parts += ["## Through the profiles", "", _md_table(PROFILE_HEADER, profile_rows(result)), ""]
    parts += ["## Per gesture type", "", _md_table(PER_CLASS_HEADER, per_class_rows(result)), ""]
    parts += [
        "## Accuracy against ground-truth intensity",
        "",
        _md_table(
            ["Intensity (mm)", "Observations", "Gesture type acc.", "Contact count acc."], intensity_rows(result)
        ),
        "",
    ]
    if config:
        parts += [
            "## Pipeline hyperparameters",
            "",
            _md_table(["Parameter", "Value"], [[k, str(v)] for k, v in config.items()]),
            "",
        ]
    parts += ["## Figures", ""]
    for name, caption in FIGURES.items():
        parts += [f"![{caption}]({name})", "", f"*{caption}.*", ""]
    summary = out_dir / "summary.md"
    with AtomicFile(summary, what="summary") as fh:
        fh.write("\n".join(parts))
    return summary
