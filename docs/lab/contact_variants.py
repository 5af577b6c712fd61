"""Variants of the contacts stage's candidate maxima, compared on the development families.

    python3 docs/lab/contact_variants.py replay --out DIR --variant NAME [--families ...]
    python3 docs/lab/contact_variants.py family --out DIR --variant NAME --data SRC [--families ...]

``replay`` scores a variant on ``contact_replay.py record``'s windows (contact count per type);
``family`` runs ``family_eval.py`` with the variant in place of the product's maxima, in
``DIR/NAME`` with the datasets of ``SRC`` linked in (``--sessions``: game sessions; ``--jobs 1``:
the variant is patched into this process). Figures only.

Variants (the maxima step after RANSAC, ``contacts._maxima``; ``t`` the dynamic threshold
a * mean ||v||, r the neighbourhood radius):

* ``outliers``: the candidates are RANSAC's outliers (the rest model when they give none);
* ``union``: the candidates are the outliers and every marker with ||v|| > t;
* ``union_floor03`` / ``06`` / ``1``: the outliers and every marker with ||v|| > max(t, 0.3 /
  0.6 / 1 px) (when they give no contact, as ``outliers``);
* ``union_strong``: the outliers' maxima, plus the union's maxima above 2.5 t farther than 1.6 r
  from all of them;
* ``residual05`` / ``07``: the outliers' maxima (as ``outliers``), the outliers being the
  markers the homography maps farther than 0.5 / 0.7 t from where they are (or that USAC rejects);
* ``union_outlier_peaks`` (``0``, ``03``): as ``union_floor06`` (floor 0, 0.3 px), but only the
  maxima that are outliers are kept; ``union_share03`` / ``025``: the others too when their ||v||
  is at least 0.3 / 0.25 of the strongest maximum's;
* ``plateau_shape`` / ``plateau_shape3``: the product's maxima, and a flat top at least
  floor(L / W) fingers (L / W its elongation, round fingertips side by side) / 3 fingers when
  L / W >= 3, beside its area's count (``contacts_plateau.plateau_contacts``);
* ``plateau_uncapped``: flat tops by their area only (a finger per pi r^2), with no cap of 3
  contacts a window;
* ``plateau_no_row``: flat tops by their area only (a finger per pi r^2), with the cap (no
  three-in-a-row rule);
* ``plateau_round115`` / ``plateau_round15``: the product's, and a flat top whose elongation is
  below 1.15 / 1.5 is one finger (a deep fingertip's round footprint); ``plateau_round105_two``:
  the same below 1.05, only where the flat top's area reads two fingers;
* ``plateau_footprint1`` / ``15`` / ``2``: the product's, with a finger per 1 / 1.5 / 2 pi r^2
  of a flat top's area (the product: ``contacts_plateau.FOOTPRINTS_PER_FINGER``);
* ``plateau_any_height``: the product's, but a weaker maximum's flat top may hold markers
  displaced more than its maximum (a stronger finger's slope); ``plateau_below_own_top``: the
  strongest maximum's may not either;
* ``plateau_round_by_area``: the product's, but a round flat top whose area reads two fingers
  is read by its area whatever the press showed before (``long_before`` always True);
  ``plateau_round105_two_unless_seen``: instead of the product's long flat top, a press keeps two
  for a round flat top when it showed two contacts before its first flat top of two fingers;
* ``no_missed_finger``: the product's, without the finger the bumps find where the maxima missed
  it (``contacts_bump.with_missed_finger``: the bump fit alone);
* ``product``: the product's own (``union_outlier_peaks`` with ``ContactsConfig.min_move_mm``).
"""

from __future__ import annotations

import math
import sys
from pathlib import Path

import cv2
import numpy as np
import typer

sys.path.insert(0, str(Path(__file__).parent))

import contact_replay  # noqa: E402

from neurotouch_hid.pipeline import contacts as C  # noqa: E402
from neurotouch_hid.pipeline import fit_path as F  # noqa: E402
from neurotouch_hid.pipeline import pipeline as P  # noqa: E402
from neurotouch_hid.pipeline.contacts_bump import bump_fit  # noqa: E402
from neurotouch_hid.pipeline.contacts_plateau import (  # noqa: E402
    FOOTPRINTS_PER_FINGER,
    MAX_FINGERS,
    PLATEAU_MARKERS,
    ROW_ELONGATION,
    _despiked,
    _elongation,
    _plateau,
    _split_along_axis,
    at_most_three,
)
from neurotouch_hid.views.console import command_app  # noqa: E402

