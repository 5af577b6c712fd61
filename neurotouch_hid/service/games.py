"""A profile per game: the user's map from a game to a profile, the mapped games running now, and
the running driver's watcher that switches to a game's profile while the game runs.

The map is ``games.yaml`` beside the user's profiles folder
(``$XDG_CONFIG_HOME/neurotouch-hid/games.yaml``; ``neurotouch-hid profile auto add/remove`` edit
it, comments kept): ``steam:`` maps a Steam app id, ``executable:`` a process name, to a profile.

A game is recognised among the processes of the user running the driver (psutil reads
``/proc``): a Steam game by ``SteamAppId`` in its environment (every process Steam starts for a
game inherits it, Proton's included), any program by its name (the kernel's process name, the
file name of its executable or of its command line's first word: ``Game.exe`` under Wine). So it
works the same on X11, Wayland and a console, without asking the desktop which window has focus.
When several mapped games run, the one started last counts. A game a wrapper execs late is found.

The watcher (:class:`GameProfiles`) polls every :data:`POLL_S`, a timer on the run's loop: when a
mapped game starts, the driver switches to its profile by the same path as ``profile use`` (every
output released and centred first); when it exits, back to the profile it had before. A ``profile
use`` while a game runs wins until that game exits. ``games.yaml`` is read again when it changes.
"""

from __future__ import annotations

import contextlib
import logging
import os
import threading
import time
from dataclasses import dataclass
from pathlib import Path, PureWindowsPath
from typing import TYPE_CHECKING, Any, Callable

import psutil

from neurotouch_hid.core.errors import NeurotouchError
from neurotouch_hid.core.limits import (
    YamlError,
    key_line,
    load_yaml,
    printable,
    read_outside_text,
    read_proc_file,
    read_proc_once,
    short,
    where,
)

if TYPE_CHECKING:
    from neurotouch_hid.engine.loop import Loop

log = logging.getLogger(__name__)

#: The environment variable Steam sets for the processes of a game it starts (its app id).
STEAM_APP_ENV = "SteamAppId"
#: How often the driver looks at the user's processes (s): a game's profile is on within this
#: (plus a profile load, milliseconds) of the game's start.
POLL_S = 0.5
#: A process younger than this (s) when it was read is read again at the next polls: a program
#: started by fork and exec may be seen between the two, under its parent's name.
YOUNG_S = 2.0
STEAM, EXECUTABLE = "steam", "executable"
#: Largest games.yaml (bytes): an entry is a line of some 40 bytes.
MAX_GAMES_BYTES = 256 * 1024
#: Most games in one section: a scan compares every process with each.
MAX_GAMES = 1000
#: Largest Steam app id (they are 32-bit numbers); a longer SteamAppId is no app's.
MAX_STEAM_APP_ID = 2**32 - 1
#: Longest executable name (NAME_MAX, a file name's most bytes on Linux).
MAX_NAME_CHARS = 255
#: Most bytes read of a process's environment or command line (``/proc/PID/environ``,
#: ``cmdline``): a desktop session's environment is a few KB; what lies beyond is not looked at.
MAX_PROC_BYTES = 128 * 1024
HEADER = (
    "# neurotouch-hid: a profile per game (`neurotouch-hid profile auto add GAME PROFILE` edits this file).\n"
    "# steam: Steam app id -> profile; executable: process name -> profile. Profiles: names or paths.\n"
)


class GameMapError(NeurotouchError):
    """games.yaml cannot be read or breaks its format, or an entry to add or remove is invalid."""


def games_file() -> Path:
    """The user's map: ``platformdirs.user_config_dir("neurotouch-hid")/games.yaml``, beside the
    profiles folder (:func:`~neurotouch_hid.mapping.profile.user_profiles_dir`). Not created here."""
    from neurotouch_hid.mapping.profile import user_profiles_dir

    return user_profiles_dir().parent / "games.yaml"


