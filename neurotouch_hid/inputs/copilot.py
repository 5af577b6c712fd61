"""The copilot: a profile's ``copilot:`` devices merged into the gel's pad (a :class:`~neurotouch_hid.stages.Merge`).

:meth:`Copilot.start` opens and grabs every device the profile names that is there
(:mod:`neurotouch_hid.inputs.match`, :class:`~neurotouch_hid.inputs.device.MergedInput`) and starts
one thread. The thread sleeps in ``select`` on the merged devices' nodes, an inotify descriptor
watching ``/dev/input`` (and its ``by-id``/``by-path`` folders) and a wake-up pipe: nothing runs
while nobody touches a merged device and no device comes or goes (no polling). When a merged
device's controls change (at its SYN_REPORT) the thread calls ``on_input``; the runtime then
publishes :meth:`Copilot.merge` of the gel's last state at once.

Hot-plug: a device that goes away (its read fails with ENODEV) is closed and its controls count as
neutral at once (``on_input`` is called, so the pad lets go of what it held); a device named but
missing, at start or since, is waited for: each new node under ``/dev/input`` (inotify IN_CREATE,
and IN_ATTRIB when udev sets its permissions) is matched again, so a device plugged back in, or a
new one with the same name, rejoins. :meth:`Copilot.stop` releases every grab and closes
everything; the merged controls are neutral from then on.

Library: inotify_simple (inotify(7)); python-evdev for the devices.
"""

from __future__ import annotations

import contextlib
import errno
import logging
import os
import select
import threading
from pathlib import Path
from typing import TYPE_CHECKING, Callable, Sequence

from neurotouch_hid.inputs.device import GONE_ERRNOS, MergedInput
from neurotouch_hid.inputs.hide import Hider, may_hide
from neurotouch_hid.inputs.match import INPUT_DIR, STABLE_DIRS, SYSFS_INPUT, InputInfo, input_devices, matches
from neurotouch_hid.mapping.merge import merge_state

if TYPE_CHECKING:
    from neurotouch_hid.controller import ControllerState
    from neurotouch_hid.mapping.profile import CopilotDevice, Profile
    from neurotouch_hid.stages import Feedback

