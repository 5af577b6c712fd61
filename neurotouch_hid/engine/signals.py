"""What the engine sets for the length of a run: its signal handlers, which hand their work to the
run's loop (:class:`~neurotouch_hid.engine.loop.Loop`), and the interpreter's thread switch
interval for real-time runs.

Source: Python's :mod:`signal` (handlers run in the main thread between bytecodes;
``signal.set_wakeup_fd`` writes each signal's number to a descriptor, so a ``select`` that sleeps
on it wakes) and :func:`sys.setswitchinterval`.
"""

from __future__ import annotations

import contextlib
import signal
import sys
import threading
from typing import TYPE_CHECKING, Callable, Iterator

if TYPE_CHECKING:
    from neurotouch_hid.engine.loop import Loop

#: The interpreter's thread switch interval (s) during real-time runs, instead of Python's 5 ms:
#: a thread waiting for the GIL (the pipeline, while the resting thread runs Python code) gets it
#: within 0.5 ms. Measured (benchmarks/bench_latency.py): p99 processing latency 3.4 -> 1.7 ms.
REALTIME_SWITCH_INTERVAL_S = 0.0005


@contextlib.contextmanager
def handled(loop: Loop, actions: dict[str, Callable[[], object]]) -> Iterator[None]:
    """While the block runs, each signal named in ``actions`` (``SIGTERM``, ``SIGHUP``,
    ``SIGTSTP``; one the platform lacks is left out) calls its action in the loop's thread, and
    every signal wakes the loop (its pipe is the wakeup descriptor); the handlers before are put
    back after. ``SIGTERM``'s action is called in the handler itself (a stop is safe from one).
    Nothing is installed outside the main thread (signals go to the main thread only)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    wakeup = signal.set_wakeup_fd(loop.wakeup_fd)
    previous = {}
    for name, action in actions.items():
        number = getattr(signal, name, None)
        if number is None:
            continue
        if number == signal.SIGTERM:
            handler = lambda *_, action=action: action()  # noqa: E731
        else:
            handler = lambda *_, action=action: loop.call_soon(action)  # noqa: E731
        previous[number] = signal.signal(number, handler)
    try:
        yield
    finally:
        for number, handler in previous.items():
            signal.signal(number, handler)
        signal.set_wakeup_fd(wakeup)


@contextlib.contextmanager
def switch_interval(realtime: bool) -> Iterator[None]:
    """While the block runs, a real-time run's switch interval (:data:`REALTIME_SWITCH_INTERVAL_S`)."""
    previous = sys.getswitchinterval()
    if realtime:
        sys.setswitchinterval(min(previous, REALTIME_SWITCH_INTERVAL_S))
    try:
        yield
    finally:
        sys.setswitchinterval(previous)
