"""The gadget's ``hid`` functions as :class:`~neurotouch_hid.core.stages.Target` s: ``/dev/hidgN`` nodes
(the FunctionFS functions: :mod:`~neurotouch_hid.targets.gadget.ffs`).

* :class:`HidgTarget`: one ``hid`` function (the joystick, the Switch pad, the keyboard, the
  mouse). Reports go to ``/dev/hidgN`` (opened non-blocking) through a
  :class:`~neurotouch_hid.targets.gadget.writer.ReportWriter`; the host's output reports (a
  keyboard's LEDs, HORI's vendor report) are read from the same node when it is readable, at
  most :data:`MAX_OUTPUT_REPORT` bytes a read (Documentation/usb/gadget_hid.rst).

Whatever stops the driver, :meth:`close` sends the neutral report first and waits up to
:data:`NEUTRAL_WAIT_S` for the host to take it.
"""

from __future__ import annotations

import dataclasses
import errno
import logging
import os
import threading
import time
from typing import TYPE_CHECKING, Callable

from neurotouch_hid.core.controller import ControllerState, Feedback
from neurotouch_hid.core.errors import DeviceError
from neurotouch_hid.service.udev import sudo_command
from neurotouch_hid.targets.gadget.writer import QUEUE_MOTION, QUEUE_STATE, ReportWriter

if TYPE_CHECKING:
    from neurotouch_hid.mapping.profile import Profile
    from neurotouch_hid.targets.reports import ReportFormat

log = logging.getLogger(__name__)

#: Largest output report read from the host in one read (bytes); longer ones are cut there.
MAX_OUTPUT_REPORT = 64
#: How long :meth:`close` waits for the host to take the neutral report (s).
NEUTRAL_WAIT_S = 0.5
#: Feedback requests kept until a target's ``feedback`` takes them; older ones are dropped.
MAX_PENDING_FEEDBACK = 64


class _Announced:
    """Feedback (rumble, LEDs) that a target's own reader thread receives, handed to the run's
    loop: the last :data:`MAX_PENDING_FEEDBACK` requests kept, and announced on a pipe whose
    reading end is the target's :meth:`fileno` (the Target Protocol: the loop calls
    :meth:`feedback` when it is readable). Set up by :meth:`_open_announcements`, closed by
    :meth:`_close_announcements`; ``_closed`` is the target's."""

    _closed: bool

    def _open_announcements(self) -> None:
        self._wake_r, self._wake_w = os.pipe2(os.O_NONBLOCK | os.O_CLOEXEC)
        self._pending: list[Feedback] = []
        self._pending_lock = threading.Lock()

    def fileno(self) -> int | None:
        """A pipe that becomes readable when the host sent rumble or LED requests."""
        return None if self._closed else self._wake_r

    def feedback(self) -> list[Feedback]:
        """The host's rumble and LED requests that arrived since the last call."""
        return self._take_announced()

    def _take_announced(self) -> list[Feedback]:
        try:
            os.read(self._wake_r, 4096)
        except OSError:
            pass
        with self._pending_lock:
            taken, self._pending = self._pending, []
        return taken

    def _announce(self, requests: list[Feedback]) -> None:
        """From the reader thread: ``requests`` kept, the loop woken."""
        if not requests:
            return
        with self._pending_lock:
            self._pending = [*self._pending, *requests][-MAX_PENDING_FEEDBACK:]
        try:
            os.write(self._wake_w, b"\0")
        except OSError:
            pass  # the pipe is full: the loop is already told

    def _close_announcements(self) -> None:
        for fd in (self._wake_r, self._wake_w):
            try:
                os.close(fd)
            except OSError:
                pass


