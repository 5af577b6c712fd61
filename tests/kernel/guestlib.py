"""Helpers for guest checks (run inside the qemu guest): shell, udev, reading evdev devices."""

from __future__ import annotations

import contextlib
import errno
import os
import select
import shutil
import subprocess
import sys
import time
from pathlib import Path


def sh(cmd: list[str], timeout: float = 60, **kw) -> subprocess.CompletedProcess:
    """Run a command, capture text output, never raise on a non-zero exit."""
    return subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, **kw)


def _udevd_binary() -> str | None:
    for path in ("/lib/systemd/systemd-udevd", "/usr/lib/systemd/systemd-udevd"):
        if os.access(path, os.X_OK):
            return path
    return shutil.which("systemd-udevd")


def start_udevd() -> dict:
    """Make sure systemd-udevd runs with the current rules (virtme-ng's init normally started it and
    did the coldplug; if not, start it and coldplug everything), then settle."""
    running = sh(["pgrep", "-x", "systemd-udevd"]).returncode == 0
    if running:
        sh(["udevadm", "control", "--reload"])
    else:
        binary = _udevd_binary()
        if binary is None:
            raise RuntimeError("systemd-udevd not found on the host root (apt-get install udev)")
        if sh([binary, "--daemon"]).returncode != 0:
            raise RuntimeError(f"{binary} --daemon failed")
        sh(["udevadm", "trigger", "--action=add"])
    settle()
    return {"was_running": running}


def settle() -> None:
    sh(["udevadm", "settle", "--timeout=30"])


def udev_properties(devnode: str, timeout_s: float = 30.0) -> dict[str, str]:
    """``udevadm info --query=property`` of a device node, as a dict, once udev has processed it
    (``USEC_INITIALIZED`` set; the node exists on devtmpfs before udev's rules have run, and a
    fast guest read only the kernel's five properties then). After ``timeout_s``, what it has."""
    deadline = time.monotonic() + timeout_s
    while True:
        out = sh(["udevadm", "info", "--query=property", f"--name={devnode}"]).stdout
        props = dict(line.split("=", 1) for line in out.splitlines() if "=" in line)
        if "USEC_INITIALIZED" in props or time.monotonic() >= deadline:
            return props
        time.sleep(0.05)


def udev_info(devnode: str) -> str:
    """``udevadm info`` of a node: properties (E:), symlinks (S:), tags (G:/Q:)."""
    return sh(["udevadm", "info", f"--name={devnode}"]).stdout


def _cli_main(args: tuple[str, ...]) -> int:
    """``neurotouch-hid ARGS`` by the CLI's own ``main`` (``sys.argv`` set to it): its exit code."""
    from neurotouch_hid.cli import main

    sys.argv = ["neurotouch-hid", *args]
    try:
        main()
        return 0
    except SystemExit as exc:
        return exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 1)


def cli_in_process(*args: str, env: dict[str, str] | None = None) -> tuple[int, str, str]:
    """``neurotouch-hid ARGS`` run by the CLI's own ``main`` in this process: (exit code, stdout,
    stderr), with ``env``'s variables set in ``os.environ`` for the call. No Python start, which
    costs tens of seconds under emulation; a check that is about the process itself (its signals,
    its exit, the devices it leaves) starts a real one instead."""
    import contextlib
    import io

    out, err = io.StringIO(), io.StringIO()
    argv = sys.argv
    saved = {name: os.environ.get(name) for name in env or {}}
    os.environ.update(env or {})
    try:
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            code = _cli_main(args)
    finally:
        sys.argv = argv
        for name, value in saved.items():
            if value is None:
                os.environ.pop(name, None)
            else:
                os.environ[name] = value
    return code, out.getvalue(), err.getvalue()


#: The user and group nobody (Debian's 65534).
NOBODY = 65534


