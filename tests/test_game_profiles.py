"""A profile per game (neurotouch_hid/games.py): the map and its CLI, the scanner on real
processes (a child with SteamAppId in its environment, a renamed executable, a fork that execs
late), the watcher's decisions, and a running `run --source sim` switched through its control
path by real processes."""

from __future__ import annotations

import os
import secrets
import shutil
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from neurotouch_hid.core.errors import ProfileError
from neurotouch_hid.service.control import SOCKET_NAME
from neurotouch_hid.service.games import (
    EXECUTABLE,
    STEAM,
    GameMap,
    GameMapError,
    GameProfiles,
    ProcessScanner,
    add_game,
    games_file,
    load_game_map,
    parse_game,
    remove_game,
)

REPO = Path(__file__).resolve().parent.parent
#: Generous: a loaded two-core machine; the driver polls every 0.5 s.
WAIT_S = 60.0
#: The Steam app id and the executable name of this run's games, which no other process has:
#: the scanner sees every process of this user, and other runs of these tests (other checkouts,
#: other users' sessions under the same uid) start games of their own at the same time. The id
#: is past every real Steam app's (they are under 10^7) and holds this process's pid, unique
#: among the processes running; the name is random, 11 characters (the kernel keeps 15 of a
#: process's name).
APP_ID = 3_000_000_000 + os.getpid() * 256 + secrets.randbelow(256)
GAME = f"tux{secrets.token_hex(4)}"


def _cli(*args: str, env: dict | None = None) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "neurotouch_hid.cli", *args],
        capture_output=True,
        text=True,
        env=dict(os.environ, PYTHONPATH=str(REPO), **(env or {})),
        timeout=120,
    )


def _wait_for(condition, timeout_s: float = WAIT_S, step_s: float = 0.05) -> bool:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if condition():
            return True
        time.sleep(step_s)
    return condition()


def _steam_game(start, app_id: int = APP_ID) -> subprocess.Popen:
    """A `sleep` Steam would have started: SteamAppId in its environment."""
    return start(["sleep", "600"], env=dict(os.environ, SteamAppId=str(app_id)))


def _renamed(start, tmp_path: Path, name: str = GAME) -> subprocess.Popen:
    """The `sleep` program copied under a game's name, started from there."""
    exe = tmp_path / "bin" / name
    exe.parent.mkdir(exist_ok=True)
    shutil.copy2(shutil.which("sleep"), exe)
    return start([str(exe), "600"])


def _stop(proc: subprocess.Popen) -> None:
    proc.kill()
    proc.wait(10)


# --- the map and its CLI -------------------------------------------------------------------------
def test_a_number_is_a_steam_app_and_a_name_an_executable():
    assert parse_game("4242") == (STEAM, 4242)
    assert parse_game("supertuxkart") == (EXECUTABLE, "supertuxkart")
    assert parse_game("Game.exe") == (EXECUTABLE, "Game.exe")
    for bad in ("", "  ", "/usr/games/supertuxkart", "C:\\Games\\game.exe"):
        with pytest.raises(GameMapError):
            parse_game(bad)


def test_add_and_remove_edit_games_yaml_beside_the_profiles_and_keep_the_users_comments(user_config_in_tmp):
    path = games_file()
    assert path == user_config_in_tmp / "neurotouch-hid" / "games.yaml"
    assert load_game_map() == GameMap({}, {})  # no file: nothing mapped
    assert add_game("4242", "mouse") == (STEAM, 4242, "mouse")
    text = path.read_text()
    path.write_text(text.replace("\nsteam:", "\nsteam:  # my Steam games"))
    add_game("supertuxkart", "spacecraft")
    add_game("4242", "accessibility")  # replaces
    assert load_game_map() == GameMap({4242: "accessibility"}, {"supertuxkart": "spacecraft"})
    assert "# my Steam games" in path.read_text()
    assert remove_game("supertuxkart") == (EXECUTABLE, "supertuxkart", "spacecraft")
    assert load_game_map() == GameMap({4242: "accessibility"}, {})
    assert "# my Steam games" in path.read_text()
    assert remove_game("4242") == (STEAM, 4242, "accessibility")
    assert load_game_map() == GameMap({}, {})