@dataclass(frozen=True)
class GameMap:
    """Game -> profile (a name or an absolute path): ``steam`` by app id, ``executable`` by name."""

    steam: dict[int, str]
    executable: dict[str, str]

    def __bool__(self) -> bool:
        return bool(self.steam or self.executable)

    def profile_for_name(self, names: set[str]) -> tuple[str, str] | None:
        """``(mapped name, profile)`` for the first of the map's executables among ``names``
        (compared case-insensitively), or None."""
        folded = {n.casefold() for n in names}
        for name, profile in self.executable.items():
            if name.casefold() in folded:
                return name, profile
        return None


def parse_game(game: str) -> tuple[str, int | str]:
    """What ``profile auto add GAME`` means: a number is a Steam app id (``("steam", 4242)``),
    anything else an executable's name (``("executable", "supertuxkart")``).

    Raises:
        GameMapError: empty, a path (a name is matched, not a path), a number past
            :data:`MAX_STEAM_APP_ID` or a name longer than :data:`MAX_NAME_CHARS`.
    """
    game = game.strip()
    if game.isascii() and game.isdigit():
        app_id = _app_id(game)
        if app_id is None:
            raise GameMapError(f"'{printable(game)}' is not a Steam app id (a whole number up to {MAX_STEAM_APP_ID})")
        return STEAM, app_id
    if not game or "/" in game or "\\" in game:
        name = Path(game.replace(chr(92), "/")).name or "supertuxkart"
        raise GameMapError(
            f"'{printable(game)}' is not a game: give a Steam app id (a number) or an executable's name without "
            f"its folder (e.g. {printable(name)})"
        )
    if len(game) > MAX_NAME_CHARS or not game.isprintable():
        raise GameMapError(
            f"'{printable(game)}' is not an executable's name (at most {MAX_NAME_CHARS} printable characters)"
        )
    return EXECUTABLE, game


def _app_id(text: str) -> int | None:
    """A Steam app id from its decimal digits (ASCII), or None when it is none (too long, not
    digits): never converts more than 10 digits."""
    if not (0 < len(text) <= 10 and text.isascii() and text.isdigit()):
        return None
    value = int(text)
    return value if value <= MAX_STEAM_APP_ID else None


def _check_section(path: Path, data: dict, section: str, root: Any) -> dict:
    value = data.get(section) or {}
    if not isinstance(value, dict):
        raise GameMapError(
            f"{where(path, key_line(root, section))}: '{section}' must map games to profiles (GAME: PROFILE), "
            f"found {short(value)}"
        )
    if len(value) > MAX_GAMES:
        raise GameMapError(
            f"{where(path, key_line(root, section))}: {section}: {len(value)} games "
            f"(at most {MAX_GAMES}, docs/limits.md)"
        )
    for game, profile in value.items():
        at = where(path, key_line(root, section, game))
        if not isinstance(profile, str) or not profile.strip():
            raise GameMapError(
                f"{at}: {section}.{printable(game)}: expected a profile name or path, found {short(profile)}"
            )
        if section == STEAM and not (
            isinstance(game, int) and not isinstance(game, bool) and 0 <= game <= MAX_STEAM_APP_ID
        ):
            quoted = isinstance(game, str) and _app_id(game) is not None
            raise GameMapError(
                f"{at}: steam: '{printable(game)}' is not a Steam app id (a whole number up to {MAX_STEAM_APP_ID})"
                + ("; write it without quotes" if quoted else "")
            )
        if section == EXECUTABLE and not isinstance(game, str):
            raise GameMapError(f"{at}: executable: '{printable(game)}' is not a name (quote it)")
        if section == EXECUTABLE and (len(game) > MAX_NAME_CHARS or not game.isprintable()):
            raise GameMapError(
                f"{at}: executable: '{printable(game)}' is not a name (at most {MAX_NAME_CHARS} printable characters)"
            )
        if section == EXECUTABLE and ("/" in game or "\\" in game):
            name = PureWindowsPath(game).name or "Game.exe"
            raise GameMapError(
                f"{at}: executable: '{printable(game)}' is a path: a process is matched by its executable's name, "
                f"written without its folder (e.g. {printable(name)})"
            )
    return value