log = logging.getLogger(__name__)


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
    ) -> None:
        self._specs = list(devices)
        self._say = say
        self._input_dir = Path(input_dir)
        self._sysfs = Path(sysfs)
        self._lock = threading.Lock()
        self._open: list[MergedInput | None] = [None] * len(self._specs)
        self._failed: dict[str, str] = {}  # node -> the last reason it could not be opened (said once)
        self._thread: threading.Thread | None = None
        self._stopping = threading.Event()
        self._wake: tuple[int, int] | None = None
        self._inotify = None
        self._watches: dict[int, Path] = {}
        self._on_input: Callable[[], None] = lambda: None
        self._hider = hider
        self._unhidden = unhidden

    # --- the Merge seam ------------------------------------------------------------------------
    def start(self, on_input: Callable[[], None]) -> None:
        """Watch ``/dev/input``, open and grab what is there, start the reading thread."""
        from inotify_simple import INotify

        self._on_input = on_input
        self._stopping.clear()
        self._inotify = INotify(nonblocking=True)
        self._watch(self._input_dir)
        for sub in STABLE_DIRS:
            self._watch(self._input_dir / sub)
        self._wake = os.pipe()
        self._scan()
        self._thread = threading.Thread(target=self._loop, name="nt-copilot", daemon=True)
        self._thread.start()

    def merge(self, gel: ControllerState) -> ControllerState:
        """``gel`` combined with every merged device's controls, in the profile's order."""
        with self._lock:
            levels = [(d.levels, spec.policies) for spec, d in zip(self._specs, self._open) if d is not None]
        return merge_state(gel, levels) if levels else gel

    def feedback(self, request: Feedback) -> None:
        """A game's rumble on the pad, played on every merged device that can rumble (a failure
        is logged, never raised: the game's request was answered already)."""
        with self._lock:
            targets = [d for d in self._open if d is not None and d.can_rumble]
        for device in targets:
            try:
                device.rumble(request)
            except OSError as exc:
                log.warning("could not rumble %s: %s", device.spec.device, exc)

    def stop(self) -> None:
        """Stop the thread, release every grab, close every node; idempotent."""
        self._stopping.set()
        if self._wake is not None:
            with contextlib.suppress(OSError):
                os.write(self._wake[1], b"x")
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(2.0)
        self._thread = None
        with self._lock:
            for i, device in enumerate(self._open):
                if device is not None:
                    self._let_go(device)
                    self._open[i] = None
        if self._hider is not None:
            self._hider.restore_all()
        if self._inotify is not None:
            with contextlib.suppress(OSError):
                self._inotify.close()
            self._inotify = None
        if self._wake is not None:
            for fd in self._wake:
                with contextlib.suppress(OSError):
                    os.close(fd)
            self._wake = None

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

    def _scan(self) -> bool:
        """Open and grab each missing device that is there now; returns whether any joined."""
        with self._lock:
            missing = [i for i, d in enumerate(self._open) if d is None]
            if not missing:
                return False
            taken = {d.info.path for d in self._open if d is not None}
        joined = False
        infos = [info for info in input_devices(self._input_dir, self._sysfs) if info.path not in taken]
        for i in missing:
            spec = self._specs[i]
            info = next((info for info in infos if matches(spec.device, info)), None)
            if info is None:
                continue
            device = self._open_one(spec, info)
            if device is None:
                continue
            infos.remove(info)
            with self._lock:
                self._open[i] = device
            joined = True
            self._say(f"merged {spec.device} ({info.path}) into the pad")
            if self._hider is not None:
                self._hider.hide(info.path)
            else:
                self._unhidden(info)
        return joined

    def _open_one(self, spec: CopilotDevice, info: InputInfo) -> MergedInput | None:
        try:
            device = MergedInput(spec, info)
        except OSError as exc:
            reason = exc.strerror or str(exc)
            if self._failed.get(info.path) != reason:
                self._failed[info.path] = reason
                hint = " (another program grabbed it)" if exc.errno == errno.EBUSY else ""
                self._say(f"cannot merge {spec.device} ({info.path}): {reason}{hint}; waiting for it")
            return None
        self._failed.pop(info.path, None)
        return device

    def _loop(self) -> None:
        try:
            self._serve()
        except Exception:  # a bug here must not leave a device grabbed and silent
            log.exception("the copilot stopped reading its devices; they are released")
            with self._lock:
                devices, self._open = [d for d in self._open if d is not None], [None] * len(self._specs)
            for device in devices:
                self._let_go(device)
            self._on_input()

    def _serve(self) -> None:
        from inotify_simple import flags

        wake = self._wake[0]
        notify = self._inotify.fileno()
        while not self._stopping.is_set():
            with self._lock:
                opened = {d.fd: (i, d) for i, d in enumerate(self._open) if d is not None}
            try:
                ready, _, _ = select.select([wake, notify, *opened], [], [])
            except (OSError, ValueError):  # a node closed under us: look again
                continue
            if self._stopping.is_set():
                break
            changed = False
            if notify in ready:
                events = list(self._inotify.read(timeout=0))
                for event in events:
                    folder = self._watches.get(event.wd)
                    if folder == self._input_dir and event.name in STABLE_DIRS and event.mask & flags.CREATE:
                        self._watch(folder / event.name)
                if events and self._hider is not None:
                    self._hider.rehide()  # a hidden node made again: games still list one pad
                if events:
                    changed |= self._scan()
            for fd in ready:
                if fd in opened:
                    changed |= self._read(*opened[fd])
            if changed and not self._stopping.is_set():
                self._on_input()

    def _read(self, index: int, device: MergedInput) -> bool:
        try:
            return device.read()
        except OSError as exc:
            gone = exc.errno in GONE_ERRNOS
            with self._lock:
                self._open[index] = None
            self._let_go(device)
            why = "went away" if gone else f"failed ({exc.strerror or exc})"
            self._say(f"{device.spec.device} {why}: its controls are released; waiting for it to come back")
            return True

    def _let_go(self, device: MergedInput) -> None:
        """Release and close ``device``, then put its hidden nodes back (a gone device's are removed)."""
        device.close()
        if self._hider is not None:
            self._hider.restore(device.info.path)


class FeedbackRelay:
    """The pad's rumble, forwarded to the copilot of the profile in use.

    The pad exists before the run and outlives profile switches; the copilot is made per profile
    (:meth:`merge_for`, which the runtime calls at start and at each switch). Calling the relay
    with a :class:`~neurotouch_hid.stages.Feedback` hands it to that copilot's ``feedback``."""

    def __init__(self, say: Callable[[str], None] = log.warning, *, hide: bool | None = None) -> None:
        self._say = say
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
        self.merge = Copilot(profile.copilot, say=self._say, hider=hider, unhidden=self._not_hidden)
        return self.merge

    def _not_hidden(self, info: InputInfo) -> None:
        if self._told:
            return
        self._told = True
        self._say(unhidden_note(info))

    def __call__(self, request: Feedback) -> None:
        merge = self.merge
        if merge is not None:
            merge.feedback(request)


def unhidden_note(info: InputInfo | None = None) -> str:
    """What a user who is not root is told (once, and by ``doctor``): the merged devices are
    grabbed but not hidden, so a game that lists controllers at its start may still show them;
    how to avoid it (``info``: a merged device, whose USB ids the SDL variable then names)."""
    ids = f"0x{info.vendor:04x}/0x{info.product:04x}" if info is not None and info.vendor else "0xVVVV/0xPPPP"
    return (
        "the merged devices are grabbed (silent to games) but not hidden (that needs root): a game that "
        "lists controllers when it starts may still show the helper's pad as a second one; to avoid it, "
        "run the driver as root (a system service), or start the game with "
        f"SDL_GAMECONTROLLER_IGNORE_DEVICES={ids}"
    )
