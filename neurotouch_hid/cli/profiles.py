"""Profiles: ``profile list|use|show|new|set|unset|delete|reset|validate|edit|path|test|tune`` and
``profile auto`` (a profile per game).

Each command parses its options, calls one function of what it drives (mapping/profile/,
mapping/editor.py, games.py, control.py, mapping/replay.py) and prints.
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Optional

import typer

from neurotouch_hid.cli.common import (
    MODEL_OPTION,
    chosen_model,
    console,
    duration,
    err_console,
    finite,
    long_lived_start_up,
    say_err,
)
from neurotouch_hid.core.errors import NeurotouchError, ProfileError
from neurotouch_hid.core.kinds import SourceKind
from neurotouch_hid.core.limits import printable, short
from neurotouch_hid.core.tables import print_table

profile_app = typer.Typer(
    help="List, show, create, edit, validate, test, tune, delete, reset and use (switch the running driver to) "
    "profiles.",
    no_args_is_help=True,
    rich_markup_mode=None,
)
auto_app = typer.Typer(
    help="A profile per game: the running driver switches to a game's profile while the game runs "
    "(a Steam app id or an executable's name; the user's games.yaml). Without a command: list.",
    invoke_without_command=True,
)
profile_app.add_typer(auto_app, name="auto")


# --- profiles (mapping/) ----------------------------------------------------------------------
@profile_app.command("list")
def profile_list() -> None:
    """List the profiles: shipped ones and the user's (a user copy shadows a shipped one)."""
    from rich.table import Table
    from rich.text import Text

    from neurotouch_hid.core.errors import ProfileError
    from neurotouch_hid.mapping.profile import (
        MAX_PROFILE_NAME_CHARS,
        available_profiles,
        load_profile,
        shipped_profiles_dir,
    )

    table = Table("name", "where", "description", "status")
    shipped = {p.stem for p in shipped_profiles_dir().glob("*.yaml")}
    for name, path in available_profiles().items():
        user = path.parent != shipped_profiles_dir()
        where = ("user (shadows shipped)" if name in shipped else "user") if user else "shipped"
        shown = printable(name, MAX_PROFILE_NAME_CHARS)  # file names and descriptions are text (no markup)
        try:
            loaded = load_profile(path)
            table.add_row(shown, where, printable(loaded.description, 200), Text("ok", style="green"))
        except ProfileError:
            status = Text("invalid", style="red") + f" (neurotouch-hid profile validate {printable(path, None)})"
            table.add_row(shown, where, "", status)
    print_table(console, table)


@profile_app.command("use")
def profile_use(
    name: str = typer.Argument(..., help="profile name or path"),
    serial: Optional[str] = typer.Option(None, "--serial", help="the driver of this camera (when several run)"),
) -> None:
    """Switch the running driver (`neurotouch-hid run`) to this profile, every output neutral first.

    Talks to the driver over $XDG_RUNTIME_DIR/neurotouch-hid/control.sock (control-SERIAL.sock for
    a driver run with --serial); with no driver running, says so (exit 2). A profile given by path
    is read here first, as this user: a bad one is refused with its problems (file, line, field),
    the driver not asked."""
    from neurotouch_hid.mapping.profile import _is_path, load_profile
    from neurotouch_hid.service.control import request_use

    if _is_path(name):
        load_profile(name)  # ProfileError: the driver would refuse it without echoing the file
    console.print(request_use(name, serial=serial), highlight=False, soft_wrap=True)


@profile_app.command("show")
def profile_show(name: str = typer.Argument(..., help="profile name or path")) -> None:
    """Print a profile's file (with its comments) and where it is.

    To a pipe or a file (``profile show NAME > mine.yaml``) it writes the file's exact bytes, and
    where it is to stderr."""
    from rich.syntax import Syntax

    from neurotouch_hid.mapping.profile import find_profile, read_profile_text

    path = find_profile(name)
    text = read_profile_text(path)  # bounded: a FIFO or a link to /dev/zero is refused
    if not console.is_terminal:
        err_console.print(f"# {printable(path, None)}", highlight=False, markup=False, soft_wrap=True)
        sys.stdout.flush()
        sys.stdout.buffer.write(text.encode("utf-8"))
        sys.stdout.buffer.flush()
        _say_copilot(path, err_console)
        return
    console.print(f"# {printable(path, None)}", highlight=False, markup=False)
    shown = "\n".join(printable(line, None) for line in text.split("\n"))  # no escape sequence reaches the terminal
    console.print(Syntax(shown, "yaml", background_color="default"))
    _say_copilot(path)


