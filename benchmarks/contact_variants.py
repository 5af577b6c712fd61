"""Variants of the contacts stage's candidate maxima, compared on the development families.

    python3 benchmarks/contact_variants.py replay --out DIR --variant NAME [--families ...]
    python3 benchmarks/contact_variants.py family --out DIR --variant NAME --data SRC [--families ...]

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
* ``product``: the product's own (``union_floor`` with the gesture step's minimum intensity).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import typer

sys.path.insert(0, str(Path(__file__).parent))

import contact_replay  # noqa: E402

from neurotouch_hid.pipeline import contacts as C  # noqa: E402
from neurotouch_hid.pipeline.contacts_plateau import _despiked  # noqa: E402

PRODUCT = C._maxima


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


VARIANTS = {
    "outliers": _outliers,
    "union": _union_floor(0.0),
    "union_strong": _union_strong,
    "union_floor03": _union_floor(0.3),
    "union_floor06": _union_floor(0.6),
    "union_floor1": _union_floor(1.0),
    "product": PRODUCT,
}

app = typer.Typer(add_completion=False)


def _use(variant: str) -> None:
    C._maxima = VARIANTS[variant]


@app.command()
def replay(
    out: Path = typer.Option(...),
    variant: str = typer.Option(...),
    families: str = typer.Option("default,fingers,strong,powerlaw,camera"),
) -> None:
    _use(variant)
    contact_replay.VARIANTS[variant] = contact_replay.VARIANTS["current"]
    contact_replay.score(out=out, families=families, variant=variant)


@app.command()
def family(
    out: Path = typer.Option(...),
    variant: str = typer.Option(...),
    data: Path = typer.Option(..., help="a family_eval.py folder whose datasets are linked in"),
    families: str = typer.Option("default,fingers,strong,powerlaw,camera"),
    sessions: bool = typer.Option(False, "--sessions", help="SRC holds family_eval.py --sessions datasets"),
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
        users="0,3",
        seconds=4.0,
        seed=2,
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