PRODUCT = C._maxima


def _holding_nothing(variant):
    """A variant below (written before a press held its fingers' peaks) as ``contacts._maxima`` is
    called today: ``held`` (the last argument) ignored, each maximum held at its own ||v||."""

    def maxima(*args):
        peaks, magnitudes = variant(*args[:-1])
        return peaks, magnitudes[peaks], magnitudes

    return maxima


def _outliers(rest, magnitudes, outliers, table, spike_fraction, r2, n_min, threshold, min_move=0.0):
    """The candidates are RANSAC's outliers; the rest model when they give no contact."""
    magnitudes = _despiked(table, magnitudes, spike_fraction)
    chosen = np.flatnonzero(outliers)
    peaks = chosen[C._local_maxima(rest[chosen], magnitudes[chosen], r2, n_min)]
    if len(peaks) == 0:
        moved = np.flatnonzero(magnitudes > threshold)
        peaks = moved[C._local_maxima(rest[moved], magnitudes[moved], r2, n_min)]
    return peaks, magnitudes


def _union_floor(floor):
    """The outliers and the markers moved more than max(t, floor) px; else as ``outliers``."""

    def variant(rest, magnitudes, outliers, table, spike_fraction, r2, n_min, threshold, min_move=0.0):
        despiked = _despiked(table, magnitudes, spike_fraction)
        chosen = np.flatnonzero(outliers | (despiked > max(threshold, floor)))
        peaks = chosen[C._local_maxima(rest[chosen], despiked[chosen], r2, n_min)]
        if len(peaks) == 0:
            return _outliers(rest, magnitudes, outliers, table, spike_fraction, r2, n_min, threshold)
        return peaks, despiked

    return variant


def _union_kept(floor, share):
    """As ``union_floor`` (floor px), but a maximum that is no outlier is kept only when its
    ||v|| is at least ``share`` of the strongest maximum's (share > 1: never)."""

    def variant(rest, magnitudes, outliers, table, spike_fraction, r2, n_min, threshold, min_move=0.0):
        despiked = _despiked(table, magnitudes, spike_fraction)
        chosen = np.flatnonzero(outliers | (despiked > max(threshold, floor)))
        peaks = chosen[C._local_maxima(rest[chosen], despiked[chosen], r2, n_min)]
        if len(peaks):
            top = despiked[peaks].max()
            peaks = peaks[outliers[peaks] | (despiked[peaks] >= share * top)]
        if len(peaks) == 0:
            return _outliers(rest, magnitudes, outliers, table, spike_fraction, r2, n_min, threshold)
        return peaks, despiked

    return variant


def _union_strong(rest, magnitudes, outliers, table, spike_fraction, r2, n_min, threshold, min_move=0.0):
    """The outliers' maxima, plus the union's above 2.5 t farther than 1.6 r from all of them."""
    level, far = 2.5, 1.6
    peaks, magnitudes = _outliers(rest, magnitudes, outliers, table, spike_fraction, r2, n_min, threshold)
    if len(peaks) == 0:
        return peaks, magnitudes
    chosen = np.flatnonzero(outliers | (magnitudes > threshold))
    more = chosen[C._local_maxima(rest[chosen], magnitudes[chosen], r2, n_min)]
    extra = [
        p
        for p in more
        if magnitudes[p] > level * threshold and np.min(np.sum((rest[peaks] - rest[p]) ** 2, axis=1)) > far * far * r2
    ]
    if not extra:
        return peaks, magnitudes
    out = np.concatenate([peaks, np.array(extra, dtype=np.int64)])
    return out[np.argsort(-magnitudes[out], kind="mergesort")], magnitudes


ORIGINAL_OUTLIERS = C.homography_outliers