def forked(func, *, as_nobody: bool = False, env: dict[str, str] | None = None, timeout_s: float = 300.0) -> object:
    """``func()`` in a forked child of this process, as a process of its own (its own pid, its own
    user when ``as_nobody``: groups dropped, gid and uid 65534) without a Python start, which costs
    tens of seconds under emulation: the child has what this process imported. ``env`` is set in
    the child's ``os.environ`` first. Returns what ``func`` returned (JSON-able). Raises
    AssertionError with the child's error when it raised, exited without an answer or did not
    answer within ``timeout_s`` (it is killed then). The child must not need a library this
    process has already started threads or a USB context in (libusb is not fork-safe)."""
    import json
    import traceback

    read_fd, write_fd = os.pipe()
    child = os.fork()
    if child == 0:
        try:
            os.close(read_fd)
            os.environ.update(env or {})
            if as_nobody:
                os.setgroups([])
                os.setgid(NOBODY)
                os.setuid(NOBODY)
            try:
                answer = {"ok": True, "value": func()}
            except BaseException as exc:  # noqa: BLE001 - handed to the parent
                answer = {"ok": False, "error": f"{type(exc).__name__}: {exc}\n{traceback.format_exc()[-3000:]}"}
            data = json.dumps(answer, default=str).encode()
            while data:
                data = data[os.write(write_fd, data) :]
        finally:
            os._exit(0)
    os.close(write_fd)
    chunks: list[bytes] = []
    end = time.monotonic() + timeout_s
    try:
        while True:
            left = end - time.monotonic()
            if left <= 0 or not select.select([read_fd], [], [], left)[0]:
                os.kill(child, 9)
                raise AssertionError(f"{getattr(func, '__name__', func)} did not answer in {timeout_s:.0f} s")
            chunk = os.read(read_fd, 65536)
            if not chunk:
                break
            chunks.append(chunk)
    finally:
        os.close(read_fd)
        os.waitpid(child, 0)
    if not chunks:
        raise AssertionError(f"{getattr(func, '__name__', func)}'s process ended without an answer")
    answer = json.loads(b"".join(chunks))
    if not answer["ok"]:
        raise AssertionError(answer["error"])
    return answer["value"]


class _Text:
    """What a :class:`ForkedCli` child wrote on its stderr so far (``read()``, as a pipe's)."""

    def __init__(self) -> None:
        self.chunks: list[bytes] = []

    def read(self) -> str:
        return b"".join(self.chunks).decode(errors="replace")


class ForkedCli:
    """``neurotouch-hid ARGS`` run by the CLI's own ``main`` in a forked child of this process: a
    process of its own (its pid, its signal handlers, its exit code, its devices, which go with
    it), without a Python start, which costs ~30 s under emulation (the child has what this process
    imported). The shape of :class:`subprocess.Popen` that the checks use: ``poll``,
    ``send_signal``, ``kill``, ``communicate`` (stdout is /dev/null: ``("", stderr)``),
    ``returncode`` (negative: the signal that ended it) and ``stderr.read()``. ``env`` is set in
    the child's ``os.environ`` first. The child must not need a library this process has already
    started threads or a USB context in (libusb is not fork-safe)."""

    def __init__(self, *args: str, env: dict[str, str] | None = None) -> None:
        import threading

        read_fd, write_fd = os.pipe()
        self.pid = os.fork()
        if self.pid == 0:
            code = 1
            try:
                os.close(read_fd)
                devnull = os.open(os.devnull, os.O_WRONLY)
                os.dup2(devnull, 1)
                os.dup2(write_fd, 2)
                os.environ.update(env or {})
                code = _cli_main(args)
            finally:
                with contextlib.suppress(Exception):
                    sys.stdout.flush()
                    sys.stderr.flush()
                os._exit(code)
        os.close(write_fd)
        self.returncode: int | None = None
        self.stderr = _Text()

        def collect() -> None:
            while chunk := os.read(read_fd, 65536):
                self.stderr.chunks.append(chunk)
            os.close(read_fd)

        self._reader = threading.Thread(target=collect, daemon=True)
        self._reader.start()

    def poll(self) -> int | None:
        if self.returncode is None:
            pid, status = os.waitpid(self.pid, os.WNOHANG)
            if pid:
                self.returncode = os.waitstatus_to_exitcode(status)
        return self.returncode

    def send_signal(self, signum: int) -> None:
        if self.poll() is None:
            os.kill(self.pid, signum)

    def kill(self) -> None:
        if self.poll() is None:
            os.kill(self.pid, 9)
            self.returncode = os.waitstatus_to_exitcode(os.waitpid(self.pid, 0)[1])

    def communicate(self, timeout: float) -> tuple[str, str]:
        """Wait for the child to end (killed past ``timeout``: AssertionError); ("", its stderr)."""
        if not wait_for(lambda: self.poll() is not None, timeout, 0.05):
            self.kill()
            raise AssertionError(f"the forked CLI did not end in {timeout:.0f} s: {self.stderr.read()[-1500:]}")
        self._reader.join(10)
        return "", self.stderr.read()


