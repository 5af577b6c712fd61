"""Rich consoles and command-line help whose output to a pipe or a file is exact: no wrapping or
cropping at 80 columns.

rich sizes a console that is not a terminal at 80 columns (or ``$COLUMNS``) and wraps text and
crops table rows to it, so ``neurotouch-hid profile list > list.txt`` or a benchmark's table in a
CI log lost its right-hand side. :func:`make_console` keeps rich's behaviour on a terminal and
gives every other destination a width no line reaches (:data:`PIPE_WIDTH`), so tables keep
their natural width and text its own lines. :func:`command_app` does the same for a typer
command's ``--help`` and usage errors (click re-flows them to 80 columns, and typer's rich boxes
crop them).
"""

from __future__ import annotations

import sys
from typing import TYPE_CHECKING

from rich.console import Console

if TYPE_CHECKING:
    import typer

#: Columns of a console that does not write to a terminal: wider than any line this package
#: prints, so rich never wraps or crops (a table is as wide as its content, not this).
PIPE_WIDTH = 10_000


def make_console(*, stderr: bool = False) -> Console:
    """A rich Console on stdout (or stderr): the terminal's width on a terminal, else
    :data:`PIPE_WIDTH` columns, so that what goes to a pipe or a file is never cut (rich).

    Its markup is off: a file name or a message with ``[`` in it is printed as it is (with
    markup, ``q[/]p.jsonl`` raised rich's MarkupError after the command's work, and ``[b]``
    vanished from a name); a line that styles itself says ``markup=True`` and escapes the text
    it holds (``rich.markup.escape``)."""
    console = Console(stderr=stderr, markup=False)
    return console if console.is_terminal else Console(stderr=stderr, width=PIPE_WIDTH, markup=False)


def command_app(**options: object) -> typer.Typer:
    """A typer app whose ``--help`` (and ``-h``) and usage errors are click's plain text, re-flowed to the
    terminal's width on a terminal and to :data:`PIPE_WIDTH` elsewhere (each paragraph and option
    on one line, nothing cut), with plain tracebacks and no shell-completion options. ``options``
    go to :class:`typer.Typer` (typer; click's ``terminal_width`` / ``max_content_width``)."""
    import typer  # here, not at the top: the runtime's consoles do not need it

    width = {} if sys.stdout.isatty() else {"terminal_width": PIPE_WIDTH, "max_content_width": PIPE_WIDTH}
    width["help_option_names"] = ["-h", "--help"]  # every command and group: subcommands inherit it
    return typer.Typer(
        add_completion=False,
        pretty_exceptions_enable=False,
        # click's plain help: flags without rich's `<bool>`, each paragraph re-flowed whole (rich's
        # boxes broke docstrings at their source line ends, mid-sentence, and cropped them in a pipe)
        rich_markup_mode=None,
        context_settings=width,
        **options,
    )