def test_a_profile_file_is_stored_as_its_absolute_path(tmp_path, monkeypatch):
    mine = tmp_path / "mine.yaml"
    shutil.copy(REPO / "neurotouch_hid" / "profiles" / "mouse.yaml", mine)
    monkeypatch.chdir(tmp_path)
    add_game("77", "mine.yaml")
    assert load_game_map().steam == {77: str(mine)}


def test_adding_an_unknown_or_invalid_profile_changes_nothing(tmp_path):
    add_game("4242", "mouse")
    before = games_file().read_text()
    with pytest.raises(ProfileError, match="no profile named 'nosuch'"):
        add_game("55", "nosuch")
    broken = tmp_path / "broken.yaml"
    broken.write_text("mappings: [\n")
    with pytest.raises(ProfileError):
        add_game("55", str(broken))
    assert games_file().read_text() == before


@pytest.mark.parametrize(
    ("text", "says", "line"),
    [
        ("steam:\n\t4242: mouse\n", "not valid YAML", 2),
        ("- 4242\n", "expected the sections", 1),
        ("# mine\ngames:\n  4242: mouse\n", "unknown section(s) games", 2),
        ("# mine\nsteam:\n  1: mouse\n  abc: mouse\n", "'abc' is not a Steam app id", 4),
        ("steam:\n  4242: 7\n", "steam.4242: expected a profile name or path", 2),
        ("# mine\nexecutable: mouse\n", "'executable' must map games to profiles", 2),
        ("executable:\n  supertux: mouse\n  42: mouse\n", "'42' is not a name", 3),
    ],
)
def test_a_broken_games_yaml_is_one_line_naming_the_file_and_line_exit_2(text, says, line):
    """The file, the line and what was expected (docs/profiles.md): a wrong section or game once
    named only the file."""
    path = games_file()
    path.parent.mkdir(parents=True)
    path.write_text(text)
    with pytest.raises(GameMapError) as caught:
        load_game_map()
    assert f"{path}:{line}: " in str(caught.value) and says in str(caught.value), str(caught.value)
    result = _cli("profile", "auto", "list", env={"XDG_CONFIG_HOME": os.environ["XDG_CONFIG_HOME"]})
    assert result.returncode == 2, result
    assert "Traceback" not in result.stderr and says in result.stderr
    assert result.stderr.strip().count("\n") == 0, result.stderr  # one line


def test_profile_auto_cli_adds_lists_what_runs_and_removes(children, tmp_path):
    env = {"XDG_CONFIG_HOME": os.environ["XDG_CONFIG_HOME"]}
    empty = _cli("profile", "auto", env=env)
    assert empty.returncode == 0 and "no game is mapped" in empty.stdout
    added = _cli("profile", "auto", "add", str(APP_ID), "mouse", env=env)
    assert added.returncode == 0 and added.stdout.startswith(f"Steam app {APP_ID} -> mouse"), added
    assert _cli("profile", "auto", "add", GAME, "spacecraft", env=env).returncode == 0
    game = _steam_game(children)
    listed = _cli("profile", "auto", "list", env=env)
    assert listed.returncode == 0, listed
    assert f"Steam app {APP_ID} -> mouse  running: pid {game.pid}" in listed.stdout
    assert f"{GAME} -> spacecraft\n" in listed.stdout
    assert f"matched now: Steam app {APP_ID} (pid {game.pid}, sleep) -> mouse" in listed.stdout
    refused = _cli("profile", "auto", "add", "4343", "nosuch", env=env)
    assert refused.returncode == 2 and "no profile named 'nosuch'" in refused.stderr
    removed = _cli("profile", "auto", "remove", str(APP_ID), env=env)
    assert removed.returncode == 0 and f"removed Steam app {APP_ID} -> mouse" in removed.stdout
    again = _cli("profile", "auto", "remove", str(APP_ID), env=env)
    assert again.returncode == 2 and f"'{APP_ID}' is not in" in again.stderr and GAME in again.stderr
    assert "matched now: none" in _cli("profile", "auto", env=env).stdout


