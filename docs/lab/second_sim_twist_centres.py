"""About which centres the second simulator's session_c twist_cw (three fingers ~15 mm apart, 1.25 mm
at its peak) is read as a twist (docs/accuracy.md, "A second simulator's sessions").

    python3 docs/lab/second_sim_twist_centres.py [--data ../shared/data/second-simulator]

The session is run once through the product's pipeline, keeping each window's fit inputs (rest and
tracked positions, the gel's motion in its mount), its contact step's two sets of centres (the
field's maxima, ``Contacts.peaks_px``, and the bump fit's fingers, ``Contacts.points_px``) and its
answer. The type of every window is then read again about four sets of centres: the maxima, the
fitted fingers, the product's choice between them (docs/method.md, "Gesture": the fingers where
each lies inside its maximum, from 0.4 mm), and the labelled contact points. The intensity stays
the pipeline's (about the maxima) and so does the contact count; each set's types go through the product's episode vote
(``EpisodeVote``) as the pipeline's own did (the first row replays the pipeline as it ran before the
type was read about the fitted fingers). Per set: the windows of each type from the twist's first
labelled frame to one APS frame period after its last, those answered another type at or above the
0.8 mm dead zone (felt wrong, docs/dataset.md), the median offset (px) of the centre nearest each
labelled finger over the hold (100 ms in from either end), outward from the labelled fingers' mean
and along the turn (image frame, (u_y, -u_x) of the outward u: the way this twist turns), and the
median contact features of the learned type (``learned.FEATURES``: contact_radial,
contact_tangential, user frame) over the hold. The replay feeds the vote no creep filter or
override, so its count can differ from the pipeline's own by a window or two (printed last).
"""

from __future__ import annotations

import sys
from collections import Counter
from pathlib import Path

import numpy as np

import neurotouch_hid.pipeline.fit_path as product
from neurotouch_hid.core.dataset import labels_at, read_labels
from neurotouch_hid.core.estimate import GestureType
from neurotouch_hid.core.sensor import SensorGeometry
from neurotouch_hid.evaluation.felt import DEFAULT_DEADZONE_MM, FRAME_PERIOD_US
from neurotouch_hid.pipeline.contacts_bump import maxima_pushed_out
from neurotouch_hid.pipeline.episode import PROVISIONAL_MM, EpisodeVote
from neurotouch_hid.pipeline.gesture import estimate_gesture
from neurotouch_hid.pipeline.learned import gesture_features, learned_gesture
from neurotouch_hid.pipeline.pipeline import GesturePipeline
from neurotouch_hid.sources.recording import RecordingReader


def capture(data: Path) -> tuple[GesturePipeline, list, list]:
    """The pipeline, its fits (dicts of the inputs and centres) and its estimates, each with the
    number of fits made before it."""
    pipeline = GesturePipeline(SensorGeometry.load(data / "sensor.yaml"))
    fits: list[dict] = []
    motion: dict = {}
    real_estimate, real_fit = product.estimate_gesture, pipeline._fit

    def estimate(*args, **kwargs):
        motion["now"] = kwargs.get("gel_motion")
        return real_estimate(*args, **kwargs)

    def fit(rest_px, current, valid, held=None):
        contacts, result = real_fit(rest_px, current, valid, held)
        fits.append(
            dict(
                rest=rest_px,
                current=current.copy(),
                valid=valid.copy(),
                motion=motion["now"],
                maxima=np.array(contacts.peaks_px),
                fingers=np.array(contacts.points_px),
            )
        )
        return contacts, result

    product.estimate_gesture, pipeline._fit = estimate, fit
    try:
        with RecordingReader(data / "session_c.aedat4") as reader:
            estimates = [(e, len(fits)) for e in pipeline.run(reader.stream())]
    finally:
        product.estimate_gesture = real_estimate
    return pipeline, fits, estimates


def read_type(pipeline: GesturePipeline, fit: dict, centres: np.ndarray) -> tuple[GestureType, np.ndarray | None]:
    """The window's type read about ``centres`` (A and the intensity's ``none`` about the maxima),
    and the learned type's features."""
    c = pipeline.config
    result = estimate_gesture(
        fit["rest"],
        fit["current"],
        fit["valid"],
        fit["maxima"],
        pipeline.sensor,
        r_px=c.r_px,
        reproj_factor=c.gesture_reproj_factor,
        min_reproj_px=c.min_gesture_reproj_px,
        min_intensity_px=c.min_intensity_px,
        intensity_sigma_px=c.intensity_sigma_px,
        origin_radius_px=c.origin_radius_px,
        gel_motion=fit["motion"],
        type_centres_px=centres,
    )
    if result.gesture is GestureType.NONE:
        return result.gesture, None
    features = gesture_features(
        result, centres, fit["rest"], fit["current"], fit["valid"], pipeline.sensor, c.r_px, c.origin_radius_px
    )
    return learned_gesture(features, c.classifier), features


