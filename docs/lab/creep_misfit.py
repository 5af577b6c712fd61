"""How much of an elastic gel's misfit the best creep model leaves, on each family's press and on
creeping presses made from one (docs/method.md, "Creep": only a creep that explains the press).

    python3 docs/lab/creep_misfit.py --out DIR [--families default,stickslip,viscoelastic]

``DIR`` is a ``benchmarks/family_eval.py`` folder: ``DIR/presses/FAMILY`` the press each family's
creep is calibrated on (tuning user 5's push, with its sensor.yaml and the simulator's true markers).
Per family, on the tracked amplitude (what ``calibrate --press`` fits,
``calibration.press_amplitude``) and on the true markers' (the same mean of the 10 largest
displacements, every 10 ms): the best (q, tau) of the grid and its misfit as a share of the elastic
gel's (``creep.creep_misfit``), and whether ``creep.fit_creep`` keeps it. Then the first
family's true amplitude, as a load, through the simulator's standard linear solid
(``physics.sls_deformation``) for a few (q, tau), alone and with the tracker's error on that press
(tracked minus true) added. Markdown rows.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import typer

from neurotouch_hid.calibration.measure import PRESS_MARKERS, press_amplitude
from neurotouch_hid.core.sensor import SensorGeometry
from neurotouch_hid.pipeline.creep import SHARES, TIMES_S, creep_misfit, fit_creep
from neurotouch_hid.sources.physics import sls_deformation
from neurotouch_hid.views.console import command_app

#: The press family_eval.py simulates for each family (its PRESS_USER).
PRESS = "u5_push"
#: Creeps made from the first family's press: (q, tau s).
MADE = ((0.05, 0.1), (0.1, 0.1), (0.15, 0.1), (0.05, 0.3), (0.1, 0.3), (0.05, 1.0), (0.1, 1.0), (0.3, 0.3))


def best(t_us: np.ndarray, amplitude: np.ndarray) -> str:
    """'q Q, tau T s, S of the elastic misfit' for the least misfit of the grid."""
    cost = creep_misfit(t_us, amplitude)
    i, j = np.unravel_index(np.argmin(cost), cost.shape)
    share = cost[i, j] / cost[0, 0] if cost[0, 0] > 0 else 1.0
    kept = "none" if fit_creep(t_us, amplitude) is None else "kept"
    return f"q {SHARES[i]:.2f}, tau {TIMES_S[j]:.2f} s: {share:.2f} ({kept})"


def true_amplitude(folder: Path) -> tuple[np.ndarray, np.ndarray]:
    """(t_us, amplitude px) of the simulator's true markers, every 10 ms (a window)."""
    markers = np.load(folder / f"{PRESS}.markers.npz")
    moved = np.hypot(*(markers["positions_px"] - markers["rest_px"]).transpose(2, 0, 1))
    amplitude = np.sort(moved, axis=1)[:, -PRESS_MARKERS:].mean(axis=1)
    t = markers["t_us"]
    every = np.searchsorted(t, np.arange(t[0], t[-1] + 1, 10_000))
    return t[every], amplitude[every]


def main(
    out: Path = typer.Option(..., "--out", help="a benchmarks/family_eval.py folder"),
    families: str = typer.Option("", "--families", help="comma-separated; default: every family with a press"),
) -> None:
    presses = out / "presses"
    names = [f for f in families.split(",") if f] or sorted(
        p.name for p in presses.glob("*") if (p / f"{PRESS}.aedat4").exists()
    )
    missing = [f for f in names if not (presses / f / f"{PRESS}.aedat4").exists()]
    if not names or missing:
        what = f"{', '.join(missing)}: no press" if missing else "no family presses"
        typer.echo(f"{presses}: {what} (benchmarks/family_eval.py --out {out} simulates them)", err=True)
        raise typer.Exit(2)
    print("| family | tracked (what calibrate --press fits) | true markers |")
    print("| --- | --- | --- |")
    first = None
    for family in names:
        folder = presses / family
        t, tracked = press_amplitude(folder / f"{PRESS}.aedat4", SensorGeometry.load(folder / "sensor.yaml"))
        t_true, true = true_amplitude(folder)
        print(f"| {family} | {best(t, tracked)} | {best(t_true, true)} |", flush=True)
        if first is None:
            first = (family, t_true, true, np.interp(t_true, t, tracked) - true)
    family, t, load, error = first
    print(f"\n| {family}'s press crept: q, tau | alone | with the tracker's error |")
    print("| --- | --- | --- |")
    for share, time_s in MADE:
        crept = sls_deformation(load, 10_000.0, share, time_s * 1e6)
        print(f"| {share:g}, {time_s:g} s | {best(t, crept)} | {best(t, crept + error)} |", flush=True)


if __name__ == "__main__":
    app = command_app()
    app.command()(main)
    app()
