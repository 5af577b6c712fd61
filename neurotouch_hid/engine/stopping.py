"""A SIGTERM that comes before the run has started: a clean stop, not the default death.

``run`` makes its devices (the pad, the UHID device, the gadget's functions, the merged devices'
grabs) before the engine starts, and the engine's start may wait long: a first run's compile, a
camera waited for (``--wait``). A service manager's SIGTERM meanwhile (systemd's stop, a
user's ``kill``) must stop the driver as one during the run does: every device sent its
neutral report and removed, the merged devices let go, exit status 0 (``run``'s docs).
:class:`EarlyStop` is installed before the first device is made: until the engine installs its
own handler, a SIGTERM raises :class:`StopRequested` in the main thread (so a wait of any length
ends at once and everything opened is closed on the way out); from then on it only sets
:attr:`EarlyStop.requested`, which the engine reads when it starts.

Source: Python's :mod:`signal` (handlers run in the main thread, between bytecodes; a blocking
wait on a lock or ``select`` is interrupted, PEP 475).
"""

from __future__ import annotations

import signal
import threading


class StopRequested(BaseException):
    """A SIGTERM before the run started (a BaseException, like KeyboardInterrupt: no ``except
    Exception`` on the way out swallows it)."""


class EarlyStop:
    """SIGTERM's handler from before the first device to the engine's start (module docstring).
    A context manager; outside the main thread it installs nothing (signals go to the main
    thread only).

    Attributes:
        requested: set by every SIGTERM while installed.
    """

    def __init__(self) -> None:
        self.requested = threading.Event()
        self._raising = False
        self._previous = None
        self._installed = False

    def __enter__(self) -> EarlyStop:
        if threading.current_thread() is threading.main_thread():
            self._previous = signal.signal(signal.SIGTERM, self._handle)
            self._installed = True
            self._raising = True
        return self

    def _handle(self, signum: int, frame: object) -> None:
        self.requested.set()
        if self._raising:
            self._raising = False  # once: what runs on the way out is not interrupted again
            raise StopRequested()

    def quiet(self) -> None:
        """From now on a SIGTERM only sets :attr:`requested` (the engine has started, or the way
        out has begun)."""
        self._raising = False

    def __exit__(self, *exc_info: object) -> None:
        self._raising = False
        if self._installed:
            signal.signal(signal.SIGTERM, self._previous)
            self._installed = False
