"""What is undone for the driver when it dies without undoing it itself.

Closing in an orderly way (SIGTERM, Ctrl-C, an error) undoes everything the driver did outside
itself; a driver killed by SIGKILL, by the OOM killer or by a crash in native code runs nothing
more. The kernel undoes most of it (a uinput or UHID device goes with its descriptor, a grab with
its device's), not all:

* a ``hid`` gadget function stays bound to its UDC when the process writing to its ``/dev/hidgN``
  ends: the host keeps the last report it read (an interrupt IN endpoint with nothing new only
  NAKs, Documentation/usb/gadget_hid.rst), so the host's game would keep the stick held and the
  buttons pressed. (A FunctionFS function's gadget is unbound when the last of its files
  closes, ``ffs_data_closed()`` in drivers/usb/gadget/function/f_fs.c: below.)
* a UHID device goes with the driver's descriptor, and a FunctionFS function's gadget is unbound
  when the function's files close: either way the host's readers last read the report before, a
  DualSense's touch points active and its stick held, until the device is gone. The guard holds a
  copy of the descriptor (:class:`~neurotouch_hid.targets.uhid.UhidDevice`) or of the IN
  endpoint (:meth:`~neurotouch_hid.targets.gadget.ffs.FfsTarget.guarded`), sends the neutral
  report, stays a moment for the readers, and the device goes when the guard ends.
* a merged device's nodes moved out of ``/dev`` (:mod:`~neurotouch_hid.inputs.hide`) stay there:
  no game would list the helper's pad until the driver's next start.

:class:`Guard` starts a small process beside the driver: this Python, isolated and without
``site`` (``-I -S``, about 3 MiB of its own memory), running :data:`GUARD_CODE`. It holds its own
descriptors of the ``hid`` nodes and blocks in a read of a pipe whose only writer is the driver,
so at rest it costs no CPU and no wake-up. When the driver ends its run it writes one byte and the
guard exits with nothing done. When the driver dies, the kernel closes the pipe's write end and
the read returns end-of-file: the guard writes each node's neutral report, retrying every
:data:`RETRY_S` while the host has not taken the one before (EAGAIN, the node being non-blocking)
or is away, for at most :data:`GIVE_UP_S` (a timer cuts short a write that blocks: a FunctionFS
endpoint's returns once the host took the report), and stays a moment when asked (a UHID device goes
with the guard's copy of its descriptor, and evdev drops what its readers had not read); then it
runs what it was given: Python prepared from its start in a thread at nice 19 (the hidden nodes
put back: the imports are paid while the driver lives, about 5 MiB more), or a command in its
place (``execv``). It ignores SIGINT, SIGTERM and SIGHUP, and so does its command: Ctrl-C signals
the terminal's whole process group and systemd's stop the unit's whole cgroup, and the guard's
own end is decided by the driver's pipe alone.
"""

from __future__ import annotations

import logging
import os
import subprocess
import sys
from collections.abc import Sequence

log = logging.getLogger(__name__)

#: How long the guard keeps trying to hand the host the neutral reports (s).
GIVE_UP_S = 2.0
#: Pause between two tries while the host has not taken a report (s).
RETRY_S = 0.004
#: How long a guard whose end removes the device (UHID, FunctionFS) stays once it wrote the
#: neutral reports (s): evdev drops what its readers had not read when the device goes; a crash is
#: rare, and a loaded machine's readers are slow.
LINGER_S = 0.5
#: How long :meth:`Guard.release` waits for the guard to exit before killing it (s).
RELEASE_WAIT_S = 2.0
#: The guard's program (``python -I -S -c``): argv is the pipe's read end, how long to try (s),
#: how long to stay once the reports are written (s), one ``FD:HEXREPORT`` per node, then ``--``
#: and the command to run after them, if any. Only the os, signal and time modules (and
#: threading for Python to prepare).
GUARD_CODE = f"""
import os, signal, sys, time
for number in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
    signal.signal(number, signal.SIG_IGN)
pipe, give_up_s, linger_s = int(sys.argv[1]), float(sys.argv[2]), float(sys.argv[3])
args = sys.argv[4:]
cut = args.index("--") if "--" in args else len(args)
left = [(int(fd), bytes.fromhex(report)) for fd, report in (a.split(":") for a in args[:cut])]
then = args[cut + 1 :]
preparing, prepared = None, {{}}
if then[:1] == ["-c"]:  # Python to run here: prepared (imported) while the driver lives, called once it died
    import threading
    code, sys.argv[1:] = then[1], then[2:]
    then = [sys.executable, "-I", "-c", code, *then[2:]]  # if it cannot be prepared: as a command

    def prepare():
        os.nice(19)  # this thread only (Linux): its imports take what the driver leaves idle
        try:
            scope = {{"__name__": "__guard__"}}
            exec(code, scope)
            prepared["then"] = scope["then"]
        except Exception as exc:
            prepared["error"] = exc

    preparing = threading.Thread(target=prepare, daemon=True)
    preparing.start()
while True:
    try:
        said = os.read(pipe, 1)
        break
    except InterruptedError:
        continue
if said:
    os._exit(0)  # at once, even while it prepares
class GiveUp(Exception):
    pass


def give_up(*_):
    raise GiveUp


signal.signal(signal.SIGALRM, give_up)  # a write that blocks (a FunctionFS endpoint) is cut short too
end = time.monotonic() + give_up_s
try:
    signal.setitimer(signal.ITIMER_REAL, give_up_s)
    while left and time.monotonic() < end:
        for node in list(left):
            try:
                os.write(*node)
                left.remove(node)
            except OSError:
                pass
        if left:
            time.sleep({RETRY_S!r})
    signal.setitimer(signal.ITIMER_REAL, 0)
except GiveUp:
    pass
if linger_s > 0:
    time.sleep(linger_s)
if preparing is not None:
    try:  # the driver died while it prepared: finish at the normal priority (root may raise it back)
        os.setpriority(os.PRIO_PROCESS, preparing.native_id, 0)
    except OSError:
        pass
    preparing.join()
    if "then" in prepared:
        prepared["then"]()
        then = []
    else:
        print("neurotouch-hid guard: cannot prepare its work:", prepared.get("error"), file=sys.stderr)
if then:
    os.execv(then[0], then)
"""