def _load_document(path: Path, round_trip: bool = False) -> Any:
    """games.yaml's document (None when there is no file): read and parsed within the bounds of
    :mod:`neurotouch_hid.core.limits` (a regular file of at most :data:`MAX_GAMES_BYTES`, YAML depth,
    aliases, numbers and strings bounded), then checked. ``round_trip``: ruamel's round-trip
    document (comments kept, for ``profile auto add/remove``), parsed only once the bounded
    parse passed; else plain Python data."""
    try:
        text = read_outside_text(path, MAX_GAMES_BYTES, "games file", GameMapError, missing=None)
    except FileNotFoundError:
        return None
    try:
        data, root = load_yaml(text)
    except YamlError as exc:
        raise GameMapError(f"{where(path, exc.line)}: not valid YAML: {exc.problem}; fix or delete it") from None
    if data is not None and not isinstance(data, dict):
        raise GameMapError(
            f"{where(path, key_line(root))}: expected the sections 'steam:' and 'executable:', "
            f"found {type(data).__name__}"
        )
    unknown = [k for k in (data or {}) if k not in (STEAM, EXECUTABLE)]
    if unknown:
        names = printable(", ".join(sorted(printable(k) for k in unknown)), 200)
        raise GameMapError(
            f"{where(path, key_line(root, unknown[0]))}: unknown section(s) {names} "
            "(expected 'steam:' and 'executable:')"
        )
    for section in (STEAM, EXECUTABLE):
        _check_section(path, data or {}, section, root)
    if not round_trip:
        return data
    from ruamel.yaml import YAML

    yaml = YAML()  # round-trip: `profile auto add/remove` keep the user's comments
    yaml.width = 4096
    return yaml.load(text)


def load_game_map(path: Path | None = None) -> GameMap:
    """Read the map (``path``, default :func:`games_file`); a missing file is an empty map.

    Raises:
        GameMapError: unreadable, not YAML, or not the format above (file, line where YAML
            says, and what was expected).
    """
    data = _load_document(path if path is not None else games_file()) or {}
    return GameMap(
        steam={int(k): str(v) for k, v in (data.get(STEAM) or {}).items()},
        executable={str(k): str(v) for k, v in (data.get(EXECUTABLE) or {}).items()},
    )


def _save(path: Path, data: Any) -> None:
    import io

    from ruamel.yaml import YAML

    from neurotouch_hid.mapping.editor import _write

    yaml = YAML()
    yaml.width = 4096
    yaml.dump(data, buffer := io.StringIO())
    _write(path, buffer.getvalue())


def add_game(game: str, profile: str, path: Path | None = None) -> tuple[str, int | str, str]:
    """Map ``game`` (a Steam app id or an executable's name, :func:`parse_game`) to ``profile``
    (a name, or a path stored as an absolute path) in the map; returns ``(section, key,
    profile)``. The profile must exist and be valid (it is loaded here).

    Raises:
        GameMapError: a bad game or map file; ProfileError: no such profile, or an invalid one.
    """
    from ruamel.yaml.comments import CommentedMap

    from neurotouch_hid.mapping.profile import _is_path, load_profile

    section, key = parse_game(game)
    load_profile(profile)
    if _is_path(profile):
        profile = str(Path(profile).resolve())
    path = path if path is not None else games_file()
    from neurotouch_hid.mapping.editor import _editing

    with _editing(path.parent, "the per-game profiles"):  # side by side, every entry lands
        data = _load_document(path, round_trip=True)
        if data is None:
            data = CommentedMap()
            data.yaml_set_start_comment(HEADER.replace("# ", "").rstrip("\n"))
        if data.get(section) is None:
            data[section] = CommentedMap()
        data[section][key] = profile
        _save(path, data)
    return section, key, profile


def remove_game(game: str, path: Path | None = None) -> tuple[str, int | str, str]:
    """Remove ``game``'s entry; returns ``(section, key, the profile it had)``.

    Raises:
        GameMapError: a bad game or map file, or no such entry (the entries are listed).
    """
    section, key = parse_game(game)
    path = path if path is not None else games_file()
    from neurotouch_hid.mapping.editor import _editing

    with _editing(path.parent, "the per-game profiles"):
        return _remove_entry(path, game, section, key)


