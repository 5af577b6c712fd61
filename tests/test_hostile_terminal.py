"""What reaches the terminal from outside (docs/limits.md): profile descriptions, file names, game
names and log lines are printed with their control characters escaped."""

from __future__ import annotations

import subprocess
import sys

from hostile_helpers import _env, _user_profiles, cli

# --- terminal escapes ---------------------------------------------------------------------------
OSC = "\x1b]52;c;cm0gLXJmIH4K\x07\x1b]0;pwned\x07"  # a clipboard write and a window title


def test_descriptions_file_names_and_game_names_reach_the_terminal_escaped(user_config_in_tmp):
    """A profile whose description holds OSC sequences (clipboard write, window title), a
    profile file whose name holds one, a game name with a newline: printed with their control
    characters escaped, never as they are."""
    folder = _user_profiles(user_config_in_tmp)
    (folder / "evil.yaml").write_text(f'description: "{OSC.encode("unicode_escape").decode()}"\nmappings: {{}}\n')
    (folder / f"name{OSC}.yaml").write_text("mappings: {}\n")
    code, out, err, _ = cli("profile", "list")
    assert code == 0, err
    assert "\x1b" not in out + err and "\x07" not in out + err, repr(out)
    assert "\\x1b]52;c;" in out, out
    code, out, err, _ = cli("profile", "validate", str(folder / f"missing{OSC}.yaml"))
    assert code == 2 and "\x1b" not in out + err and "\\x1b]0;pwned" in err, repr(err)
    code, out, err, _ = cli("profile", "auto", "add", "game\nname\x1b[2J", "default")
    assert code == 2 and "\x1b" not in out + err and "game\\nname\\x1b[2J" in err, repr(err)
    assert len(err.strip().splitlines()) == 1, err


def test_log_lines_reach_the_terminal_escaped():
    """Whatever a log message quotes (a file name, a process's name) is printed with its control
    characters escaped: the command's log handler formats every line through limits.printable."""
    code = (
        "import logging, sys\nimport neurotouch_hid.cli as cli\n"
        "shout = lambda: logging.getLogger('neurotouch_hid.x').warning('game \\x1b]0;pwned\\x07 runs')\n"
        "cli.app.command('shout')(shout)\n"
        "sys.argv = ['neurotouch-hid', 'shout']\ncli.main()\n"
    )
    done = subprocess.run([sys.executable, "-c", code], env=_env(), capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert "\x1b" not in done.stderr and "game \\x1b]0;pwned\\x07 runs" in done.stderr, repr(done.stderr)
