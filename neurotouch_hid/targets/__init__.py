"""The devices the system sees, fed from the controller state, behind one subscriber.

A :class:`~neurotouch_hid.core.stages.Target` is one device (the uinput pad, keyboard and mouse, a
UHID device, a USB gadget's function, ...); :class:`TargetOutputs` is the one
:class:`~neurotouch_hid.core.stages.Subscriber` over a run's targets, whatever the output: each
window's changed state goes to every target (each writes only what changed for it), a profile
switch neutralises and prepares them all, and :meth:`TargetOutputs.close` sends every target its
neutral report before any is removed, releasing each even when another fails. What games and
hosts send back (rumble, player LEDs: :class:`~neurotouch_hid.core.stages.Feedback`) is read on the
run's loop (:class:`~neurotouch_hid.engine.loop.Loop`, which sleeps in ``select`` on the targets'
:meth:`~neurotouch_hid.core.stages.Target.fileno` among the run's other descriptors, so nothing runs
at rest; a target whose device is made later, the uinput pad when a profile first drives it, is
watched from its :meth:`~neurotouch_hid.core.stages.Target.prepare` on), is told to the user (the
gel has no motor, no LED) and is forwarded (the merged pads' rumble). The wire formats are
:mod:`neurotouch_hid.targets.reports`; docs/architecture.md, "Targets and inputs".
"""

from __future__ import annotations

import contextlib
import dataclasses
import logging
import threading
import time
from typing import TYPE_CHECKING, Callable, Iterable

from neurotouch_hid.core.controller import ControllerState, Feedback

if TYPE_CHECKING:
    from neurotouch_hid.core.stages import Target, WindowRecord
    from neurotouch_hid.engine.loop import Loop
    from neurotouch_hid.mapping.profile import Profile

log = logging.getLogger(__name__)

#: Feedback lines of one source are told to the user at most this often (s): a game may send its
#: rumble every frame, with new magnitudes each time (:class:`FeedbackLines`).
FEEDBACK_REPEAT_S = 1.0


#: The boot keyboard's LED bits, lowest first (HID Usage Tables, LED page: Num Lock 1 ... Kana 5).
KEYBOARD_LEDS = ("Num Lock", "Caps Lock", "Scroll Lock", "Compose", "Kana")


def describe_feedback(feedback: Feedback) -> str:
    """One line for the user about ``feedback``: what was asked, that the gel cannot do it, and
    which target received it, e.g. ``rumble (the gel has no motor): strong 0.50 weak 0.25 for
    200 ms, on UHID joystick``."""
    where = f", on {feedback.source}" if feedback.source else ""
    if feedback.kind == "rumble":
        if feedback.strong == 0 and feedback.weak == 0:
            what = "stop"
        else:
            what = f"strong {feedback.strong:.2f} weak {feedback.weak:.2f}"
            what += "" if feedback.duration_ms is None else f" for {feedback.duration_ms} ms"
        return f"rumble (the gel has no motor): {what}{where}"
    if feedback.kind == "led":
        return f"player LED (the gel has none): pattern {feedback.led}{where}"
    if feedback.kind == "lightbar":
        return f"light bar (the gel has none): colour #{(feedback.led or 0) & 0xFFFFFF:06x}{where}"
    if feedback.kind == "keyboard_leds":
        lit = [name for bit, name in enumerate(KEYBOARD_LEDS) if (feedback.led or 0) >> bit & 1]
        return f"keyboard LEDs (the gel has none): {', '.join(lit) or 'all off'}{where}"
    return f"{feedback.kind} (not handled){where}"