#: x86-64 system calls that wait on file descriptors (asm/unistd_64.h) and the argument that
#: holds their timeout: a NULL pointer (select, pselect6, ppoll, epoll_pwait2) or -1 (poll,
#: epoll_wait, epoll_pwait) waits with none.
_FD_WAITS = {23: (4, 0), 270: (4, 0), 271: (2, 0), 441: (3, 0), 7: (2, -1), 232: (3, -1), 281: (3, -1)}


def waits_without_timeout(native_id: int) -> str | None:
    """How this process's thread ``native_id`` waits, when it sleeps on file descriptors with no
    timeout (e.g. ``select(23) without a timeout``); None when it runs, waits with a timeout or in
    another call. Read from ``/proc/self/task/TID/syscall`` (proc(5): the call's number and
    arguments), x86-64 numbers: a thread with no timer of its own, whatever the machine's speed."""
    fields = Path(f"/proc/self/task/{native_id}/syscall").read_text().split()
    if not fields or not fields[0].isdigit() or int(fields[0]) not in _FD_WAITS:
        return None
    number = int(fields[0])
    index, none = _FD_WAITS[number]
    value = int(fields[1 + index], 16)
    value = value - (1 << 64) if value >= 1 << 63 else value
    return f"call {number} without a timeout" if value == none or (none == -1 and value < 0) else None


def wait_for(predicate, timeout_s: float = 10.0, interval_s: float = 0.05):
    """Poll ``predicate()`` until it returns a truthy value (returned) or the timeout (None)."""
    end = time.monotonic() + timeout_s
    while True:
        value = predicate()
        if value:
            return value
        if time.monotonic() > end:
            return None
        time.sleep(interval_s)


def busy_s() -> float:
    """The guest's CPU time so far, every process's (the first line of /proc/stat: user, nice,
    system, irq, softirq; idle and iowait left out), in seconds: the host's core that qemu
    emulates on is spent in proportion."""
    fields = Path("/proc/stat").read_text().split("\n", 1)[0].split()[1:]
    user, nice, system, _idle, _iowait, irq, softirq = (int(v) for v in fields[:7])
    return (user + nice + system + irq + softirq) / os.sysconf("SC_CLK_TCK")


#: EV_SYN's code for "the kernel dropped events: this reader fell behind" (linux/input-event-codes.h).
SYN_DROPPED = 3


