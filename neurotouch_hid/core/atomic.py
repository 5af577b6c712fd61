"""Output files that never destroy an input: every file a command writes is made as a temporary
file in the same folder and renamed over its name only when it is complete (``rename`` is atomic
within a file system), so a failure, a Ctrl-C or a full disk leaves what was there before.

:func:`check_output` refuses, before anything is written, an output that is a symbolic link (a
write would go wherever it points), a folder, or the same file as one of the command's inputs
(``track X.aedat4 --out X.aedat4`` emptied the recording before reading it). A FIFO or a
character device (``--out /dev/stdout``, a pipe made with ``mkfifo``) is written as it is: there
is nothing there to lose, and another process reads it live.

Library: the standard library (``tempfile.mkstemp``, ``os.replace``).
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import os
import stat
import tempfile
import time
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import IO

from neurotouch_hid.core.errors import NeurotouchError
from neurotouch_hid.core.limits import printable, read_proc_file


class OutputError(NeurotouchError):
    """An output path that may not be written: a symbolic link, a folder, or one of the inputs."""


#: The errors of a write that the disk refuses (full, over quota, read-only, a file too large
#: for it, a failing device): one line and exit 2, what was there kept.
DISK_ERRNOS = frozenset({errno.ENOSPC, errno.EDQUOT, errno.EROFS, errno.EFBIG, errno.EIO})
#: Longest wait for another command's lock on a folder (s) before saying so.
LOCK_WAIT_S = 10.0


def disk_error(path: str | os.PathLike, exc: OSError, what: str = "output") -> OutputError:
    """``exc`` (a write that failed) as one line naming ``path``, what happened and what to do."""
    return OutputError(
        f"{printable(path, 200)}: cannot write the {what}: {exc.strerror or exc}; nothing was replaced "
        "(free some space or write elsewhere)"
    )


@contextlib.contextmanager
def locked(folder: str | os.PathLike, what: str) -> Iterator[None]:
    """Hold an exclusive ``flock`` on ``folder`` (created) for a read-modify-write of the files in
    it, so that commands run side by side change them one after the other and none of their
    changes is lost. No lock file is made: the lock is on the folder itself, and the kernel drops
    it when the process ends, however it ends.

    Raises:
        OutputError: the folder cannot be made or opened, or another process held it for
            :data:`LOCK_WAIT_S` (``what`` names what was being changed; nothing was changed).

    Library: ``fcntl.flock`` (flock(2)).
    """
    folder = Path(folder)
    try:
        folder.mkdir(parents=True, exist_ok=True)
        fd = os.open(folder, os.O_RDONLY | os.O_DIRECTORY | os.O_CLOEXEC)
    except OSError as exc:
        raise OutputError(
            f"{printable(folder, 200)}: cannot change {what}: {exc.strerror or exc}; nothing was changed"
        ) from None
    try:
        end = time.monotonic() + LOCK_WAIT_S
        while True:
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                break
            except BlockingIOError:
                if time.monotonic() > end:
                    raise OutputError(
                        f"{printable(folder, 200)}: another neurotouch-hid command has been changing {what} for "
                        f"{LOCK_WAIT_S:.0f} s: nothing was changed; try again when it is done"
                    ) from None
                time.sleep(0.02)
        yield
    finally:
        os.close(fd)  # releases the lock


def _umask() -> int:
    """The process's umask (``/proc/self/status``; 0o022 where that is not available): a file
    made by ``mkstemp`` is 0600, a renamed output gets what ``open`` would have given it."""
    with contextlib.suppress(OSError, ValueError):
        status, _ = read_proc_file("/proc/self/status", 64 * 1024)
        for line in status.decode("ascii", "replace").splitlines():
            if line.startswith("Umask:"):
                return int(line.split()[1], 8)
    return 0o022


def is_stream(path: str | os.PathLike) -> bool:
    """True when ``path`` is a FIFO or a character device (written in place, read live)."""
    try:
        mode = os.stat(path).st_mode
    except OSError:
        return False
    return stat.S_ISFIFO(mode) or stat.S_ISCHR(mode)


def check_output(
    path: str | os.PathLike,
    inputs: Iterable[str | os.PathLike | None] = (),
    what: str = "output",
    others: Iterable[tuple[str, str | os.PathLike]] = (),
) -> Path:
    """``path`` as a :class:`Path`, once it is known that writing it destroys no input and no
    other output of the same command.

    Args:
        path: the output file.
        inputs: the command's input files and folders (None entries are skipped).
        what: the output's name for the user (``"markers file"``).
        others: the command's other outputs, as (name, path): none may be ``path``, whether or
            not it exists yet.
    Raises:
        OutputError: ``path`` is a symbolic link, a folder, the same file as one of ``inputs``
            (compared by device and inode, so a hard link or another spelling of the same path
            is caught too) or an existing file of an input folder, or names one of ``others``'
            files (resolved: another spelling too); the message names it and the other file.
    """
    path = Path(path)
    shown = printable(path, 200)
    for name, other_path in others:
        if path.resolve() == Path(other_path).resolve():
            raise OutputError(f"{shown}: the {what} is also the {name}; give each its own name")
    if path.is_symlink():
        if is_stream(path):  # /dev/stdout, /dev/fd/N, >(...) of a pipe or a terminal: written in place
            return path
        raise OutputError(
            f"{shown}: the {what} is a symbolic link (to {printable(os.readlink(path), 200)}); "
            "give the file itself, or another name: a link is never written through"
        )
    try:
        info = path.stat()
    except OSError:
        return path  # not there (yet): nothing to lose
    if stat.S_ISDIR(info.st_mode):
        raise OutputError(f"{shown}: the {what} is a folder; give a file name")
    for source in inputs:
        if source is None:
            continue
        with contextlib.suppress(OSError):
            other = os.stat(source)
            if (other.st_dev, other.st_ino) == (info.st_dev, info.st_ino):
                raise OutputError(
                    f"{shown}: the {what} is the same file as the input {printable(source, 200)}; "
                    "writing it would destroy what is read: give another name"
                )
            if stat.S_ISDIR(other.st_mode) and os.path.samefile(path.parent, source):  # a dataset's folder
                raise OutputError(
                    f"{shown}: a file of the input folder {printable(source, 200)}; the {what} never overwrites "
                    "an input: give a name outside that folder, or a new one"
                )
    return path


def _temporary(path: Path) -> tuple[int, str]:
    """A new hidden file beside ``path``, with ``path``'s suffix (libraries that write by name
    pick the format from it): ``.NAME.RANDOM.part.SUFFIX``. Raises OutputError when the folder
    cannot be written (missing, read-only, full)."""
    try:
        return tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=f".part{path.suffix}")
    except OSError as exc:
        folder = printable(path.parent if str(path.parent) else ".", 200)
        raise OutputError(f"{printable(path, 200)}: cannot write in {folder}: {exc.strerror or exc}") from None


@contextlib.contextmanager
def replacing(
    path: str | os.PathLike, inputs: Iterable[str | os.PathLike | None] = (), what: str = "output"
) -> Iterator[Path]:
    """A temporary path in ``path``'s folder to write the output to (by name: numpy, imageio,
    dv-processing); renamed over ``path`` when the block ends normally, removed when it raises.
    A FIFO or character device at ``path`` is given as it is.

    Raises:
        OutputError: see :func:`check_output`; or the folder cannot be written (missing,
            read-only, full).
    """
    path = check_output(path, inputs, what)
    if is_stream(path):
        yield path
        return
    tmp = temporary_beside(path)
    try:
        yield tmp
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def temporary_beside(path: Path) -> Path:
    """A new empty file beside ``path`` (:func:`_temporary`, with the mode ``open`` would give
    it), for a writer that takes a name and is renamed into place by the caller.

    Raises:
        OutputError: the folder cannot be written.
    """
    fd, tmp = _temporary(path)
    try:
        os.fchmod(fd, 0o666 & ~_umask())
    finally:
        os.close(fd)
    return Path(tmp)


class PathBeside:
    """A temporary path beside ``path`` for a writer that takes a name (dv-processing), renamed
    over ``path`` by :meth:`publish` (the writer may go on writing: the file is the same) or when
    the block ends normally; removed when the block raises before it was published.

    Raises:
        OutputError: see :func:`check_output`; or the folder cannot be written.
    """

    def __init__(self, path: str | os.PathLike, inputs: Iterable[str | os.PathLike | None] = (), what: str = "output"):
        self.target = check_output(path, inputs, what)
        self.tmp = temporary_beside(self.target)
        self.published = False

    def publish(self) -> None:
        """Rename the file over ``path`` (once; a no-op after)."""
        if not self.published:
            os.replace(self.tmp, self.target)
            self.published = True

    def __enter__(self) -> "PathBeside":
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            self.publish()
        elif not self.published:
            self.tmp.unlink(missing_ok=True)


class AtomicFile:
    """A text or binary file object writing to a temporary file beside ``path``.

    :meth:`publish` renames it over ``path`` (the lines written so far become the file, later
    writes go on in it: a live output is published at its first line); :meth:`close` publishes
    (``keep=True``) or removes it (``keep=False``, when it was never published). A FIFO or
    character device at ``path`` is opened and written in place.

    Raises:
        OutputError: see :func:`check_output`; or the folder cannot be written.
        OSError: a FIFO or device at ``path`` cannot be opened.
    """

    def __init__(
        self,
        path: str | os.PathLike,
        inputs: Iterable[str | os.PathLike | None] = (),
        *,
        what: str = "output",
        mode: str = "w",
        newline: str | None = None,
    ) -> None:
        self.path = check_output(path, inputs, what)
        encoding = None if "b" in mode else "utf-8"
        if is_stream(self.path):
            self._tmp: Path | None = None
            self.file: IO = open(self.path, mode, encoding=encoding, newline=newline)  # noqa: SIM115
            return
        fd, tmp = _temporary(self.path)
        self._tmp = Path(tmp)
        try:
            os.fchmod(fd, 0o666 & ~_umask())
            self.file = os.fdopen(fd, mode, encoding=encoding, newline=newline)
        except BaseException:
            os.close(fd)
            self._tmp.unlink(missing_ok=True)
            raise

    @property
    def published(self) -> bool:
        """True once the file is at ``path`` (or was a stream all along)."""
        return self._tmp is None

    def publish(self) -> None:
        """Rename the file written so far over ``path`` (once; a no-op after)."""
        if self._tmp is not None:
            self.file.flush()
            os.replace(self._tmp, self.path)
            self._tmp = None

    def pending(self) -> Path | None:
        """The temporary file being written, None once published (or for a stream)."""
        return self._tmp

    def close(self, keep: bool = True, leave: bool = False) -> None:
        """Close; publish when ``keep``, else remove the file if it was never published (with
        ``leave``, the temporary file (:meth:`pending`) is left for the caller to move). A write
        the disk refuses (full, read-only: :data:`DISK_ERRNOS`) raises OutputError naming the file,
        and what was at ``path`` stays as it was."""
        try:
            try:
                if keep:
                    self.publish()
            finally:
                try:
                    self.file.close()
                finally:
                    if self._tmp is not None:
                        if not leave:
                            self._tmp.unlink(missing_ok=True)
                        self._tmp = None
        except OSError as exc:
            if exc.errno in DISK_ERRNOS:
                raise disk_error(self.path, exc) from None
            raise

    def __enter__(self) -> IO:
        return self.file

    def __exit__(self, exc_type, exc, tb) -> None:
        try:
            self.close(keep=exc_type is None)
        except OutputError:
            if exc_type is None:
                raise
        if isinstance(exc, OSError) and exc.errno in DISK_ERRNOS:  # a write in the block
            raise disk_error(self.path, exc) from None


#: ``renameat2``'s flag that swaps two paths in one step (linux/fs.h).
_RENAME_EXCHANGE = 2


def exchange(a: str | os.PathLike, b: str | os.PathLike) -> None:
    """Swap the two existing paths ``a`` and ``b`` (folders too) in one step: no moment when
    either name is missing (``renameat2(RENAME_EXCHANGE)``, Linux 3.15; ext4, xfs, btrfs, tmpfs).
    Where the file system cannot, ``b`` is moved aside, ``a`` renamed to it and the old ``b``
    put at ``a``: each step atomic, ``b`` missing for a moment.

    Raises OSError as ``rename`` does.

    Library: glibc's ``renameat2`` through ``ctypes`` (the standard library has no wrapper).
    """
    import ctypes

    libc = ctypes.CDLL(None, use_errno=True)
    renameat2 = getattr(libc, "renameat2", None)
    if renameat2 is not None:
        at_fdcwd = -100
        if renameat2(at_fdcwd, os.fsencode(a), at_fdcwd, os.fsencode(b), _RENAME_EXCHANGE) == 0:
            return
        code = ctypes.get_errno()
        if code not in (errno.EINVAL, errno.ENOSYS, errno.EOPNOTSUPP):
            raise OSError(code, os.strerror(code), str(b))
    aside = Path(tempfile.mkdtemp(dir=Path(b).parent, prefix=f".{Path(b).name}.", suffix=".old"))
    os.replace(b, aside / "x")
    os.replace(a, b)
    os.replace(aside / "x", a)
    aside.rmdir()
