"""Rich consoles whose output to a pipe or a file is exact: no wrapping or cropping at 80 columns.

rich sizes a console that is not a terminal at 80 columns (or ``$COLUMNS``) and wraps text and
crops table rows to it, so ``neurotouch-hid profile list > list.txt`` or a benchmark's table in a
CI log lost its right-hand side. :func:`make_console` keeps rich's behaviour on a terminal and
gives every other destination a width no line reaches (:data:`PIPE_WIDTH`), so tables keep
their natural width and text its own lines.
"""

from __future__ import annotations

from rich.console import Console

#: Columns of a console that does not write to a terminal: wider than any line this package
#: prints, so rich never wraps or crops (a table is as wide as its content, not this).
PIPE_WIDTH = 10_000


def make_console(*, stderr: bool = False) -> Console:
    """A rich Console on stdout (or stderr): the terminal's width on a terminal, else
    :data:`PIPE_WIDTH` columns, so that what goes to a pipe or a file is never cut (rich)."""
    console = Console(stderr=stderr)
    return console if console.is_terminal else Console(stderr=stderr, width=PIPE_WIDTH)
