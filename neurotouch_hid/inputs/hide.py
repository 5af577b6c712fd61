"""Merged devices hidden from games: their nodes moved out of ``/dev`` while merged, put back after.

A grab (EVIOCGRAB) silences a device for every other reader, but a game still lists it: SDL's
Linux joystick backend enumerates through udev (``udev_enumerate`` of the ``input`` subsystem,
then ``open`` of the device's node) or, without udev (a container, ``SDL_JOYSTICK_DISABLE_UDEV``),
through the ``event*`` names under ``/dev/input`` and inotify there; either way a node that cannot
be opened is skipped. So, where this process may (root: the system service, a test guest), each
merged device's nodes are moved into :data:`HIDDEN_DIR` ``/<pid>/``: its ``input/eventN``, its
joystick ``input/jsN`` and the ``hidrawN`` of its own HID device, that interface's only (SDL's
HIDAPI drivers open those; :func:`related_nodes`), as InputPlumber (``/dev/inputplumber/sources``)
and Handheld Daemon do. A game started after the merge lists one controller; one started before
keeps its open descriptor of the helper's node, which the grab keeps silent.

The move is a rename (the hidden folder is on ``/dev``, the node's own devtmpfs), else (a folder on
another file system, as in the tests) a new node with the same device number, mode, owner and extended
attributes (the POSIX ACL udev's ``uaccess`` wrote) made first, then the old one removed: a node
is never lost. Putting back is the same move the other way; a node whose device is gone (its
``/sys/class/<subsystem>/<name>/dev`` no longer has that number) is only removed. Each process
hides into its own ``<pid>`` folder. A driver killed without putting back (SIGKILL, the OOM killer,
a crash in native code) has its guard (:class:`~neurotouch_hid.service.guard.Guard`, a small process
started at the first node hidden) put its folder back at once (:data:`RESTORE_CODE`); what is left
even so (the guard killed too, a power cut) :func:`restore_stale` puts back at the next start.

Library: the standard library (os.mknod, os.rename, xattrs); the node numbers: sysfs-rules.rst.
"""

from __future__ import annotations

import contextlib
import errno
import logging
import os
import stat
import sys
from pathlib import Path

from neurotouch_hid.core.limits import read_proc_file
from neurotouch_hid.service.guard import Guard

log = logging.getLogger(__name__)

#: Where hidden nodes wait, one folder per driver process (its pid): on ``/dev`` itself (devtmpfs),
#: as InputPlumber's ``/dev/inputplumber/sources``, so that hiding and putting back are renames of
#: the kernel's own node. A copy made with mknod elsewhere and put back would be a node devtmpfs
#: does not own (``drivers/base/devtmpfs.c``: it removes only the nodes it made) and would stay in
#: ``/dev/input`` after its device is unplugged, a dead node that breaks every program listing the
#: input devices. Not /run/neurotouch-hid either: a system unit's ``RuntimeDirectory`` is removed
#: when the unit stops, and would take nodes not yet put back with it.
HIDDEN_DIR = Path("/dev/neurotouch-hid-hidden")
DEV_DIR = Path("/dev")
SYSFS = Path("/sys")
#: How many folders up from an input device its HID device is looked for (input -> HID device ->
#: interface -> USB device).
_USB_DEPTH = 6
#: What a :class:`Hider`'s guard prepares at its start and calls when the driver died (Python run
#: in the guard: :class:`~neurotouch_hid.service.guard.Guard`'s ``then``): argv is the folder holding the
#: package, then the dead driver's pid, the root, ``/dev`` and ``/sys`` (:func:`put_back_dead`).
RESTORE_CODE = """
import sys
sys.path.insert(0, sys.argv[1])
from neurotouch_hid.inputs.hide import put_back_dead
def then():
    put_back_dead(int(sys.argv[2]), *sys.argv[3:6])
if __name__ == "__main__":
    then()
"""


def may_hide(dev: Path = DEV_DIR) -> bool:
    """Whether this process may move device nodes: root (mknod needs CAP_MKNOD) with ``dev``/input
    writable."""
    return os.geteuid() == 0 and os.access(dev / "input", os.W_OK)