def _residual_outliers(share):
    """``contacts.homography_outliers`` whose outliers also hold the markers the homography maps
    farther than ``share`` of the threshold from where they are (px)."""

    def outliers(rest_px, current_px, reproj_threshold_px, max_iters=2000, method="usac_fast"):
        src = np.ascontiguousarray(rest_px, dtype=np.float32)
        dst = np.ascontiguousarray(current_px, dtype=np.float32)
        h, inliers = cv2.findHomography(
            src, dst, C.HOMOGRAPHY_METHODS[method], float(reproj_threshold_px), maxIters=int(max_iters)
        )
        if h is None or inliers is None:
            return np.ones(len(src), dtype=bool)
        mapped = cv2.perspectiveTransform(src.reshape(-1, 1, 2).astype(np.float64), h).reshape(-1, 2)
        residual = np.linalg.norm(mapped - np.asarray(current_px, dtype=np.float64), axis=1)
        return (inliers.ravel() == 0) | (residual > share * reproj_threshold_px)

    return outliers


#: Variants patched in place of ``contacts.homography_outliers`` (with ``_outliers`` maxima).
RESIDUAL = {"residual05": _residual_outliers(0.5), "residual07": _residual_outliers(0.7)}

VARIANTS = {
    "outliers": _holding_nothing(_outliers),
    "union": _holding_nothing(_union_floor(0.0)),
    "union_strong": _holding_nothing(_union_strong),
    "union_floor03": _holding_nothing(_union_floor(0.3)),
    "union_floor06": _holding_nothing(_union_floor(0.6)),
    "union_floor1": _holding_nothing(_union_floor(1.0)),
    "product": PRODUCT,
    "union_outlier_peaks": _holding_nothing(_union_kept(0.6, 2.0)),
    "union_outlier_peaks0": _holding_nothing(_union_kept(0.0, 2.0)),
    "union_outlier_peaks03": _holding_nothing(_union_kept(0.3, 2.0)),
    "union_share03": _holding_nothing(_union_kept(0.6, 0.3)),
    "union_share025": _holding_nothing(_union_kept(0.6, 0.25)),
}

ORIGINAL_PLATEAUS = C.plateau_contacts


def _area_plateaus(table, current_px, magnitudes, peaks, fraction, pitch_px, finger_radius_px):
    """The product's ``plateau_contacts`` of one window without its press: a round flat top read
    by its area (``long_before`` True); (kept, fingers, points)."""
    return ORIGINAL_PLATEAUS(table, current_px, magnitudes, peaks, fraction, pitch_px, finger_radius_px, True)[:3]


def _one_window(variant):
    """``variant``, a rule of one window's flat tops returning (kept, fingers, points), called as
    ``plateau_contacts`` is: the press's history ignored, no long flat top reported."""
    return lambda *args: (*variant(*args[:7]), False)


def _product_top(magnitude: float, strongest: bool) -> float:
    """How high a marker the product's flat top of a maximum of ``magnitude`` holds: any height for
    the strongest maximum, no higher than the maximum for the others."""
    return np.inf if strongest else magnitude


def _flat_tops(table, magnitudes, peaks, fraction, top=_product_top):
    """(p, mask, level) for each maximum of ``peaks`` not on a stronger one's flat top, as
    ``plateau_contacts`` walks them: its flat top (M,) bool at ``level`` = ``fraction`` of its
    magnitude, no higher than ``top(magnitude, strongest)``."""
    covered = np.zeros(len(magnitudes), dtype=bool)
    for p in peaks:
        if covered[p]:
            continue
        level = fraction * magnitudes[p]
        mask = _plateau(table, magnitudes, p, level, top(magnitudes[p], not covered.any()), covered)
        covered |= mask
        yield p, mask, level


def _plateaus_by_count(table, current_px, magnitudes, peaks, fraction, pitch_px, finger_radius_px, count, top):
    """``plateau_contacts`` with a wide flat top's fingers ``count(size, points, weights)`` and its
    height bound ``top`` (:func:`_flat_tops`)."""
    kept, fingers, points = [], [], []
    for p, mask, level in _flat_tops(table, magnitudes, peaks, fraction, top):
        kept.append(p)
        size = int(mask.sum())
        if size > PLATEAU_MARKERS:
            weights = magnitudes[mask] - level + 1e-9
            n = min(
                MAX_FINGERS,
                max(1, count(size * pitch_px**2 / (math.pi * finger_radius_px**2), current_px[mask], weights)),
            )
            points.append(_split_along_axis(current_px[mask], weights, n))
            fingers.append(n)
        else:
            fingers.append(0)
    pts = np.concatenate(points) if points else np.zeros((0, 2))
    return np.array(kept, dtype=np.int64), np.array(fingers, dtype=np.int64), pts


