"""games.yaml and the processes the driver looks at, crafted to break it (docs/limits.md): a
games.yaml that is a FIFO, never ends or is too large, a process with a huge Steam app id, and the
scanner under the unit as shipped."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
from helpers import started
from hostile_helpers import ROOT, _env, assert_refused, cli
from hostile_inputs import ALIAS_BOMB, DEEP_YAML


# --- games.yaml and the processes the driver looks at -----------------------------------------
def _games_yaml(tmp_path: Path) -> tuple[Path, dict]:
    config = tmp_path / "config"
    (config / "neurotouch-hid").mkdir(parents=True)
    return config / "neurotouch-hid" / "games.yaml", _env(XDG_CONFIG_HOME=str(config))


@pytest.mark.parametrize(
    "text, says",
    [
        (ALIAS_BOMB.replace("a: &a", "steam: {}\nexecutable: {}\na: &a"), "aliases"),
        (DEEP_YAML.replace("mappings", "steam"), "nested more than"),
        ("executable:\n  game: " + "x" * 200_000 + "\n", "a value of 200000 characters"),
        ("steam:\n  " + "4" * 5000 + ": mouse\n", "a number of 5000 characters"),
        ("steam:\n  " + "4" * 12 + ": mouse\n", "is not a Steam app id"),
        ('executable:\n  "a\\nb\\e]0;x\\a": mouse\n', "'a\\nb\\x1b]0;x\\x07' is not a name"),
    ],
    ids=["alias-bomb", "8000-deep", "200k-value", "5000-digits", "12-digit-app", "control-characters"],
)
def test_games_yaml_goes_through_the_bounded_reader(tmp_path, text, says):
    """``profile auto list`` on a crafted games.yaml: one short line (the value never echoed
    whole, control characters escaped), bounded time and memory."""
    path, env = _games_yaml(tmp_path)
    path.write_text(text)
    assert_refused(cli("profile", "auto", "list", env=env), says, str(path))


@pytest.mark.parametrize("kind", ["fifo", "dev-zero"])
def test_a_games_yaml_that_never_ends_blocks_neither_the_command_nor_the_watcher(tmp_path, kind):
    """A FIFO (a read would wait for a writer for ever) or a link to /dev/zero (a read never
    ends) as games.yaml: refused by ``profile auto list``; the running driver's watcher says so
    and goes on polling."""
    import threading

    from neurotouch_hid.service.games import GameProfiles

    path, env = _games_yaml(tmp_path)
    if kind == "fifo":
        os.mkfifo(path)
    else:
        path.symlink_to("/dev/zero")
    assert_refused(cli("profile", "auto", "list", env=env), "not a regular file")

    class NoGames:
        def games(self, game_map):
            return []

    watcher = GameProfiles(lambda ref, why: ref, "default", path=path, scanner=NoGames())
    polled = threading.Thread(target=lambda: [watcher.poll() for _ in range(3)], daemon=True)
    polled.start()
    polled.join(30.0)
    assert not polled.is_alive(), "the watcher blocked on games.yaml"


def test_a_process_with_a_huge_steam_app_id_does_not_hide_the_game_beside_it(tmp_path):
    """A process whose SteamAppId is 5000 digits (Python refuses to convert it) and one whose
    environment is 800 KB of padding before SteamAppId: the game beside them is still found, and
    neither is taken for a game."""
    from neurotouch_hid.service.games import GameMap, ProcessScanner

    sleeper = [sys.executable, "-c", "import time; time.sleep(120)"]
    base = {"PATH": os.environ.get("PATH", "")}
    # app ids no other process has (the scanner sees all of this user's, other test runs' too):
    # past every real Steam app's, holding this process's pid
    game = 3_000_000_000 + os.getpid() * 256
    padded = game + 1
    procs = [
        subprocess.Popen(sleeper, env=dict(base, SteamAppId="9" * 5000)),
        subprocess.Popen(
            sleeper, env=dict(base, **{f"PAD{i}": "p" * 100_000 for i in range(8)}, SteamAppId=str(padded))
        ),
        subprocess.Popen(sleeper, env=dict(base, SteamAppId=str(game))),
    ]
    try:
        for proc in procs:
            started(proc)
        game_map = GameMap({game: "mouse", padded: "spacecraft", int("9" * 10): "x"}, {})
        found = ProcessScanner().games(game_map)
        assert [(g.key, g.pid) for g in found] == [(game, procs[2].pid)], found
    finally:
        for proc in procs:
            proc.kill()
            proc.wait()


# --- per-game profiles under the unit as shipped ------------------------------------------------
_SCAN = (
    "import sys\nfrom neurotouch_hid.service.games import GameMap, ProcessScanner\n"
    "print(' '.join(str(g.pid) for g in ProcessScanner().games(GameMap({4242: 'mouse'}, {}))))\n"
)


def test_the_shipped_unit_lets_the_driver_see_the_users_games():
    """The scanner run as the unit runs it (in the user namespace ``PrivateUsers=`` would make,
    ``unshare --user --map-current-user``, if the unit asked for it): a Steam game of the same
    user beside it is found. In such a namespace the kernel refuses to show the driver any other
    process's environment and executable, so no game was ever found under the service; the unit
    asks for no namespace (test_packaging.py, tests/kernel/checks_user_unit.py)."""
    from test_packaging import UNIT, _rule_lines

    private_users = "PrivateUsers=yes" in set(_rule_lines(UNIT.read_text()))
    wrap = ["unshare", "--user", "--map-current-user"] if private_users else []
    game = subprocess.Popen(
        [sys.executable, "-c", "import time; time.sleep(120)"], env={"PATH": os.environ["PATH"], "SteamAppId": "4242"}
    )
    try:
        started(game)
        found = subprocess.run(
            [*wrap, sys.executable, "-c", _SCAN], env=_env(), capture_output=True, text=True, timeout=60, cwd=ROOT
        )
        assert found.returncode == 0, found.stderr
        assert str(game.pid) in found.stdout.split(), f"the game (pid {game.pid}) was not found: {found.stdout!r}"
    finally:
        game.kill()
        game.wait()
