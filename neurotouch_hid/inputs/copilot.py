"""The copilot: a profile's ``copilot:`` devices merged into the gel's pad (a
:class:`~neurotouch_hid.core.stages.Merge`).

:meth:`Copilot.start` opens and grabs every device the profile names that is there
(:mod:`neurotouch_hid.inputs.match`, :class:`~neurotouch_hid.inputs.device.MergedInput`) and waits
on a loop (:class:`~neurotouch_hid.engine.loop.Loop`: the driver's, which the run's main thread
serves, or one of its own in a thread) for the merged devices' nodes and an inotify descriptor
watching ``/dev/input`` (and its ``by-id``/``by-path`` folders): nothing runs while nobody touches
a merged device and no device comes or goes (no polling), save the two timers below, each only
while it is needed. When a merged device's controls change (at its SYN_REPORT) the loop calls
``on_input``; the engine then publishes :meth:`Copilot.merge` of the gel's last state at once.

Hot-plug: a device that goes away (its read fails with ENODEV) is closed and its controls count as
neutral at once (``on_input`` is called, so the pad lets go of what it held); a device named but
missing, at start or since, is waited for: each new node under ``/dev/input`` (inotify IN_CREATE,
and IN_ATTRIB when udev sets its permissions) is matched again, so a device plugged back in, or a
new one with the same name, rejoins. After a device goes away the devices already there are
matched again at once (another device of the same name is taken). A device another program grabbed
(EVIOCGRAB fails with EBUSY) is tried again every :data:`BUSY_RETRY_S` while it is: that program
letting go makes no inotify event. :meth:`Copilot.stop` releases every grab and closes everything;
the merged controls are neutral from then on.

Rumble: a game may play several effects at once on the gel's pad. Each playing one is kept (by the
effect id the sender gives, its end time from its duration); the merged pads play the strongest of
them (each motor's magnitude, the largest among them), uploaded again when that changes, as an
effect changes it or ends (a timer at the next end while one has an end), and stopped
when none plays.

Library: inotify_simple (inotify(7)); python-evdev for the devices.
"""

from __future__ import annotations

import collections
import contextlib
import errno
import logging
import os
import threading
import time
from pathlib import Path
from typing import TYPE_CHECKING, Callable, Sequence

from neurotouch_hid.inputs.device import GONE_ERRNOS, MergedInput
from neurotouch_hid.inputs.hide import Hider, may_hide
from neurotouch_hid.inputs.match import INPUT_DIR, STABLE_DIRS, SYSFS_INPUT, InputInfo, input_devices, matches
from neurotouch_hid.mapping.merge import merge_state

if TYPE_CHECKING:
    from neurotouch_hid.core.controller import ControllerState
    from neurotouch_hid.core.stages import Feedback
    from neurotouch_hid.engine.loop import Loop, Timer
    from neurotouch_hid.mapping.profile import CopilotDevice, Profile

log = logging.getLogger(__name__)

#: A device another program grabbed (EBUSY) is tried again this often (s) while it is: letting go of
#: a grab makes no inotify event, and 1.5 s is a short wait for a user who just quit that program
#: while an open-and-grab attempt (two syscalls) that often costs nothing. No time-out otherwise.
BUSY_RETRY_S = 1.5

#: (strong, weak magnitudes 0..1, end on time.monotonic() or None: until stopped) of a playing effect.
_Effect = tuple[float, float, float | None]