class EventReader:
    """Reads an event node like a game: tracks key and axis state from the events themselves.

    ``keys``: set of codes pressed; ``axes``: code -> last value; ``reports``: list of reports,
    each a list of (type, code, value) up to its SYN_REPORT, ``report_times`` the kernel's time of
    each (s, the SYN_REPORT's ``input_event`` time); ``gone``: the device disappeared;
    ``dropped``: how many times the kernel dropped events because this reader fell behind
    (SYN_DROPPED). After a drop the reader does what Documentation/input/event-codes.rst asks of a
    client: it ignores the events up to and including the next SYN_REPORT, reads the keys' and
    axes' state from the device (EVIOCGKEY, EVIOCGABS), and records the report
    ``[(EV_SYN, SYN_DROPPED, 0)]`` where the lost events were, so that a reader of ``reports``
    knows that what came before and after is not continuous."""

    def __init__(self, path: str):
        from evdev import InputDevice

        self.device = InputDevice(path)
        self.keys: set[int] = set(self.device.active_keys())
        self.axes: dict[int, int] = {code: info.value for code, info in self.device.capabilities().get(3, [])}
        self.reports: list[list[tuple[int, int, int]]] = []
        self.report_times: list[float] = []  # each report's SYN_REPORT time, the kernel's (s)
        self._pending: list[tuple[int, int, int]] = []
        self.gone = False
        self.dropped = 0
        self._dropping = False

    def pump(self, timeout_s: float = 0.5, until=None, max_s: float | None = None) -> None:
        """Read events until ``until(self)`` is true, the device is gone, ``timeout_s`` passes
        without any event or, when given, ``max_s`` passes (a pad that keeps moving)."""
        end = None if max_s is None else time.monotonic() + max_s
        while not self.gone and not (until and until(self)) and not (end and time.monotonic() > end):
            ready, _, _ = select.select([self.device.fd], [], [], timeout_s)
            if not ready:
                return
            try:
                events = list(self.device.read())
            except OSError as exc:
                if exc.errno in (errno.ENODEV, errno.EBADF):
                    self.gone = True
                    return
                raise
            for ev in events:
                if ev.type == 0 and ev.code == SYN_DROPPED:
                    self.dropped += 1
                    self._dropping, self._pending = True, []
                    continue
                if ev.type == 0 and ev.code == 0:  # SYN_REPORT
                    self.report_times.append(ev.timestamp())
                    if self._dropping:
                        self._dropping = False
                        self._resync()
                        self.reports.append([(0, SYN_DROPPED, 0)])
                    else:
                        self.reports.append(self._pending)
                    self._pending = []
                    continue
                if self._dropping:
                    continue
                self._pending.append((ev.type, ev.code, ev.value))
                if ev.type == 1:
                    (self.keys.add if ev.value else self.keys.discard)(ev.code)
                elif ev.type == 3:
                    self.axes[ev.code] = ev.value

    def _resync(self) -> None:
        """The keys' and axes' state read from the device after a SYN_DROPPED."""
        try:
            self.keys = set(self.device.active_keys())
            for code in list(self.axes):
                self.axes[code] = self.device.absinfo(code).value
        except OSError as exc:
            if exc.errno not in (errno.ENODEV, errno.EBADF):
                raise
            self.gone = True

    def close(self) -> None:
        try:
            self.device.close()
        except OSError:
            pass


def sdl_env() -> dict[str, str]:
    """The environment for an SDL2 (pygame) probe in the guest: no display, no audio, no
    banner, and this interpreter's import path."""
    return dict(
        os.environ,
        SDL_VIDEODRIVER="dummy",
        SDL_AUDIODRIVER="dummy",
        PYGAME_HIDE_SUPPORT_PROMPT="1",
        PYTHONPATH=os.pathsep.join(sys.path),
    )


@contextlib.contextmanager
def python_readable_by_all():
    """Let other users (nobody, a check's user) run and read this Python's files (a child forked
    as nobody imports what this process has not imported yet; a user's systemd starts the
    driver): when it lives under a /root that others may not traverse (0700, as on the host whose
    root the guest shares read-only), lay a throw-away overlay over /root for the block and make
    it 0711."""
    root = Path("/root")
    if not str(Path(sys.executable).resolve()).startswith("/root/") or root.stat().st_mode & 0o001:
        yield
        return
    scratch = Path("/run/neurotouch-rootov")
    scratch.mkdir(exist_ok=True)
    assert sh(["mount", "-t", "tmpfs", "none", str(scratch)]).returncode == 0
    (scratch / "up").mkdir()
    (scratch / "work").mkdir()
    mount = sh(
        [
            "mount",
            "-t",
            "overlay",
            "overlay",
            "-o",
            f"lowerdir=/root,upperdir={scratch}/up,workdir={scratch}/work",
            "/root",
        ]
    )
    assert mount.returncode == 0, f"overlay on /root: {mount.stderr}"
    try:
        os.chmod("/root", 0o711)
        yield
    finally:
        sh(["umount", "-l", "/root"])
        sh(["umount", "-l", str(scratch)])