class Guard:
    """The guard process (module docstring) for ``nodes``, each an open ``/dev/hidgN`` descriptor
    and the neutral report to write there if the driver dies, and ``then``, a command run after
    them.

    Args:
        nodes: (descriptor, report bytes) pairs; the descriptors stay the caller's, the guard
            gets copies of them.
        then: argv of the command the guard becomes once the reports are written (its first item
            an absolute path: ``execv`` does not search PATH); empty: none. ``("-c", CODE, *ARGS)``
            is Python run in the guard itself: CODE runs in a thread of the guard from its start,
            at nice 19, with ``sys.argv[1:]`` = ARGS (its imports paid while the driver lives, on
            what the driver leaves idle) and defines ``then()``, called once the reports are written
            (the thread waited for first, raised back to nice 0 where it may be): nothing to start
            when the driver died (a new Python and its imports took seconds in an emulated, loaded
            machine). :meth:`release` never waits for it. CODE failing is said on standard error,
            and it is then run as ``python -I -c CODE ARGS`` instead.
        give_up_s: how long the guard tries to hand the host the reports once the driver died (s).
        linger_s: how long the guard stays once it wrote them (s): its copies of the nodes stay
            open meanwhile (a UHID device's readers take the neutral report before the device
            goes with the guard's descriptor).
        what: whose guard, in the log's lines.
    Raises:
        OSError: the guard could not be started (no process or descriptor left).
    """

    def __init__(
        self,
        nodes: Sequence[tuple[int, bytes]] = (),
        *,
        then: Sequence[str] = (),
        give_up_s: float = GIVE_UP_S,
        linger_s: float = 0.0,
        what: str = "the USB gadget",
    ):
        self.what = what
        read_end, self._write_end = os.pipe()  # not inherited: only the guard gets the read end
        try:
            args = [str(read_end), repr(give_up_s), repr(linger_s), *(f"{fd}:{report.hex()}" for fd, report in nodes)]
            if then:
                args += ["--", *then]
            self._proc = subprocess.Popen(
                [sys.executable, "-I", "-S", "-c", GUARD_CODE, *args],
                pass_fds=(read_end, *(fd for fd, _ in nodes)),
                stdin=subprocess.DEVNULL,
                stdout=subprocess.DEVNULL,
            )
        except BaseException:
            os.close(self._write_end)
            raise
        finally:
            os.close(read_end)

    @property
    def pid(self) -> int:
        return self._proc.pid

    def release(self) -> None:
        """The run ended in order (it undid what it did itself): the guard exits with nothing
        done; waited for up to :data:`RELEASE_WAIT_S`, killed after that. Its
        descriptors of the nodes are closed when this returns. Idempotent."""
        if self._write_end < 0:
            return
        try:
            os.write(self._write_end, b"\0")
        except OSError:
            pass  # the guard is gone already
        os.close(self._write_end)
        self._write_end = -1
        try:
            self._proc.wait(RELEASE_WAIT_S)
        except subprocess.TimeoutExpired:
            log.warning("%s's guard (pid %d) did not exit; killed", self.what, self._proc.pid)
            self._proc.kill()
            self._proc.wait()