# --- the processes ---------------------------------------------------------------------------------
def test_the_scanner_finds_a_steam_game_and_a_renamed_executable_newest_first(children, tmp_path):
    game_map = GameMap({APP_ID: "mouse"}, {GAME.upper(): "spacecraft"})  # names compare case-insensitively
    scanner = ProcessScanner()
    assert scanner.games(game_map) == []
    steam = _steam_game(children)
    children(["sleep", "600"])  # a sleep without SteamAppId is no game
    assert [(g.section, g.key, g.pid, g.name) for g in scanner.games(game_map)] == [(STEAM, APP_ID, steam.pid, "sleep")]
    time.sleep(0.05)  # create_time has clock-tick resolution
    tux = _renamed(children, tmp_path)
    found = scanner.games(game_map)
    assert [(g.key, g.pid, g.profile) for g in found] == [
        (GAME.upper(), tux.pid, "spacecraft"),
        (APP_ID, steam.pid, "mouse"),
    ]
    assert found[0].label() == f"{GAME.upper()} (pid {tux.pid}, {GAME})"
    _stop(tux)
    assert [g.pid for g in scanner.games(game_map)] == [steam.pid]
    _stop(steam)
    assert scanner.games(game_map) == []


def test_a_game_started_by_fork_then_exec_is_found_once_it_has_execd(children, tmp_path):
    """A process first seen under its parent's name (before its exec) is read again while young."""
    exe = tmp_path / "bin" / GAME
    exe.parent.mkdir()
    shutil.copy2(shutil.which("sleep"), exe)
    scanner = ProcessScanner()
    game_map = GameMap({}, {GAME: "spacecraft"})
    launcher = subprocess.Popen(
        [sys.executable, "-c", f"import os, sys; sys.stdin.readline(); os.execv({str(exe)!r}, ['x', '600'])"],
        stdin=subprocess.PIPE,
        text=True,
    )
    try:
        assert scanner.games(game_map) == []  # seen as python, waiting to exec
        launcher.stdin.write("go\n")
        launcher.stdin.flush()
        assert _wait_for(lambda: [g.pid for g in scanner.games(game_map)] == [launcher.pid], 10.0)
    finally:
        launcher.kill()
        launcher.wait(10)


def test_the_scanner_skips_its_own_process_even_with_steamappid(children):
    """A driver started from Steam inherits SteamAppId: it is not a game."""
    other = _steam_game(children)
    code = (
        "import os; from neurotouch_hid.service.games import GameMap, ProcessScanner; "
        f"print(os.getpid(), *[g.pid for g in ProcessScanner().games(GameMap({{{APP_ID}: 'mouse'}}, {{}}))])"
    )
    result = subprocess.run(
        [sys.executable, "-c", code],
        capture_output=True,
        text=True,
        env=dict(os.environ, PYTHONPATH=str(REPO), SteamAppId=str(APP_ID)),
        timeout=60,
    )
    own, *found = (int(x) for x in result.stdout.split())
    assert own not in found and other.pid in found, result


# --- the watcher's decisions, on real processes ----------------------------------------------------
class Switches:
    """Stands in for Runtime.use_profile: records (profile, reason); refuses 'broken'."""

    def __init__(self):
        self.calls: list[tuple[str, str | None]] = []

    def __call__(self, ref: str, reason: str | None) -> str:
        if ref == "broken":
            raise ProfileError("profile broken is invalid")
        self.calls.append((ref, reason))
        return f"switched to profile {ref}"


def test_the_watcher_follows_a_game_and_comes_back_to_the_profile_it_had(children, tmp_path):
    add_game(str(APP_ID), "mouse")
    use = Switches()
    games = GameProfiles(use, "default")
    games.poll()
    assert use.calls == [] and games.game is None
    steam = _steam_game(children)
    games.poll()
    assert use.calls == [("mouse", f"Steam app {APP_ID} (pid {steam.pid}, sleep) is running")]
    games.poll()  # nothing changed
    assert len(use.calls) == 1
    _stop(steam)
    games.poll()
    assert use.calls[-1] == ("default", f"Steam app {APP_ID} (pid {steam.pid}, sleep) exited")
    assert games.game is None


