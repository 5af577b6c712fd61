"""Print a help2man include file: a COMMANDS section with every sub-command's ``--help``.

help2man(1) makes the man page from ``neurotouch-hid --help``, which lists the commands only;
this adds each command's own help (typer's plain-text help, as ``TYPER_USE_RICH=0`` prints it),
so ``man neurotouch-hid`` documents every command. Used by packaging/build-deb.sh, run with the
packaged interpreter: ``python3 packaging/man_commands.py > commands.h2m``.
"""

from __future__ import annotations

import os
import sys

os.environ["TYPER_USE_RICH"] = "0"  # read when typer is imported: plain help, no boxes

import typer  # noqa: E402

from neurotouch_hid.cli import app  # noqa: E402


def _roff(text: str) -> str:
    """Plain text as roff lines: backslashes escaped, a leading dot or quote made literal."""
    lines = []
    for line in text.rstrip().splitlines():
        line = line.replace("\\", "\\e")
        lines.append("\\&" + line if line.startswith((".", "'")) else line)
    return "\n".join(lines)


def _walk(command, ctx, path):
    """(name path, help text) of every command under ``command``, depth first, in name order."""
    subcommands = getattr(command, "commands", {})
    for name in sorted(subcommands):
        sub = subcommands[name]
        if sub.hidden:
            continue
        sub_ctx = sub.make_context(name, [], parent=ctx, resilient_parsing=True)
        yield [*path, name], sub.get_help(sub_ctx)
        yield from _walk(sub, sub_ctx, [*path, name])


def main() -> None:
    root = typer.main.get_command(app)
    ctx = root.make_context("neurotouch-hid", [], resilient_parsing=True)
    out = ["[COMMANDS]"]
    for path, text in _walk(root, ctx, ["neurotouch-hid"]):
        out += [f'.SS "{" ".join(path)}"', ".nf", _roff(text), ".fi"]
    sys.stdout.write("\n".join(out) + "\n")


if __name__ == "__main__":
    main()
