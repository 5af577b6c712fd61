"""The ``neurotouch-hid`` command (typer): the main app, its global options and :func:`main`.

Each command is a thin layer: it parses options, calls one function of the stage it belongs to,
and prints. Heavy modules (numba, OpenCV, dv-processing) are imported inside the commands so
``--help`` stays fast. Every :class:`~neurotouch_hid.core.errors.NeurotouchError` becomes one clear
line on stderr and exit code 2 (see :func:`main`).

The commands live in one module per group, each a typer sub-application beside what it drives:
:mod:`~neurotouch_hid.cli.devices` (the controller and its devices),
:mod:`~neurotouch_hid.cli.recordings` (recordings and datasets),
:mod:`~neurotouch_hid.cli.enrolment` (enrolment) and :mod:`~neurotouch_hid.cli.profiles`
(profiles); :mod:`~neurotouch_hid.cli.common` holds what they share.
"""

from __future__ import annotations

import os
import re
import sys

import typer
from typer.core import TyperGroup

from neurotouch_hid.cli import devices, enrolment, gadget, profiles, recordings
from neurotouch_hid.cli.common import err_console
from neurotouch_hid.core.errors import NeurotouchError, did_you_mean, in_plain_words
from neurotouch_hid.views.console import command_app

#: The main help's lead: where a new user starts.
MAIN_HELP = (
    "NeuroTouch soft tactile sensor -> standard game controller.\n\n"
    "New here? `neurotouch-hid demo` shows every gesture on a simulated gel through the default profile "
    "(no camera needed); `neurotouch-hid doctor` says what your setup still lacks and how to fix it. "
    "Every command takes -h for its help, with an example. The guide: docs/getting-started.md, and "
    "docs/troubleshooting.md for every message, in the source tree (README.md)."
)
#: The commands the main help lists first (where a new user starts), then the others in order.
FIRST_COMMANDS = ("demo", "doctor")


class _StartHereGroup(TyperGroup):
    """The main command group: :data:`FIRST_COMMANDS` lead its help's command list."""

    def list_commands(self, ctx) -> list[str]:
        names = super().list_commands(ctx)
        return [n for n in FIRST_COMMANDS if n in names] + [n for n in names if n not in FIRST_COMMANDS]


app = command_app(name="neurotouch-hid", help=MAIN_HELP, no_args_is_help=True, cls=_StartHereGroup)
app.add_typer(devices.app)
app.add_typer(recordings.app)
app.add_typer(enrolment.app)
app.add_typer(profiles.profile_app, name="profile")
app.add_typer(gadget.gadget_app, name="gadget")

#: One example per command, shown at the end of its help (``-h``); tests check that each one's
#: options are the command's.
EXAMPLES: dict[str, tuple[str, ...]] = {
    "run": ("neurotouch-hid run --source davis --profile default", "neurotouch-hid run --source sim --output term"),
    "demo": ("neurotouch-hid demo --seconds 20",),
    "devices": ("neurotouch-hid devices",),
    "doctor": ("neurotouch-hid doctor",),
    "calibrate": (
        "neurotouch-hid calibrate",
        "neurotouch-hid calibrate --source sim --sim-rotation 40 --out /tmp/sensor.yaml",
    ),
    "info": ("neurotouch-hid info rec.aedat4",),
    "record": ("neurotouch-hid record rec.aedat4 --seconds 10",),
    "simulate": ("neurotouch-hid simulate --out my-dataset --preset quick --seed 1",),
    "track": ("neurotouch-hid track rec.aedat4 --out pred.jsonl",),
    "eval": ("neurotouch-hid eval my-dataset --report report/", "neurotouch-hid eval my-dataset --profile mine"),
    "view": ("neurotouch-hid view rec.aedat4 --out rec.png",),
    "enrol": ("neurotouch-hid enrol --source sim",),
    "adapt": ("neurotouch-hid adapt ~/.local/share/neurotouch-hid/enrolments/*",),
    "profile": ("neurotouch-hid profile new mine --from default", "neurotouch-hid profile test mine --source sim"),
    "profile list": ("neurotouch-hid profile list",),
    "profile use": ("neurotouch-hid profile use mouse",),
    "profile show": ("neurotouch-hid profile show default",),
    "profile new": ("neurotouch-hid profile new mine --from default",),
    "profile set": ("neurotouch-hid profile set mine mappings.push.deadzone_mm 1.0",),
    "profile unset": ("neurotouch-hid profile unset mine mappings.push.deadzone_mm",),
    "profile delete": ("neurotouch-hid profile delete mine",),
    "profile reset": ("neurotouch-hid profile reset default",),
    "profile validate": ("neurotouch-hid profile validate ~/.config/neurotouch-hid/profiles/mine.yaml",),
    "profile edit": ("EDITOR=nano neurotouch-hid profile edit mine",),
    "profile path": ("neurotouch-hid profile path default",),
    "profile test": (
        "neurotouch-hid profile test mine --source sim",
        "neurotouch-hid profile test mine --source pred.jsonl",
    ),
    "profile tune": ("neurotouch-hid profile tune mine --from my-recording.aedat4",),
    "profile auto": ("neurotouch-hid profile auto add 4242 mouse",),
    "profile auto add": ("neurotouch-hid profile auto add supertuxkart spacecraft",),
    "profile auto remove": ("neurotouch-hid profile auto remove 4242",),
    "profile auto list": ("neurotouch-hid profile auto list",),
    # sudo searches only its secure_path, not ~/.local/bin (pipx): the command by its absolute path
    "gadget": ('sudo "$(command -v neurotouch-hid)" gadget setup --protocol hid',),
    "gadget setup": ('sudo "$(command -v neurotouch-hid)" gadget setup --protocol xinput --user alice',),
    "gadget remove": ('sudo "$(command -v neurotouch-hid)" gadget remove',),
}