def test_a_manual_profile_use_during_a_game_wins_until_that_game_exits(children, tmp_path):
    add_game(str(APP_ID), "mouse")
    add_game(GAME, "spacecraft")
    use = Switches()
    games = GameProfiles(use, "default")
    assert games.manual_use("accessibility") == "switched to profile accessibility"  # no game: the new base
    steam = _steam_game(children)
    games.poll()
    assert use.calls[-1][0] == "mouse"
    answer = games.manual_use("switch-access")
    assert answer == f"switched to profile switch-access (until Steam app {APP_ID} (pid {steam.pid}, sleep) exits)"
    tux = _renamed(children, tmp_path)  # another mapped game starts: the user's choice still wins
    games.poll()
    assert use.calls[-1] == ("switch-access", None)
    _stop(steam)
    games.poll()  # the game it was chosen in exited: the game still running counts again
    assert use.calls[-1] == ("spacecraft", f"{GAME} (pid {tux.pid}, {GAME}) is running")
    _stop(tux)
    games.poll()
    assert use.calls[-1] == ("accessibility", f"{GAME} (pid {tux.pid}, {GAME}) exited")


def test_a_game_whose_profile_fails_keeps_the_driver_on_its_profile_and_says_so(children, caplog):
    path = games_file()
    path.parent.mkdir(parents=True)
    path.write_text(f"steam:\n  {APP_ID}: broken\n")
    use = Switches()
    games = GameProfiles(use, "default")
    _steam_game(children)
    games.poll()
    assert use.calls == []
    assert "but profile broken could not be used" in caplog.text and "staying on default" in caplog.text


def test_games_yaml_is_read_again_when_it_changes_and_a_broken_one_keeps_the_last(children, caplog):
    use = Switches()
    games = GameProfiles(use, "default")
    steam = _steam_game(children)
    games.poll()
    assert use.calls == []  # not mapped yet
    add_game(str(APP_ID), "mouse")  # `profile auto add` while the driver runs
    games.poll()
    assert use.calls == [("mouse", f"Steam app {APP_ID} (pid {steam.pid}, sleep) is running")]
    games_file().write_text("steam: [\n")
    games.poll()
    assert "keeping the map read before" in caplog.text
    assert len(use.calls) == 1


# --- the running driver ----------------------------------------------------------------------------
class Driver:
    """`neurotouch-hid run --source sim --output jsonl` in its own process; its stderr lines
    collected by a thread."""

    def __init__(self, env: dict, out: Path):
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "neurotouch_hid.cli", "run", "--source", "sim", "--output", "jsonl"]
            + ["--out", str(out), "--seconds", "600"],
            stdout=subprocess.DEVNULL,
            stderr=subprocess.PIPE,
            text=True,
            env=env,
        )
        self.lines: list[str] = []
        self._thread = threading.Thread(target=self._read, daemon=True)
        self._thread.start()

    def _read(self) -> None:
        for line in self.proc.stderr:
            self.lines.append(line.rstrip("\n"))

    def said(self, text: str) -> bool:
        return any(text in line for line in self.lines)

    def stop(self) -> int:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
        code = self.proc.wait(60)
        self._thread.join(10)
        return code