def _remove_entry(path: Path, game: str, section: str, key: int | str) -> tuple[str, int | str, str]:
    data = _load_document(path, round_trip=True)
    entries = (data or {}).get(section) or {}
    if key not in entries:
        known = load_game_map(path)
        listed = [str(k) for k in known.steam] + list(known.executable)
        mapped = ", ".join(listed) or "nothing"
        raise GameMapError(f"'{game}' is not in {path} (mapped: {mapped}; see `neurotouch-hid profile auto list`)")
    profile = str(entries.pop(key))
    if not entries:  # no empty section left behind (ruamel would write "{}" after its comment)
        del data[section]
    _save(path, data)
    return section, key, profile


@dataclass(frozen=True)
class Game:
    """A mapped game running now: ``section`` (steam or executable), ``key`` (app id or mapped
    name), its ``profile``, and the process found: ``pid``, ``name``, ``started`` (s since the
    epoch, psutil's ``create_time``)."""

    section: str
    key: int | str
    profile: str
    pid: int
    name: str
    started: float

    @property
    def ident(self) -> tuple[int, float]:
        """The process (a pid is reused only by a later process)."""
        return self.pid, self.started

    @property
    def entry(self) -> tuple[str, int | str]:
        """The map's entry it matched, ``(section, key)``: the same for every process of the game
        (a launcher, the game it starts, their helpers)."""
        return self.section, self.key

    def label(self) -> str:
        """How the user is told, e.g. ``Steam app 4242 (pid 1234, sleep)``."""
        what = f"Steam app {self.key}" if self.section == STEAM else printable(self.key)
        return f"{what} (pid {self.pid}, {printable(self.name)})"


@dataclass
class _Seen:
    started: float
    read_at: float
    comm: bytes | None = None  # /proc/PID/comm as read then: another one means the process exec'ed
    name: str = ""
    names: frozenset[str] = frozenset()
    app_id: int | None = None
    ours: bool = False


def _steam_app_id(pid: int) -> int | None:
    """``SteamAppId`` in process ``pid``'s environment (the first :data:`MAX_PROC_BYTES` of
    ``/proc/PID/environ``), or None: absent, not a valid app id, or not readable."""
    try:
        data, _ = read_proc_file(f"/proc/{pid}/environ", MAX_PROC_BYTES)
    except OSError:
        return None
    key = STEAM_APP_ENV.encode() + b"="
    for entry in data.split(b"\0"):
        if entry.startswith(key):
            return _app_id(entry[len(key) : len(key) + 11].decode("ascii", "replace"))
    return None


def _first_word(pid: int) -> str:
    """The file name of process ``pid``'s command line's first word (``Game.exe`` of Wine's
    ``Z:\\...\\Game.exe``), from the first :data:`MAX_PROC_BYTES` of ``/proc/PID/cmdline``;
    empty when unreadable."""
    try:
        data, _ = read_proc_file(f"/proc/{pid}/cmdline", MAX_PROC_BYTES)
    except OSError:
        return ""
    first = data.split(b"\0", 1)[0].decode("utf-8", "surrogateescape")
    return PureWindowsPath(first).name[:MAX_NAME_CHARS] if first else ""  # splits on / and \\


def _read_process(pid: int, uid: int) -> _Seen | None:
    """What the scanner needs of one process: None when it is gone or unreadable.

    psutil gives its start time and owner; the kernel name (``comm``, 15 bytes) and the
    executable (``readlink`` of ``/proc/PID/exe``, at most PATH_MAX; refused for a process that
    is not dumpable, where psutil's ``exe()`` would read the whole command line instead) are read
    here; the environment and the command line, which the process itself fills and may make
    megabytes long, are read bounded (:func:`read_proc_file`)."""
    try:
        proc = psutil.Process(pid)  # comm first: an exec during this read changes it again
        seen = _Seen(comm=_comm_bytes(pid), started=proc.create_time(), read_at=time.time())
        if proc.uids().real != uid:
            return seen  # another user's: no game of ours (read again only while young)
        seen.ours = True
        # the environment first: a fork that exec's meanwhile shows its new environment only
        # once it has its new name, so a game found by SteamAppId is never named as its parent
        seen.app_id = _steam_app_id(pid)
        seen.name = _comm(pid)
        names = {seen.name, _first_word(pid)}
        with contextlib.suppress(OSError):  # a game updated while it runs: its file "game (deleted)"
            exe = os.readlink(f"/proc/{pid}/exe").removesuffix(" (deleted)")
            names.add(os.path.basename(exe)[:MAX_NAME_CHARS])
        seen.names = frozenset(n for n in names if n)
        return seen
    except (psutil.NoSuchProcess, psutil.AccessDenied, psutil.ZombieProcess, OSError):
        return None


