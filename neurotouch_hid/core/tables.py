"""Rich tables printed whole to a pipe or a file: what the commands and the evaluation's report
share (no stage of the data flow)."""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from rich.console import Console
    from rich.table import Table


def print_table(console: Console, table: Table) -> None:
    """Print a rich table; to a pipe or a file its title goes on a line of its own, whole (rich
    wraps a title to the table's width: ``eval | head -2`` broke a sentence in two, ``info`` a long
    path at 40 columns). On a terminal, rich's own layout."""
    if console.is_terminal or table.title is None:
        console.print(table)
        return
    title, table.title = table.title, None
    try:
        console.print(title, highlight=False, soft_wrap=True)
        console.print(table)
    finally:
        table.title = title
