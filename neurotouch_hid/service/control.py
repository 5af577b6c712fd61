"""The running driver's control socket: ``neurotouch-hid profile use NAME`` switches its profile.

The driver (:class:`~neurotouch_hid.engine.engine.Engine`'s loop) listens on the Unix stream socket
:func:`socket_path` (``$XDG_RUNTIME_DIR/neurotouch-hid/control.sock``: per user, on a tmpfs only that user
can write). Neither side trusts the place as found: the folder must be the user's own and closed
to others (:func:`check_folder`; the driver repairs the mode of a folder of its own, and refuses
one of another user), and each side asks the kernel who the other is (``SO_PEERCRED``): the
driver answers only its own user, and ``profile use`` talks only to a driver of its own user
(a socket another user made would otherwise answer it).

A request is one JSON line ``{"command": "use", "profile": NAME_OR_ABSOLUTE_PATH}``; the answer
one JSON line ``{"ok": bool, "message": str}``. The driver loads the profile (a bad
one is refused and nothing changes), neutralises every output, then maps with the new profile.

Library: the standard library's :mod:`socket` (AF_UNIX); no D-Bus dependency.
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import socket
import stat
import struct
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Callable

from neurotouch_hid.core.errors import NeurotouchError
from neurotouch_hid.core.limits import printable

if TYPE_CHECKING:
    from neurotouch_hid.engine.loop import Loop, Timer

log = logging.getLogger(__name__)

#: The socket, under $XDG_RUNTIME_DIR: in a folder of its own (0700), the one place the systemd
#: unit lets the driver write there (RuntimeDirectory=neurotouch-hid).
SOCKET_NAME = "neurotouch-hid/control.sock"
#: Longest request or answer (bytes): a command and a profile path.
MAX_MESSAGE = 8192
#: How long the client waits for the driver's answer (s): loading a profile takes milliseconds.
ANSWER_TIMEOUT_S = 10.0
#: How long the driver waits for a client's request line (s): a client sends it at once; a
#: silent one is dropped after this, and never holds up the others (each waits on the loop).
REQUEST_TIMEOUT_S = 2.0
#: Clients served at once; more are answered "busy" and closed (threads and memory bounded).
MAX_CLIENTS = 8
#: Connections the kernel holds for the driver before it accepts them (``listen``'s backlog):
#: with 4, ten `profile use` run at once failed with "Resource temporarily unavailable". A
#: client finding it full, or answered busy, tries again until its answer's deadline.
BACKLOG = 128
#: The answer to a client over :data:`MAX_CLIENTS`.
BUSY = "the driver is busy; try again"
#: Deepest JSON nesting in a request (a request is a flat object).
MAX_JSON_DEPTH = 4


def check_folder(folder: Path, repair: bool = False) -> None:
    """Make sure nobody but this user can reach into ``folder`` (the socket's): a real folder (not
    a link), owned by this user, with no access for the group or others. ``repair``: a folder of
    this user's with a wider mode is narrowed to 0700 (logged) instead of refused.

    Raises:
        NeurotouchError: a link, not a folder, another user's, or open to others (not repaired).
    """
    info = os.lstat(folder)
    if not stat.S_ISDIR(info.st_mode):
        raise NeurotouchError(f"{folder} is not a folder (a link or a file): the control socket is not used")
    if info.st_uid != os.getuid():
        raise NeurotouchError(
            f"{folder} belongs to another user (uid {info.st_uid}): the control socket is not used "
            "(remove the folder, or set XDG_RUNTIME_DIR to your own runtime folder)"
        )
    if info.st_mode & 0o077:
        if not repair:
            raise NeurotouchError(
                f"{folder} is open to other users (mode {stat.S_IMODE(info.st_mode):o}): the control socket is not used"
            )
        os.chmod(folder, 0o700)
        log.warning("%s was open to other users (mode %o): made 0700", folder, stat.S_IMODE(info.st_mode))


def peer_uid(conn: socket.socket) -> int:
    """The user id of the process at the other end of a Unix socket (``SO_PEERCRED``, set by the
    kernel at connect time: the peer cannot forge it)."""
    creds = conn.getsockopt(socket.SOL_SOCKET, socket.SO_PEERCRED, struct.calcsize("3i"))
    return struct.unpack("3i", creds)[1]


def socket_path(serial: str | None = None) -> Path | None:
    """``$XDG_RUNTIME_DIR/neurotouch-hid/control.sock``, or for the driver of the camera
    ``serial`` ``control-SERIAL.sock`` beside it (two drivers, one per camera, each its own);
    None when XDG_RUNTIME_DIR is not set. Raises ValueError for an invalid serial."""
    runtime_dir = os.environ.get("XDG_RUNTIME_DIR")
    if not runtime_dir:
        return None
    if serial is None:
        return Path(runtime_dir) / SOCKET_NAME
    from neurotouch_hid.service.serials import check_serial

    return (Path(runtime_dir) / SOCKET_NAME).with_name(f"control-{check_serial(serial)}.sock")


def running_serials() -> list[str]:
    """The serials whose driver has a control socket file now (``control-SERIAL.sock``), sorted;
    a file may be left by a driver that was killed (:func:`request_use` then says nobody listens)."""
    path = socket_path()
    if path is None or not path.parent.is_dir():
        return []
    return sorted(p.name[len("control-") : -len(".sock")] for p in path.parent.glob("control-*.sock"))


def _chosen_socket(serial: str | None) -> Path | None:
    """The socket ``profile use`` talks to: the driver of ``serial``; without one, the driver
    started without a serial, else the one driver that has a serial. Raises NeurotouchError when
    several drivers with serials run and none was named, or for an invalid serial."""
    try:
        path = socket_path(serial)
    except ValueError as exc:
        raise NeurotouchError(f"--serial: {exc}") from None
    if serial is not None or path is None or path.exists():
        return path
    serials = running_serials()
    if len(serials) == 1:
        return socket_path(serials[0])
    if len(serials) > 1:
        raise NeurotouchError(
            f"a driver runs for each of the cameras {', '.join(serials)}: say which with --serial SERIAL"
        )
    return path


def _read_line(conn: socket.socket, within_s: float) -> bytes | None:
    """The first line (without its newline) of at most MAX_MESSAGE bytes, or None when the peer
    sends more than that without a newline. Raises TimeoutError when the line is not complete
    ``within_s`` seconds (in all: a peer sending a byte now and then gains nothing)."""
    deadline = time.monotonic() + within_s
    data = b""
    while b"\n" not in data:
        left = deadline - time.monotonic()
        if left <= 0:
            raise TimeoutError
        conn.settimeout(left)
        chunk = conn.recv(MAX_MESSAGE)
        if not chunk:
            break
        data += chunk
        if len(data) > MAX_MESSAGE and b"\n" not in data[: MAX_MESSAGE + 1]:
            return None
    line = data.split(b"\n", 1)[0]
    return line if len(line) <= MAX_MESSAGE else None


def _fit(message: str) -> str:
    """``message`` cut to fit an answer line the client reads (:data:`MAX_MESSAGE` bytes)."""
    limit = MAX_MESSAGE // 2  # JSON escapes may double it
    return message if len(message) <= limit else message[: limit - 5] + " ..."


def _json_depth(value, limit: int) -> int:
    """Nesting depth of a decoded JSON value, counted up to ``limit + 1`` at most."""
    depth, level = 0, [value]
    while level and depth <= limit:
        depth += 1
        level = [
            child
            for item in level
            if isinstance(item, (list, dict))
            for child in (item.values() if isinstance(item, dict) else item)
        ]
    return depth


def _not_a_profile(ref: str) -> str | None:
    """Why a profile given by path cannot be used, said without what the file holds (the path may
    name any file the driver can read: a key, a password file), or None when it loads. A profile
    given by name (the profile folders) is left to the driver, whose message is complete."""
    from neurotouch_hid.core.errors import ProfileError
    from neurotouch_hid.mapping.profile import _is_path, load_profile

    if not _is_path(ref):
        return None
    try:
        load_profile(ref)
    except ProfileError as exc:
        first = str(exc).split("\n", 1)[0]
        head, yaml_error, _ = first.partition(": not valid YAML: ")
        if yaml_error and "docs/limits.md" not in first:
            first = f"{head}: not valid YAML"
        first = first.split(" (docs/limits.md)")[0].split("docs/limits.md):")[0]
        return _fit(f"{printable(first, 600)} (`neurotouch-hid profile validate` on that file says why)")
    return None


class ControlServer:
    """Serves :func:`socket_path` on a :class:`~neurotouch_hid.engine.loop.Loop`; ``use(profile)
    -> message`` does a switch and raises NeurotouchError to refuse one (its message goes back to
    the client).

    :meth:`start` returns False (and logs why) when there is no XDG_RUNTIME_DIR, the socket
    cannot be made, or another running driver already serves it; the driver then runs without
    a control socket. A stale socket file (nobody listening) is replaced. The listening socket
    and each client's wait on the loop (no thread of their own): a client's request line is read
    as it comes, bounded in size (:data:`MAX_MESSAGE`) and time (:data:`REQUEST_TIMEOUT_S`, a timer),
    then answered and closed; at most :data:`MAX_CLIENTS` at once.
    """

    def __init__(
        self, use: Callable[[str], str], path: Path | None = None, status: Callable[[], str] | None = None
    ) -> None:
        self._use = use
        self._status = status  # ``{"command": "status"}``'s answer: one line on what runs
        self.path = path if path is not None else socket_path()
        self._sock: socket.socket | None = None
        self._loop: Loop | None = None
        self._own_loop = False
        self._inode: int | None = None
        self._clients: dict[int, _Client] = {}  # by descriptor
        self._switch = threading.Lock()  # one profile switch at a time

    def start(self, loop: Loop | None = None) -> bool:
        """Listen and serve on ``loop`` (the driver's; None: a loop of its own, in a thread)."""
        if self.path is None:
            log.info("XDG_RUNTIME_DIR is not set: no control socket, `profile use` cannot reach this driver")
            return False
        try:
            self.path.parent.mkdir(mode=0o700, exist_ok=True)
            check_folder(self.path.parent, repair=True)
        except (OSError, NeurotouchError) as exc:
            log.warning("no control socket (%s): `profile use` cannot reach this driver", printable(exc, 300))
            return False
        if self.path.exists():
            with contextlib.suppress(OSError), socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as probe:
                probe.connect(str(self.path))
                log.warning("another neurotouch-hid driver serves %s: `profile use` switches that one", self.path)
                return False
            with contextlib.suppress(OSError):
                self.path.unlink()
        sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        try:
            sock.bind(str(self.path))
            os.chmod(self.path, 0o600)
            sock.listen(BACKLOG)
        except OSError as exc:
            sock.close()
            log.warning("no control socket at %s (%s): `profile use` cannot reach this driver", self.path, exc.strerror)
            return False
        from neurotouch_hid.engine.loop import Loop

        sock.setblocking(False)
        self._sock, self._inode = sock, os.stat(self.path).st_ino
        self._own_loop = loop is None
        self._loop = loop if loop is not None else Loop()
        self._loop.add_reader(sock.fileno(), self._accept)
        if self._own_loop:
            self._loop.run_in_thread("nt-control")
        return True

    def _accept(self) -> None:
        """The loop: a client connected (one at each readiness; the others wake it again)."""
        if self._sock is None:
            return
        try:
            conn, _ = self._sock.accept()
        except OSError:  # gone meanwhile, or nothing there after all
            return
        if len(self._clients) >= MAX_CLIENTS:
            log.warning("control socket: more than %d clients at once; one refused", MAX_CLIENTS)
            with conn, contextlib.suppress(OSError):
                conn.setblocking(False)
                conn.send(json.dumps({"ok": False, "message": BUSY}).encode() + b"\n")
            return
        try:
            uid = peer_uid(conn)
        except OSError:
            conn.close()
            return
        if uid != os.getuid():
            log.warning("control socket: a process of another user (uid %d) connected; refused", uid)
            conn.close()
            return
        conn.setblocking(False)
        fd = conn.fileno()
        timer = self._loop.call_later(REQUEST_TIMEOUT_S, lambda: self._too_slow(fd))
        self._clients[fd] = _Client(conn, timer)
        self._loop.add_reader(fd, lambda: self._readable(fd))

    def _too_slow(self, fd: int) -> None:
        if fd in self._clients:
            log.warning("control socket: a client sent no request in %.0f s; dropped", REQUEST_TIMEOUT_S)
            self._drop(fd)

    def _drop(self, fd: int) -> None:
        client = self._clients.pop(fd, None)
        if client is None:
            return
        client.timer.cancel()
        self._loop.remove_reader(fd)
        client.conn.close()

    def _readable(self, fd: int) -> None:
        """The loop: a client sent something: its line answered once complete (or once it is
        longer than :data:`MAX_MESSAGE`, or the client closed its side)."""
        client = self._clients.get(fd)
        if client is None:
            return
        try:
            chunk = client.conn.recv(MAX_MESSAGE)
        except BlockingIOError:
            return
        except OSError as exc:
            log.warning("control socket: %s", exc)
            self._drop(fd)
            return
        client.data += chunk
        if chunk and b"\n" not in client.data and len(client.data) <= MAX_MESSAGE:
            return  # more to come
        line = client.data.split(b"\n", 1)[0]
        answer = self._answer(line if len(line) <= MAX_MESSAGE else None)
        if not answer["ok"]:
            log.warning("control socket: request refused: %s", printable(answer["message"], 200))
        try:
            client.conn.setblocking(True)
            client.conn.settimeout(ANSWER_TIMEOUT_S)  # a line of at most MAX_MESSAGE: the socket takes it
            client.conn.sendall(json.dumps(answer).encode() + b"\n")
        except OSError as exc:
            log.warning("control socket: %s", exc)
        self._drop(fd)

    def _answer(self, line: bytes | None) -> dict:
        if line is None:
            return {"ok": False, "message": f"request longer than {MAX_MESSAGE} bytes"}
        try:
            request = json.loads(line)
        except (ValueError, UnicodeDecodeError, RecursionError):
            return {"ok": False, "message": "not a JSON request"}
        if _json_depth(request, MAX_JSON_DEPTH) > MAX_JSON_DEPTH:
            return {"ok": False, "message": f"request nested deeper than {MAX_JSON_DEPTH} levels"}
        if isinstance(request, dict) and request.get("command") == "status" and len(request) == 1:
            return {"ok": True, "message": _fit(self._status() if self._status is not None else "running")}
        if (
            not isinstance(request, dict)
            or request.get("command") != "use"
            or not isinstance(request.get("profile"), str)
        ):
            return {"ok": False, "message": 'expected {"command": "use", "profile": NAME} or {"command": "status"}'}
        if "\0" in request["profile"]:  # no file name holds one: the OS refuses it (ValueError)
            return {"ok": False, "message": "a profile's name or path has no NUL character"}
        refused = _not_a_profile(request["profile"])
        if refused is not None:
            return {"ok": False, "message": refused}
        try:
            with self._switch:
                return {"ok": True, "message": self._use(request["profile"])}
        except NeurotouchError as exc:
            return {"ok": False, "message": _fit(str(exc))}
        except Exception as exc:  # the driver keeps running; the client learns why
            log.exception("profile switch failed")
            return {"ok": False, "message": _fit(f"the driver could not switch: {type(exc).__name__}: {exc}")}

    def stop(self) -> None:
        """Stop serving and remove the socket file (if it is still ours)."""
        if self._loop is not None and self._sock is not None:
            self._loop.call_and_wait(self._unwatch)
        if self._own_loop and self._loop is not None:
            self._loop.close()
        if self._sock is not None:
            self._sock.close()
            with contextlib.suppress(OSError):
                if self.path is not None and os.stat(self.path).st_ino == self._inode:
                    self.path.unlink()
            self._sock = None

    def _unwatch(self) -> None:
        self._loop.remove_reader(self._sock.fileno())
        for fd in list(self._clients):
            self._drop(fd)


@dataclass
class _Client:
    """A connected client: its socket, what it sent so far, its request's deadline (a timer)."""

    conn: socket.socket
    timer: Timer
    data: bytes = b""


@dataclass(frozen=True)
class RunningDriver:
    """A driver that answers on a control socket (:func:`running_drivers`).

    Attributes:
        serial: the camera it runs for (``control-SERIAL.sock``), None for ``control.sock``.
        pid: its process id (the socket's peer credentials, ``SO_PEERCRED``).
        status: its one-line answer to ``status`` (the profile it maps with).
        unit: the systemd unit it runs in (``/proc/PID/cgroup``), None when none or unreadable.
    """

    serial: str | None
    pid: int
    status: str
    unit: str | None

    def to_json(self) -> dict:
        return {"serial": self.serial, "pid": self.pid, "status": self.status, "unit": self.unit}


#: How long :func:`running_drivers` waits for each driver's answer (s).
STATUS_TIMEOUT_S = 2.0


def running_drivers(timeout_s: float = STATUS_TIMEOUT_S) -> list[RunningDriver]:
    """The drivers of this user that answer on their control socket now: the one started without
    a serial first, then one per camera serial, sorted. A socket file nobody answers on (a driver
    that was killed) is left out; so is one in a folder that is not this user's alone."""
    path = socket_path()
    if path is None:
        return []
    try:
        check_folder(path.parent)
    except (OSError, NeurotouchError):  # no folder (no driver ever ran), or one not ours: nothing asked there
        return []
    found = []
    for serial in [None, *running_serials()]:
        try:
            where = socket_path(serial)
        except ValueError:  # a file name that is no serial: not one of ours
            continue
        if where is None or not where.exists():
            continue
        try:
            pid, line = _ask_status(where, timeout_s)
        except (OSError, NeurotouchError, ValueError):
            continue
        found.append(RunningDriver(serial, pid, line, _unit_of(pid)))
    return found


def _ask_status(path: Path, timeout_s: float) -> tuple[int, str]:
    """``(pid, status line)`` of the driver serving ``path``. Raises OSError when nobody
    listens, NeurotouchError when it refuses or answers nothing readable."""
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as sock:
        sock.settimeout(timeout_s)
        sock.connect(str(path))
        creds = sock.getsockopt(socket.SOL_SOCKET, socket.SO_PEERCRED, struct.calcsize("3i"))
        pid, uid, _ = struct.unpack("3i", creds)
        if uid != os.getuid():
            raise NeurotouchError(f"{path} is served by another user (uid {uid})")
        sock.sendall(json.dumps({"command": "status"}).encode() + b"\n")
        line = _read_line(sock, timeout_s)
    try:
        answer = json.loads(line or b"")
    except (ValueError, UnicodeDecodeError):
        raise NeurotouchError(f"{path}: no answer") from None
    if not isinstance(answer, dict) or not answer.get("ok") or not isinstance(answer.get("message"), str):
        raise NeurotouchError(f"{path}: no status")
    return pid, printable(answer["message"], 200)


def _unit_of(pid: int) -> str | None:
    """The systemd service process ``pid`` runs in: the last part of its cgroup path when it is a
    ``*.service`` (``/proc/PID/cgroup``, cgroup v2's ``0::/user.slice/.../neurotouch-hid@X.service``),
    else None (a terminal's scope, under ``user@UID.service``, is no unit of the driver's)."""
    from neurotouch_hid.core.limits import read_proc_file

    try:
        data, _ = read_proc_file(f"/proc/{pid}/cgroup", 4096)
    except OSError:
        return None
    for line in data.decode(errors="replace").splitlines():
        last = line.rsplit(":", 1)[-1].rstrip("/").rsplit("/", 1)[-1]
        if last.endswith(".service"):
            return printable(last, 120)
    return None


def request_use(
    profile: str, path: Path | None = None, timeout_s: float = ANSWER_TIMEOUT_S, serial: str | None = None
) -> str:
    """Ask the running driver (the camera ``serial``'s, :func:`socket_path`; None: the one
    driver there is) to switch to ``profile`` (a name, or a path made absolute here); returns its
    one-line answer.

    Raises:
        NeurotouchError: no driver is running (no socket, or nobody listening), the socket's
            folder is not this user's alone or the socket is served by another user
            (:func:`check_folder`, :func:`peer_uid`), or the driver refused (a missing or
            invalid profile: its message).
    """
    path = path if path is not None else _chosen_socket(serial)
    if path is None:
        raise NeurotouchError(
            "no neurotouch-hid driver is running: XDG_RUNTIME_DIR is not set, so there is no "
            "control socket (start one with `neurotouch-hid run`)"
        )
    if os.sep in profile or profile.endswith((".yaml", ".yml")):
        profile = str(Path(profile).resolve())
    try:
        check_folder(path.parent)
    except FileNotFoundError:
        pass  # no driver: said when connecting
    except OSError as exc:
        raise NeurotouchError(f"cannot reach the driver at {path}: {exc.strerror or exc}") from None
    deadline = time.monotonic() + timeout_s
    while True:
        ok, message = _ask(path, profile, timeout_s)
        if ok or message != BUSY or time.monotonic() > deadline:
            break
        time.sleep(0.02)  # the driver serves MAX_CLIENTS at once: wait for one to finish
    if not ok:
        raise NeurotouchError(message)
    return message


def _ask(path: Path, profile: str, timeout_s: float) -> tuple[bool, str]:
    """One request to the driver at ``path``: (ok, its message). A full backlog (``EAGAIN`` at
    connect) is tried again until ``timeout_s``. Raises NeurotouchError as :func:`request_use`."""
    deadline = time.monotonic() + timeout_s
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as sock:
        sock.settimeout(timeout_s)
        while True:
            try:
                sock.connect(str(path))
                break
            except BlockingIOError:  # the listen backlog is full: the driver accepts them in turn
                if time.monotonic() > deadline:
                    raise NeurotouchError(f"the driver at {path} is busy: no connection in {timeout_s:.0f} s") from None
                time.sleep(0.02)
            except (FileNotFoundError, ConnectionRefusedError):
                raise NeurotouchError(
                    f"no neurotouch-hid driver is running (nothing listens on {path}); "
                    f"start one with `neurotouch-hid run --profile {printable(profile, 200)}`"
                ) from None
            except OSError as exc:
                raise NeurotouchError(f"cannot reach the driver at {path}: {exc.strerror}") from None
        uid = peer_uid(sock)
        if uid != os.getuid():
            raise NeurotouchError(
                f"{path} is served by a process of another user (uid {uid}), not your driver: not asked"
            )
        try:
            try:
                sock.sendall(json.dumps({"command": "use", "profile": profile}).encode() + b"\n")
            except BrokenPipeError:
                pass  # a request over the driver's bound: it answered so and closed; read why
            line = _read_line(sock, timeout_s) or b""
        except OSError as exc:
            why = exc.strerror or str(exc) or f"no answer in {timeout_s:.0f} s"
            raise NeurotouchError(f"the driver at {path} did not answer: {why}") from None
    try:
        answer = json.loads(line)
        return bool(answer["ok"]), str(answer["message"])
    except (ValueError, KeyError, TypeError):
        raise NeurotouchError(f"the driver at {path} gave no valid answer") from None