def _running(pid: int) -> bool:
    """Whether process ``pid`` still runs: False when it is gone or a zombie (it exited and its
    parent has not yet waited for it: it stays in ``/proc`` under its name). The state is the
    field after the name in ``/proc/PID/stat`` (proc(5)), within its first 256 bytes."""
    try:
        data, _ = read_proc_file(f"/proc/{pid}/stat", 256)
    except OSError:
        return False
    return data.rpartition(b")")[2][1:2] not in (b"Z", b"X", b"x")


def _comm_bytes(pid: int) -> bytes | None:
    """``/proc/PID/comm`` (None: unreadable): what a scan pays per process to notice an exec."""
    return read_proc_once(f"/proc/{pid}/comm", 64)


def _comm(pid: int) -> str:
    """The kernel's name of process ``pid`` (``/proc/PID/comm``, at most 15 bytes; psutil's
    ``name()`` would read the whole command line to complete a 15-byte one)."""
    data, _ = read_proc_file(f"/proc/{pid}/comm", 64)
    return data.decode("utf-8", "surrogateescape").rstrip("\n")


class ProcessScanner:
    """The mapped games among the processes of this user (psutil).

    A process is read (name, executable, command line, ``SteamAppId``) when a scan first sees it,
    again while it is younger than :data:`YOUNG_S` (a fork not yet exec'ed has its parent's name
    and user), and whenever its ``/proc/PID/comm``, read at every scan, changed: an exec however
    late (a wrapper that execs the game after seconds), another user's process too. The scanner's
    own process is never a game (a driver started from Steam inherits SteamAppId)."""

    def __init__(self, uid: int | None = None):
        self._uid = os.getuid() if uid is None else uid
        self._seen: dict[int, _Seen] = {}
        self._own = os.getpid()

    def games(self, game_map: GameMap) -> list[Game]:
        """Every mapped game running now, the one started last first."""
        pids = set(psutil.pids())
        pids.discard(self._own)
        for gone in self._seen.keys() - pids:
            del self._seen[gone]
        now = time.time()
        found = []
        for pid in pids:
            seen = self._seen.get(pid)
            # read again while young (a fork not yet exec'ed or dropped to this uid, sudo -u) or exec'ed
            young = seen is not None and seen.read_at - seen.started < YOUNG_S and now - seen.read_at > 0.1
            if seen is None or young or _comm_bytes(pid) != seen.comm:
                seen = _read_process(pid, self._uid)
                if seen is None:
                    continue
                self._seen[pid] = seen
            if not seen.ours:
                continue
            if seen.app_id is not None and seen.app_id in game_map.steam:
                found.append(Game(STEAM, seen.app_id, game_map.steam[seen.app_id], pid, seen.name, seen.started))
                continue
            hit = game_map.profile_for_name(set(seen.names))
            if hit is not None:
                found.append(Game(EXECUTABLE, hit[0], hit[1], pid, seen.name, seen.started))
        found = [game for game in found if _running(game.pid)]
        return sorted(found, key=lambda g: (g.started, g.pid), reverse=True)