class Copilot:
    """A profile's ``copilot:`` devices, read, grabbed and combined with the gel's state.

    Args:
        devices: the profile's entries, in order (combined in that order, :func:`~neurotouch_hid.
            mapping.merge.merge_state`).
        say: one line for the user when a device is merged, goes away or cannot be opened.
        input_dir, sysfs: where the nodes and their descriptions are (tests point elsewhere).
        hider: moves a merged device's nodes out of ``/dev`` while merged, so that games do not
            list it (:mod:`~neurotouch_hid.inputs.hide`; root only); None: grabbed only.
        unhidden: called with each device merged without being hidden (the note for the user).
        loop: where its descriptors wait (the driver's :class:`~neurotouch_hid.engine.loop.Loop`);
            None: a loop of its own, in a thread (``nt-copilot``).
    """

    def __init__(
        self,
        devices: Sequence[CopilotDevice],
        *,
        say: Callable[[str], None] = log.warning,
        input_dir: Path = INPUT_DIR,
        sysfs: Path = SYSFS_INPUT,
        hider: Hider | None = None,
        unhidden: Callable[[InputInfo], None] = lambda info: None,
        loop: Loop | None = None,
    ) -> None:
        self._specs = list(devices)
        self._say = say
        self._input_dir = Path(input_dir)
        self._sysfs = Path(sysfs)
        self._lock = threading.Lock()
        self._open: list[MergedInput | None] = [None] * len(self._specs)
        self._failed: dict[str, str] = {}  # node -> the last reason it could not be opened (said once)
        self._loop = loop
        self._own_loop = False
        self._started = False  # grabbed and watched (:meth:`grab`), until :meth:`stop`
        self._timer: Timer | None = None  # the next effect's end or busy device's retry
        self._stopping = threading.Event()
        self._inotify = None
        self._watches: dict[int, Path] = {}
        self._on_input: Callable[[], None] = lambda: None
        self._hider = hider
        self._unhidden = unhidden
        self._busy: set[str] = set()  # nodes another program holds (EBUSY at the last scan)
        self._retry_at = 0.0  # when to try them again (time.monotonic())
        self._rumble_lock = threading.Lock()
        self._effects: dict[int | None, _Effect] = {}  # the effects playing, by the sender's id
        self._rumbling: _Effect | None = None  # what the merged pads were given last
        self._senders: dict[int, _RumbleSender] = {}  # each merged device's, by id(device)

    # --- the Merge seam ------------------------------------------------------------------------
    def grab(self) -> None:
        """Watch ``/dev/input``, open and grab (and hide) what is there, wait for them on the loop;
        nothing when that was done. Called before the pad exists (``run_driver``): a game that
        lists controllers at its start sees the gel's pad only."""
        if self._started:
            return
        from inotify_simple import INotify

        from neurotouch_hid.engine.loop import Loop

        self._stopping.clear()
        if self._loop is None or self._own_loop:
            self._own_loop = True
            self._loop = Loop()
        self._inotify = INotify(nonblocking=True)
        self._watch(self._input_dir)
        for sub in STABLE_DIRS:
            self._watch(self._input_dir / sub)
        self._started = True
        self._scan()
        self._loop.add_reader(self._inotify.fileno(), lambda: self._guarded(self._on_notify))
        self._schedule()
        if self._own_loop:
            self._loop.run_in_thread("nt-copilot")

    def start(self, on_input: Callable[[], None]) -> None:
        """:meth:`grab` (if not done yet), then call ``on_input`` whenever a merged device's
        controls change or a device comes or goes."""
        self._on_input = on_input
        self.grab()

    def merge(self, gel: ControllerState) -> ControllerState:
        """``gel`` combined with every merged device's controls, in the profile's order."""
        with self._lock:
            levels = [(d.levels, spec.policies) for spec, d in zip(self._specs, self._open) if d is not None]
        return merge_state(gel, levels) if levels else gel

    def feedback(self, request: Feedback) -> None:
        """A game's rumble on the pad, played on every merged device that can rumble.

        Args:
            request: a ``"rumble"`` plays its ``effect`` (the game's effect id on the pad,
                several may play at once; None: the sender's requests are one effect, each
                replacing the last) with its magnitudes (0..1) for its ``duration_ms`` (ms; None
                or 0: until it is stopped); magnitudes 0 stop it; any other kind is ignored.

        The merged devices play the strongest of the effects playing (:meth:`_update_rumble`).
        A failure is logged, never raised: the game's request was answered already.
        """
        if request.kind != "rumble":
            return
        now, effect = time.monotonic(), request.effect
        with self._rumble_lock:
            first = self._next_effect_end()
            if request.strong <= 0 and request.weak <= 0:
                self._effects.pop(effect, None)
            else:
                end = now + request.duration_ms / 1000 if request.duration_ms else None
                self._effects[effect] = (min(request.strong, 1.0), min(request.weak, 1.0), end)
            self._update_rumble(now)
            sooner = self._next_effect_end()
        if sooner is not None and (first is None or sooner < first):
            self._nudge()  # the timer is past this effect's end: set again, to its end

    def post(self, request: Feedback) -> None:
        """Play ``request`` (:meth:`feedback`) on the copilot's loop, after what the loop is doing
        (the feedback path that received it), and return at once; played here when the copilot
        is not started."""
        loop = self._loop
        if not self._started or loop is None:
            self.feedback(request)
            return
        loop.call_soon(lambda: self.feedback(request))

    def stop(self) -> None:
        """Stop waiting for the devices, release every grab, close every node; idempotent."""
        self._stopping.set()
        loop = self._loop
        if self._started and loop is not None:
            with contextlib.suppress(Exception):  # (a loop closed already: nothing waits)
                loop.call_and_wait(self._unwatch)
            if self._own_loop:
                loop.close()
        self._started = False
        deadline = time.monotonic() + _RumbleSender.SETTLE_S
        for sender in list(self._senders.values()):  # the last rumble written before the stop
            sender.settle(deadline)
        with self._lock:
            for i, device in enumerate(self._open):
                if device is not None:
                    self._open[i] = None
                    try:
                        self._let_go(device)
                    except Exception:  # the other devices are let go all the same
                        log.exception("could not let %s go", device.spec.device)
        with self._rumble_lock:
            self._effects.clear()
            self._rumbling = None
        if self._hider is not None:
            self._hider.restore_all()
        if self._inotify is not None:
            with contextlib.suppress(OSError):
                self._inotify.close()
            self._inotify = None

    def status(self) -> tuple[tuple[str, ...], tuple[str, ...]]:
        """(the devices merged now, the devices waited for), as the profile names them."""
        with self._lock:
            merged = tuple(s.device for s, d in zip(self._specs, self._open) if d is not None)
            missing = tuple(s.device for s, d in zip(self._specs, self._open) if d is None)
        return merged, missing

    # --- the thread ----------------------------------------------------------------------------
    def _watch(self, folder: Path) -> None:
        from inotify_simple import flags

        # a node created or moved in, or its permissions set (udev's chmod after devtmpfs made it)
        mask = flags.CREATE | flags.ATTRIB | flags.MOVED_TO
        try:
            self._watches[self._inotify.add_watch(str(folder), mask)] = folder
        except OSError:
            pass  # by-id/ appears with the first device that has one: watched from then on

    def _scan(self, skip: frozenset[str] = frozenset()) -> bool:
        """Open and grab each missing device that is there now (a node of ``skip`` is not tried:
        a device that just went away, whose node udev has not removed yet); returns whether any
        joined. Of several nodes matching one entry the first that opens is taken. The nodes
        another program holds (EBUSY) are remembered, to be tried again."""
        with self._lock:
            missing = [i for i, d in enumerate(self._open) if d is None]
            taken = {d.info.path for d in self._open if d is not None}
        busy: set[str] = set()
        joined = False
        there = input_devices(self._input_dir, self._sysfs) if missing else []
        infos = [info for info in there if info.path not in taken and info.path not in skip]
        for i in missing:
            spec = self._specs[i]
            for info in [info for info in infos if matches(spec.device, info)]:
                device = self._open_one(spec, info, busy)
                if device is not None:
                    break
            else:
                continue
            infos.remove(info)
            with self._lock:
                self._open[i] = device
            self._loop.add_reader(
                device.fd, lambda i=i, device=device: self._guarded(lambda: self._on_device(i, device))
            )
            joined = True
            self._say(f"merged {spec.device} ({info.path}) into the pad")
            if self._hider is not None:
                self._hider.hide(info.path)
            else:
                self._unhidden(info)
        self._busy = busy
        if busy:
            self._retry_at = time.monotonic() + BUSY_RETRY_S
        if joined:
            with self._rumble_lock:
                self._rumbling = None  # a device that joined is given the rumble playing now, if any
                self._update_rumble(time.monotonic())
        return joined

    def _open_one(self, spec: CopilotDevice, info: InputInfo, busy: set[str]) -> MergedInput | None:
        try:
            device = MergedInput(spec, info)
        except OSError as exc:
            reason = exc.strerror or str(exc)
            if exc.errno == errno.EBUSY:
                busy.add(info.path)
            if self._failed.get(info.path) != reason:
                self._failed[info.path] = reason
                hint = " (another program grabbed it)" if exc.errno == errno.EBUSY else ""
                self._say(f"cannot merge {spec.device} ({info.path}): {reason}{hint}; waiting for it")
            return None
        self._failed.pop(info.path, None)
        return device

    def _unwatch(self) -> None:
        """Nothing of this copilot waits on the loop any more (in the loop's thread)."""
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None
        if self._inotify is not None:
            self._loop.remove_reader(self._inotify.fileno())
        with self._lock:
            for device in self._open:
                if device is not None:
                    self._loop.remove_reader(device.fd)

    def _guarded(self, step: Callable[[], bool]) -> None:
        """One of the loop's calls: ``step()`` (whether the merged controls changed), the rumble's
        effects that ended dropped, the timer set again, ``on_input`` when they changed. A bug
        here must not leave a device grabbed and silent: every device is let go."""
        if self._stopping.is_set():
            return
        try:
            changed = step()
            with self._rumble_lock:
                if self._effects:
                    self._update_rumble(time.monotonic())  # an effect may have ended
            self._schedule()
        except Exception:
            log.exception("the copilot stopped reading its devices; they are released")
            with self._lock:
                devices, self._open = [d for d in self._open if d is not None], [None] * len(self._specs)
            for device in devices:
                self._loop.remove_reader(device.fd)
                self._let_go(device)
            changed = True
        if changed and not self._stopping.is_set():
            self._on_input()

    def _on_notify(self) -> bool:
        """The loop: nodes appeared under ``/dev/input`` (or their permissions changed)."""
        from inotify_simple import flags

        events = list(self._inotify.read(timeout=0))
        for event in events:
            folder = self._watches.get(event.wd)
            if folder == self._input_dir and event.name in STABLE_DIRS and event.mask & flags.CREATE:
                self._watch(folder / event.name)
        if events and self._hider is not None:
            self._hider.rehide()  # a hidden node made again: games still list one pad
        return bool(events) and self._scan()

    def _on_device(self, index: int, device: MergedInput) -> bool:
        """The loop: a merged device's node is readable (its events, or its going away)."""
        if self._open[index] is not device:
            return False
        gone: set[str] = set()
        fd = device.fd  # (a device let go has none: -1)
        changed = self._read(index, device, gone)
        if gone:  # another device of the same name may be there already: taken at once
            self._loop.remove_reader(fd)
            changed |= self._scan(frozenset(gone))
        return changed

    def _on_timer(self) -> bool:
        """The loop: a busy device's retry is due, or a playing effect ends (``_guarded`` then
        drops it)."""
        self._timer = None
        if self._busy and time.monotonic() >= self._retry_at:
            return self._scan()
        return False

    def _schedule(self) -> None:
        """The loop's timer for this copilot at :meth:`_due` (none when nothing is due)."""
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None
        due = self._due()
        if due is not None and self._started and not self._stopping.is_set():
            self._timer = self._loop.call_at(due, lambda: self._guarded(self._on_timer))

    def _due(self) -> float | None:
        """When the loop must call again (``time.monotonic()``): None (until a node or inotify is
        readable) unless a device is busy (:data:`BUSY_RETRY_S`) or a playing effect ends."""
        with self._rumble_lock:
            due = [end for end in (self._next_effect_end(),) if end is not None]
        if self._busy:
            due.append(self._retry_at)
        return min(due) if due else None

    def _read(self, index: int, device: MergedInput, gone: set[str]) -> bool:
        """Read ``device``; one that fails is let go (its node added to ``gone``)."""
        try:
            return device.read()
        except OSError as exc:
            with self._lock:
                self._open[index] = None
            self._let_go(device)
            gone.add(device.info.path)
            why = "went away" if exc.errno in GONE_ERRNOS else f"failed ({exc.strerror or exc})"
            self._say(f"{device.spec.device} {why}: its controls are released; waiting for it to come back")
            return True

    # --- rumble ------------------------------------------------------------------------------------
    def _next_effect_end(self) -> float | None:
        """The soonest end of a playing effect (time.monotonic()), None if none has an end."""
        ends = [end for _, _, end in self._effects.values() if end is not None]
        return min(ends) if ends else None

    def _update_rumble(self, now: float) -> None:
        """The effects that ended are dropped; when the strongest of those left changed, the
        merged devices that can rumble are given it (:meth:`~neurotouch_hid.inputs.device.
        MergedInput.rumble`): each motor's largest magnitude, until the last of them ends (or
        until stopped when one plays until stopped); a stop when none plays. Called with
        ``_rumble_lock`` held. A device's failure is logged, never raised."""
        from neurotouch_hid.core.stages import Feedback

        self._effects = {k: e for k, e in self._effects.items() if e[2] is None or e[2] > now}
        playing: _Effect | None = None
        if self._effects:
            ends = [end for _, _, end in self._effects.values()]
            playing = (
                max(strong for strong, _, _ in self._effects.values()),
                max(weak for _, weak, _ in self._effects.values()),
                None if None in ends else max(ends),
            )
        if playing == self._rumbling:
            return
        self._rumbling = playing
        if playing is None:
            request = Feedback("rumble", source="copilot")
        else:
            strong, weak, end = playing
            duration = None if end is None else max(round((end - now) * 1000), 1)
            request = Feedback("rumble", strong, weak, duration, source="copilot")
        with self._lock:
            targets = [d for d in self._open if d is not None and d.can_rumble]
        for device in targets:
            sender = self._senders.get(id(device))
            if sender is None or sender.device is not device:
                sender = self._senders[id(device)] = _RumbleSender(device)
            sender.send(request)

    def _nudge(self) -> None:
        """Set the loop's timer again (an effect's end came sooner), in the loop's thread."""
        if self._started and self._loop is not None:
            self._loop.call_soon(self._schedule)

    def _let_go(self, device: MergedInput) -> None:
        """Release and close ``device``, then put its hidden nodes back (a gone device's are removed)."""
        self._senders.pop(id(device), None)
        device.close()
        if self._hider is not None:
            self._hider.restore(device.info.path)


