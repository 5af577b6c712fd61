"""``neurotouch-hid adapt``: the recogniser fitted to one gel and hand from enrolment datasets
(docs/method.md, "Adaptation"; not in the paper).

1. **Record.** The shipped pipeline runs once over every sequence of the enrolment datasets
   (docs/dataset.md folders). Each window's type before the episode vote, intensity, contact count
   and the learned type's nine features (``pipeline/learned.py``) are kept, and each APS frame's
   resting distance (``pipeline/resting.py``). The episode vote only reads each window's type,
   intensity, contact count and time, in order, so what the pipeline would answer with other
   values of what is fitted is replayed from these records without running it again
   (:func:`~neurotouch_hid.enrolment.adapt_fit.replay`; the vote is ``pipeline/episode.py``'s own;
   the records are :mod:`neurotouch_hid.enrolment.adapt_record`'s).
2. **Hold out by prompt.** The labelled gestures of each type are numbered in time; every third,
   from the second on (:data:`~neurotouch_hid.enrolment.adapt_record.HOLD_EVERY`), is held out,
   with the rest before it: the fit never sees a window of a held-out gesture.
3. **Fit** on the other gestures, each fitted value with the shipped one as its prior:

   - the learned type: the multinomial logistic regression refitted from the shipped weights,
     L2-regularised toward them (:func:`~neurotouch_hid.enrolment.adapt_fit.fit_classifier`; the
     strength picked by a 3-fold cross-validation by gesture within the fitted part);
   - the minimum intensity (the contact threshold, ``gesture.min_intensity_mm``), from the shipped
     value up (:data:`MIN_INTENSITY_STEPS`), scored on the windows outside a collar about each
     change of the labelled type (:data:`THRESHOLD_COLLAR_US`);
   - how long one contact alone keeps an episode undecided (``episode.first_finger_us``, the hand's
     lag between its first and second finger), from the shipped value down
     (:data:`~neurotouch_hid.enrolment.adapt_fit.FIRST_FINGER_STEPS_US`), the fitted part's best
     accuracy among the values that show no more windows of another type above the dead zone
     (:data:`~neurotouch_hid.enrolment.adapt_fit.DEADZONE_MM`) than the shipped one;
   - the resting threshold (``resting.centroid_threshold_mm2``), the frames' best resting F1;
   - the intensity scale (``gesture.intensity_gain``), least squares against the labels.

4. **Check** on the held-out gestures: each fitted value is kept only where it beats the shipped
   one there by more than :data:`MIN_GAIN` of the windows' gesture type accuracy (the type, the
   contact threshold (outside the collar) and the first finger's wait: replayed, the wait with no
   more windows of another type above the dead zone either; the resting threshold: the pipeline
   run again with it, and its frames' resting F1 higher too; the scale: an intensity MAE lower by
   more than :data:`MIN_MAE_GAIN` of it, and no accuracy lost);
   otherwise the shipped value stays. The model (``model.py``) holds only what was kept.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Sequence

import numpy as np

from neurotouch_hid.core.errors import DatasetError, NeurotouchError
from neurotouch_hid.enrolment.adapt_fit import (
    _accuracy,
    _felt_wrong,
    _fit_first_finger,
    _mae,
    _resting_f1,
    _rows,
    fit_classifier,
    pick_strength,
    replay,
)
from neurotouch_hid.enrolment.adapt_record import Record, held_out_prompts
from neurotouch_hid.pipeline.episode import FIRST_FINGER_US
from neurotouch_hid.pipeline.learned import CLASSES

#: Minimum intensities tried (multiples of the shipped one; only up: a lower one would need the
#: windows the shipped threshold skipped).
MIN_INTENSITY_STEPS = (1.0, 1.25, 1.5, 2.0, 2.5)
#: Resting thresholds tried (multiples of the shipped one), at most the near-rest threshold.
RESTING_STEPS = (0.5, 0.75, 1.0, 1.5, 2.0, 3.0, 5.0)
#: Fewest held-out gestures (all types together) for a check; fewer: the shipped model is kept.
MIN_HELD_OUT = 3
#: A fitted value is kept only when it beats the shipped one on the held-out gestures' windows by
#: more than this (gesture type accuracy, 0..1): 0.2 points is ~7 windows of a 3-minute enrolment's
#: ~3400 held-out ones, less than one tap: a smaller gain is within what another hold-out moves.
MIN_GAIN = 0.002
#: The contact threshold is fitted and checked on the windows more than this from every change of
#: the labelled type (us; one APS frame, the collar docs/dataset.md puts about the resting flag). A
#: higher threshold moves only a gesture's weakest windows, its attack's first and its release's
#: last, and there the enrolment's labels, which take a gesture's moments from the gel's motion
#: (``label.py``: from the last window near the level before the cue to a tenth of the peak), are
#: unsure by a window or more. Scored on every window, a threshold was kept for answering ``none``
#: in the 10-40 ms after a labelled end (intensity 0.15-0.24 mm), where a game's labels, which end
#: a gesture when its fingers have left, still call it the gesture (docs/method.md, "Adaptation").
THRESHOLD_COLLAR_US = 40_000
#: The intensity scale is kept only when it lowers the held-out intensity MAE by more than this share
#: of it: a scale within a few thousandths of 1 changes nothing a profile can feel.
MIN_MAE_GAIN = 0.05


# --- adapt --------------------------------------------------------------------------------
@dataclass
class Check:
    """One fitted value and its held-out check.

    Attributes:
        what: the setting (``gesture.min_intensity_mm``, ``classifier``, ...).
        metric: what the check compares (e.g. "gesture type accuracy").
        shipped, fitted: the metric on the held-out gestures with the shipped and the fitted value.
        kept: whether the fitted value was kept (it beat the shipped one).
        value: the fitted value (a number, or a phrase for the classifier).
        higher_is_better: the metric's sense.
    """

    what: str
    metric: str
    shipped: float
    fitted: float
    kept: bool
    value: str
    higher_is_better: bool = True


@dataclass
class Adaptation:
    """What :func:`adapt` fitted and checked.

    Attributes:
        model: the model (only the kept values).
        checks: one :class:`Check` per fitted value, in the order they were fitted.
        held_out: held-out gestures; gestures: all labelled gestures.
        windows: held-out labelled windows.
        accuracy_before, accuracy_after: the held-out windows' gesture type accuracy with the
            shipped method and with the model (replayed).
        note: why nothing was fitted, when so (then nothing is worth writing: ``adapt`` writes no model).
        missing: the gesture types (CLASSES values) with no labelled gesture in the enrolments:
            nothing was checked on them.
    """

    model: "Model"  # noqa: F821 (model.py)
    checks: list[Check]
    held_out: int
    gestures: int
    windows: int
    accuracy_before: float
    accuracy_after: float
    note: str = ""
    missing: tuple[str, ...] = ()


def adapt(records: Sequence[Record], rerun: Callable[..., list[Record]] | None = None) -> Adaptation:
    """Fit, check and keep (module docstring, 3-4) from recorded enrolments. ``rerun(config)``
    records the same enrolments with other settings (:func:`record_datasets`); without it the
    resting threshold, which only a new run can check, stays the shipped one.

    Raises:
        NeurotouchError: the enrolments hold no labelled gesture. DatasetError: the labels'
            intensities are out of scale with the gel's (an intensity gain outside
            ``model.SETTING_RANGES``: labels in micrometres).
    """
    from neurotouch_hid.enrolment.model import SETTING_RANGES, Model, out_of_range
    from neurotouch_hid.pipeline.config import GestureConfig, RestingConfig

    held = held_out_prompts(records)
    every = {p for r in records for p in r.prompt_type}
    if not every:
        raise NeurotouchError("the enrolment datasets hold no labelled gesture: nothing to fit (docs/dataset.md)")
    kinds = {k for r in records for k in r.prompt_type.values()}
    missing = tuple(c.value for i, c in enumerate(CLASSES) if i not in kinds)
    fit_part = {p for r in records for p in np.unique(np.concatenate([r.prompt, r.frame_prompt])).tolist()} - held
    shipped_answers = [replay(r) for r in records]
    before, windows = _accuracy(records, shipped_answers, held)
    if len(held) < MIN_HELD_OUT:
        return Adaptation(
            Model(),
            [],
            len(held),
            len(every),
            windows,
            before,
            before,
            f"only {len(held)} gesture(s) could be held out (at least {MIN_HELD_OUT}): no change can be checked, "
            "so nothing is fitted; enrol again (`neurotouch-hid enrol`) and give adapt all your enrolment folders "
            "together",
            missing,
        )
    checks: list[Check] = []
    # the learned type
    x, y, prompts = _rows(records, fit_part)
    classifier = None
    if len(set(y.tolist())) >= 2:
        strength = pick_strength(x, y, prompts)
        candidate = fit_classifier(x, y, strength)
        after, _ = _accuracy(records, [replay(r, candidate) for r in records], held)
        kept = after > before + MIN_GAIN
        checks.append(
            Check("classifier", "gesture type accuracy", before, after, kept, f"refitted, prior strength {strength:g}")
        )
        classifier = candidate if kept else None
    with_type = [replay(r, classifier) for r in records]
    current = _accuracy(records, with_type, held)[0]
    # the contact threshold: the fitted part's best, then checked, outside the collar
    shipped_min = GestureConfig().min_intensity_mm
    collar = THRESHOLD_COLLAR_US
    fit_scores = [
        (_accuracy(records, [replay(r, classifier, shipped_min * s) for r in records], fit_part, collar)[0], -s)
        for s in MIN_INTENSITY_STEPS
    ]
    step = -max(fit_scores)[1]
    min_intensity = None
    if step != 1.0:
        with_step = [replay(r, classifier, shipped_min * step) for r in records]
        shipped_outside = _accuracy(records, with_type, held, collar)[0]
        after_outside = _accuracy(records, with_step, held, collar)[0]
        kept = after_outside > shipped_outside + MIN_GAIN
        checks.append(
            Check(
                "gesture.min_intensity_mm",
                f"gesture type accuracy outside the {collar // 1000} ms collar",
                shipped_outside,
                after_outside,
                kept,
                f"{shipped_min * step:g}",
            )
        )
        if kept:
            min_intensity, current = shipped_min * step, _accuracy(records, with_step, held)[0]
    # the first finger's wait: the fitted part's best among the waits felt wrong no more often
    first_finger = _fit_first_finger(records, classifier, min_intensity or 0.0, fit_part)
    if first_finger != FIRST_FINGER_US:
        wait_answers = [replay(r, classifier, min_intensity or 0.0, first_finger_us=first_finger) for r in records]
        after = _accuracy(records, wait_answers, held)[0]
        felt_before = _felt_wrong(records, [replay(r, classifier, min_intensity or 0.0) for r in records], held)
        felt_after = _felt_wrong(records, wait_answers, held)
        kept = after > current + MIN_GAIN and felt_after <= felt_before
        checks.append(
            Check(
                "episode.first_finger_us",
                f"gesture type accuracy (windows of another type above the dead zone {felt_before} -> {felt_after})",
                current,
                after,
                kept,
                f"{first_finger}",
            )
        )
        if kept:
            current = after
        else:
            first_finger = FIRST_FINGER_US
    # the resting threshold: the frames' best F1 in the fitted part, checked by running the
    # pipeline again with it (the tracker's re-anchoring follows the verdicts: no replay)
    rest = RestingConfig()
    candidates = [
        rest.centroid_threshold_mm2 * s
        for s in RESTING_STEPS
        if rest.centroid_threshold_mm2 * s <= rest.centroid_reset_threshold_mm2
    ]
    best = max(candidates, key=lambda t: (_resting_f1(records, fit_part, t), t == rest.centroid_threshold_mm2))
    resting = None
    if best != rest.centroid_threshold_mm2 and rerun is not None:
        from neurotouch_hid.pipeline.config import PipelineConfig

        again = rerun(PipelineConfig(resting=RestingConfig(centroid_threshold_mm2=best)))
        after = _accuracy(again, [replay(r, classifier, min_intensity or 0.0, 1.0, first_finger) for r in again], held)[
            0
        ]
        f_shipped, f_fitted = _resting_f1(records, held, rest.centroid_threshold_mm2), _resting_f1(records, held, best)
        kept = after > current + MIN_GAIN and f_fitted > f_shipped
        checks.append(
            Check(
                "resting.centroid_threshold_mm2",
                f"gesture type accuracy (resting F1 of the frames {_percent(f_shipped)} -> {_percent(f_fitted)})",
                current,
                after,
                kept,
                f"{best:g}",
            )
        )
        if kept:
            resting, current, records = best, after, again
    # the intensity scale
    num = den = 0.0
    for r in records:
        m = (r.label >= 0) & (r.gesture >= 0) & np.isin(r.prompt, list(fit_part))
        num += float(np.sum(r.intensity_mm[m] * r.label_intensity_mm[m]))
        den += float(np.sum(r.intensity_mm[m] ** 2))
    gain = None
    if den > 0 and math.isfinite(num / den) and num > 0:
        fitted_gain = round(num / den, 4)
        if out_of_range("gesture.intensity_gain", fitted_gain) is not None:
            low, high = SETTING_RANGES["gesture.intensity_gain"]
            raise DatasetError(
                f"the labels' intensities are {fitted_gain:.4g} times what the gel measures, outside the {low:g} to "
                f"{high:g} a gel can be: are they in another unit? intensity_mm is in millimetres (docs/dataset.md)"
            )
        if fitted_gain != 1.0:
            mae_shipped, _ = _mae(records, held, 1.0)
            mae_fitted, _ = _mae(records, held, fitted_gain)
            with_gain = _accuracy(
                records, [replay(r, classifier, min_intensity or 0.0, fitted_gain, first_finger) for r in records], held
            )[0]
            kept = mae_fitted < (1.0 - MIN_MAE_GAIN) * mae_shipped and with_gain >= current
            checks.append(
                Check(
                    "gesture.intensity_gain",
                    "intensity MAE mm",
                    mae_shipped,
                    mae_fitted,
                    kept,
                    f"{fitted_gain:g}",
                    False,
                )
            )
            if kept:
                gain, current = fitted_gain, with_gain
    settings: dict[str, float] = {}
    if min_intensity is not None:
        settings["gesture.min_intensity_mm"] = float(min_intensity)
    if first_finger != FIRST_FINGER_US:
        settings["episode.first_finger_us"] = float(first_finger)
    if resting is not None:
        settings["resting.centroid_threshold_mm2"] = float(resting)
    if gain is not None:
        settings["gesture.intensity_gain"] = float(gain)
    model = Model(
        settings,
        None
        if classifier is None
        else {
            "mean": classifier.mean.tolist(),
            "scale": classifier.scale.tolist(),
            "weights": classifier.weights.tolist(),
            "intercept": classifier.intercept.tolist(),
        },
    )
    return Adaptation(model, checks, len(held), len(every), windows, before, current, missing=missing)


#: What each fitted setting means to the player, and what its value is in their words.
_FOR_PLAYERS: dict[str, tuple[str, Callable[[str], str]]] = {
    "classifier": ("which gesture it reads from how your gel moves", lambda v: "refitted to your hand"),
    "gesture.min_intensity_mm": ("how firm a touch must be to count", lambda v: f"{float(v):g} mm"),
    "episode.first_finger_us": (
        "how long it waits for your second finger before it answers",
        lambda v: f"{float(v) / 1000:g} ms",
    ),
    "resting.centroid_threshold_mm2": (
        "when the gel counts as let go",
        lambda v: f"{float(v):g} mm^2 of marker motion",
    ),
    "gesture.intensity_gain": ("how strong your gestures read (sticks, triggers)", lambda v: f"x{float(v):g}"),
}


def summary(adaptation: Adaptation) -> list[str]:
    """The report for players, one line each: what was tried, in their words, and whether it
    changes anything for them (and why a small held-out gain is not taken); then what changed
    and how many of their held-out gestures are read right before and after. The settings'
    names (docs/method.md, "Adaptation") close each line in brackets."""
    a = adaptation
    lines = [
        f"checked on {a.held_out} of your {a.gestures} gestures ({a.windows} windows) that the fit never saw "
        "(every third of each type): a change is taken only where it reads those better"
    ]
    if a.note:
        lines.append(a.note)
    if a.missing:
        kinds = " or ".join([", ".join(a.missing[:-1]), a.missing[-1]] if len(a.missing) > 1 else a.missing)
        worse = "" if a.note else ", and what changes may read them worse"
        lines.append(f"your enrolment has no {kinds} gesture: nothing is checked on them{worse}")
    for c in a.checks:
        words, value = _FOR_PLAYERS.get(c.what, (c.what, str))
        pct = "%" in c.metric or "accuracy" in c.metric or "F1" in c.metric
        fmt = _percent if pct else (lambda v: f"{v:.3f} mm")
        measured = f"{'read right' if pct else 'strength off by'} {fmt(c.shipped)} -> {fmt(c.fitted)}"
        better = (c.fitted > c.shipped) == c.higher_is_better and c.fitted != c.shipped
        small = c.fitted - c.shipped <= MIN_GAIN if pct else c.fitted >= (1.0 - MIN_MAE_GAIN) * c.shipped
        if c.kept:
            verdict = f"changed to {value(c.value)}: {measured} of your unseen gestures"
        elif better and small:
            limit = f"{100 * MIN_GAIN:g} points" if pct else f"{100 * MIN_MAE_GAIN:g} %"
            verdict = (
                f"left as shipped: {measured} of your unseen gestures with {value(c.value)}, a gain under "
                f"{limit}, which another choice of unseen gestures could undo; not worth changing how it feels"
            )
        elif better:
            verdict = (
                f"left as shipped: with {value(c.value)} {measured} of your unseen gestures, but it did worse "
                "on another thing checked (in brackets)"
            )
        else:
            verdict = f"left as shipped: {value(c.value)} did no better ({measured} of your unseen gestures)"
        lines.append(f"{words}: {verdict} [{c.what}, {c.metric}]")
    changes = a.model.changes()
    if changes:
        lines.append(
            "what changes for you: "
            + "; ".join(_FOR_PLAYERS.get(k, (k,))[0] for k in _changed(a.model))
            + f" [{'; '.join(changes)}]"
        )
    elif a.note:
        lines.append("what changes for you: nothing, too few gestures to check a change on")
    else:
        lines.append("what changes for you: nothing, the shipped recogniser already reads your hand as well")
    before, after = _percent(a.accuracy_before), _percent(a.accuracy_after)
    lines.append(f"your unseen gestures read right: shipped {before} -> adapted {after} of their windows")
    return lines


def _changed(model) -> list[str]:
    """The :data:`_FOR_PLAYERS` keys a model changes, in its order."""
    return [*model.settings, *(["classifier"] if model.classifier is not None else [])]


def _percent(share: float) -> str:
    """A share as ``12.34 %``; ``-`` when there was nothing to count (NaN: no held-out window)."""
    return f"{100 * share:.2f} %" if math.isfinite(share) else "- (no held-out window)"


def fitted_info(adaptation: Adaptation, datasets: Sequence[str | Path]) -> dict:
    """The model file's ``fitted`` mapping: sources and the held-out check (plain values)."""
    return {
        "from": [str(Path(d).resolve()) for d in datasets],
        "held_out_gestures": int(adaptation.held_out),
        "gestures": int(adaptation.gestures),
        "held_out_accuracy_shipped": round(float(adaptation.accuracy_before), 4),
        "held_out_accuracy_adapted": round(float(adaptation.accuracy_after), 4),
    }


