"""The thread that hands a USB gadget's input reports to the host, whatever the host does.

A gadget's IN endpoint is read by the host at its own pace, and the host may be gone (cable
pulled, host asleep, the gadget unbound from its UDC). A write to ``/dev/hidgN`` then fails with
EAGAIN (the previous report still waits for the host, Documentation/usb/gadget_hid.rst's
non-blocking write) or ESHUTDOWN (the function is disabled), and a write to a FunctionFS IN
endpoint waits for the host (Documentation/usb/functionfs.rst). None of that may stop or slow
the driver: :class:`ReportWriter` keeps the reports to send and writes them from its own thread,
retrying while the host is away, and sends the current report again every :data:`RESEND_S`, so
that a host that re-enumerated the gadget (and so lost what it had) gets the current state
without waiting for the next change. A host away for long (asleep, unplugged, not yet there
when the board starts) costs a few wake-ups a second: the pause between tries doubles from
:data:`RETRY_S` up to :data:`RESEND_S`, and a new report tries at once.
"""

from __future__ import annotations

import errno
import logging
import os
import threading
import time
from collections import deque

log = logging.getLogger(__name__)

#: The current report is sent again after this long without a change (s).
RESEND_S = 0.25
#: Pause before a write is first retried while the host is away (s); doubled at each failed try
#: after it, up to :data:`RESEND_S`.
RETRY_S = 0.004
#: Reports kept while the host does not take them: 1 for a state (only the latest matters),
#: more for a mouse, whose reports carry motion that adds up.
QUEUE_STATE, QUEUE_MOTION = 1, 64
#: errno values that mean "the host is not reading now": try again later.
HOST_AWAY = {errno.EAGAIN, errno.ESHUTDOWN, errno.ECONNRESET, errno.EPIPE, errno.ENODEV, errno.EINTR, errno.EIO}


class ReportWriter:
    """Writes reports to ``fd`` from a daemon thread (module docstring).

    ``submit`` queues a report (``depth`` kept: 1 keeps only the latest); the thread writes
    them in order, retrying every :data:`RETRY_S` while the host is away, and re-sends the
    last one written every :data:`RESEND_S` (``resend``: False for a mouse, whose reports are
    motion). ``what`` names the target in log lines; ``gate``: see the attribute."""

    def __init__(
        self, fd: int, what: str, *, depth: int = QUEUE_STATE, resend: bool = True, gate: threading.Event | None = None
    ):
        self.fd = fd
        #: When given, nothing is written while it is clear (an endpoint not enabled yet: its file
        #: takes its descriptors first), and a write that fails clears it: the endpoint's owner
        #: sets it again once the host configured the device anew (GadgetFS: a bus reset ends
        #: the configuration, and a write queued before the owner knows would wait for a host that
        #: no longer reads that endpoint). Reports wait as they do for an absent host.
        self.gate = gate
        self.what = what
        self._resend = resend
        self._queue: deque[bytes] = deque(maxlen=depth)
        self._last: bytes | None = None
        self._sent_at = 0.0
        self._away = False
        self._stop = False
        #: True while the thread is in a write (:meth:`interrupt`'s owner waits for it to end).
        self.writing = False
        self._cond = threading.Condition()
        self._thread = threading.Thread(target=self._run, name=f"report writer ({what})", daemon=True)
        self._thread.start()

    def submit(self, report: bytes) -> None:
        """Queue ``report`` for the host; returns at once."""
        with self._cond:
            self._queue.append(report)
            self._cond.notify_all()

    def flush(self, timeout: float) -> bool:
        """Wait up to ``timeout`` s until the host took every report queued (the last one
        submitted included); True when it did."""
        deadline = time.monotonic() + timeout
        with self._cond:
            while self._queue:
                left = deadline - time.monotonic()
                if left <= 0:
                    return False
                self._cond.wait(left)
            return not self._queue

    def stop(self) -> None:
        """End the thread (a write the host never takes is left to the kernel)."""
        with self._cond:
            self._stop = True
            self._cond.notify_all()

    @property
    def thread_id(self) -> int | None:
        """The writing thread's id (``threading.get_ident``), for a signal that ends a write the
        host will never take (GadgetFS: :mod:`~neurotouch_hid.targets.gadget.gadgetfs`)."""
        return self._thread.ident

    def _next(self) -> tuple[bytes | None, bool]:
        with self._cond:
            while not self._stop:
                if self._queue:
                    return self._queue[0], True
                if self._resend and self._last is not None:
                    wait = self._sent_at + RESEND_S - time.monotonic()
                    if wait <= 0:
                        return self._last, False
                    self._cond.wait(wait)
                else:
                    self._cond.wait()
            return None, False

    def _run(self) -> None:
        pause = RETRY_S
        while True:
            report, queued = self._next()
            if report is None:
                return
            if self.gate is not None and not self.gate.wait(RESEND_S):
                continue
            self.writing = True
            try:
                os.write(self.fd, report)
            except OSError as exc:
                self.writing = False
                if exc.errno not in HOST_AWAY:
                    log.warning("%s: writing a report failed: %s; the host gets no more reports", self.what, exc)
                    return
                if self.gate is not None:
                    self.gate.clear()
                if not self._away:
                    log.info("%s: the host is not reading (%s); retrying", self.what, os.strerror(exc.errno))
                with self._cond:
                    self._away = True
                    self._sent_at = time.monotonic()  # a re-send waits its turn again
                    self._cond.wait(pause)  # a new report (submit) ends it early
                    pause = min(pause * 2, RESEND_S)
                continue
            self.writing = False
            pause = RETRY_S
            with self._cond:
                if self._away:
                    log.info("%s: the host reads again", self.what)
                self._away = False
                self._last, self._sent_at = report, time.monotonic()
                if queued and self._queue and self._queue[0] is report:
                    self._queue.popleft()
                self._cond.notify_all()