def related_nodes(event_node: str, sysfs: Path = SYSFS) -> list[str]:
    """The nodes of the input device whose event node is ``event_node`` (``/dev/input/eventN``),
    relative to ``/dev``: ``input/eventN``, its joystick ``input/jsN`` (joydev) and the
    ``hidrawN`` of the HID device it belongs to (the sysfs folder ``BUS:VVVV:PPPP.NNNN`` above
    ``inputN`` that has a ``hidraw`` folder: the one interface that was merged), as sysfs shows
    them; just the event node when sysfs has nothing for it. The other interfaces of the same USB
    device (a headset's keys, a security key, the keyboard of a pad with a chat pad) keep their
    hidraw nodes: the search stops at the USB device (its ``idVendor``) without looking across.
    Other input devices of the same HID device (a DualSense's touchpad and motion sensors) share
    that hidraw node, whose reports they are."""
    name = Path(event_node).name
    nodes = [f"input/{name}"]
    try:
        device = (sysfs / "class" / "input" / name / "device").resolve(strict=True)
        nodes += sorted(f"input/{c.name}" for c in device.iterdir() if c.name.startswith("js"))
    except OSError:
        return nodes
    for parent in list(device.parents)[:_USB_DEPTH]:
        if (parent / "hidraw").is_dir():  # the HID device the input belongs to
            nodes += sorted(p.name for p in (parent / "hidraw").glob("hidraw*"))
            break
        if (parent / "idVendor").is_file():  # the USB device: not a HID input (xpad), no hidraw
            break
    return nodes


def _number(path: Path) -> int:
    return os.lstat(path).st_rdev


def _alive(relative: str, rdev: int, sysfs: Path) -> bool:
    """Whether the device of node ``relative`` still has device number ``rdev`` (sysfs' ``dev``)."""
    name = Path(relative).name
    subsystem = "input" if relative.startswith("input/") else "hidraw"
    try:
        data, _ = read_proc_file(sysfs / "class" / subsystem / name / "dev", 32)
    except OSError:
        return False
    return data.decode("ascii", "replace").strip() == f"{os.major(rdev)}:{os.minor(rdev)}"


def _move(src: Path, dst: Path) -> None:
    """Move node ``src`` to ``dst``: a rename, or across file systems a copy of the node (number,
    mode, owner, extended attributes) made before ``src`` is removed. Raises OSError (``src``
    is then untouched)."""
    dst.parent.mkdir(parents=True, exist_ok=True)
    try:
        os.rename(src, dst)
        return
    except OSError as exc:
        if exc.errno != errno.EXDEV:
            raise
    st = os.lstat(src)
    os.mknod(dst, st.st_mode, st.st_rdev)
    try:
        os.chown(dst, st.st_uid, st.st_gid)
        os.chmod(dst, stat.S_IMODE(st.st_mode))
        with contextlib.suppress(OSError):  # a file system without xattrs: mode and owner only
            for attr in os.listxattr(src, follow_symlinks=False):
                os.setxattr(dst, attr, os.getxattr(src, attr, follow_symlinks=False), follow_symlinks=False)
        os.unlink(src)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(dst)
        raise