class _ReportTarget:
    """What both targets share: reports packed from the state, queued on a
    :class:`~neurotouch_hid.targets.gadget.writer.ReportWriter` only when they change (a mouse's
    motion always), the neutral report on :meth:`neutralise` and first in :meth:`close`."""

    def _start(self, fd: int, fmt: ReportFormat, what: str, gate: threading.Event | None = None) -> None:
        self.what = what
        self.format = fmt
        self._motion = fmt.name == "mouse"
        depth = QUEUE_MOTION if self._motion else QUEUE_STATE
        self._writer = ReportWriter(fd, what, depth=depth, resend=not self._motion, gate=gate)
        self._last: bytes | None = None
        self._lock = threading.Lock()
        self._closed = False
        self.neutralise()

    def write(self, state: ControllerState) -> None:
        """Queue ``state``'s report when it differs from the last one (a mouse's motion always)."""
        report = self.format.pack(state)
        with self._lock:
            if self._closed or (report == self._last and not (self._motion and any(state.rel.values()))):
                return
            self._last = report
            self._writer.submit(report)

    def neutralise(self) -> None:
        """Queue the neutral report now."""
        with self._lock:
            if not self._closed:
                self._last = self.format.neutral()
                self._writer.submit(self._last)

    #: Said on each profile readied: what of it the gadget cannot carry (set by the gadget on its
    #: first target; :func:`~neurotouch_hid.targets.gadget.say_what_cannot_go`).
    lacks: Callable[[Profile], object] | None = None

    def prepare(self, profile: Profile) -> None:
        """The function's report layout is the same for every profile; what of ``profile`` the
        gadget cannot carry is said (:attr:`lacks`)."""
        if self.lacks is not None:
            self.lacks(profile)

    def _close_neutral(self, twice: bool = False) -> bool:
        """Send the neutral report, wait up to :data:`NEUTRAL_WAIT_S` for the host to take it,
        stop the writer; False when already closed. ``twice``: once taken, the neutral report is
        sent again and waited for (within the same time): an endpoint's write returns when the
        host's controller took the report, before the host's driver has handled it (in the test
        kernel xpad's input event came 2-21 ms after the write returned), while a host that keeps
        one transfer queued (Linux's xpad queues the next once it handled the last) takes the
        second only once it handled the first."""
        with self._lock:
            if self._closed:
                return False
            self._last = self.format.neutral()
            self._writer.submit(self._last)
            self._closed = True
        deadline = time.monotonic() + NEUTRAL_WAIT_S
        taken = self._writer.flush(NEUTRAL_WAIT_S)
        if taken and twice:
            self._writer.submit(self._last)
            taken = self._writer.flush(max(deadline - time.monotonic(), 0.0))
        if not taken:
            log.info("%s: the host did not take the neutral report within %.1f s", self.what, NEUTRAL_WAIT_S)
        self._writer.stop()
        return True


def _why_not(number: int | None) -> str:
    """Why a ``/dev/hidgN`` would not open, and the fix, by the open's errno: EPERM is a device
    policy (the device cgroup: a systemd unit's ``DevicePolicy=``, Documentation/admin-guide/
    cgroup-v1/devices.rst), not the node's owner, which is EACCES."""
    if number == errno.ENOENT:
        return "no such node: the gadget is not set up (or not bound)\n" + sudo_command("gadget setup --user $USER")
    if number == errno.EPERM:
        return (
            "a device policy denies it (a systemd unit's DevicePolicy=closed without DeviceAllow=char-hidg rw, "
            "which packaging/neurotouch-hid.service has)"
        )
    return "the gadget's device nodes are not this user's\n" + sudo_command("gadget setup --user $USER")


class HidgTarget(_ReportTarget):
    """One ``hid`` function's ``/dev/hidgN`` (module docstring), fed with ``format``'s reports.

    Raises:
        DeviceError: the node cannot be opened (missing, or not this user's: the fix says how).
    """

    def __init__(self, node: str | os.PathLike, fmt: ReportFormat, what: str):
        try:
            self._fd = os.open(node, os.O_RDWR | os.O_NONBLOCK | os.O_CLOEXEC)
        except OSError as exc:
            raise DeviceError(f"cannot open {node} ({exc.strerror}): {_why_not(exc.errno)}") from None
        self._start(self._fd, fmt, what)

    def fileno(self) -> int | None:
        """The node: readable when the host sent an output report."""
        return None if self._closed else self._fd

    def guarded(self) -> tuple[int, bytes]:
        """The node's descriptor and its neutral report, for the guard that sends it if the
        driver dies (:class:`~neurotouch_hid.service.guard.Guard`)."""
        return self._fd, self.format.neutral()

    def feedback(self) -> list[Feedback]:
        """Read the host's output reports waiting on the node (bounded: at most 16 reads of
        :data:`MAX_OUTPUT_REPORT` bytes), each parsed by the function's format
        (:meth:`~neurotouch_hid.targets.reports.ReportFormat.parse_output`: a keyboard's LED
        report as a ``"keyboard_leds"`` :class:`Feedback`); one that asks nothing is logged only."""
        out = []
        for _ in range(16):
            try:
                data = os.read(self._fd, MAX_OUTPUT_REPORT)
            except OSError:
                break
            if not data:
                break
            received = self.format.parse_output(data)
            if not received:
                log.debug("%s: output report %s from the host", self.what, data.hex())
            out += [dataclasses.replace(request, source=self.what) for request in received]
        return out

    def close(self) -> None:
        """Neutral report, wait for the host to take it (up to :data:`NEUTRAL_WAIT_S`), close the node."""
        if self._close_neutral():
            os.close(self._fd)
