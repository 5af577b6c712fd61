"""What every command module of the CLI shares: the consoles, the option checks, the start-up
block of long-running commands, and the live camera's settings from the command line."""

from __future__ import annotations

import contextlib
import gc
import math
from collections.abc import Iterator
from typing import Optional

import typer

from neurotouch_hid.core.errors import NeurotouchError
from neurotouch_hid.views.console import make_console


def _closed_streams_to_null() -> None:
    """A standard stream the caller closed (``cmd >&-``: Python's ``sys.stdout`` is None) becomes
    /dev/null, its file descriptor too, so that the consoles and typer start, what would have
    been printed is dropped, and no file a command opens later takes descriptor 1 or 2 (a library
    writing there would write into it)."""
    import os
    import sys

    for fd, name, mode in ((0, "stdin", "r"), (1, "stdout", "w"), (2, "stderr", "w")):
        if getattr(sys, name) is None:
            null = os.open(os.devnull, os.O_RDWR)
            if null != fd:
                os.dup2(null, fd)
                os.close(null)
            setattr(sys, name, open(fd, mode, encoding="utf-8", closefd=False))  # noqa: SIM115


_closed_streams_to_null()
console = make_console()
err_console = make_console(stderr=True)


def to_stdout(out: object) -> bool:
    """Whether an output option is standard output: ``-``, or another name of the file open there
    (``/dev/stdout``, ``/dev/fd/1``); the command's human lines then go to stderr
    (:func:`human_console`), so that standard output holds its result only."""
    import os

    if out is None:
        return False
    if str(out) == "-":
        return True
    try:
        here, there = os.fstat(1), os.stat(out)  # type: ignore[arg-type]
    except (OSError, TypeError, ValueError):
        return False
    return (here.st_dev, here.st_ino) == (there.st_dev, there.st_ino)


def no_stdout(flag: str, out: object, what: str) -> None:
    """Refuse ``-`` for an output that cannot be standard output (``what`` says why: a folder, a
    binary file another command reads), before any work; a file named ``-`` was written instead.

    Raises:
        NeurotouchError: ``out`` is ``-``.
    """
    if out is not None and str(out) == "-":
        raise NeurotouchError(f"{flag} -: {what}, not standard output; give a path")


def human_console(*outs: object):
    """The console for a command's human lines: stderr when one of ``outs`` is standard output
    (:func:`to_stdout`; it holds the result, exactly), else stdout."""
    return err_console if any(to_stdout(out) for out in outs) else console


def say_err(line: str) -> None:
    """One line for the user on stderr, exactly as given: no markup, no highlighting, never
    wrapped (a pipe or a file gets the whole line)."""
    err_console.print(line, markup=False, highlight=False, soft_wrap=True)


def finite(value: Optional[float]) -> Optional[float]:
    """Every float option: ``nan`` and ``inf`` are usage errors (exit 2, the option named), not a
    traceback later on."""
    if value is not None and not math.isfinite(value):
        raise typer.BadParameter(f"expected a finite number, got {value}")
    return value


def duration(value: Optional[float]) -> Optional[float]:
    """``--seconds``: a finite, positive duration (0 or less ran nothing and said nothing)."""
    if value is not None and not (math.isfinite(value) and value > 0):
        raise typer.BadParameter(f"expected a positive duration (seconds), got {value}")
    return value


@contextlib.contextmanager
def long_lived_start_up() -> Iterator[None]:
    """A command's start-up: what is made inside (imports, numba's loaded code: ~130 k objects
    for ``track``) lives as long as the process. The garbage collector is off meanwhile and
    those objects are frozen at the end (``gc.freeze``), so that none of its passes walks them
    again: its full passes over them were ~0.5 s of CPU of a 40 s ``track`` (docs/performance.md,
    "track"). Cyclic garbage made inside is never freed: keep the block to
    imports and set-up."""
    enabled = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        gc.freeze()
        if enabled:
            gc.enable()


#: ``--model``, one definition for every command that runs the pipeline (run, track, eval, profile
#: test; the service runs ``run``): the adapted model (``enrolment/model.py``).
MODEL_OPTION = typer.Option(
    None,
    "--model",
    metavar="PATH|none",
    help="adapted model written by `neurotouch-hid adapt` (a model.yaml), or none for the shipped method; "
    "default: your model.yaml (beside sensor.yaml) when there is one",
)


def chosen_model(option: Optional[str]):
    """The model ``--model`` picks (``enrolment.model.resolve_model``: None for the shipped
    method), said on stderr when it is an adapted one. Raises ModelError for a bad file."""
    from neurotouch_hid.enrolment.model import describe, resolve_model

    model = resolve_model(option)
    if model is not None:
        err_console.print(f"model: {describe(model)}", highlight=False, soft_wrap=True, markup=False)
    return model


#: ``--method``'s help (track, eval, run).
METHOD_HELP = "the gesture pipeline: default (the product's) or paper (the paper's method exactly)"


def _not_a_method(value: Optional[str]) -> None:
    """``--preset`` on track and eval: it is simulate's option, not the pipeline's (exit 2)."""
    if value is not None:
        raise typer.BadParameter(
            f"--preset is simulate's dataset size; the pipeline is chosen with --method (--method {value})"
        )


#: A hidden ``--preset`` on the pipeline's commands that says to use ``--method``.
PRESET_IS_NOT_A_METHOD = typer.Option(None, "--preset", hidden=True, callback=_not_a_method)


def davis_config(serial: Optional[str], exposure_us: str, stall_timeout: float):
    """The live camera's settings from the command line (sources/davis.py DavisConfig)."""
    from neurotouch_hid.sources.davis import DavisConfig

    if exposure_us != "auto" and not (exposure_us.isdigit() and len(exposure_us) <= 9):
        from neurotouch_hid.core.limits import short

        raise NeurotouchError(
            f"--exposure-us {short(exposure_us)}: expected a whole number of microseconds (at most 9 digits) or 'auto'"
        )
    try:
        return DavisConfig(
            serial=serial,
            exposure_us=None if exposure_us == "auto" else int(exposure_us),
            stall_timeout_s=stall_timeout,
        )
    except ValueError as exc:
        raise NeurotouchError(f"camera settings: {exc}") from None