def _say_copilot(path: Path, to=None) -> None:
    """For a profile with ``copilot:``: which of its devices are plugged in now and which the
    driver would wait for (one line on ``to``, the console by default, after the file; nothing for
    a profile that does not load)."""
    from neurotouch_hid.core.errors import ProfileError
    from neurotouch_hid.inputs.match import mergeable_devices, presence_line
    from neurotouch_hid.mapping.profile import load_profile

    try:
        profile = load_profile(path)
    except ProfileError:
        return
    if profile.copilot:
        line = presence_line([c.device for c in profile.copilot], mergeable_devices())
        (to or console).print(f"# copilot: {printable(line, None)}", highlight=False, markup=False, soft_wrap=True)


@profile_app.command("new")
def profile_new(
    name: str = typer.Argument(..., help="name of the new user profile"),
    from_name: str = typer.Option("default", "--from", help="profile (name or path) to copy"),
) -> None:
    """Create a user profile as a copy of another one."""
    from neurotouch_hid.mapping.editor import new_profile

    console.print(f"created {new_profile(name, from_name)} (a copy of {from_name})", highlight=False)


def _note_shadow(name: str, path: Path) -> None:
    """Say that a change to the shipped profile ``name`` went to a user copy that now shadows it."""
    err_console.print(
        f"note: '{name}' is a shipped profile, so the change went to your copy, {path}, which replaces it "
        f"from now on (neurotouch-hid profile reset {name} goes back to the shipped one)",
        highlight=False,
        markup=False,
        soft_wrap=True,
    )


@profile_app.command("set", context_settings={"ignore_unknown_options": True})  # VALUE may be -1
def profile_set(
    name: str = typer.Argument(..., help="profile name (a shipped one is copied to the user folder)"),
    key: str = typer.Argument(..., help="dotted key, e.g. mappings.push.deadzone_mm"),
    value: str = typer.Argument(..., help="YAML value, e.g. 1.5, true, ABS_RX"),
) -> None:
    """Set one value; the profile is validated first and left unchanged if the result is invalid."""
    from neurotouch_hid.mapping.editor import creates_shadow, parse_value, set_values, yaml_text

    shadow = creates_shadow(name)
    new = parse_value(value)
    try:
        path, previous = set_values(name, {key: new})
    except ProfileError as exc:
        hint = _set_hint(name, key, value, new, str(exc))
        raise ProfileError(f"{exc}\n  {hint}" if hint else str(exc)) from None
    before = yaml_text(previous[key]) if key in previous else "(not set)"
    console.print(f"{path}: {key}: {before} -> {yaml_text(new)}", highlight=False, markup=False, soft_wrap=True)
    if shadow:
        _note_shadow(name, path)


def _set_hint(name: str, key: str, text: str, value: object, problem: str) -> str:
    """What to do when ``profile set NAME KEY TEXT`` (read as YAML: ``value``) was refused with
    ``problem`` ("" when nothing more is to be said): null is not how a key is removed; text that
    YAML reads as a mapping, list, number or boolean where a string was expected is quoted as a
    YAML string."""
    import shlex

    if value is None:
        return (
            f"to remove a key: `neurotouch-hid profile unset {name} {key}` (on a copy of a shipped profile: once "
            f"back to its value, again to remove it), or delete its lines in `neurotouch-hid profile edit {name}`"
        )
    if isinstance(value, str) or "string" not in problem:
        return ""
    kinds = ((dict, "a mapping"), (list, "a list"), (bool, "a boolean"))
    kind = next((word for base, word in kinds if isinstance(value, base)), "a number")
    as_yaml = "'" + text.replace("'", "''") + "'"  # a YAML single-quoted string
    plain = not any(c in text for c in '"$`\\!')
    quoted = f'"{as_yaml}"' if plain else shlex.quote(as_yaml)  # in the shell's double quotes where it can
    return (
        f"{short(text)} was read as YAML, as {kind}; for text, quote it for YAML inside the shell's quotes: "
        f"neurotouch-hid profile set {name} {key} {quoted}"
    )