class GameProfiles:
    """The running driver's profile per game (see the module's docstring).

    Args:
        use: switches the driver (``Engine.use_profile(ref, reason)``: loads ``ref``, releases
            every output, maps with the new profile, logs the switch; raises NeurotouchError
            and changes nothing for a bad profile).
        profile: the profile the driver runs now (a name or path): the one it returns to.
        path: the map (default :func:`games_file`).
        scanner: where the games come from (a :class:`ProcessScanner` by default).
        on_game: told the game whose profile is on (None: none), e.g. for the live view.
    """

    def __init__(
        self,
        use: Callable[[str, str | None], str],
        profile: str,
        *,
        path: Path | None = None,
        poll_s: float = POLL_S,
        scanner: ProcessScanner | None = None,
        on_game: Callable[[Game | None], None] | None = None,
    ):
        self._use, self._on_game, self._poll_s = use, on_game, poll_s
        self._base = self._current = profile
        self._path = path if path is not None else games_file()
        self._scanner = scanner if scanner is not None else ProcessScanner()
        self._map, self._map_stamp = GameMap({}, {}), None  # the map, its file's (mtime ns, size)
        self._game: Game | None = None  # the game whose profile was asked for
        self._manual_during: tuple[str, int | str] | None = None  # a `profile use` while this game ran
        self._lock, self._stop = threading.Lock(), threading.Event()
        self._loop: Loop | None = None  # where it polls (:meth:`start`), its own or not
        self._own_loop, self._timer, self._failed = False, None, ""  # (the last failure logged)

    @property
    def game(self) -> Game | None:
        """The mapped game the driver follows now, or None."""
        return self._game

    def manual_use(self, ref: str) -> str:
        """``profile use REF`` (the control socket): switch now; while a mapped game runs this wins
        until that game exits, otherwise ``ref`` becomes the profile to come back to."""
        with self._lock:
            message = self._use(ref, None)
            self._current = ref
            if self._game is not None:
                self._manual_during = self._game.entry
                message += f" (until {self._game.label()} exits)"
            else:
                self._base = ref
            return message

    def _read_map(self) -> GameMap:
        """The map, read again when games.yaml changed; a broken one keeps the last good map
        (said once)."""
        try:
            st = self._path.stat()
            stamp = (st.st_mtime_ns, st.st_size)
        except OSError:
            stamp = None
        if stamp != self._map_stamp:
            self._map_stamp = stamp
            try:
                self._map = load_game_map(self._path) if stamp is not None else GameMap({}, {})
            except GameMapError as exc:
                log.error("profiles per game: %s (keeping the map read before)", exc)
        return self._map

    def poll(self) -> None:
        """Look at the processes once and switch if the game to follow changed."""
        game_map = self._read_map()
        games = self._scanner.games(game_map) if game_map else []
        with self._lock:
            if self._manual_during is not None:
                if any(g.entry == self._manual_during for g in games):
                    return  # the user chose a profile during this game: theirs until all of it exits
                self._manual_during = None
            game = games[0] if games else None
            if game == self._game:
                return
            previous, self._game = self._game, game
            if game is not None:
                target, reason = game.profile, f"{game.label()} is running"
            else:
                target, reason = self._base, f"{previous.label()} exited" if previous else None
            if self._on_game is not None:
                self._on_game(game)
            if target == self._current:
                return
            try:
                self._use(target, reason)
                self._current = target
            except NeurotouchError as exc:
                log.error(
                    "%s, but profile %s could not be used: %s (staying on %s)", reason, target, exc, self._current
                )

    def _tick(self) -> None:
        """A poll (a failure logged once while it stays the same: profiles stay as they are), the
        next one ``poll_s`` later on the loop, until :meth:`stop`."""
        if self._stop.is_set():
            return
        try:
            self.poll()
            self._failed = ""
        except Exception as exc:
            why = printable(f"{type(exc).__name__}: {exc}", 200)
            if why != self._failed:
                log.error("profiles per game: looking at the processes failed: %s", why)
            self._failed = why
        self._timer = None if self._stop.is_set() else self._loop.call_later(self._poll_s, self._tick)

    def start(self, loop: Loop | None = None) -> None:
        """Poll every ``poll_s`` until :meth:`stop`: a timer on ``loop`` (the run's, no thread of
        its own), else on a loop of its own in a thread."""
        from neurotouch_hid.engine.loop import Loop

        self._own_loop, self._loop = loop is None, loop if loop is not None else Loop()
        self._timer = self._loop.call_later(self._poll_s, self._tick)
        if self._own_loop:
            self._loop.run_in_thread("nt-games")

    def stop(self) -> None:
        self._stop.set()
        if self._timer is not None:
            self._timer.cancel()
        if self._own_loop:
            self._loop.close()