class _RumbleSender:
    """One merged device's rumble, written off the loop.

    EVIOCSFF on a device made by uinput returns only once its owner has answered the upload, up
    to uinput's 30 s time-out (drivers/input/misc/uinput.c, ``uinput_request_send``): written on
    the run's one loop, a merged pad that never answers would hold up everything the loop serves,
    the gel's pad's own uploads from the game among them. A thread writes the request while one
    is pending and ends when none is: none at rest, at most one per device. Requests are written in
    order; while one is written at most :data:`PENDING` more wait, the oldest dropped first (a pad
    that never answers keeps only the latest magnitudes, which are what counts).
    """

    PENDING = 4
    #: How long a stop waits for the requests under way (s): a pad that answers takes
    #: milliseconds; one that never answers is let go without them.
    SETTLE_S = 1.0

    def __init__(self, device: MergedInput) -> None:
        self.device = device
        self._lock = threading.Lock()
        self._pending: collections.deque[Feedback] = collections.deque(maxlen=self.PENDING)
        self._busy = False
        self._idle = threading.Condition(self._lock)  # notified when the writer ends

    def send(self, request: Feedback) -> None:
        """Write ``request`` (:meth:`~neurotouch_hid.inputs.device.MergedInput.rumble`) soon, in
        this device's writer thread; returns at once."""
        with self._lock:
            self._pending.append(request)
            if self._busy:
                return
            self._busy = True
        threading.Thread(target=self._write, name="nt-rumble", daemon=True).start()

    def settle(self, deadline: float) -> None:
        """Wait until what was sent is written, or ``deadline`` (``time.monotonic()``) has come."""
        with self._idle:
            self._idle.wait_for(lambda: not self._busy, max(deadline - time.monotonic(), 0.0))

    def _write(self) -> None:
        while True:
            with self._lock:
                if not self._pending:
                    self._busy = False
                    self._idle.notify_all()
                    return
                request = self._pending.popleft()
            try:
                self.device.rumble(request)
            except Exception as exc:  # OSError from the kernel; whatever else, the game's request stands
                log.warning("could not rumble %s: %s", self.device.spec.device, exc)