def _epilog(path: str) -> str:
    """The help's closing paragraph for the command at ``path`` (its examples, one a line)."""
    lines = EXAMPLES[path]
    return "\b\nExample" + ("s" * (len(lines) > 1)) + ":\n" + "\n".join(f"  {line}" for line in lines)


def _add_examples(typer_app: typer.Typer, prefix: str) -> None:
    """Give each command of ``typer_app`` (its sub-groups too) its :data:`EXAMPLES` as epilog."""
    for info in typer_app.registered_commands:
        name = info.name or info.callback.__name__.replace("_", "-")
        info.epilog = _epilog(f"{prefix}{name}")
    for group in typer_app.registered_groups:
        if not isinstance(group.name, str):  # no name of its own: its commands are the parent's
            _add_examples(group.typer_instance, prefix)
            continue
        group.typer_instance.info.epilog = _epilog(f"{prefix}{group.name}")
        _add_examples(group.typer_instance, f"{prefix}{group.name} ")


_add_examples(app, "")

#: The variable through which shells ask for completions (click's protocol):
#: ``_NEUROTOUCH_HID_COMPLETE=source_bash neurotouch-hid`` prints the bash script (zsh, fish too).
COMPLETE_ENV = "_NEUROTOUCH_HID_COMPLETE"


def _print_version(value: bool) -> None:
    """``--version``: the installed distribution's version (the package's own when run from a
    checkout without an install), then exit 0."""
    if not value:
        return
    import importlib.metadata

    from neurotouch_hid import __version__

    try:
        version = importlib.metadata.version("neurotouch-hid")
    except importlib.metadata.PackageNotFoundError:
        version = __version__
    typer.echo(f"neurotouch-hid {version}")
    raise typer.Exit()


@app.callback()
def _options(
    version: bool = typer.Option(False, "--version", callback=_print_version, is_eager=True, help="print the version"),
) -> None:
    """NeuroTouch soft tactile sensor -> standard game controller."""


class _Terminated(BaseException):
    """SIGTERM or SIGHUP arrived: unwinds the command as Ctrl-C does (an output's temporary file
    removed, ``atomic``), then :func:`main` ends the process by that signal, as it would have
    died without a handler (its parent, systemd or a shell, sees the same status)."""

    def __init__(self, signum: int) -> None:
        super().__init__(signum)
        self.signum = signum


def _unwind_on_termination() -> None:
    """SIGTERM and SIGHUP (a closed terminal) raise :class:`_Terminated` in the main thread where
    their action is the default one (ignored, as under nohup, they stay ignored). Commands that
    handle them themselves (``run``, ``record``, ``enrol``) set their own while they run."""
    import signal

    from neurotouch_hid.engine.stopping import deliver_again, raise_later

    def unwind(signum: int, frame) -> None:
        if raise_later(frame):  # in a finalizer (the stop would be dropped) or an import (left half-made)
            deliver_again(signum)
            return
        raise _Terminated(signum)

    for number in (signal.SIGTERM, signal.SIGHUP):
        if signal.getsignal(number) is signal.SIG_DFL:
            signal.signal(number, unwind)


