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

A SIGTERM that comes while the main thread is importing a module (the first run imports the
pipeline and OpenCV after its first device is made) or running an object's finalizer is raised
only once that is over (:func:`raise_later`).

Source: Python's :mod:`signal` (handlers run in the main thread, between bytecodes; a blocking
wait on a lock or ``select`` is interrupted, PEP 475); :mod:`importlib` (an import runs in the
frames of ``importlib._bootstrap``).
"""

from __future__ import annotations

import os
import signal
import threading
import types

#: How soon a signal deferred by :func:`raise_later` is delivered again (s).
RAISE_AGAIN_S = 0.02


def importing(frame: types.FrameType | None) -> bool:
    """Whether ``frame`` (a signal handler's: the main thread's current one) runs inside an
    import: one of its callers is in ``importlib._bootstrap``'s frames."""
    while frame is not None:
        if frame.f_code.co_filename.startswith("<frozen importlib._bootstrap"):
            return True
        frame = frame.f_back
    return False


def in_finalizer(frame: types.FrameType | None) -> bool:
    """Whether ``frame`` runs inside an object's ``__del__``: an exception raised there is printed
    as "Exception ignored" and dropped (Python's data model, ``object.__del__``), as a first run's
    compile does in llvmlite's finalizers."""
    while frame is not None:
        if frame.f_code.co_name == "__del__":
            return True
        frame = frame.f_back
    return False


def raise_later(frame: types.FrameType | None) -> bool:
    """Whether a signal handler that would raise to unwind the main thread must not raise at
    ``frame`` (where the signal interrupted it), but have the signal delivered again a moment later
    (:data:`RAISE_AGAIN_S`): inside a finalizer the exception would be dropped and the stop lost;
    inside an import it would leave the module half-made (OpenCV's loader then stays marked as
    loading, and every later ``import cv2`` in the process fails with "recursion is detected")."""
    return in_finalizer(frame) or importing(frame)


def deliver_again(signum: int) -> None:
    """The signal ``signum`` sent to this process again in :data:`RAISE_AGAIN_S` (from a timer
    thread), so that its handler raises outside the import or finalizer it first met
    (:func:`raise_later`)."""
    timer = threading.Timer(RAISE_AGAIN_S, os.kill, (os.getpid(), signum))
    timer.daemon = True
    timer.start()


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
        self._timer: threading.Timer | None = None
        self._sending = threading.Lock()  # the deferred signal is sent before the handler is put back, or not at all

    def __enter__(self) -> EarlyStop:
        if threading.current_thread() is threading.main_thread():
            self._previous = signal.signal(signal.SIGTERM, self._handle)
            self._installed = True
            self._raising = True
        return self

    def _handle(self, signum: int, frame: types.FrameType | None) -> None:
        self.requested.set()
        if not self._raising:
            return
        if raise_later(frame):  # raised once the import or finalizer is over: the signal again, a moment later
            self._timer = threading.Timer(RAISE_AGAIN_S, self._again)
            self._timer.daemon = True
            self._timer.start()
            return
        self._raising = False  # once: what runs on the way out is not interrupted again
        raise StopRequested()

    def _again(self) -> None:
        """The SIGTERM deferred by :func:`raise_later`, sent again while this handler still raises."""
        with self._sending:
            if self._raising and self._installed:
                os.kill(os.getpid(), signal.SIGTERM)

    def quiet(self) -> None:
        """From now on a SIGTERM only sets :attr:`requested` (the engine has started, or the way
        out has begun)."""
        self._raising = False

    def __exit__(self, *exc_info: object) -> None:
        self._raising = False
        if self._timer is not None:
            self._timer.cancel()
        with self._sending:
            if self._installed:
                signal.signal(signal.SIGTERM, self._previous)
                self._installed = False
