"""One loop for everything a run waits on that has a file descriptor: the merged devices' nodes,
the targets' readable sides (force feedback, a host's output reports), the control socket and
its clients, the signals (``signal.set_wakeup_fd``), and the few timers (the games watcher's
scan). It sleeps in one ``select`` (:mod:`selectors`) until one of them is ready or the next
timer is due, so nothing wakes at rest that has nothing to do (as hhd's one select loop does).

A :class:`Loop` is run by one thread at a time: the engine's main thread during the run
(:meth:`Loop.run_until`); a thread of its own before it (:meth:`Loop.run_in_thread`, e.g. while a
first run compiles and the devices already answer their hosts), which :meth:`Loop.run_until`
takes over. Other threads hand it work with :meth:`Loop.call_soon` (thread-safe, it wakes the
loop through a pipe).
"""

from __future__ import annotations

import collections
import heapq
import itertools
import logging
import os
import selectors
import threading
import time
from typing import Callable

log = logging.getLogger(__name__)


class Timer:
    """A callback due at a time on ``time.monotonic()`` (:meth:`Loop.call_at`); :meth:`cancel`
    before it runs and it does not."""

    __slots__ = ("when", "callback", "cancelled")

    def __init__(self, when: float, callback: Callable[[], None]) -> None:
        self.when = when
        self.callback = callback
        self.cancelled = False

    def cancel(self) -> None:
        """It will not run."""
        self.cancelled = True


