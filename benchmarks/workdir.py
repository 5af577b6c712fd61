"""The families of a ``family_eval.py`` working folder, for the scripts that read one
(``felt_errors.py``, ``resting_errors.py``, ``onset_bound.py``, ``wait_bound.py``, ``profile_felt.py``,
and the lab scripts docs/lab/contact_count.py and type_commitment.py), their lists of numbers, and
their usage errors.

A working folder holds each family's dataset under ``DIR/FAMILY`` (its ``sensor.yaml`` and
sequences) and each method's predictions under ``DIR/predictions/FAMILY/METHOD``
(``family_eval.py``'s module docstring).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import NoReturn

import typer


def families_in(out: Path, names: str = "", method: str | None = None) -> list[str]:
    """The families to read: ``names`` (comma-separated) if given, else every family of ``out``
    with a dataset (and, when ``method`` is given, that method's predictions), sorted.

    Raises:
        typer.Exit: (status 2, after one line on stderr naming the folder and the command that
            fills it) ``out`` is not a folder, a named family has no dataset (or no predictions
            of ``method``) there, or no family qualifies.
    """
    if not out.is_dir():
        usage_error(f"{out}: no such folder (a family_eval.py --out folder)")

    def ready(family: str) -> str | None:
        if not (out / family / "sensor.yaml").is_file():
            make = f"python3 benchmarks/family_eval.py --out {out} --families {family}"
            return f"{out / family}: no dataset (make it with: {make})"
        if method is not None and not (out / "predictions" / family / method).is_dir():
            make = f"python3 benchmarks/family_eval.py --out {out} --families {family} --method {method}=default"
            where = out / "predictions" / family / method
            return f"{where}: no predictions of method {method!r} (make them with: {make})"
        return None

    chosen = [f.strip() for f in names.split(",") if f.strip()]
    if chosen:
        for family in chosen:
            problem = ready(family)
            if problem is not None:
                usage_error(problem)
        return chosen
    found = sorted(p.name for p in out.iterdir() if p.is_dir() and ready(p.name) is None)
    if not found:
        what = "datasets" if method is None else f"datasets with predictions of method {method!r}"
        usage_error(f"{out}: no family {what} (run benchmarks/family_eval.py --out {out} first)")
    return found


def numbers(text: str, option: str, finite: bool = False) -> list[float]:
    """The comma-separated numbers of option ``option``, each >= 0 (``inf`` too unless ``finite``).

    Raises:
        typer.Exit: (a usage error naming the option and the value) one is not such a number.
    """
    values = []
    for item in text.split(","):
        try:
            value = float(item)
        except ValueError:
            value = float("nan")
        if not value >= 0 or (finite and math.isinf(value)):
            kind = "finite numbers" if finite else "numbers"
            usage_error(f"{option}: expected comma-separated {kind} >= 0, got {item.strip()!r}")
        values.append(value)
    return values


def usage_error(message: str) -> NoReturn:
    """``error: MESSAGE``: one line on stderr, unwrapped (a pipe or a log gets it whole), then exit status 2."""
    typer.echo(f"error: {message}", err=True)
    raise typer.Exit(2)