def main() -> None:
    """Console-script entry point: user errors become one line on stderr and exit code 2.

    A mistyped command line (missing argument, unknown option or command, bad value) is printed
    as typer prints it (usage, the error, exit code 2), a bad value in the project's words
    (:func:`usage_in_plain_words`), whichever click typer uses (typer 0.29 carries its own copy
    and no longer installs click: its exception classes are found through typer's).
    """
    if COMPLETE_ENV in os.environ:  # a shell asks for completions (the scripts the package installs)
        from typer.completion import completion_init

        completion_init()
    import logging

    from neurotouch_hid.core.limits import PrintableFormatter

    logs = logging.StreamHandler()  # what Python's last-resort handler prints, control characters escaped
    logs.setFormatter(PrintableFormatter("%(message)s"))
    logging.basicConfig(level=logging.WARNING, handlers=[logs])
    click_exception = next(c for c in typer.BadParameter.__mro__ if c.__name__ == "ClickException")
    _unwind_on_termination()
    try:
        code = app(standalone_mode=False)  # usage errors come back here, to be said in plain words
    except typer.BadParameter as exc:
        exc.message = usage_in_plain_words(exc.message)
        exc.show()
        sys.exit(exc.exit_code)
    except click_exception as exc:  # the other usage errors (a missing argument, an unknown option)
        exc.show()
        sys.exit(exc.exit_code)
    except typer.Abort:  # the end of the input at a prompt
        err_console.print("Aborted!", highlight=False)
        sys.exit(1)
    except NeurotouchError as exc:
        from rich.markup import escape  # the message's own brackets (an extra's name) are text

        from neurotouch_hid.core.limits import printable  # a file name's escape sequences never reach the terminal

        said = "; ".join([str(exc), *getattr(exc, "__notes__", ())])  # an output kept aside says where
        message = "\n".join(printable(line, None) for line in said.split("\n"))
        err_console.print(f"[bold red]error:[/] {escape(message)}", highlight=False, markup=True, soft_wrap=True)
        sys.exit(2)
    except KeyboardInterrupt as exc:
        _say_notes(exc)
        sys.exit(130)
    except _Terminated as exc:  # unwound: now end by the signal itself
        import signal

        _say_notes(exc)
        sys.stdout.flush()
        signal.signal(exc.signum, signal.SIG_DFL)
        os.kill(os.getpid(), exc.signum)
    except OSError as exc:  # a write the disk refused where no stage said it in its own words
        from neurotouch_hid.core.atomic import DISK_ERRNOS
        from neurotouch_hid.core.limits import printable

        if exc.errno not in DISK_ERRNOS:
            raise
        where = f"{printable(exc.filename, 200)}: " if exc.filename else ""
        err_console.print(
            f"error: {where}cannot write: {exc.strerror or exc}; what was there before is kept (free some space or "
            "write elsewhere)",
            highlight=False, markup=False, soft_wrap=True,
        )  # fmt: skip
        sys.exit(2)
    sys.exit(code if isinstance(code, int) else 0)


def _say_notes(exc: BaseException) -> None:
    """The notes an interrupted command's outputs added to ``exc`` (where what was computed went,
    :class:`~neurotouch_hid.core.jsonl_writer.JsonlWriter`), one line each on stderr."""
    from neurotouch_hid.core.limits import printable

    for note in getattr(exc, "__notes__", ()):
        err_console.print(printable(note, None), highlight=False, markup=False, soft_wrap=True)


def usage_in_plain_words(message: str) -> str:
    """A bad option value's message in the project's words: typer validates through pydantic,
    whose wording (``Value error, ...``, ``Input should be ...``) is not ours; a choice
    mistyped gets the nearest one."""
    message = in_plain_words(message)
    choice = re.fullmatch(r"'(.*)' is not one of (.*?)\.?", message)
    if choice is not None:
        choices = re.findall(r"'([^']*)'", choice.group(2))
        message = f"'{choice.group(1)}' is not one of {choice.group(2)}{did_you_mean(choice.group(1), choices)}"
    return message


if __name__ == "__main__":  # pragma: no cover
    main()