class Loop:
    """A selector over file descriptors, timers, and callbacks from other threads.

    A callback that raises is logged (with its traceback) and the loop goes on: one device's
    failure never stops the others being served.
    """

    def __init__(self) -> None:
        self._selector = selectors.DefaultSelector()
        self._wake_r, self._wake_w = os.pipe()
        os.set_blocking(self._wake_r, False)
        os.set_blocking(self._wake_w, False)
        self._selector.register(self._wake_r, selectors.EVENT_READ, None)
        self._timers: list[tuple[float, int, Timer]] = []
        self._order = itertools.count()
        self._soon: collections.deque[Callable[[], None]] = collections.deque()
        self._lock = threading.Lock()  # the registrations and timers: any thread may add them
        self._stopping = False  # the thread running it is asked to return
        self._thread: threading.Thread | None = None  # its own thread (:meth:`run_in_thread`)
        self._runner: threading.Thread | None = None  # the thread running it now, if any
        self.closed = False

    # --- what it waits on --------------------------------------------------------------------
    def add_reader(self, fd: int, callback: Callable[[], None]) -> None:
        """Call ``callback()`` whenever ``fd`` is readable (replaces an earlier one for ``fd``)."""
        with self._lock:
            if fd in self._selector.get_map():
                self._selector.modify(fd, selectors.EVENT_READ, callback)
            else:
                self._selector.register(fd, selectors.EVENT_READ, callback)
        self.wake()

    def remove_reader(self, fd: int) -> None:
        """Stop watching ``fd`` (nothing if it was not watched, or the loop is closed)."""
        with self._lock:
            if fd >= 0 and not self.closed and fd in self._selector.get_map():
                self._selector.unregister(fd)

    def call_at(self, when: float, callback: Callable[[], None]) -> Timer:
        """Call ``callback()`` once at ``when`` (``time.monotonic()``, s)."""
        timer = Timer(when, callback)
        with self._lock:
            heapq.heappush(self._timers, (when, next(self._order), timer))
        self.wake()
        return timer

    def call_later(self, delay_s: float, callback: Callable[[], None]) -> Timer:
        """Call ``callback()`` once, ``delay_s`` (s) from now."""
        return self.call_at(time.monotonic() + delay_s, callback)

    def call_soon(self, callback: Callable[[], None]) -> None:
        """Call ``callback()`` in the loop's thread as soon as it can; from any thread."""
        self._soon.append(callback)
        self.wake()

    def call_and_wait(self, callback: Callable[[], None], timeout_s: float = 5.0) -> None:
        """Call ``callback()`` where it cannot meet the loop's own callbacks: in the loop's thread
        when another thread runs the loop now (waiting up to ``timeout_s`` for it), else here.
        What it raises is raised here."""
        runner = self._runner
        if runner is None or runner is threading.current_thread() or self.closed:
            callback()
            return
        done = threading.Event()
        failure: list[BaseException] = []

        def run() -> None:
            try:
                callback()
            except BaseException as exc:
                failure.append(exc)
            finally:
                done.set()

        self.call_soon(run)
        if not done.wait(timeout_s):
            log.warning("the loop did not run %r within %.0f s", callback, timeout_s)
        if failure:
            raise failure[0]

    def wake(self) -> None:
        """Make the loop look again (from any thread, a signal handler too)."""
        try:
            os.write(self._wake_w, b"w")
        except (BlockingIOError, OSError):  # full: it is woken already; closed: nothing to wake
            pass

    @property
    def next_timer(self) -> float | None:
        """When the next timer is due (``time.monotonic()``, s), None when none is set."""
        with self._lock:
            due = [when for when, _, timer in self._timers if not timer.cancelled]
        return min(due) if due else None

    @property
    def wakeup_fd(self) -> int:
        """The pipe's writing end, for ``signal.set_wakeup_fd``: a signal wakes the loop."""
        return self._wake_w

    # --- running it -------------------------------------------------------------------------
    def run_until(self, done: Callable[[], bool]) -> None:
        """Serve in this thread until ``done()`` (asked after every wake-up; make it true with
        :meth:`call_soon` or :meth:`wake`). A thread running the loop (:meth:`run_in_thread`) is
        stopped first: this thread takes over."""
        self.stop_thread()
        self._stopping = False
        self._runner = threading.current_thread()
        try:
            while not done() and not self._stopping and not self.closed:
                self.run_once()
        finally:
            self._runner = None

    def run_in_thread(self, name: str = "nt-loop") -> None:
        """Serve in a thread of its own until :meth:`stop_thread` or :meth:`run_until`."""
        if self._thread is not None:
            return
        self._stopping = False
        self._thread = threading.Thread(target=self._serve, name=name, daemon=True)
        self._thread.start()

    def stop_thread(self) -> None:
        """Stop the loop's own thread, if it runs (it finishes the callback it is in)."""
        thread, self._thread = self._thread, None
        if thread is None:
            return
        self._stopping = True
        self.wake()
        if thread is not threading.current_thread():
            thread.join(5.0)
            self._stopping = False

    def _serve(self) -> None:
        self._runner = threading.current_thread()
        try:
            while not self._stopping and not self.closed:
                self.run_once()
        finally:
            self._runner = None

    def run_once(self) -> None:
        """Wait until something is ready or a timer is due, then call what is."""
        with self._lock:
            while self._timers and self._timers[0][2].cancelled:
                heapq.heappop(self._timers)
            due = self._timers[0][0] if self._timers else None
        timeout = None if due is None else max(due - time.monotonic(), 0.0)
        if self._soon:
            timeout = 0.0
        try:
            ready = self._selector.select(timeout)
        except (OSError, ValueError):  # a descriptor closed under it: look again
            ready = []
            self._forget_closed()
        for key, _ in ready:
            if key.data is None:
                self._drain()
                continue
            self._call(key.data)
        while self._soon:
            self._call(self._soon.popleft())
        now = time.monotonic()
        while True:
            with self._lock:
                if not self._timers or self._timers[0][0] > now:
                    break
                _, _, timer = heapq.heappop(self._timers)
            if not timer.cancelled:
                timer.cancelled = True
                self._call(timer.callback)

    def _drain(self) -> None:
        try:
            while os.read(self._wake_r, 512):
                pass
        except (BlockingIOError, OSError):
            pass

    def _forget_closed(self) -> None:
        with self._lock:
            for fd in list(self._selector.get_map()):
                try:
                    os.fstat(fd)
                except OSError:
                    self._selector.unregister(fd)

    @staticmethod
    def _call(callback: Callable[[], None]) -> None:
        try:
            callback()
        except Exception:
            log.exception("the loop's callback %r failed", callback)

    def close(self) -> None:
        """Stop its thread and close the selector; idempotent. The wake-up pipe stays open until
        the loop is collected: a late :meth:`wake` (a stop after the run, a signal) then writes
        into its own pipe, never into a descriptor number the process reused meanwhile."""
        if self.closed:
            return
        self.stop_thread()
        self.closed = True
        self._selector.close()

    def __del__(self) -> None:
        for fd in (getattr(self, "_wake_r", None), getattr(self, "_wake_w", None)):
            if fd is not None:
                try:
                    os.close(fd)
                except OSError:
                    pass