def written_outputs(name: str) -> dict[str, str]:
    """Each mapping's ``output:`` of profile ``name`` as its file writes it (``space``, ``A``,
    ``RT``: the names a player chose, which loading turns into evdev names,
    :func:`~neurotouch_hid.mapping.profile.resolve_output`); empty where the file cannot be read
    again (the profile was loaded: it is only for display)."""
    from neurotouch_hid.core.limits import load_yaml
    from neurotouch_hid.mapping.profile import find_profile, read_profile_text

    try:
        data, _ = load_yaml(read_profile_text(find_profile(name)))
    except Exception:  # noqa: BLE001 - display only: the evdev names stay
        return {}
    mappings = data.get("mappings") if isinstance(data, dict) else None
    if not isinstance(mappings, dict):
        return {}
    return {
        str(k): str(m["output"])
        for k, m in mappings.items()
        if isinstance(m, dict) and isinstance(m.get("output"), str)
    }


def _as_written(output: str, mappings: tuple[str, ...], written: dict[str, str]) -> str:
    """``output`` as the profile's file writes it, with the evdev name beside when they differ
    (``space (KEY_SPACE)``)."""
    names = {written[m] for m in mappings if m in written}
    if len(names) != 1 or output in names:
        return output
    return f"{names.pop()} ({output})"


@profile_app.command("unset")
def profile_unset(
    name: str = typer.Argument(..., help="profile name"),
    key: str = typer.Argument(..., help="dotted key to undo"),
) -> None:
    """Undo one key: the shipped profile's value when the profile is a copy of one and holds
    another value, else removed (its default applies; a mapping removed maps nothing): on a copy,
    unset once goes back to the shipped value, twice removes the key.

    The profile is validated first and left unchanged if the result is invalid."""
    from neurotouch_hid.mapping.editor import creates_shadow, unset_value, yaml_text

    shadow = creates_shadow(name)
    path, removed, shipped, already = unset_value(name, key)
    if already:
        now = "it was the shipped value already: removed, its default applies"
    elif shipped is None:
        now = "removed, its default applies"
    else:
        now = f"back to the shipped value {yaml_text(shipped)} (unset it again to remove it)"
    console.print(f"{path}: {key}: {yaml_text(removed)} -> {now}", highlight=False, markup=False, soft_wrap=True)
    if shadow:
        _note_shadow(name, path)


@profile_app.command("delete")
def profile_delete(name: str = typer.Argument(..., help="user profile name")) -> None:
    """Delete one of your profiles (a copy of a shipped one: the shipped one applies again)."""
    from neurotouch_hid.mapping.editor import backup_path, delete_profile

    path, shipped = delete_profile(name)
    again = f"; the shipped '{name}' ({shipped}) applies again" if shipped is not None else ""
    console.print(f"deleted {path} (kept as {backup_path(path)}){again}", highlight=False, soft_wrap=True)
    _games_pointing_at(name, path, "gone" if shipped is None else f"the shipped '{name}'")


@profile_app.command("reset")
def profile_reset(name: str = typer.Argument(..., help="shipped profile name")) -> None:
    """Put a shipped profile back as shipped: delete your copy of it."""
    from neurotouch_hid.mapping.editor import backup_path, reset_profile

    path, shipped = reset_profile(name)
    if path is None:
        console.print(f"'{name}' is already the shipped one ({shipped}): nothing to reset", highlight=False)
    else:
        console.print(
            f"deleted {path} (kept as {backup_path(path)}): '{name}' is the shipped one again ({shipped})",
            highlight=False,
            soft_wrap=True,
        )
        _games_pointing_at(name, path, f"the shipped '{name}'")


def _games_pointing_at(name: str, path: Path, now: str) -> None:
    """Warn (stderr) about the games.yaml entries that name profile ``name`` or its file
    ``path``, just taken away: what those games get now (``now``: ``gone`` or the profile that
    applies) and the commands that change it."""
    from neurotouch_hid.service.games import EXECUTABLE, STEAM, games_file, load_game_map

    try:
        game_map = load_game_map(games_file())
    except NeurotouchError:
        return  # a broken map is said by `profile auto list` and the driver
    entries = [(STEAM, k, v) for k, v in game_map.steam.items()] + [
        (EXECUTABLE, k, v) for k, v in game_map.executable.items()
    ]
    for section, key, profile in entries:
        if profile != name and profile != str(path):
            continue
        game = _game_label(section, key)
        if now == "gone":
            say_err(
                f"warning: {games_file()} maps {game} -> {printable(profile, None)}, which no longer exists: when "
                f"that game starts the driver stays on its profile; `neurotouch-hid profile auto remove {key}` "
                "removes the entry, or rename the backup back"
            )
        else:
            say_err(f"note: {games_file()} maps {game} -> {printable(profile, None)}: that game now gets {now}")