class FeedbackLines:
    """The user's lines about feedback, bounded: per source (the target that received it), at most
    one line per ``repeat_s``; the lines held back meanwhile are counted, and the next line of that
    source says how many (``... (3 more since the last line)``). So a game that rumbles every frame
    gives a line a second, not a hundred, whatever the magnitudes.

    Args:
        say: where a line goes.
        repeat_s: the least time between two lines of one source (s).
        clock: the time (s), ``time.monotonic`` by default (a test's own).
    """

    def __init__(
        self,
        say: Callable[[str], None],
        repeat_s: float = FEEDBACK_REPEAT_S,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.say, self.repeat_s, self.clock = say, repeat_s, clock
        self._told: dict[str, tuple[float, int]] = {}  # source -> (when its last line was said, lines held back)

    def tell(self, feedback: Feedback) -> None:
        """Say ``feedback`` (:func:`describe_feedback`) unless its source had a line less than
        ``repeat_s`` ago (then it is counted). Raises what ``say`` raises (counted as said)."""
        now, source = self.clock(), feedback.source
        said_at, held = self._told.get(source, (None, 0))
        if said_at is not None and now - said_at < self.repeat_s:
            self._told[source] = (said_at, held + 1)
            return
        self._told[source] = (now, 0)
        line = describe_feedback(feedback)
        self.say(line if not held else f"{line} ({held} more since the last line)")


class TargetOutputs:
    """The run's targets as one :class:`~neurotouch_hid.core.stages.Subscriber`.

    Args:
        targets: the devices, in the order they are written; at least one. They are owned from
            here on: :meth:`close` closes them (also when this constructor fails).
        say: one line for the user per feedback (:func:`describe_feedback`; of one source at most
            one per :data:`FEEDBACK_REPEAT_S`, :class:`FeedbackLines`); default: the log.
        forward: called with every :class:`~neurotouch_hid.core.stages.Feedback` too (e.g. the merged
            pads' rumble, :meth:`~neurotouch_hid.core.stages.Merge.feedback`), in the loop's thread.
        loop: where the targets' readable sides wait (the driver's
            :class:`~neurotouch_hid.engine.loop.Loop`, served by the run's main thread); None: a
            loop of its own, in a thread (``nt-feedback``).

    Thread-safe: :meth:`close` may come from a signal handler's thread while :meth:`write` runs.
    """

    #: Draws no markers (:class:`~neurotouch_hid.core.stages.Subscriber`).
    wants_markers = False

    def __init__(
        self,
        targets: Iterable[Target],
        *,
        say: Callable[[str], None] | None = None,
        forward: Callable[[Feedback], None] | None = None,
        loop: Loop | None = None,
    ) -> None:
        from neurotouch_hid.engine.loop import Loop

        self.targets: list[Target] = list(targets)
        self.say = say or log.info
        self.forward = forward
        self.feedbacks = 0  # feedback values received (rumble, LED)
        self._lock = threading.RLock()
        self._closed = False
        self._own_loop = loop is None
        self._loop = loop if loop is not None else Loop()
        self._lines = FeedbackLines(self.say)
        self._watched: dict[int, int] = {}  # target index -> its registered descriptor
        self._given_up: set[int] = set()  # targets whose reading failed: no longer read
        try:
            self._watch()
            if self._own_loop:
                self._loop.run_in_thread("nt-feedback")
        except BaseException:
            self.close()
            raise

    def publish(self, record: WindowRecord) -> None:
        """A window's record: its state written to every target when it changed."""
        if record.state_changed:
            self.write(record.state)

    def write(self, state: ControllerState) -> None:
        """``state`` to every target (each sends only what changed for it); nothing after :meth:`close`."""
        with self._lock:
            if self._closed:
                return
            for target in self.targets:
                target.write(state)

    def neutralise(self) -> None:
        """Every target's neutral report; all are tried, the first failure is raised after."""
        self._each(lambda target: target.neutralise())

    def prepare(self, profile: Profile) -> None:
        """Every target readied for ``profile`` (after :meth:`neutralise`); a device made or
        replaced meanwhile is watched from now on."""
        try:
            self._each(lambda target: target.prepare(profile))
        finally:
            with self._lock:
                if not self._closed:
                    self._loop.call_soon(self._watch)  # the loop looks at the descriptors again

    def _watch(self) -> None:
        """Register each target's readable side on the loop, where it changed since the last look
        (the loop's thread, or the constructor before the loop serves it)."""
        if self._closed:
            return
        for index, target in enumerate(self.targets):
            fd = None if index in self._given_up else target.fileno()
            if self._watched.get(index) == fd:
                continue
            if index in self._watched:
                self._loop.remove_reader(self._watched.pop(index))
            if fd is not None:
                self._loop.add_reader(fd, lambda index=index: self._read_feedback(index))
                self._watched[index] = fd

    def _unwatch(self) -> None:
        for fd in self._watched.values():
            self._loop.remove_reader(fd)
        self._watched.clear()

    def close(self) -> None:
        """Stop reading feedback, send every target its neutral report, then close each (neutral
        again, then removed). Every target is released even when another fails; the first failure
        is raised after. Idempotent."""
        with self._lock:
            if self._closed:
                return
            self._closed = True
        with contextlib.suppress(Exception):  # (a loop already closed: nothing is watched)
            self._loop.call_and_wait(self._unwatch)
        if self._own_loop:
            self._loop.close()
        errors = self._try_each(lambda target: target.neutralise())
        errors += self._try_each(lambda target: target.close())
        if errors:
            raise errors[0]

    def _each(self, action: Callable[[Target], None]) -> None:
        with self._lock:
            if self._closed:
                return
            errors = self._try_each(action)
        if errors:
            raise errors[0]

    def _try_each(self, action: Callable[[Target], None]) -> list[Exception]:
        errors = []
        for target in self.targets:
            try:
                action(target)
            except Exception as exc:  # the next target must still be released
                log.warning("%s: %s", target.what, exc)
                errors.append(exc)
        return errors

    def _read_feedback(self, index: int) -> None:
        """The loop: target ``index``'s side is readable: let it read and answer what arrived, and
        tell the user. A target whose reading fails is no longer read; a ``say`` or ``forward``
        that fails is logged: the other targets must still be read."""
        if self._closed:
            return
        target = self.targets[index]
        try:
            received = target.feedback()
        except Exception as exc:  # one device's failure stops only its own feedback
            log.warning("%s: reading what the host sent failed, no longer read: %s", target.what, exc)
            self._loop.remove_reader(self._watched.pop(index))
            self._given_up.add(index)
            return
        for feedback in received:  # a GET_REPORT, a driver binding: the targets must still be read
            self.feedbacks += 1
            try:
                self._lines.tell(feedback if feedback.source else dataclasses.replace(feedback, source=target.what))
            except Exception as exc:
                log.warning("%s: could not tell %s: %s", target.what, feedback, exc)
            if self.forward is not None:
                try:
                    self.forward(feedback)
                except Exception as exc:
                    log.warning("%s: could not forward %s: %s", target.what, feedback, exc)

    def __enter__(self) -> TargetOutputs:
        return self

    def __exit__(self, *exc_info) -> None:
        self.close()