def main(data: Path) -> None:
    labels = read_labels(data / "session_c.labels.csv")
    twist = [r for r in labels if r.gesture is GestureType.TWIST_CW]
    t0, t1 = twist[0].t_us, twist[-1].t_us
    pipeline, fits, estimates = capture(data)

    def labelled(fit: dict, t_us: int) -> np.ndarray:
        row = labels_at(labels, np.array([t_us]))[0]
        return np.asarray(row.contacts_px[: row.n_contacts], dtype=float) if row.n_contacts else fit["maxima"]

    def product_rule(fit: dict, t_us: int) -> np.ndarray:  # GesturePipeline._fit's choice
        intensity = next(e.intensity_mm for e, _ in estimates if e.t_us == t_us)
        pushed_out = maxima_pushed_out(fit["maxima"], fit["fingers"])
        return fit["fingers"] if pushed_out and intensity >= PROVISIONAL_MM else fit["maxima"]

    sets = {
        "the field's maxima (before)": lambda fit, t: fit["maxima"],
        "the bump fit's fingers, every window": lambda fit, t: fit["fingers"],
        "the fingers where inside their maxima, from 0.4 mm (now)": product_rule,
        "the labelled contacts": labelled,
    }
    print(
        "| centres | window types | felt wrong windows | centre - finger, outward / along the turn, median px "
        "| contact radial / tangential |"
    )
    print("| --- | --- | ---: | ---: | --- |")
    for name, centres_of in sets.items():
        vote, types, wrong, offsets, features = EpisodeVote(), Counter(), 0, [], []
        for estimate, n_fits in estimates:
            t = estimate.t_us
            if n_fits == 0 or (estimate.gesture is GestureType.NONE and estimate.intensity_mm == 0):
                vote.update(GestureType.NONE, 0.0, 0, t)
                continue
            fit = fits[n_fits - 1]
            centres = centres_of(fit, t)
            kind, f = read_type(pipeline, fit, centres)
            answer = vote.update(kind, estimate.intensity_mm, estimate.n_contacts, t)
            if t0 <= t < t1 + FRAME_PERIOD_US:
                types[kind.value] += 1
                wrong += answer not in (GestureType.NONE, GestureType.TWIST_CW) and (
                    estimate.intensity_mm >= DEFAULT_DEADZONE_MM
                )
            if t0 + 100_000 <= t <= t1 - 100_000 and len(centres):
                fingers = labelled(fit, t)
                for finger in fingers:
                    off = centres[np.argmin(np.linalg.norm(centres - finger, axis=1))] - finger
                    out = (finger - fingers.mean(axis=0)) / np.linalg.norm(finger - fingers.mean(axis=0))
                    offsets.append((off @ out, off[0] * out[1] - off[1] * out[0]))
                if f is not None and len(centres) >= 2:
                    features.append(f[5:7])
        radial, tangential = np.median(np.array(features), axis=0)
        print(
            f"| {name} | {', '.join(f'{k} {v}' for k, v in types.most_common())} | {wrong} | "
            f"{np.median(np.array(offsets)[:, 0]):+.1f} / {np.median(np.array(offsets)[:, 1]):+.1f} | "
            f"{radial:+.2f} / {tangential:+.2f} |"
        )
    said = [e for e, _ in estimates if t0 <= e.t_us < t1 + FRAME_PERIOD_US]
    wrong = [e for e in said if e.gesture not in (GestureType.NONE, GestureType.TWIST_CW)]
    felt = [e for e in wrong if e.intensity_mm >= DEFAULT_DEADZONE_MM]
    print(
        f"\nThe pipeline as it runs (its own vote, creep filter and overrides): {len(felt)} felt wrong windows, "
        f"at {', '.join(f'{(e.t_us - t0) / 1000:.0f}' for e in felt)} ms after the first labelled frame."
    )


if __name__ == "__main__":
    args = sys.argv[1:]
    main(Path(args[args.index("--data") + 1]) if "--data" in args else Path("../shared/data/second-simulator"))