@profile_app.command("validate")
def profile_validate(path: str = typer.Argument(..., help="profile file (or name)")) -> None:
    """Check a profile; every problem is listed with its file, line, field, value and expectation."""
    from neurotouch_hid.mapping.profile import find_profile, load_profile

    loaded = load_profile(path)
    touchpad = ", a touchpad" if loaded.touchpad is not None else ""
    console.print(f"{find_profile(path)}: ok ({len(loaded.mappings)} mappings{touchpad})", highlight=False)


def _edit_again(problem: str) -> bool:
    """After an invalid edit: show why and ask (on stdin, a terminal or not) whether to edit
    again; yes by default, no at the end of the input."""
    err_console.print(problem, highlight=False, markup=False, soft_wrap=True)
    err_console.print("edit it again? [Y/n] ", end="", highlight=False, markup=False)
    try:
        answer = sys.stdin.readline()
    except (OSError, ValueError):  # no input to read from
        answer = ""
    if not answer:
        err_console.print("")
    return bool(answer) and answer.strip().lower() in ("", "y", "yes")


@profile_app.command("edit")
def profile_edit(name: str = typer.Argument(..., help="profile name (a shipped one is copied when changed)")) -> None:
    """Edit a profile in $VISUAL or $EDITOR, as crontab -e: saved only when valid.

    An invalid save shows the problem and asks to edit again; answering no leaves the profile as
    it was and keeps your edit beside it (NAME.yaml.rejected), where the next edit starts."""
    from neurotouch_hid.mapping.editor import creates_shadow, edit_profile

    shadow = creates_shadow(name)
    path = edit_profile(name, _edit_again, note=lambda line: err_console.print(line, highlight=False, soft_wrap=True))
    if path is None:
        console.print(f"'{name}' unchanged", highlight=False)
        return
    console.print(f"{path}: ok", highlight=False, soft_wrap=True)
    if shadow:
        _note_shadow(name, path)


@profile_app.command("path")
def profile_path(name: str = typer.Argument(..., help="profile name")) -> None:
    """Print the file a profile name resolves to (the user's copy, else the shipped one)."""
    from neurotouch_hid.mapping.profile import find_profile

    typer.echo(str(find_profile(name)))


def _game_label(section: str, key: object) -> str:
    return f"Steam app {key}" if section == "steam" else printable(key, None)


SERIAL_OPTION = typer.Option(None, "--serial", help="this camera's table (its own games.yaml, else the shared one)")


def _games_path(serial: Optional[str], own: bool = False) -> Path:
    """The games.yaml ``profile auto`` reads (``serial``: the one its driver reads) or edits (``own``)."""
    from neurotouch_hid.service.games import games_file
    from neurotouch_hid.service.serials import own_path, sensor_file

    try:  # the camera's own file, to edit; the one its driver reads; the shared one
        return own_path(serial, "games") if own and serial else sensor_file(serial, "games", games_file())
    except ValueError as exc:
        raise NeurotouchError(f"--serial: {exc}") from None


@auto_app.callback()
def profile_auto(ctx: typer.Context) -> None:
    """A profile per game: `add GAME PROFILE`, `remove GAME`, `list` (also without a command).

    A game is a Steam app id (Steam sets SteamAppId in its processes' environment) or an
    executable's name; the running driver looks at your processes twice a second, switches to the
    game's profile (every output released first) and back when it exits. `profile use` during a
    game wins until the game exits."""
    if ctx.invoked_subcommand is None:
        profile_auto_list(None)