class Hider:
    """One process's hidden nodes: :meth:`hide` a merged device's, :meth:`restore` them.

    Args:
        root: the hidden folders' parent (:data:`HIDDEN_DIR`); dev: ``/dev``; sysfs: ``/sys``;
        pid: whose folder (this process).
        guarded: start a guard at the first node hidden, which puts the folder back if this
            process dies before :meth:`restore_all` (module docstring); released by it.
    """

    def __init__(
        self,
        root: Path = HIDDEN_DIR,
        dev: Path = DEV_DIR,
        sysfs: Path = SYSFS,
        pid: int | None = None,
        *,
        guarded: bool = False,
    ):
        self.dev, self.sysfs = Path(dev), Path(sysfs)
        self.folder = Path(root) / str(os.getpid() if pid is None else pid)
        self._hidden: dict[str, list[str]] = {}  # event node -> the nodes hidden with it (relative to dev)
        self._guarded = guarded
        self._guard: Guard | None = None

    def hide(self, event_node: str) -> list[str]:
        """Move ``event_node``'s nodes (:func:`related_nodes`) into this process's folder; the ones
        moved (relative to ``/dev``). A node that cannot be moved stays (logged)."""
        moved = []
        for relative in related_nodes(event_node, self.sysfs):
            src = self.dev / relative
            if not os.path.lexists(src) or os.path.lexists(self.folder / relative):
                continue
            try:
                _move(src, self.folder / relative)
            except OSError as exc:
                log.warning("cannot hide %s from games: %s", src, exc.strerror or exc)
                continue
            moved.append(relative)
        if moved:
            self._hidden.setdefault(event_node, []).extend(moved)
            self._start_guard()
        return moved

    def _start_guard(self) -> None:
        if not self._guarded or self._guard is not None:
            return
        package_parent = str(Path(__file__).resolve().parents[2])
        where = [str(self.folder.parent), str(self.dev), str(self.sysfs)]
        then = ["-c", RESTORE_CODE, package_parent, self.folder.name, *where]
        try:
            self._guard = Guard(then=then, what="the hidden devices")
        except OSError as exc:
            log.warning(
                "the hidden devices' guard could not start (%s): if the driver is killed, the merged "
                "devices stay hidden from games until its next start",
                exc.strerror or exc,
            )

    def restore(self, event_node: str) -> list[str]:
        """Put ``event_node``'s hidden nodes back; the ones put back (a gone device's are removed)."""
        return [r for r in self._hidden.pop(event_node, []) if self._put_back(r)]

    def restore_all(self) -> list[str]:
        """Put back everything in this process's folder (also what an earlier process of this pid
        left), then remove the folder; the nodes put back."""
        self._hidden.clear()
        back = []
        if self.folder.is_dir():
            for path in sorted(self.folder.rglob("*")):
                if not path.is_dir() and self._put_back(str(path.relative_to(self.folder))):
                    back.append(str(path.relative_to(self.folder)))
            for path in sorted(self.folder.rglob("*"), reverse=True):
                with contextlib.suppress(OSError):
                    path.rmdir()
            with contextlib.suppress(OSError):
                self.folder.rmdir()
        if self._guard is not None:  # everything is back: nothing left for it to do
            self._guard.release()
            self._guard = None
        return back

    def rehide(self) -> list[str]:
        """Remove a hidden node that reappeared in ``/dev`` with the same number (made again by
        someone while merged): games must still list one pad; the removed nodes."""
        removed = []
        for relative in [r for nodes in self._hidden.values() for r in nodes]:
            again, hidden = self.dev / relative, self.folder / relative
            with contextlib.suppress(OSError):
                if _number(again) == _number(hidden):
                    os.unlink(again)
                    removed.append(relative)
        return removed

    def _put_back(self, relative: str) -> bool:
        hidden, target = self.folder / relative, self.dev / relative
        try:
            rdev = _number(hidden)
        except OSError:
            return False
        try:
            if _alive(relative, rdev, self.sysfs) and not os.path.lexists(target):
                _move(hidden, target)
                if _alive(relative, rdev, self.sysfs):
                    return True
                os.unlink(target)  # unplugged while it was put back: no dead node in /dev
                return False
            os.unlink(hidden)  # the device is gone, or its node is there again: nothing to put back
        except OSError as exc:
            log.warning("cannot put %s back in %s: %s", relative, self.dev, exc.strerror or exc)
        return False


def _running(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def restore_stale(root: Path = HIDDEN_DIR, dev: Path = DEV_DIR, sysfs: Path = SYSFS) -> list[str]:
    """Put back the nodes that driver processes no longer running left hidden in ``root`` (a
    crash, SIGKILL); the nodes put back. Nothing when ``root`` is absent."""
    back = []
    with contextlib.suppress(OSError):
        for folder in sorted(Path(root).iterdir()):
            if folder.name.isdigit() and (int(folder.name) == os.getpid() or not _running(int(folder.name))):
                back += Hider(root, dev, sysfs, pid=int(folder.name)).restore_all()
    return back


def put_back_stale(say=log.warning) -> None:
    """At a driver's start, where this process may (:func:`may_hide`): :func:`restore_stale`, and
    one line for the user naming what was put back."""
    if not may_hide():
        return
    back = restore_stale()
    if back:
        say(f"put back {_named(back)}, left hidden by a driver that did not stop cleanly")


def put_back_dead(pid: int, root: Path = HIDDEN_DIR, dev: Path = DEV_DIR, sysfs: Path = SYSFS) -> list[str]:
    """What a dead driver's guard runs (:data:`RESTORE_CODE`): driver ``pid``'s hidden nodes put
    back (:meth:`Hider.restore_all`), and one line on standard error (the driver's: the terminal
    or the journal) naming them; the nodes put back."""
    back = Hider(root, dev, sysfs, pid=pid).restore_all()
    if back:
        print(f"neurotouch-hid: the driver died with merged devices hidden; put back {_named(back)}", file=sys.stderr)
    return back


def _named(back: list[str]) -> str:
    """Nodes relative to ``/dev``, as the user names them."""
    return ", ".join("/dev/" + n for n in back)