def test_a_running_driver_switches_to_a_games_profile_and_back_through_its_control_path(children, tmp_path):
    """The real `run` process, real games (a SteamAppId child, a renamed executable), the real
    control socket for the manual `profile use`."""
    runtime_dir = tmp_path / "xdg-runtime"
    runtime_dir.mkdir(mode=0o700)
    env = dict(os.environ, PYTHONPATH=str(REPO), XDG_RUNTIME_DIR=str(runtime_dir), PYTHONUNBUFFERED="1")
    add_game(str(APP_ID), "mouse")
    add_game(GAME, "spacecraft")
    states = tmp_path / "states.jsonl"
    driver = Driver(env, states)
    try:
        assert _wait_for(lambda: (runtime_dir / SOCKET_NAME).exists() or driver.proc.poll() is not None, 300)
        assert driver.proc.poll() is None, driver.lines
        steam = _steam_game(children)
        game = f"Steam app {APP_ID} (pid {steam.pid}, sleep)"
        assert _wait_for(lambda: driver.said(f"switched to profile mouse ({game} is running)")), driver.lines
        _stop(steam)
        assert _wait_for(lambda: driver.said(f"switched to profile default ({game} exited)")), driver.lines

        tux = _renamed(children, tmp_path)
        tux_game = f"{GAME} (pid {tux.pid}, {GAME})"
        assert _wait_for(lambda: driver.said(f"switched to profile spacecraft ({tux_game} is running)")), driver.lines
        manual = _cli("profile", "use", "accessibility", env={"XDG_RUNTIME_DIR": str(runtime_dir)})
        assert manual.returncode == 0, manual
        assert f"switched to profile accessibility (until {tux_game} exits)" in manual.stdout
        time.sleep(1.5)  # three polls while the game still runs: the user's choice stays (asserted below)
        _stop(tux)
        assert _wait_for(lambda: driver.said(f"switched to profile default ({tux_game} exited)")), driver.lines
    finally:
        code = driver.stop()
    switches = [line for line in driver.lines if line.startswith("switched to profile")]
    assert switches == [
        f"switched to profile mouse ({game} is running)",
        f"switched to profile default ({game} exited)",
        f"switched to profile spacecraft ({tux_game} is running)",
        "switched to profile accessibility",
        f"switched to profile default ({tux_game} exited)",
    ], driver.lines
    assert code == 0, driver.lines
    assert states.stat().st_size > 0


def test_a_steam_game_that_execs_while_it_is_read_is_never_named_as_its_parent(monkeypatch):
    """A fork exec's between two reads of it: whichever is read first sees the parent (its name
    ``python``, its environment without SteamAppId), what is read after sees the game. The
    environment is read first, so a game found by its SteamAppId has its own name."""
    import neurotouch_hid.service.games as games

    state = {"execd": False}

    def read_once(before, after):
        def read(pid):
            value = after if state["execd"] else before
            state["execd"] = True  # the exec happens right after the first read
            return value

        return read

    monkeypatch.setattr(games, "_comm", read_once("python", "sleep"))
    monkeypatch.setattr(games, "_steam_app_id", read_once(None, APP_ID))
    monkeypatch.setattr(games, "_first_word", lambda pid: "sleep" if state["execd"] else "python")
    seen = games._read_process(os.getpid(), os.getuid())
    assert seen.app_id is None and seen.name == "sleep"  # not a game yet: read again while young
    state["execd"] = True
    seen = games._read_process(os.getpid(), os.getuid())
    assert seen.app_id == APP_ID and seen.name == "sleep"


def test_a_steam_game_read_before_its_exec_wrote_its_environment_is_found_at_the_next_scan(children, monkeypatch):
    """Right after an exec the kernel has not yet written the new program's environment (its
    ``/proc/PID/environ`` reads empty, a few microseconds: ``helpers.started``): a game read then
    shows no SteamAppId, and is read again while young."""
    import neurotouch_hid.service.games as games

    real = games._steam_app_id
    reads: list[int] = []

    def first_read_mid_exec(pid: int) -> int | None:
        reads.append(pid)
        return None if reads.count(pid) == 1 else real(pid)

    monkeypatch.setattr(games, "_steam_app_id", first_read_mid_exec)
    scanner = ProcessScanner()
    game_map = GameMap({APP_ID: "mouse"}, {})
    steam = _steam_game(children)
    assert scanner.games(game_map) == []
    assert _wait_for(lambda: [g.pid for g in scanner.games(game_map)] == [steam.pid], 10.0)
    assert reads.count(steam.pid) == 2