@auto_app.command("add")
def profile_auto_add(
    game: str = typer.Argument(..., help="Steam app id (a number) or executable name (e.g. supertuxkart)"),
    profile: str = typer.Argument(..., help="profile name or path"),
    serial: Optional[str] = SERIAL_OPTION,
) -> None:
    """Map a game to a profile (an entry already there is replaced); with --serial, in that camera's
    own games.yaml (made if needed: then that camera no longer reads the shared one)."""
    from neurotouch_hid.service.games import STEAM, add_game, load_game_map, parse_game

    path = _games_path(serial, own=True)
    section, key = parse_game(game)
    known = load_game_map(path)
    before = (known.steam if section == STEAM else known.executable).get(key)
    section, key, profile = add_game(game, profile, path)
    replaced = (
        f", replacing {_game_label(section, key)} -> {printable(before, None)}" if before not in (None, profile) else ""
    )
    typer.echo(
        f"{_game_label(section, key)} -> {printable(profile, None)} (in {path}{replaced}); a running driver follows it"
    )


@auto_app.command("remove")
def profile_auto_remove(
    game: str = typer.Argument(..., help="Steam app id or executable name, as added"),
    serial: Optional[str] = SERIAL_OPTION,
) -> None:
    """Remove a game's entry (with --serial, from the table that camera reads)."""
    from neurotouch_hid.service.games import remove_game

    path = _games_path(serial)
    section, key, profile = remove_game(game, path)
    typer.echo(f"removed {_game_label(section, key)} -> {printable(profile, None)} (from {path})")


@auto_app.command("list")
def profile_auto_list(serial: Optional[str] = SERIAL_OPTION) -> None:
    """List the map (with --serial, the one that camera's driver reads), and which mapped game
    runs now (the one the driver follows)."""
    from neurotouch_hid.core.errors import ProfileError
    from neurotouch_hid.mapping.profile import find_profile
    from neurotouch_hid.service.games import EXECUTABLE, STEAM, ProcessScanner, load_game_map

    path = _games_path(serial)
    game_map = load_game_map(path)
    if not game_map:
        typer.echo(f"no game is mapped ({path} has no entry); add one: neurotouch-hid profile auto add 4242 mouse")
        return
    running = ProcessScanner().games(game_map)
    typer.echo(f"games -> profiles ({path}):")
    entries = [(STEAM, k, v) for k, v in game_map.steam.items()] + [
        (EXECUTABLE, k, v) for k, v in game_map.executable.items()
    ]
    for section, key, profile in entries:
        pids = [str(g.pid) for g in running if g.section == section and g.key == key]
        now = f"  running: pid {', '.join(pids)}" if pids else ""
        try:
            find_profile(profile)
        except ProfileError:
            now += "  NO SUCH PROFILE: the driver stays on its profile when this game runs"
        typer.echo(f"  {_game_label(section, key)} -> {printable(profile, None)}{now}")
    if running:
        typer.echo(f"matched now: {running[0].label()} -> {printable(running[0].profile, None)}")
    else:
        typer.echo("matched now: none (no mapped game is running)")