class FeedbackRelay:
    """The pad's rumble, forwarded to the copilot of the profile in use.

    The pad exists before the run and outlives profile switches; the copilot is made per profile
    (:meth:`merge_for`, which the runtime calls at start and at each switch). Calling the relay
    with a :class:`~neurotouch_hid.core.stages.Feedback` hands it to that copilot's ``feedback``."""

    def __init__(
        self, say: Callable[[str], None] = log.warning, *, hide: bool | None = None, loop: Loop | None = None
    ) -> None:
        self._say = say
        self._loop = loop  # where each copilot waits (None: each a loop of its own)
        self.merge: Copilot | None = None
        self._hide = may_hide() if hide is None else hide
        self._told = False

    def merge_for(self, profile: Profile) -> Copilot | None:
        """The copilot of ``profile`` (None when it merges nothing), remembered for the rumble; it
        hides the merged devices from games where this process may (:func:`~neurotouch_hid.inputs.
        hide.may_hide`), else says once that a game may still list them."""
        if not profile.copilot:
            self.merge = None
            return None
        hider = Hider(guarded=True) if self._hide else None
        self.merge = Copilot(profile.copilot, say=self._say, hider=hider, unhidden=self._not_hidden, loop=self._loop)
        return self.merge

    def _not_hidden(self, info: InputInfo) -> None:
        if self._told:
            return
        self._told = True
        self._say(unhidden_note(info))

    def __call__(self, request: Feedback) -> None:
        """Hand ``request`` to the copilot in use (:meth:`Copilot.post`: played on its loop after
        the caller's turn); nothing when the profile merges nothing."""
        merge = self.merge
        if merge is not None:
            merge.post(request)


def unhidden_note(info: InputInfo | None = None) -> str:
    """What a user who is not root is told (once, and by ``doctor``): the merged devices are
    grabbed but not hidden, so a game that lists controllers at its start may still show them;
    how to avoid it (``info``: a merged device, whose USB ids the SDL variable then names)."""
    ids = f"0x{info.vendor:04x}/0x{info.product:04x}" if info is not None and info.vendor else "0xVVVV/0xPPPP"
    if os.geteuid() == 0:  # root, but /dev/input cannot be changed here (a container, a read-only /dev)
        why, fix = "/dev/input is not writable here, even as root", "give the driver a writable /dev"
    else:
        why, fix = "that needs root", "run the driver as root (a system service)"
    return (
        f"the merged devices are grabbed (silent to games) but not hidden ({why}): a game that "
        "lists controllers when it starts may still show the helper's pad as a second one; to avoid it, "
        f"{fix}, or start the game with SDL_GAMECONTROLLER_IGNORE_DEVICES={ids}"
    )