def _plateaus_by_shape(table, current_px, magnitudes, peaks, fraction, pitch_px, finger_radius_px, least=1.0):
    """``plateau_contacts`` whose wide plateau holds at least floor(L / W) fingers, L / W its
    elongation (round fingertips side by side), beside its area's count (a finger per pi r^2)."""

    def count(footprints, points, weights):
        elongation = _elongation(points, weights)
        return max(math.ceil(footprints), int(elongation) if elongation >= least else 1)

    return _plateaus_by_count(
        table, current_px, magnitudes, peaks, fraction, pitch_px, finger_radius_px, count, _product_top
    )


def _capped(variant):
    """``variant`` with the product's cap (``contacts_plateau.at_most_three``)."""
    return lambda *args: at_most_three(*variant(*args))


def _round_flat_tops(least, most=MAX_FINGERS):
    """The product's ``plateau_contacts`` where a flat top split into 2 to ``most`` fingers whose
    elongation L / W is below ``least`` is one finger (the caller places its contact)."""

    def variant(table, current_px, magnitudes, peaks, fraction, pitch_px, finger_radius_px):
        args = (table, current_px, magnitudes, peaks, fraction, pitch_px, finger_radius_px)
        kept, fingers, points = _area_plateaus(*args)
        groups = np.split(points, np.cumsum(fingers)[:-1]) if len(fingers) else []
        fingers = fingers.copy()
        for k, (_, mask, level) in enumerate(_flat_tops(table, magnitudes, kept, fraction)):
            if 2 <= fingers[k] <= most and _elongation(current_px[mask], magnitudes[mask] - level + 1e-9) < least:
                fingers[k], groups[k] = 0, points[:0]
        pts = np.concatenate(groups) if groups else np.zeros((0, 2))
        return kept, fingers, pts.reshape(-1, 2)

    return variant


def _flat_top_heights(bounded: str):
    """The product's ``plateau_contacts`` with another bound on how high a marker a maximum's flat
    top holds (the product: no higher than its maximum, but for the strongest maximum's):
    ``bounded`` "none", any height (a weaker maximum's flat top may climb a stronger finger's
    slope); "all", no higher than its maximum for the strongest too."""

    def count(footprints, points, weights):
        if _elongation(points, weights) >= ROW_ELONGATION:
            return MAX_FINGERS
        return math.ceil(footprints / FOOTPRINTS_PER_FINGER)

    def top(magnitude, strongest):
        return magnitude if bounded == "all" else np.inf

    def variant(*args):
        return at_most_three(*_plateaus_by_count(*args, count, top))

    return variant


def _footprint(per_finger):
    """The product's ``plateau_contacts`` with a finger per ``per_finger`` pi r^2 of a flat top."""
    scale = math.sqrt(per_finger / FOOTPRINTS_PER_FINGER)
    return lambda *args: _area_plateaus(*args[:6], args[6] * scale)


#: Variants patched in place of ``contacts.plateau_contacts`` (with the product's maxima).
PLATEAUS = {
    "plateau_shape": _plateaus_by_shape,
    "plateau_shape3": lambda *args: _plateaus_by_shape(*args, least=3.0),
    "plateau_uncapped": lambda *args: _plateaus_by_shape(*args, least=math.inf),
    "plateau_no_row": _capped(lambda *args: _plateaus_by_shape(*args, least=math.inf)),
    "plateau_round115": _round_flat_tops(1.15),
    "plateau_round15": _round_flat_tops(1.5),
    "plateau_round105_two": _round_flat_tops(1.05, most=2),
    "plateau_footprint1": _footprint(1.0),
    "plateau_footprint15": _footprint(1.5),
    "plateau_footprint2": _footprint(2.0),
    "plateau_any_height": _flat_top_heights("none"),
    "plateau_below_own_top": _flat_top_heights("all"),
    "plateau_round_by_area": _area_plateaus,
}

ORIGINAL_MISSED = C.with_missed_finger


def _no_missed_finger(rest, v, centres, table, knot, n_knots, r):
    """``contacts_bump.with_missed_finger`` without the missed finger: the bump fit alone."""
    return bump_fit(rest, v, centres, knot, n_knots), -1