@profile_app.command("test")
def profile_test(
    name: str = typer.Argument(..., help="profile name or path"),
    source: str = typer.Option("sim", "--source", help="sim, an AEDAT4 recording, or predictions PRED.jsonl"),
    plot: Optional[Path] = typer.Option(None, "--plot", help="also draw the timeline to this PNG"),
    seconds: Optional[float] = typer.Option(
        None,
        "--seconds",
        help="only the first N seconds (sim: one cycle of the simulated hand's gestures, ~25 s, by default)",
        callback=duration,
    ),
    every_ms: int = typer.Option(100, "--every-ms", help="timeline sampling period (ms)"),
    json_out: bool = typer.Option(False, "--json", help="print the summary as JSON instead of tables"),
    model: Optional[str] = MODEL_OPTION,
) -> None:
    """Replay a source through the pipeline and the profile; print the axis and button timeline,
    then every output the profile maps, those never reached marked.

    The simulated hand (--source sim) pushes up, right, down and left and twists both ways within
    one cycle, so that each mapping is tried both ways."""
    import json

    from rich.table import Table

    from neurotouch_hid.core.controller import AXES
    from neurotouch_hid.engine.assembly import estimates_from_source
    from neurotouch_hid.mapping.profile import load_profile
    from neurotouch_hid.mapping.replay import (
        deflection,
        plot_timeline,
        pressed,
        reach,
        replay,
        sample_timeline,
        summarise,
    )

    if plot is not None:  # before the replay, not after it
        from neurotouch_hid.service.extras import require

        require("plots", "profile test --plot")
    loaded = load_profile(name)
    if not source.endswith(".jsonl"):  # the pipeline runs from the first item: a first run compiles
        with long_lived_start_up():
            from neurotouch_hid.service.warmup import compile_before

            compile_before(say_err, simulator=source == SourceKind.SIM)  # in child processes, said
    estimates = list(estimates_from_source(source, seconds, chosen_model(model)))
    states = replay(loaded, estimates)
    summary = summarise(states)
    reached = reach(loaded, states)
    if plot is not None:
        plot_timeline(estimates, states, plot)
    if json_out:
        outputs = [
            {"output": r.output, "mappings": list(r.mappings), "reached": r.reached, "detail": r.detail}
            for r in reached
        ]
        typer.echo(
            json.dumps(
                {
                    "estimates": len(estimates),
                    "max_deflection": summary.max_deflection,
                    "presses": summary.presses,
                    "outputs": outputs,
                }
            )
        )
        return
    moved = [a for a in AXES if summary.max_deflection[a] > 0]
    table = Table("t (s)", "gesture", "mm", *moved, "buttons", title=f"{name} on {source} ({len(estimates)} windows)")
    t0 = estimates[0].t_us if estimates else 0
    for row in sample_timeline(estimates, states, every_ms * 1000):
        down = " ".join(b.removeprefix("BTN_") for b in pressed(row.state))
        table.add_row(
            f"{(row.t_us - t0) / 1e6:.1f}",
            row.estimate.gesture.value,
            f"{row.estimate.intensity_mm:.1f}",
            *(f"{deflection(a, row.state.axes[a]):+.2f}" for a in moved),
            down,
        )
    print_table(console, table)
    totals = Table("output", "mapping", "reached", title=f"summary: every output {name} maps")
    written = written_outputs(name)
    for r in reached:
        shown = _as_written(r.output, r.mappings, written)
        totals.add_row(shown, ", ".join(r.mappings), r.detail if r.reached else f"never reached ({r.detail})")
    print_table(console, totals)
    missed = [_as_written(r.output, r.mappings, written) for r in reached if not r.reached]
    if missed:
        console.print(
            f"never reached: {', '.join(missed)} (a longer --seconds, or a recording with those gestures, tries them)",
            highlight=False,
            soft_wrap=True,
        )
    if plot is not None:
        console.print(f"plot: {plot}", highlight=False)


@profile_app.command("tune")
def profile_tune(
    name: str = typer.Argument(..., help="profile name (written to the user's copy)"),
    from_source: str = typer.Option(..., "--from", help="AEDAT4 recording or predictions PRED.jsonl of this user"),
    percentile: float = typer.Option(
        95.0, "--percentile", help="intensity percentile that gives full deflection", callback=finite
    ),
) -> None:
    """Set each analogue mapping's saturation to what this user reaches (weak fingers, for one)."""
    from neurotouch_hid.engine.assembly import estimates_from_source
    from neurotouch_hid.mapping.editor import creates_shadow, set_values
    from neurotouch_hid.mapping.profile import load_profile
    from neurotouch_hid.mapping.replay import tuned_saturations

    if not 0 < percentile <= 100:
        raise NeurotouchError(f"--percentile {percentile}: expected a value in (0, 100]")
    takes = (
        "tune takes a recording (AEDAT4) or predictions (.jsonl) of your own gestures; record some with "
        "`neurotouch-hid record me.aedat4`, then `profile tune NAME --from me.aedat4`"
    )
    if from_source in (SourceKind.SIM, SourceKind.DAVIS):
        reach = "the simulated hand's reach is not yours" if from_source == SourceKind.SIM else "not the live camera"
        raise NeurotouchError(f"--from {from_source}: {reach}; {takes}")
    if not Path(from_source).is_file():
        raise NeurotouchError(f"--from {from_source}: no such file; {takes}")
    tuned = tuned_saturations(load_profile(name), estimates_from_source(from_source), percentile)
    if not tuned:
        raise NeurotouchError(
            f"{from_source}: no gesture there exercises an analogue mapping of '{name}'; nothing tuned"
        )
    shadow = creates_shadow(name)
    path, _ = set_values(name, {f"mappings.{m}.saturation_mm": new for m, (_, new) in tuned.items()})
    for mapping, (old, new) in tuned.items():
        console.print(f"{mapping}: saturation_mm {old:g} -> {new:g}", highlight=False)
    console.print(f"written to {path}", highlight=False, soft_wrap=True)
    if shadow:
        _note_shadow(name, path)
