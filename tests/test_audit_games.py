"""A profile per game and the control socket, as a user meets them: a game of several processes, a
game that exited but is not yet reaped, a process whose executable cannot be read, a games.yaml
written by hand with a path, a request on the control socket with a NUL in its profile."""

from __future__ import annotations

import json
import os
import secrets
import socket
import subprocess
import sys
import time
from pathlib import Path

import psutil
import pytest
from helpers import wait_until

from neurotouch_hid.core.errors import ProfileError
from neurotouch_hid.service.control import ControlServer
from neurotouch_hid.service.games import (
    GameMap,
    GameMapError,
    GameProfiles,
    ProcessScanner,
    add_game,
    games_file,
    load_game_map,
)

#: An app id no other process has (past every real Steam app's, holding this process's pid): the
#: scanner sees every process of this user.
APP_ID = 3_100_000_000 + os.getpid() * 256 + secrets.randbelow(256)
SLEEP = [sys.executable, "-c", "import time; time.sleep(600)"]


class Switches:
    """Stands in for Runtime.use_profile: records (profile, reason)."""

    def __init__(self):
        self.calls: list[tuple[str, str | None]] = []

    def __call__(self, ref: str, reason: str | None) -> str:
        self.calls.append((ref, reason))
        return f"switched to profile {ref}"


def _steam(start) -> subprocess.Popen:
    return start(SLEEP, env=dict(os.environ, SteamAppId=str(APP_ID)))


def _wait_zombie(pid: int) -> None:
    """Until the killed process is a zombie (the bound only ends a hang)."""
    assert wait_until(lambda: psutil.Process(pid).status() == psutil.STATUS_ZOMBIE, 300), f"{pid} never ended"


def test_a_manual_profile_use_lasts_while_any_process_of_that_game_runs(children):
    """A Steam game is several processes (a launcher, then the game it starts, then helpers): the
    user's `profile use` during the game held only while the one process that was newest at the
    time ran, and the game's profile came back while the game still ran."""
    add_game(str(APP_ID), "mouse")
    use = Switches()
    games = GameProfiles(use, "default")
    launcher = _steam(children)
    time.sleep(0.05)  # create_time has clock-tick resolution
    game = _steam(children)
    games.poll()
    assert use.calls[-1][0] == "mouse"
    games.manual_use("accessibility")
    game.kill()
    game.wait(10)  # the newest process of the game exits; its launcher still runs
    games.poll()
    assert use.calls[-1] == ("accessibility", None), use.calls
    launcher.kill()
    launcher.wait(10)
    games.poll()  # the whole game exited: back to the profile the driver had
    assert use.calls[-1][0] == "default"


def test_a_game_that_exited_but_is_not_yet_reaped_is_not_running(children):
    """A game whose parent (its launcher) has not yet waited for it stays a zombie in /proc, under
    its name and with its pid: the driver stayed on the game's profile."""
    game = _steam(children)
    scanner = ProcessScanner()
    game_map = GameMap({APP_ID: "mouse"}, {})
    assert [g.pid for g in scanner.games(game_map)] == [game.pid]
    os.kill(game.pid, 9)
    _wait_zombie(game.pid)
    assert scanner.games(game_map) == []
    use = Switches()
    watcher = GameProfiles(use, "default", scanner=scanner)
    watcher.poll()
    assert use.calls == [] and watcher.game is None


def test_a_process_whose_executable_is_refused_has_its_command_line_read_bounded(children, monkeypatch):
    """``/proc/PID/exe`` is refused for a process that is not dumpable (ssh-agent, an anti-cheat, a
    program that changed its user), and psutil then read the process's whole command line to guess
    its executable: megabytes a process may choose, past the bounded reader."""
    import psutil._pslinux as pslinux

    import neurotouch_hid.service.games as games

    proc = children([sys.executable, "-c", "import time; time.sleep(600)", *["x" * 100_000] * 12])
    real_readlink, read_whole = os.readlink, []

    def refused(path, *args, **kwargs):
        if str(path) == f"/proc/{proc.pid}/exe":
            raise PermissionError(13, "Permission denied", str(path))
        return real_readlink(path, *args, **kwargs)

    def denied(self):
        raise psutil.AccessDenied(self.pid)

    monkeypatch.setattr(os, "readlink", refused)
    monkeypatch.setattr(pslinux.Process, "exe", denied)
    monkeypatch.setattr(pslinux.Process, "cmdline", lambda self: read_whole.append(self.pid) or [])
    seen = games._read_process(proc.pid, os.getuid())
    assert seen is not None and seen.ours
    assert read_whole == [], "the whole command line was read"
    assert Path(sys.executable).name[:15] in seen.names or "python" in " ".join(seen.names)


def _refused(text: str) -> tuple[Path, str]:
    """games.yaml written as ``text``: its path and the error loading it."""
    path = games_file()
    path.parent.mkdir(parents=True)
    path.write_text(text)
    with pytest.raises(GameMapError) as caught:
        load_game_map()
    message = str(caught.value)
    return path, message