#: The camera name the simulated gel writes into its recordings (``enrol --source sim``,
#: ``simulate``, ``record --source sim``): ``NeuroTouch-sim_DAVIS346``.
SIMULATED_CAMERA_PREFIX = "NeuroTouch-sim"


def simulated_sequences(datasets: Sequence[str | Path]) -> list[str]:
    """The sequences (``DATASET/NAME``) of ``datasets`` recorded from the simulated camera (their
    AEDAT4 header's camera name starts with :data:`SIMULATED_CAMERA_PREFIX`). Reads only the
    headers. Raises what ``dataset.list_sequences`` and the recording reader raise."""
    from neurotouch_hid.core.dataset import list_sequences
    from neurotouch_hid.sources.recording import RecordingReader

    found = []
    for d in datasets:
        for name in list_sequences(d):
            with RecordingReader(Path(d) / f"{name}.aedat4") as reader:
                if reader.camera_name.startswith(SIMULATED_CAMERA_PREFIX):
                    found.append(f"{d}/{name}")
    return found


def check_output(out: str | Path, datasets: Sequence[str | Path]) -> Path:
    """``out`` if writing there destroys no input: not a folder, not a file of an enrolment
    dataset. Raises NeurotouchError naming the clash."""
    from neurotouch_hid.core.atomic import check_output as outside_checks

    out = Path(out).expanduser()
    if str(out) == "-":  # standard output
        return out
    # a symbolic link is never written through; a folder, or an existing file of a dataset, never replaced
    return outside_checks(out, datasets, what="model")