#: Variants patched in place of ``contacts.with_missed_finger`` (with the product's maxima).
BUMPS = {"no_missed_finger": _no_missed_finger}

ORIGINAL_DETECT = F.detect_contacts
ORIGINAL_NONE = P.GesturePipeline._none


def _round_unless_seen(least):
    """(detect_contacts, GesturePipeline._none) where ``_round_flat_tops(least, most=2)`` holds
    unless a window of the press showed two contacts or more before its first flat top of two
    fingers or more (in place of the product's long flat top). A press ends at a window without a
    gesture (``_none``). One pipeline at a time (``--jobs 1``)."""
    round_rule = _round_flat_tops(least, most=2)
    press = {"seen": 0, "wide": False}

    def plateaus(*args):
        kept, fingers, points = _area_plateaus(*args[:7])
        wide = len(fingers) and fingers.max() >= 2
        if wide and press["seen"] < 2:
            kept, fingers, points = round_rule(*args[:7])
        press["wide"] = press["wide"] or wide
        return kept, fingers, points, False

    def detect(*args, **kwargs):
        C.plateau_contacts = plateaus
        try:
            contacts = C.detect_contacts(*args, **kwargs)
        finally:
            C.plateau_contacts = ORIGINAL_PLATEAUS
        if not press["wide"]:
            press["seen"] = max(press["seen"], len(contacts.points_px))
        return contacts

    def none(self, t_us, *, resting, fed=False):
        press["seen"], press["wide"] = 0, False
        return ORIGINAL_NONE(self, t_us, resting=resting, fed=fed)

    return detect, none


#: Variants patched in place of ``pipeline.detect_contacts`` and ``GesturePipeline._none``: rules
#: that read the press's earlier windows.
PRESS = {"plateau_round105_two_unless_seen": _round_unless_seen(1.05)}

app = command_app()


def _use(variant: str) -> None:
    C.plateau_contacts = _one_window(PLATEAUS[variant]) if variant in PLATEAUS else ORIGINAL_PLATEAUS
    C.with_missed_finger = BUMPS.get(variant, ORIGINAL_MISSED)
    F.detect_contacts, P.GesturePipeline._none = PRESS.get(variant, (ORIGINAL_DETECT, ORIGINAL_NONE))
    if variant in PLATEAUS or variant in BUMPS or variant in PRESS:
        C.homography_outliers = ORIGINAL_OUTLIERS
        C._maxima = PRODUCT
    elif variant in RESIDUAL:
        C.homography_outliers = RESIDUAL[variant]
        C._maxima = _holding_nothing(_outliers)
    else:
        C.homography_outliers = ORIGINAL_OUTLIERS
        C._maxima = VARIANTS[variant]


@app.command()
def replay(
    out: Path = typer.Option(...),
    variant: str = typer.Option(...),
    families: str = typer.Option("default,fingers,strong,powerlaw,camera"),
) -> None:
    _use(variant)
    contact_replay.VARIANTS.setdefault(variant, contact_replay.VARIANTS["current"])
    contact_replay.score(out=out, families=families, variant=variant)


@app.command()
def family(
    out: Path = typer.Option(...),
    variant: str = typer.Option(...),
    data: Path = typer.Option(..., help="a family_eval.py folder whose datasets are linked in"),
    families: str = typer.Option("default,fingers,strong,powerlaw,camera"),
    sessions: bool = typer.Option(False, "--sessions", help="SRC holds family_eval.py --sessions datasets"),
    users: str = typer.Option("0,3", help="the users of SRC's datasets (5,7: tuning users)"),
    seed: int = typer.Option(2, help="the seed of SRC's datasets (odd: tuning users)"),
) -> None:
    import family_eval

    _use(variant)
    folder = out / variant
    folder.mkdir(parents=True, exist_ok=True)
    names = [f for f in families.split(",") if f]
    for fam in names:
        if not (folder / fam).exists():
            (folder / fam).symlink_to((data / fam).resolve())
    family_eval.main(
        out=folder,
        families=",".join(names),
        users=users,
        seconds=4.0,
        seed=seed,
        jobs=1,
        method=["ours=default"],
        final_run=False,
        rerun=False,
        sessions=sessions,
        deadzone_mm=family_eval.DEFAULT_DEADZONE_MM,
        creep=True,
        vote_of=None,
    )


if __name__ == "__main__":
    app()
