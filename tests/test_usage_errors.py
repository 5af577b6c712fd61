"""Mistyped command lines, run as a user runs them (a subprocess of the installed package).

Every usage error (missing argument, unknown option, bad value, unknown command), for every
command and ``profile`` sub-command, prints the usage line and the error on stderr and exits
with code 2; never a traceback, whichever click (typer's own copy, or none installed) typer uses.
"""

from __future__ import annotations

import subprocess

import pytest
import typer
from helpers import run_cli

from neurotouch_hid.cli import app


def _commands() -> list[tuple[str, ...]]:
    """Every leaf command's words, e.g. ``("track",)``, ``("profile", "show")``, from the app itself."""
    found: list[tuple[str, ...]] = []

    def walk(group, prefix: tuple[str, ...]) -> None:
        for name, command in sorted(group.commands.items()):
            if hasattr(command, "commands"):
                walk(command, (*prefix, name))
            else:
                found.append((*prefix, name))

    walk(typer.main.get_command(app), ())
    return found


COMMANDS = _commands()


def assert_usage_error(result: subprocess.CompletedProcess, message: str) -> None:
    shown = result.stdout + result.stderr
    assert "Traceback" not in shown, shown
    assert result.returncode == 2, shown
    assert "Usage:" in result.stderr, shown
    assert message in result.stderr, shown


def test_every_command_is_covered():
    """The list the tests below walk is the app's: the main commands and profile's sub-commands."""
    assert {("track",), ("run",), ("info",), ("profile", "show"), ("profile", "validate")} <= set(COMMANDS)


@pytest.mark.parametrize("words", [c for c in COMMANDS if c != ("profile", "set")], ids=" ".join)
def test_unknown_option(words, tmp_path):
    assert_usage_error(run_cli(*words, "--no-such-option", home=tmp_path), "No such option")


@pytest.mark.parametrize(
    "words",
    [
        ("track",),
        ("info",),
        ("view",),
        ("record",),
        ("eval",),
        ("profile", "show"),
        ("profile", "new"),
        ("profile", "set"),
        ("profile", "unset"),
        ("profile", "validate"),
        ("profile", "tune"),
    ],
    ids=" ".join,
)
def test_missing_argument(words, tmp_path):
    assert_usage_error(run_cli(*words, home=tmp_path), "Missing argument")


@pytest.mark.parametrize(
    "args",
    [
        ("run", "--seed", "abc"),
        ("run", "--window-us", "1.5x"),
        ("record", "out.aedat4", "--seed", "x"),
        ("simulate", "--seed", "many"),
        ("profile", "test", "default", "--every-ms", "often"),
        ("calibrate", "--frames", "1"),
        ("run", "--seconds", "nan"),  # a float that is no number: it crashed later on
        ("run", "--max-lag-ms", "inf"),
        ("demo", "--seconds", "-inf"),
        ("simulate", "--noise-hz", "nan"),
        ("run", "--seconds", "0"),  # ran nothing and said nothing
        ("profile", "test", "default", "--seconds", "-2"),
        ("simulate", "--seed", "-5"),  # numpy's seeding raised a traceback
        ("run", "--seed", "-1"),
    ],
    ids=" ".join,
)
def test_bad_value(args, tmp_path):
    assert_usage_error(run_cli(*args, home=tmp_path), "Invalid value")


@pytest.mark.parametrize("args", [("nosuch",), ("profile", "nosuch"), ("trak", "x.aedat4")], ids=" ".join)
def test_unknown_command(args, tmp_path):
    assert_usage_error(run_cli(*args, home=tmp_path), "No such command")


@pytest.mark.parametrize("args", [(), ("profile",)], ids=lambda a: " ".join(a) or "none")
def test_no_command_shows_help(args, tmp_path):
    """No command at all: the help (the list of commands), exit 2, no traceback."""
    result = run_cli(*args, home=tmp_path)
    shown = result.stdout + result.stderr
    assert "Traceback" not in shown and result.returncode == 2, shown
    assert "Usage:" in shown and ("track" in shown if not args else "validate" in shown), shown