@pytest.mark.parametrize(
    ("text", "line"),
    [
        ("executable:\n  supertuxkart: mouse\n  /usr/games/supertuxkart: spacecraft\n", 3),
        ('executable:\n  "C:\\\\Games\\\\Game.exe": mouse\n', 2),
    ],
)
def test_an_executable_written_as_a_path_in_games_yaml_is_refused_with_its_line(text, line):
    """A name is matched, not a path: a path written by hand in games.yaml never matched any
    process, and nothing said so (``profile auto add`` refuses it)."""
    path, message = _refused(text)
    assert message.startswith(f"{path}:{line}: ") and "without its folder" in message, message


def test_a_profile_path_with_a_nul_gets_an_answer_and_the_server_keeps_serving(tmp_path):
    """A request whose profile path holds a NUL: the client thread died (ValueError, a traceback
    on the driver's log) and the client got no answer."""

    def use(ref: str) -> str:
        if ref != "default":
            raise ProfileError(f"no profile named {ref[:40]!r}")
        return "switched"

    folder = tmp_path / "run"
    folder.mkdir(mode=0o700)
    server = ControlServer(use, path=folder / "neurotouch-hid" / "control.sock")
    assert server.start()
    try:
        for profile in ("/tmp/a\0b.yaml", "a\0b"):
            answer = server._answer(json.dumps({"command": "use", "profile": profile}).encode())
            assert answer["ok"] is False and "NUL" in answer["message"], answer
            with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as sock:
                sock.settimeout(10)
                sock.connect(str(server.path))
                sock.sendall(json.dumps({"command": "use", "profile": profile}).encode() + b"\n")
                answer = json.loads(sock.makefile("rb").readline())
            assert answer["ok"] is False and "NUL" in answer["message"], answer
        assert server._answer(b'{"command": "use", "profile": "default"}') == {"ok": True, "message": "switched"}
    finally:
        server.stop()


@pytest.mark.parametrize(
    "text, expected",
    [
        ("steam:\n  true: mouse\n", "is not a Steam app id"),  # YAML's true is no app id 1
        ('steam:\n  "4242": mouse\n', "write it without quotes"),
    ],
)
def test_a_steam_key_that_is_no_number_is_refused_saying_what_to_write(text, expected):
    """``true`` was taken as Steam app 1; a quoted id was refused without saying the quotes were
    the problem."""
    path, message = _refused(text)
    assert message.startswith(f"{path}:2: ") and expected in message, message


def test_a_young_process_read_before_it_became_ours_is_read_again(monkeypatch):
    """A game started for the player by a process of another user (root forks, drops to the
    player's uid, then execs the game: a launcher, ``sudo -u``, a service) is read first while it
    still is the other user's; it must be read again while young, as a fork that has not exec'ed."""
    from neurotouch_hid.service import games

    started = time.time()
    reads = [
        games._Seen(started=started, read_at=started + 0.05),  # root's still: not ours
        games._Seen(started=started, read_at=started + 0.6, name="sleep", app_id=APP_ID, ours=True),
    ]
    monkeypatch.setattr(games.psutil, "pids", lambda: [4321])
    monkeypatch.setattr(games, "_read_process", lambda pid, uid: reads.pop(0) if reads else None)
    monkeypatch.setattr(games, "_running", lambda pid: True)
    monkeypatch.setattr(games.time, "time", lambda: started + 0.6)
    game_map = GameMap({APP_ID: "mouse"}, {})
    scanner = ProcessScanner(uid=os.getuid())
    assert scanner.games(game_map) == []
    found = scanner.games(game_map)
    assert [(g.key, g.profile) for g in found] == [(APP_ID, "mouse")], found


def test_a_game_a_wrapper_execs_after_it_is_no_longer_young_is_followed(tmp_path, monkeypatch):
    """A game started by a wrapper (a script, a launcher) that execs it after 2 s or more was never
    followed: the wrapper was read while young, under its own name, and never again."""
    import types

    from neurotouch_hid.service import games

    game_name = f"ntgame{os.getpid() % 100000}"  # the kernel's name: at most 15 bytes
    game = tmp_path / game_name
    game.symlink_to(os.path.realpath(sys.executable))
    wrapper = subprocess.Popen(
        [sys.executable, "-c", "import os, sys; sys.stdin.read(1); os.execv(sys.argv[1], sys.argv[1:])", str(game)]
        + ["-c", "import time; time.sleep(600)"],
        stdin=subprocess.PIPE,
    )
    try:
        scanner = ProcessScanner()
        game_map = GameMap({}, {game_name: "mouse"})
        # every read from now on is taken as made long after the wrapper started: no longer young
        monkeypatch.setattr(games, "time", types.SimpleNamespace(time=lambda: time.time() + 10 * games.YOUNG_S))
        deadline = time.monotonic() + 30
        while wrapper.pid not in scanner._seen or not scanner._seen[wrapper.pid].ours:
            assert scanner.games(game_map) == [] and time.monotonic() < deadline
        wrapper.stdin.write(b"x")
        wrapper.stdin.flush()
        comm = Path(f"/proc/{wrapper.pid}/comm")
        while comm.read_text().strip() != game_name:  # the exec happened
            assert time.monotonic() < deadline
            time.sleep(0.01)
        found = scanner.games(game_map)
        assert [(g.pid, g.key, g.profile) for g in found] == [(wrapper.pid, game_name, "mouse")], found
    finally:
        wrapper.kill()
        wrapper.wait(10)
